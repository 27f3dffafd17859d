// s2r batch (app/batch.h): plan, run, resume and summarise many captures.
#include "app/batch.h"

#include <fcntl.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <deque>
#include <functional>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "calibrate/calibration.h"
#include "capture/ground_truth.h"
#include "capture/session.h"
#include "app/html.h"
#include "core/atomic_file.h"
#include "core/json_fields.h"

namespace s2r::batch {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t") - b + 1);
}

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string out;
  for (size_t i = 0; i < v.size(); ++i) out += (i ? sep : "") + v[i];
  return out;
}

std::string utc_now() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

std::string host_name() {
  char buf[256] = {};
  if (gethostname(buf, sizeof buf - 1) != 0) return "?";
  return buf;
}

using html::number;

// The extra arguments a step may not carry: the batch sets them.
const std::set<std::string> kBatchFlags = {"--out", "--holdout", "--session", "--poses", "--calibration", "--report"};
// The steps whose extra arguments the options file may give, and their keys.
const std::map<std::string, std::string> kExtraKeys = {{"import", "import"},       {"calibrate", "calibrate"},
                                                       {"register", "register"},   {"reconstruct", "reconstruct"},
                                                       {"eval", "eval"},           {"export_args", "export"}};

bool exists_file(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

// The report a step wrote parses and names a stage.
std::string check_report(const fs::path& file) {
  auto j = parse_json_file(file);
  if (!j) return j.error().message;
  if (!j->is_object() || !j->contains("stage") || !(*j)["stage"].is_string()) return file.string() + ": no stage";
  return {};
}

std::string check_json(const fs::path& file) {
  auto j = parse_json_file(file);
  return j ? std::string() : j.error().message;
}

Result<json> read_json(const fs::path& file) { return parse_json_file(file); }

std::string status_path_state(const fs::path& dir) {
  auto j = read_json(dir / "status.json");
  if (!j || !j->is_object() || !(*j)["state"].is_string()) return "pending";
  return (*j)["state"].get<std::string>();
}

}  // namespace

Result<std::vector<std::string>> parse_steps(const std::string& csv) {
  std::set<std::string> chosen;
  std::stringstream ss(csv);
  std::string item;
  while (std::getline(ss, item, ',')) {
    item = trim(item);
    if (item.empty()) continue;
    if (std::find(all_steps().begin(), all_steps().end(), item) == all_steps().end())
      return fail(ErrorCode::invalid, "--steps: unknown step '" + item + "' (choose from " + join(all_steps(), ",") + ")");
    if (!chosen.insert(item).second) return fail(ErrorCode::invalid, "--steps: '" + item + "' given twice");
  }
  if (chosen.empty()) return fail(ErrorCode::invalid, "--steps: no step given (choose from " + join(all_steps(), ",") + ")");
  std::vector<std::string> out;
  for (const auto& s : all_steps())
    if (chosen.count(s)) out.push_back(s);
  return out;
}

Result<Options> parse_options(const std::string& text, const std::string& name) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    return fail(ErrorCode::format, name + ": not JSON: " + e.what());
  }
  if (!j.is_object()) return fail(ErrorCode::format, name + ": expected a JSON object");
  Options o;
  o.text = text;
  for (const auto& [key, v] : j.items()) {
    const std::string where = name + ": " + key;
    if (key == "holdout") {
      if (v.is_string()) o.holdout = v.get<std::string>();
      else if (v.is_number_integer()) o.holdout = std::to_string(v.get<int>());
      else return fail(ErrorCode::format, where + ": expected \"auto\", \"none\" or a frame list such as \"3,7\"");
      if (auto h = holdout_frames(o.holdout, 1 << 20); !h) return fail(ErrorCode::format, where + ": " + h.error().message);
    } else if (key == "heldout_views") {
      if (!v.is_number_integer() || v.get<int>() < 1) return fail(ErrorCode::format, where + ": expected an integer >= 1");
      o.heldout_views = v.get<int>();
    } else if (key == "export") {
      if (!v.is_string() || (v != "nerfstudio" && v != "colmap" && v != "gltf"))
        return fail(ErrorCode::format, where + ": expected \"nerfstudio\", \"colmap\" or \"gltf\"");
      o.export_format = v.get<std::string>();
    } else if (kExtraKeys.count(key)) {
      if (!v.is_array()) return fail(ErrorCode::format, where + ": expected an array of arguments");
      std::vector<std::string> args;
      for (const auto& a : v) {
        if (!a.is_string() && !a.is_number()) return fail(ErrorCode::format, where + ": arguments are strings or numbers");
        std::string s = a.is_string() ? a.get<std::string>() : a.dump();
        const std::string flag = s.substr(0, s.find('='));
        if (kBatchFlags.count(flag))
          return fail(ErrorCode::format, where + ": " + flag + " is set by the batch (every step's outputs go under RESULTS)");
        args.push_back(std::move(s));
      }
      o.extra[kExtraKeys.at(key)] = std::move(args);
    } else {
      return fail(ErrorCode::format, where + ": unknown key (known: holdout, heldout_views, export, import, calibrate, "
                                             "register, reconstruct, eval, export_args)");
    }
  }
  return o;
}

Result<Options> load_options(const fs::path& file) {
  if (file.empty()) {
    Options o;
    o.text = "{}";
    return o;
  }
  auto text = read_file(file);
  if (!text) return fail_with_context(text.error(), "--options");
  return parse_options(*text, file.string());
}

std::optional<std::string> capture_kind(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return std::nullopt;
  if (exists_file(dir / "session.json")) return "session";
  if (exists_file(dir / "transforms.json") || exists_file(dir / "transforms_train.json")) return "nerf";
  for (const char* f : {"cameras.txt", "cameras.bin", "sparse/0/cameras.txt", "sparse/0/cameras.bin"})
    if (exists_file(dir / f)) return "colmap";
  if ((exists_file(dir / "color/color_0.png") && exists_file(dir / "depth/depth_0.png")) ||
      (exists_file(dir / "rgb_0.png") && exists_file(dir / "depth_0.png")))
    return "realsense";
  if (exists_file(dir / "frame-000000.pose.txt") &&
      (exists_file(dir / "frame-000000.color.png") || exists_file(dir / "frame-000000.color.jpg")))
    return "7scenes";
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    if (n.size() > 8 && n.ends_with("_par.txt") && e.is_regular_file()) return "middlebury";
  }
  return std::nullopt;
}

Result<std::vector<Capture>> discover(const fs::path& root) {
  std::error_code ec;
  if (!fs::is_directory(root, ec)) return fail(ErrorCode::not_found, "'" + root.string() + "': no such folder");
  auto name_of = [](const fs::path& rel) {
    std::string n;
    for (char c : rel.generic_string()) n += (std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-') ? c : '_';
    return n;
  };
  std::vector<Capture> out;
  if (auto k = capture_kind(root)) {
    out.push_back({name_of(fs::absolute(root).lexically_normal().filename()), root, *k});
    if (out.back().name.empty()) out.back().name = "capture";
    return out;
  }
  std::function<void(const fs::path&, int)> walk = [&](const fs::path& dir, int depth) {
    std::vector<fs::path> subs;
    for (const auto& e : fs::directory_iterator(dir, ec))
      if (e.is_directory() && e.path().filename().string()[0] != '.') subs.push_back(e.path());
    std::sort(subs.begin(), subs.end());
    for (const auto& s : subs) {
      if (exists_file(s / "batch.json")) continue;  // a batch's results folder
      if (auto k = capture_kind(s)) {
        out.push_back({name_of(s.lexically_relative(root)), s, *k});
      } else if (depth < 3) {
        walk(s, depth + 1);
      }
    }
  };
  walk(root, 1);
  if (out.empty())
    return fail(ErrorCode::not_found, "'" + root.string() + "': no capture found (a session folder with session.json, "
                                      "or a data set: transforms.json, a COLMAP model, *_par.txt, RealSense colour+depth, 7-Scenes frames)");
  std::set<std::string> names;
  for (auto& c : out) {
    std::string n = c.name;
    for (int i = 2; names.count(n); ++i) n = c.name + "-" + std::to_string(i);
    c.name = n;
    names.insert(n);
  }
  return out;
}

Result<std::vector<int>> holdout_frames(const std::string& spec, int frames) {
  std::vector<int> out;
  if (spec == "none") return out;
  if (spec == "auto") {
    if (frames < 2) return out;
    for (int i = std::min(3, frames - 1); i < frames; i += 8) out.push_back(i);
    if (static_cast<int>(out.size()) >= frames) out.resize(frames - 1);
    return out;
  }
  std::stringstream ss(spec);
  std::string item;
  while (std::getline(ss, item, ',')) {
    item = trim(item);
    char* end = nullptr;
    const long v = std::strtol(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0' || v < 0)
      return fail(ErrorCode::invalid, "holdout: '" + item + "' is not a frame index (\"auto\", \"none\" or I,J,...)");
    if (v >= frames) return fail(ErrorCode::invalid, "holdout: frame " + item + " but the session has " + std::to_string(frames));
    out.push_back(static_cast<int>(v));
  }
  if (out.empty()) return fail(ErrorCode::invalid, "holdout: empty (\"auto\", \"none\" or I,J,...)");
  return out;
}

Result<CaptureState> capture_state(const Capture& c, const fs::path& dir) {
  CaptureState s;
  s.session = c.kind == "session" ? c.path : dir / "session";
  s.calibrated = exists_file(dir / "calibrate" / "calibration.json");
  s.registered = exists_file(dir / "register" / "poses.json");
  if (exists_file(s.session / "session.json")) {
    SessionLoadOptions lo;
    lo.check_images = false;
    auto sess = load_session(s.session, lo);
    if (!sess) return fail_with_context(sess.error(), "session");
    if (s.calibrated) {
      // A calibration that does not load is the calibrate step's to redo
      // (its outputs do not validate); here it only gives no table poses.
      auto cal = load_calibration(dir / "calibrate" / "calibration.json");
      s.table_poses = cal && cal->has_measured_angles(*sess);
    }
    s.frames = static_cast<int>(sess->frames.size());
    s.has_depth = sess->depth.has_value();
    s.has_poses = !sess->frames.empty();
    for (const auto& f : sess->frames) s.has_poses = s.has_poses && f.world_from_camera.has_value();
    if (!s.has_poses) s.has_poses = ground_truth_poses(s.session, sess->frames.size()).has_value();
    if (!s.has_depth)
      for (const auto& f : sess->frames) s.has_depth = s.has_depth || !f.depth.empty() || !f.points.empty();
  }
  if (exists_file(dir / "heldout" / "session.json")) {
    SessionLoadOptions lo;
    lo.check_images = false;
    auto held = load_session(dir / "heldout", lo);
    if (!held) return fail_with_context(held.error(), "held-out session");
    s.heldout = dir / "heldout";
    s.heldout_frames = static_cast<int>(held->frames.size());
  }
  return s;
}

Result<StepPlan> plan_step(const std::string& step, const Capture& c, const fs::path& dir, const CaptureState& st,
                           const Options& o) {
  StepPlan p;
  p.step = step;
  auto extra = [&](std::vector<std::string> args) {
    if (auto it = o.extra.find(step); it != o.extra.end()) args.insert(args.end(), it->second.begin(), it->second.end());
    return args;
  };
  auto pose_args = [&](std::vector<std::string>& args) {
    // The table's measured angles where the calibration has them (the
    // registration then only checks them), else the registration's poses.
    if (st.registered && !st.table_poses) args.insert(args.end(), {"--poses", (dir / "register" / "poses.json").string()});
    if (st.calibrated) args.insert(args.end(), {"--calibration", (dir / "calibrate" / "calibration.json").string()});
  };
  const std::string session = st.session.string();
  if (step == "import") {
    if (c.kind == "session") {
      p.needed = false;
      p.reason = "a session: read where it is";
      return p;
    }
    p.outputs = {"session"};
    std::vector<std::string> args = {"import", c.kind, c.path.string(), "--out", (dir / "session").string()};
    if (c.kind == "nerf" && exists_file(c.path / "transforms_train.json") && !exists_file(c.path / "transforms.json"))
      args.insert(args.end(), {"--split", "train"});
    p.commands.push_back(extra(args));
    if (c.kind == "nerf" && exists_file(c.path / "transforms_val.json")) {
      // The held-out split the eval step reads: NeRF-synthetic's val (never fitted).
      p.outputs.push_back("heldout");
      p.commands.push_back(extra({"import", "nerf", c.path.string(), "--split", "val", "--out", (dir / "heldout").string()}));
    }
    return p;
  }
  if (st.frames == 0)
    return fail(ErrorCode::not_found, "no session in '" + st.session.string() + "' (the import step makes it: add import to --steps)");
  if (step == "calibrate" || step == "register") {
    if (st.has_poses) {
      p.needed = false;
      p.reason = "the session's frames have poses (given, or the synthetic rig's truth)";
      return p;
    }
    if (step == "calibrate") {
      p.outputs = {"calibrate"};
      p.commands.push_back(extra({"calibrate", "markers", session, "--out", (dir / "calibrate" / "calibration.json").string(),
                                  "--report", (dir / "calibrate" / "report.json").string()}));
      return p;
    }
    if (!st.has_depth) {
      p.needed = false;
      p.reason = "no depth to register";
      return p;
    }
    p.outputs = {"register"};
    std::vector<std::string> args = {"register", session, "--out", (dir / "register").string()};
    if (st.calibrated) args.insert(args.end(), {"--calibration", (dir / "calibrate" / "calibration.json").string()});
    p.commands.push_back(extra(args));
    return p;
  }
  if (step == "reconstruct") {
    p.outputs = {"model"};
    std::vector<std::string> args = {"reconstruct", session, "--out", (dir / "model").string()};
    pose_args(args);
    if (st.heldout.empty()) {
      auto h = holdout_frames(o.holdout, st.frames);
      if (!h) return std::unexpected(h.error());
      if (!h->empty()) {
        std::vector<std::string> items;
        for (int i : *h) items.push_back(std::to_string(i));
        args.insert(args.end(), {"--holdout", join(items, ",")});
      }
    }
    p.commands.push_back(extra(args));
    return p;
  }
  if (step == "eval") {
    std::vector<int> frames;
    std::string eval_session = session;
    if (!st.heldout.empty()) {
      eval_session = st.heldout.string();
      const int n = std::min(o.heldout_views, st.heldout_frames);
      for (int i = 0; i < n; ++i) frames.push_back(static_cast<int>(static_cast<long>(i) * st.heldout_frames / n));
    } else {
      auto h = holdout_frames(o.holdout, st.frames);
      if (!h) return std::unexpected(h.error());
      frames = *h;
    }
    if (frames.empty()) {
      p.needed = false;
      p.reason = "no frame held out (holdout \"none\")";
      return p;
    }
    std::vector<std::string> items;
    for (int i : frames) items.push_back(std::to_string(i));
    p.outputs = {"eval"};
    std::vector<std::string> args = {"eval", (dir / "model").string(), "--session", eval_session, "--holdout",
                                      join(items, ","), "--out", (dir / "eval").string()};
    if (st.heldout.empty()) pose_args(args);
    p.commands.push_back(extra(args));
    return p;
  }
  if (step == "export") {
    p.outputs = {"export"};
    std::vector<std::string> args;
    if (o.export_format == "gltf") {
      args = {"export", "gltf", (dir / "model").string(), "--out", (dir / "export" / "model.glb").string(), "--report",
              (dir / "export" / "report.json").string()};
    } else {
      args = {"export", o.export_format, session, "--out", (dir / "export").string()};
      pose_args(args);
    }
    p.commands.push_back(extra(args));
    return p;
  }
  return fail(ErrorCode::invalid, "unknown step '" + step + "'");
}

Status write_record(const fs::path& dir, const StepRecord& r) {
  json j = {{"format", "s2r-batch-step"}, {"version", 1}, {"step", r.step},   {"commands", r.commands},
            {"seconds", r.seconds},       {"peak_mb", r.peak_mb}, {"finished", r.finished}, {"host", r.host}};
  return write_file_atomic(dir / "steps" / (r.step + ".json"), j.dump(2) + "\n");
}

Result<StepRecord> read_record(const fs::path& dir, const std::string& step) {
  const fs::path file = dir / "steps" / (step + ".json");
  auto j = parse_json_file(file);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader r(*j, file.string());
    if (r.string("format") != "s2r-batch-step") r.error("format", "expected s2r-batch-step");
    StepRecord out;
    out.step = r.string("step");
    out.seconds = r.number("seconds");
    out.peak_mb = r.number_or("peak_mb", 0);
    out.finished = r.string_or("finished", "");
    out.host = r.string_or("host", "");
    for (const auto& cmd : r.raw().at("commands")) out.commands.push_back(cmd.get<std::vector<std::string>>());
    return out;
  } catch (const std::exception& e) {
    return fail(ErrorCode::format, e.what());
  }
}

std::string why_rerun(const fs::path& dir, const StepPlan& plan) {
  auto rec = read_record(dir, plan.step);
  if (!rec) return exists_file(dir / "steps" / (plan.step + ".json")) ? "its record is unreadable" : "not run yet";
  if (rec->commands != plan.commands) return "its command changed";
  for (const auto& out : plan.outputs) {
    const fs::path d = dir / out;
    std::string bad;
    if (out == "session" || out == "heldout") {
      SessionLoadOptions lo;
      lo.check_images = false;
      if (auto s = load_session(d, lo); !s) bad = s.error().message;
    } else if (out == "calibrate") {
      bad = check_json(d / "calibration.json");
    } else if (out == "register") {
      bad = check_json(d / "poses.json");
    } else if (out == "model") {
      bad = check_json(d / "model.json");
    } else if (out == "eval") {
      if (!exists_file(d / "eval.csv")) bad = (d / "eval.csv").string() + ": missing";
    }
    if (bad.empty() && out != "session" && out != "heldout") bad = check_report(d / "report.json");
    if (!bad.empty()) return "its output does not validate (" + bad + ")";
  }
  return {};
}

Result<ProcessResult> run_process(const fs::path& program, const std::vector<std::string>& args, const fs::path& log,
                                  bool append) {
  std::error_code ec;
  fs::create_directories(log.parent_path(), ec);
  const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | (append ? O_APPEND : O_TRUNC), 0644);
  if (fd < 0) return fail(code_for_errno(errno), "cannot write " + log.string() + ": " + std::strerror(errno), errno);
  const int devnull = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
  std::vector<std::string> owned;
  owned.push_back(program.string());
  owned.insert(owned.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : owned) argv.push_back(s.data());
  argv.push_back(nullptr);
  {
    const std::string line = "$ " + join(owned, " ") + "\n";
    [[maybe_unused]] auto n = ::write(fd, line.data(), line.size());
  }
  const auto start = std::chrono::steady_clock::now();
  const pid_t parent = getpid();
  const pid_t pid = fork();
  if (pid < 0) {
    const int err = errno;
    ::close(fd);
    if (devnull >= 0) ::close(devnull);
    return fail(code_for_errno(err), std::string("fork: ") + std::strerror(err), err);
  }
  if (pid == 0) {
    // The step dies with the batch (a killed batch leaves no step writing).
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() != parent) _exit(127);
    if (devnull >= 0) dup2(devnull, 0);
    dup2(fd, 1);
    dup2(fd, 2);
    execv(argv[0], argv.data());
    const char msg[] = "batch: cannot run the step's program\n";
    [[maybe_unused]] auto n = ::write(2, msg, sizeof msg - 1);
    _exit(127);
  }
  ::close(fd);
  if (devnull >= 0) ::close(devnull);
  int status = 0;
  struct rusage ru {};
  while (wait4(pid, &status, 0, &ru) < 0) {
    if (errno != EINTR) return fail(ErrorCode::io, std::string("wait4: ") + std::strerror(errno), errno);
  }
  ProcessResult r;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  r.peak_mb = static_cast<double>(ru.ru_maxrss) / 1024.0;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  return r;
}

std::string log_tail(const fs::path& log, int lines) {
  std::ifstream in(log);
  std::deque<std::string> last;
  std::string line;
  while (std::getline(in, line)) {
    // Progress lines rewrite themselves with '\r': keep what stands last.
    if (auto cr = line.find_last_of('\r'); cr != std::string::npos && cr + 1 < line.size()) line = line.substr(cr + 1);
    last.push_back(line);
    if (static_cast<int>(last.size()) > lines) last.pop_front();
  }
  std::string out;
  for (const auto& l : last) out += l + "\n";
  return out;
}

Status write_manifest(const fs::path& results, const Manifest& m) {
  json caps = json::array();
  for (const auto& c : m.captures) caps.push_back({{"name", c.name}, {"path", fs::absolute(c.path).string()}, {"kind", c.kind}});
  json opts = json::parse(m.options.text, nullptr, false);
  json j = {{"format", "s2r-batch"}, {"version", 1},       {"root", fs::absolute(m.root).string()},
            {"steps", m.steps},      {"captures", caps}, {"options", opts}};
  return write_file_atomic(results / "batch.json", j.dump(2) + "\n");
}

Result<Manifest> read_manifest(const fs::path& results) {
  const fs::path file = results / "batch.json";
  auto j = parse_json_file(file);
  if (!j) return std::unexpected(j.error());
  try {
    FieldReader r(*j, file.string());
    if (r.string("format") != "s2r-batch") r.error("format", "expected s2r-batch");
    Manifest m;
    m.root = r.string("root");
    m.steps = r.raw().at("steps").get<std::vector<std::string>>();
    for (size_t i = 0; i < r.at("captures").array_size(); ++i) {
      FieldReader c = r.at("captures").index(i);
      m.captures.push_back({c.string("name"), c.string("path"), c.string("kind")});
    }
    auto o = parse_options(r.raw().at("options").dump(), file.string() + ": options");
    if (!o) return std::unexpected(o.error());
    m.options = *o;
    return m;
  } catch (const std::exception& e) {
    return fail(ErrorCode::format, e.what());
  }
}

namespace {

struct Printer {
  std::mutex mu;
  bool quiet = false;
  void line(const std::string& s) {
    if (quiet) return;
    std::lock_guard<std::mutex> lock(mu);
    std::printf("%s\n", s.c_str());
    std::fflush(stdout);
  }
};

Status write_status(const fs::path& dir, json j) {
  j["format"] = "s2r-batch-status";
  j["version"] = 1;
  j["updated"] = utc_now();
  j["host"] = host_name();
  return write_file_atomic(dir / "status.json", j.dump(2) + "\n");
}

// One capture through every step. True when it ended done.
bool run_capture(const fs::path& results, const Manifest& m, const Capture& c, const RunOptions& o, Printer& out,
                 const std::string& tag) {
  const fs::path dir = results / c.name;
  const std::string who = tag + " " + c.name;
  json status = {{"state", "running"}, {"pid", static_cast<int>(getpid())}, {"started", utc_now()}};
  json not_needed = json::object(), skipped = json::object();
  auto failed = [&](const std::string& step, const std::string& message, const fs::path& log) {
    status["state"] = "failed";
    status["failed_step"] = step;
    status["message"] = message;
    if (!log.empty()) {
      status["log"] = log.lexically_relative(results).string();
      status["log_tail"] = log_tail(log, 15);
    }
    status["not_needed"] = not_needed;
    status["skipped"] = skipped;
    (void)write_status(dir, status);
    out.line(who + ": FAILED at " + step + ": " + message + (log.empty() ? "" : " (log: " + log.string() + ")"));
    return false;
  };
  if (auto st = write_status(dir, status); !st) return failed("start", st.error().message, {});
  for (const auto& step : m.steps) {
    auto state = capture_state(c, dir);
    if (!state) return failed(step, state.error().message, {});
    auto plan = plan_step(step, c, dir, *state, m.options);
    if (!plan) return failed(step, plan.error().message, {});
    if (!plan->needed) {
      not_needed[step] = plan->reason;
      out.line(who + ": " + step + ": not needed (" + plan->reason + ")");
      continue;
    }
    const std::string why = why_rerun(dir, *plan);
    if (why.empty()) {
      auto rec = read_record(dir, step);
      skipped[step] = rec ? rec->finished : "";
      out.line(who + ": " + step + ": skipped, done " + (rec ? rec->finished : "") + " (outputs valid)");
      continue;
    }
    std::error_code ec;
    fs::remove(dir / "steps" / (step + ".json"), ec);
    for (const auto& o2 : plan->outputs) fs::remove_all(dir / o2, ec);
    const fs::path log = dir / "logs" / (step + ".log");
    out.line(who + ": " + step + " (" + why + ") ...");
    StepRecord rec;
    rec.step = step;
    rec.commands = plan->commands;
    for (size_t i = 0; i < plan->commands.size(); ++i) {
      auto r = run_process(o.s2r, plan->commands[i], log, i > 0);
      if (!r) return failed(step, r.error().message, log);
      rec.seconds += r->seconds;
      rec.peak_mb = std::max(rec.peak_mb, r->peak_mb);
      if (r->code != 0) {
        const std::string tail = log_tail(log, 1);
        return failed(step, "exit " + std::to_string(r->code) + (tail.empty() ? "" : ": " + trim(tail.substr(0, tail.size() - 1))),
                      log);
      }
    }
    rec.finished = utc_now();
    rec.host = host_name();
    if (auto st = write_record(dir, rec); !st) return failed(step, st.error().message, log);
    out.line(who + ": " + step + ": done in " + number(rec.seconds) + " s, peak " + number(rec.peak_mb) + " MB");
  }
  status["state"] = "done";
  status["not_needed"] = not_needed;
  status["skipped"] = skipped;
  (void)write_status(dir, status);
  out.line(who + ": done");
  return true;
}

}  // namespace

int run_captures(const fs::path& results, const Manifest& m, const std::vector<int>& indices, const RunOptions& o) {
  Printer out;
  out.quiet = o.quiet;
  std::vector<int> todo;
  int failures = 0;
  for (int i : indices) {
    const Capture& c = m.captures[i];
    const std::string prior = status_path_state(results / c.name);
    if (o.retry_failed && prior != "failed") continue;
    if (!o.retry_failed && prior == "failed") {
      out.line("batch: " + c.name + ": failed before, left as it is (--retry-failed runs it again)");
      ++failures;
      continue;
    }
    todo.push_back(i);
  }
  std::atomic<size_t> next{0};
  std::atomic<int> failed{0};
  auto worker = [&] {
    for (size_t k = next++; k < todo.size(); k = next++) {
      const Capture& c = m.captures[todo[k]];
      const std::string tag = "batch [" + std::to_string(k + 1) + "/" + std::to_string(todo.size()) + "]";
      if (!run_capture(results, m, c, o, out, tag)) ++failed;
    }
  };
  const int n = std::max(1, std::min<int>(o.jobs, static_cast<int>(todo.size())));
  std::vector<std::thread> threads;
  for (int t = 1; t < n; ++t) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  return failures + failed.load();
}

std::vector<Row> collect(const fs::path& results, const Manifest& m) {
  std::vector<Row> rows;
  for (const auto& c : m.captures) {
    const fs::path dir = results / c.name;
    Row r;
    r.name = c.name;
    r.kind = c.kind;
    r.state = "pending";
    if (auto j = read_json(dir / "status.json"); j && j->is_object()) {
      r.state = j->value("state", "pending");
      r.failed_step = j->value("failed_step", "");
      r.message = j->value("message", "");
      r.log = j->value("log", "");
      if (auto it = j->find("not_needed"); it != j->end() && it->is_object())
        for (const auto& [k, v] : it->items()) r.skipped_steps.push_back(k + ": not needed");
      if (auto it = j->find("skipped"); it != j->end() && it->is_object())
        for (const auto& [k, v] : it->items()) r.skipped_steps.push_back(k + ": done before");
    }
    for (const auto& step : m.steps) {
      if (auto rec = read_record(dir, step)) {
        r.seconds += rec->seconds;
        r.peak_mb = std::max(r.peak_mb, rec->peak_mb);
      }
    }
    for (const char* sub : {"session", "heldout", "calibrate", "register", "model", "eval", "export"}) {
      auto j = read_json(dir / sub / "report.json");
      if (!j || !j->is_object()) continue;
      if (auto w = j->find("warnings"); w != j->end() && w->is_array())
        for (const auto& s : *w)
          if (s.is_string() && r.warnings.size() < 6) r.warnings.push_back(std::string(sub) + ": " + s.get<std::string>());
      if (std::string(sub) != "eval") continue;
      if (auto e = j->find("errors"); e != j->end() && e->is_object()) {
        const std::string pre = "full_psnr_db_", post = "_held_out";
        for (const auto& [k, v] : e->items())
          if (k.starts_with(pre) && k.ends_with(post) && v.is_number())
            r.psnr[k.substr(pre.size(), k.size() - pre.size() - post.size())] = v.get<double>();
      }
    }
    rows.push_back(std::move(r));
  }
  auto rank = [](const std::string& s) { return s == "failed" ? 0 : s == "running" ? 1 : s == "pending" ? 2 : 3; };
  std::stable_sort(rows.begin(), rows.end(), [&](const Row& a, const Row& b) { return rank(a.state) < rank(b.state); });
  return rows;
}

Status write_summary(const fs::path& results, const Manifest& m, const std::vector<Row>& rows) {
  std::set<std::string> methods;
  for (const auto& r : rows)
    for (const auto& [k, v] : r.psnr) methods.insert(k);
  std::map<std::string, int> counts;
  for (const auto& r : rows) ++counts[r.state];
  std::ostringstream h;
  h << "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>s2r batch: " << html::escape(m.root.string())
    << "</title>\n<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse}"
       "td,th{border:1px solid #ccc;padding:3px 7px;vertical-align:top}th{background:#eee}"
       ".failed{background:#fdd}.running,.pending{background:#ffd}.done{background:#efe}"
       "pre{margin:0;font-size:85%;white-space:pre-wrap;max-width:60em}</style></head><body>\n";
  h << "<h1>s2r batch</h1>\n<p>root <code>" << html::escape(m.root.string()) << "</code>; steps "
    << html::escape(join(m.steps, ", ")) << "; " << rows.size() << " captures:";
  for (const auto& [s, n] : counts) h << " " << n << " " << s;
  h << "; written " << utc_now() << ".</p>\n<table>\n<tr><th>capture</th><th>kind</th><th>state</th><th>seconds</th>"
       "<th>peak MB</th>";
  for (const auto& meth : methods) h << "<th>held-out PSNR dB<br>" << html::escape(meth) << "</th>";
  h << "<th>warnings, skipped steps</th><th>links</th></tr>\n";
  for (const auto& r : rows) {
    h << "<tr class=\"" << html::escape(r.state) << "\"><td>" << html::escape(r.name) << "</td><td>" << html::escape(r.kind)
      << "</td><td>" << html::escape(r.state);
    if (r.state == "failed") h << " at " << html::escape(r.failed_step) << "<pre>" << html::escape(r.message) << "</pre>";
    h << "</td><td>" << number(r.seconds) << "</td><td>" << number(r.peak_mb) << "</td>";
    for (const auto& meth : methods) {
      auto it = r.psnr.find(meth);
      h << "<td>" << (it == r.psnr.end() ? "" : number(it->second)) << "</td>";
    }
    h << "<td>";
    for (const auto& w : r.warnings) h << html::escape(w) << "<br>";
    for (const auto& s : r.skipped_steps) h << "<i>" << html::escape(s) << "</i><br>";
    h << "</td><td>";
    const fs::path dir = results / r.name;
    for (const char* sub : {"model", "eval", "logs", "export"}) {
      std::error_code ec;
      if (fs::exists(dir / sub, ec)) h << "<a href=\"" << html::escape(r.name + "/" + sub) << "/\">" << sub << "</a> ";
    }
    if (!r.log.empty()) h << "<a href=\"" << html::escape(r.log) << "\">failed step's log</a>";
    std::error_code ec;
    if (fs::exists(dir / "eval"))
      for (const auto& e : fs::directory_iterator(dir / "eval", ec))
        if (e.path().extension() == ".png") {
          h << "<br><a href=\"" << html::escape(r.name + "/eval/" + e.path().filename().string()) << "\">"
            << html::escape(e.path().filename().string()) << "</a>";
          break;
        }
    h << "</td></tr>\n";
  }
  h << "</table>\n</body></html>\n";
  json js = json::array();
  for (const auto& r : rows)
    js.push_back({{"name", r.name},         {"kind", r.kind},       {"state", r.state}, {"failed_step", r.failed_step},
                  {"message", r.message},   {"seconds", r.seconds}, {"peak_mb", r.peak_mb},
                  {"held_out_psnr_db", r.psnr}, {"warnings", r.warnings}, {"log", r.log}});
  if (auto st = write_file_atomic(results / "index.html", h.str()); !st) return st;
  return write_file_atomic(results / "summary.json", json{{"root", m.root.string()}, {"captures", js}}.dump(2) + "\n");
}

namespace {
// Measured on this project's bundled data with 2 cores (docs/cli.md): the
// largest peak and the longest run of each step, used until a batch has
// measured its own.
const std::map<std::string, std::pair<double, double>> kStepDefaults = {
    {"import", {1024, 300}},  {"calibrate", {2048, 300}}, {"register", {3072, 900}},
    {"reconstruct", {6144, 3600}}, {"eval", {3072, 1200}}, {"export", {1024, 300}}};

// Largest peak (MB) and longest seconds each step has recorded in RESULTS.
std::map<std::string, std::pair<double, double>> measured(const fs::path& results) {
  std::map<std::string, std::pair<double, double>> out;
  std::error_code ec;
  if (!fs::is_directory(results, ec)) return out;
  for (const auto& cap : fs::directory_iterator(results, ec)) {
    if (!cap.is_directory()) continue;
    for (const auto& step : all_steps()) {
      auto rec = read_record(cap.path(), step);
      if (!rec) continue;
      auto& m = out[step];
      m.first = std::max(m.first, rec->peak_mb);
      m.second = std::max(m.second, rec->seconds);
    }
  }
  return out;
}
}  // namespace

double task_memory_mb(const fs::path& results, const std::vector<std::string>& steps) {
  const auto seen = measured(results);
  double mb = 0;
  for (const auto& s : steps) {
    auto it = seen.find(s);
    mb = std::max(mb, it != seen.end() ? it->second.first * 1.5 + 512 : kStepDefaults.at(s).first);
  }
  return std::ceil(mb / 256) * 256;
}

std::string task_time(const fs::path& results, const std::vector<std::string>& steps, int captures_per_task) {
  const auto seen = measured(results);
  double seconds = 0;
  for (const auto& s : steps) {
    auto it = seen.find(s);
    seconds += it != seen.end() ? it->second.second * 3 + 120 : kStepDefaults.at(s).second;
  }
  const long minutes = static_cast<long>(std::ceil(seconds * std::max(1, captures_per_task) / 60.0)) + 5;
  return std::to_string(minutes);
}

std::vector<int> task_captures(int task, int tasks, int captures) {
  std::vector<int> out;
  if (tasks <= 0 || task < 0 || task >= tasks) return out;
  for (int i = task; i < captures; i += tasks) out.push_back(i);
  return out;
}

namespace {
std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

Result<std::string> sbatch(const fs::path& results, const SlurmOptions& o, std::vector<std::string> args,
                           const std::string& name) {
  const fs::path log = results / "slurm" / ("sbatch_" + name + ".log");
  fs::path program = o.sbatch;
  if (!program.has_parent_path()) {
    // Find it on PATH as a shell would.
    const char* path = std::getenv("PATH");
    std::stringstream ss(path ? path : "/usr/bin:/bin");
    std::string d;
    while (std::getline(ss, d, ':'))
      if (!d.empty() && access((fs::path(d) / program).c_str(), X_OK) == 0) {
        program = fs::path(d) / program;
        break;
      }
  }
  if (access(program.c_str(), X_OK) != 0)
    return fail(ErrorCode::not_found, "sbatch not found ('" + o.sbatch.string() + "'): is Slurm's client installed and on PATH?");
  auto r = run_process(program, args, log, false);
  if (!r) return std::unexpected(r.error());
  const std::string tail = log_tail(log, 3);
  if (r->code != 0) return fail(ErrorCode::failed, "sbatch (" + name + ") failed, exit " + std::to_string(r->code) + ": " + tail);
  // --parsable prints "JOBID" or "JOBID;CLUSTER" as its last line.
  std::stringstream ss(tail);
  std::string line, id;
  while (std::getline(ss, line)) {
    line = trim(line.substr(0, line.find(';')));
    if (!line.empty() && std::all_of(line.begin(), line.end(), ::isdigit)) id = line;
  }
  if (id.empty()) return fail(ErrorCode::protocol, "sbatch (" + name + ") printed no job id: " + tail);
  return id;
}
}  // namespace

Result<Submission> submit_slurm(const fs::path& results, const Manifest& m, const fs::path& s2r, const SlurmOptions& o) {
  const int n = static_cast<int>(m.captures.size());
  Submission sub;
  sub.tasks = std::max(1, std::min(n, o.max_array));
  const int per_task = (n + sub.tasks - 1) / sub.tasks;
  sub.mem_mb = o.mem_mb > 0 ? o.mem_mb : task_memory_mb(results, m.steps);
  sub.time = !o.time.empty() ? o.time : task_time(results, m.steps, per_task);
  const fs::path abs_results = fs::absolute(results).lexically_normal();
  const fs::path slurm = abs_results / "slurm";
  const std::string array_script = "#!/bin/sh\n# One task of an s2r batch (s2r batch --slurm wrote this).\nexec " +
                                   shell_quote(fs::absolute(s2r).string()) + " batch --out " +
                                   shell_quote(abs_results.string()) + " --task \"$SLURM_ARRAY_TASK_ID\" --tasks " +
                                   std::to_string(sub.tasks) + "\n";
  const std::string summary_script = "#!/bin/sh\n# The summary of an s2r batch, after every task (afterany).\nexec " +
                                     shell_quote(fs::absolute(s2r).string()) + " batch --status " +
                                     shell_quote(abs_results.string()) + "\n";
  if (auto st = write_file_atomic(slurm / "array.sh", array_script); !st) return std::unexpected(st.error());
  if (auto st = write_file_atomic(slurm / "summary.sh", summary_script); !st) return std::unexpected(st.error());
  std::vector<std::string> common;
  if (!o.partition.empty()) common.insert(common.end(), {"--partition", o.partition});
  common.insert(common.end(), o.sbatch_args.begin(), o.sbatch_args.end());
  std::vector<std::string> a = {"--parsable", "--job-name", "s2r-batch", "--array", "0-" + std::to_string(sub.tasks - 1),
                                "--cpus-per-task", std::to_string(o.cpus_per_task),
                                "--mem", std::to_string(static_cast<long>(sub.mem_mb)), "--time", sub.time,
                                "--chdir", abs_results.string(), "--output", (slurm / "task_%a.log").string()};
  a.insert(a.end(), common.begin(), common.end());
  a.push_back((slurm / "array.sh").string());
  auto array_id = sbatch(results, o, a, "array");
  if (!array_id) return std::unexpected(array_id.error());
  sub.array_job = *array_id;
  std::vector<std::string> b = {"--parsable", "--job-name", "s2r-batch-summary", "--dependency", "afterany:" + sub.array_job,
                                "--cpus-per-task", "1", "--mem", "512", "--time", "10", "--chdir", abs_results.string(),
                                "--output", (slurm / "summary.log").string()};
  b.insert(b.end(), common.begin(), common.end());
  b.push_back((slurm / "summary.sh").string());
  auto summary_id = sbatch(results, o, b, "summary");
  if (!summary_id) return std::unexpected(summary_id.error());
  sub.summary_job = *summary_id;
  json j = {{"array_job", sub.array_job}, {"summary_job", sub.summary_job}, {"tasks", sub.tasks}, {"mem_mb", sub.mem_mb},
            {"time_minutes", sub.time},   {"submitted", utc_now()}};
  if (auto st = write_file_atomic(slurm / "jobs.json", j.dump(2) + "\n"); !st) return std::unexpected(st.error());
  return sub;
}

}  // namespace s2r::batch
