#include "capture/capture_devices.h"

#include <algorithm>
#include <atomic>
#include <functional>
#include <chrono>
#include <mutex>

#include "capture/libcamera_camera.h"
#include "capture/pixel_formats.h"
#include "capture/synth_rig.h"

namespace s2r {
namespace fs = std::filesystem;

CaptureRig::~CaptureRig() {
  devices = CaptureDevices{};  // drivers close before the devices behind them go
  firmware.reset();
}

namespace {

Result<std::unique_ptr<V4l2Io>> maybe_record(std::unique_ptr<V4l2Io> io, const DeviceOptions& o, const char* name) {
  if (o.record_dir.empty()) return io;
  return make_recording_v4l2_io(std::move(io), o.record_dir / name);
}

GrblOptions grbl_options(const DeviceOptions& o) {
  GrblOptions g;
  g.settle = o.settle;
  if (!o.record_dir.empty()) {
    g.transcript = o.record_dir / "turntable.transcript";
    std::error_code ec;
    fs::remove(g.transcript, ec);  // a new recording
  }
  return g;
}

// Simulated and replayed cameras: the recording's device path and settings.
V4l2Config recorded_camera_config(const DeviceOptions& o) {
  V4l2Config vc;
  vc.width = o.width;
  vc.height = o.height;
  vc.exposure_100us = 100;
  vc.timeout_ms = 5000;
  return vc;
}

ColorSensor color_sensor(const Camera& c, const std::string& driver) {
  ColorSensor s;
  s.driver = driver;
  s.device = c.describe();
  s.pixel_format = "RGB8";
  s.intrinsics.width = c.width();
  s.intrinsics.height = c.height();
  // Nominal until calibrated: a 60 degree horizontal field of view.
  s.intrinsics.fx = s.intrinsics.fy = c.width() / (2 * std::tan(30.0 * M_PI / 180));
  s.intrinsics.cx = (c.width() - 1) / 2.0;
  s.intrinsics.cy = (c.height() - 1) / 2.0;
  return s;
}

TurntableChoice table_choice(const DeviceOptions& o, const std::string& protocol) {
  TurntableChoice c;
  c.protocol = protocol;
  c.settle = o.settle;
  if (!o.record_dir.empty()) {
    c.transcript = o.record_dir / "turntable.transcript";
    std::error_code ec;
    fs::remove(c.transcript, ec);  // a new recording
  }
  return c;
}

// A turntable that remembers where it said it stands after each call, for a
// simulated camera to draw the scene there.
class ObservedTurntable : public Turntable {
 public:
  ObservedTurntable(std::unique_ptr<Turntable> t, std::shared_ptr<std::atomic<double>> angle)
      : t_(std::move(t)), angle_(std::move(angle)) {}
  Status home() override { return note(t_->home()); }
  Status set_position(double degrees) override { return note(t_->set_position(degrees)); }
  Status move_to(double degrees) override { return note(t_->move_to(degrees)); }
  Result<double> position() override {
    auto p = t_->position();
    if (p) angle_->store(*p);
    return p;
  }
  std::string describe() const override { return t_->describe(); }

 private:
  Status note(Status st) {
    if (st) (void)position();
    return st;
  }
  std::unique_ptr<Turntable> t_;
  std::shared_ptr<std::atomic<double>> angle_;
};

// The rig's colour and depth cameras, drawing the scene at `angle()`.
Status attach_sim_cameras(CaptureRig& rig, const SimOptions& sim, const DeviceOptions& o, std::function<double()> angle);

}  // namespace

Result<std::unique_ptr<Turntable>> open_turntable(const std::string& port, const TurntableChoice& c) {
  if (c.protocol == "grbl" || c.protocol == "horus") {
    GrblOptions g;
    g.baud = c.baud;
    g.unlock_alarm = c.unlock;
    g.settle = c.settle;
    g.transcript = c.transcript;
    g.dialect = c.protocol;
    auto t = GrblTurntable::open(port, g);
    if (!t) return std::unexpected(t.error());
    return std::unique_ptr<Turntable>(std::move(*t));
  }
  if (c.protocol == "fabscan") {
    FabScanOptions f;
    f.baud = c.baud;
    f.steps_per_turn = c.steps_per_turn;
    f.settle = c.settle;
    f.transcript = c.transcript;
    auto t = FabScanTurntable::open(port, f);
    if (!t) return std::unexpected(t.error());
    return std::unique_ptr<Turntable>(std::move(*t));
  }
  return fail(ErrorCode::invalid, "protocol: '" + c.protocol + "' (choose grbl, horus or fabscan)");
}

Result<SimBoard> start_sim_board(const std::string& protocol) {
  SimBoard b;
  if (protocol == "grbl" || protocol == "horus") {
    GrblFaults f;
    f.horus = protocol == "horus";
    auto s = GrblSim::start(f);
    if (!s) return std::unexpected(s.error());
    b.grbl = std::move(*s);
    return b;
  }
  if (protocol == "fabscan") {
    auto s = FabScanSim::start();
    if (!s) return std::unexpected(s.error());
    b.fabscan = std::move(*s);
    return b;
  }
  return fail(ErrorCode::invalid, "protocol: '" + protocol + "' (choose grbl, horus or fabscan)");
}

Result<std::unique_ptr<CaptureRig>> make_sim_capture(const SimOptions& sim, const DeviceOptions& o) {
  auto rig = std::make_unique<CaptureRig>();
  auto fw = GrblSim::start(sim.table_faults);
  if (!fw) return std::unexpected(fw.error());
  rig->firmware = std::move(*fw);
  GrblSim* firmware = rig->firmware.get();
  if (auto st = attach_sim_cameras(*rig, sim, o, [firmware] { return firmware->position(); }); !st)
    return std::unexpected(st.error());
  auto table = GrblTurntable::open(rig->firmware->port(), grbl_options(o));
  if (!table) return std::unexpected(table.error());
  Session& h = rig->devices.header;
  h.turntable = TurntableInfo{"grbl", (*table)->describe()};
  h.notes.push_back("simulated devices: real V4L2 and GRBL driver code over simulated device boundaries");
  rig->devices.table = std::move(*table);
  return rig;
}

Result<std::unique_ptr<CaptureRig>> make_sim_camera_capture(const std::string& turntable, const std::string& protocol,
                                                            const SimOptions& sim, const DeviceOptions& o) {
  auto rig = std::make_unique<CaptureRig>();
  auto table = open_turntable(turntable, table_choice(o, protocol));
  if (!table) return std::unexpected(table.error());
  auto angle = std::make_shared<std::atomic<double>>(0.0);
  auto observed = std::make_unique<ObservedTurntable>(std::move(*table), angle);
  if (auto p = observed->position(); !p) return std::unexpected(p.error());
  if (auto st = attach_sim_cameras(*rig, sim, o, [angle] { return angle->load(); }); !st) return std::unexpected(st.error());
  Session& h = rig->devices.header;
  h.source = "capture:sim-camera:" + sim.scene;
  h.turntable = TurntableInfo{protocol, observed->describe()};
  h.notes.push_back("a real turntable (" + protocol + ") with the simulated colour and depth cameras: the scene is drawn at "
                    "the angle the table reports");
  rig->devices.table = std::move(observed);
  return rig;
}

namespace {

Status attach_sim_cameras(CaptureRig& rig_ref, const SimOptions& sim, const DeviceOptions& o, std::function<double()> angle) {
  CaptureRig* rig = &rig_ref;
  SynthOptions so;
  so.scene = sim.scene;
  so.seed = sim.seed;
  so.width = o.width;
  so.height = o.height;
  so.spp = 1;
  auto scene = SynthRig::create(so);
  if (!scene) return std::unexpected(scene.error());
  rig->scene = std::shared_ptr<SynthRig>(std::move(*scene));

  // One render per table position serves the colour and the depth device.
  struct Cache {
    std::mutex mu;
    double angle = -1e9;
    SynthView view;
    int64_t t_ns = 0;
    uint64_t renders = 0;
  };
  auto cache = std::make_shared<Cache>();
  std::shared_ptr<SynthRig> scene_ptr = rig->scene;
  auto render = [cache, angle, scene_ptr](bool depth) {
    std::lock_guard lock(cache->mu);
    const double a = angle();
    if (std::abs(a - cache->angle) > 1e-9) {
      cache->view = scene_ptr->render_at(a, cache->renders++);
      cache->angle = a;
    }
    cache->t_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                      std::chrono::steady_clock::now().time_since_epoch()).count();
    SimFrame f;
    if (depth) f.depth = cache->view.depth;
    else f.rgb = cache->view.color;
    f.timestamp_ns = cache->t_ns;
    return f;
  };
  V4l2SimConfig cc;
  cc.card = "simulated colour camera (" + sim.scene + ")";
  cc.formats = {kFourccYUYV, kFourccMJPG};
  cc.width = o.width;
  cc.height = o.height;
  cc.faults = sim.color_faults;
  cc.source = [render](uint32_t) { return render(false); };
  auto cio = maybe_record(make_sim_v4l2_io(cc), o, "color.v4l2rec");
  if (!cio) return std::unexpected(cio.error());
  const V4l2Config vc = recorded_camera_config(o);
  auto color = V4l2Camera::open(std::move(*cio), "/dev/video-sim0", vc);
  if (!color) return std::unexpected(color.error());

  V4l2SimConfig dc = cc;
  dc.card = "simulated depth camera (" + sim.scene + ")";
  dc.formats = {kFourccZ16};
  dc.faults = sim.depth_faults;
  dc.source = [render](uint32_t) { return render(true); };
  auto dio = maybe_record(make_sim_v4l2_io(dc), o, "depth.v4l2rec");
  if (!dio) return std::unexpected(dio.error());
  V4l2Config dvc = vc;
  dvc.exposure_100us.reset();
  auto depth = V4l2Camera::open(std::move(*dio), "/dev/video-sim1", dvc);
  if (!depth) return std::unexpected(depth.error());

  Session& h = rig->devices.header;
  h.source = "capture:sim:" + sim.scene;
  h.color = color_sensor(**color, "v4l2-sim");
  h.color->intrinsics = rig->scene->color_intrinsics();  // the rig knows its lens
  DepthSensor ds;
  ds.driver = "v4l2-sim";
  ds.device = (*depth)->describe();
  ds.intrinsics = rig->scene->depth_intrinsics();
  ds.unit_m = so.depth_unit_m;
  ds.color_from_depth = rig->scene->color_from_depth();
  h.depth = ds;
  rig->devices.color = std::move(*color);
  rig->devices.depth = std::move(*depth);
  return {};
}

}  // namespace

Result<std::unique_ptr<CaptureRig>> make_replay_capture(const fs::path& dir, const DeviceOptions& o) {
  auto rig = std::make_unique<CaptureRig>();
  auto fw = GrblSim::replay(dir / "turntable.transcript");
  if (!fw) return std::unexpected(fw.error());
  rig->firmware = std::move(*fw);
  auto cio = make_replay_v4l2_io(dir / "color.v4l2rec");
  if (!cio) return std::unexpected(cio.error());
  const V4l2Config vc = recorded_camera_config(o);
  auto color = V4l2Camera::open(std::move(*cio), "/dev/video-sim0", vc);
  if (!color) return std::unexpected(color.error());
  rig->devices.header.color = color_sensor(**color, "v4l2-replay");
  if (fs::exists(dir / "depth.v4l2rec")) {
    auto dio = make_replay_v4l2_io(dir / "depth.v4l2rec");
    if (!dio) return std::unexpected(dio.error());
    V4l2Config dvc = vc;
    dvc.exposure_100us.reset();
    auto depth = V4l2Camera::open(std::move(*dio), "/dev/video-sim1", dvc);
    if (!depth) return std::unexpected(depth.error());
    DepthSensor ds;
    ds.driver = "v4l2-replay";
    ds.device = (*depth)->describe();
    ds.intrinsics = rig->devices.header.color->intrinsics;
    rig->devices.header.depth = ds;
    rig->devices.depth = std::move(*depth);
  }
  GrblOptions g = grbl_options(DeviceOptions{});
  g.settle = o.settle;
  auto table = GrblTurntable::open(rig->firmware->port(), g);
  if (!table) return std::unexpected(table.error());
  rig->devices.header.source = "capture:replay:" + dir.filename().string();
  rig->devices.header.turntable = TurntableInfo{"grbl-replay", (*table)->describe()};
  rig->devices.color = std::move(*color);
  rig->devices.table = std::move(*table);
  return rig;
}

Result<std::unique_ptr<CaptureRig>> make_hardware_capture(const std::string& camera, const std::string& depth,
                                                          const std::string& turntable, const DeviceOptions& o,
                                                          const std::string& protocol) {
  auto rig = std::make_unique<CaptureRig>();
  V4l2Config vc;
  vc.width = o.width;
  vc.height = o.height;
  vc.exposure_100us = 200;  // fixed exposure: no drift around the turn
  vc.gain = 0;
  vc.white_balance_k = 4600;
  if (camera.rfind("libcamera:", 0) == 0) {
    auto cam = LibcameraCamera::open(camera.substr(10), o.width, o.height);
    if (!cam) return std::unexpected(cam.error());
    rig->devices.header.color = color_sensor(**cam, "libcamera");
    rig->devices.color = std::move(*cam);
  } else {
    auto io = maybe_record(make_kernel_v4l2_io(), o, "color.v4l2rec");
    if (!io) return std::unexpected(io.error());
    auto cam = V4l2Camera::open(std::move(*io), camera, vc);
    if (!cam) return std::unexpected(cam.error());
    rig->devices.header.color = color_sensor(**cam, "v4l2");
    rig->devices.color = std::move(*cam);
  }
  if (!depth.empty()) {
    auto io = maybe_record(make_kernel_v4l2_io(), o, "depth.v4l2rec");
    if (!io) return std::unexpected(io.error());
    V4l2Config dvc;
    dvc.width = o.width;
    dvc.height = o.height;
    dvc.fourcc = kFourccZ16;
    auto cam = V4l2Camera::open(std::move(*io), depth, dvc);
    if (!cam) return std::unexpected(cam.error());
    DepthSensor ds;
    ds.driver = "v4l2";
    ds.device = (*cam)->describe();
    ds.intrinsics = rig->devices.header.color->intrinsics;
    ds.intrinsics.width = (*cam)->width();
    ds.intrinsics.height = (*cam)->height();
    ds.unit_m = 0.001;  // UVC Z16 of the D400 series; calibrate for others
    rig->devices.header.depth = ds;
    rig->devices.depth = std::move(*cam);
  }
  auto table = open_turntable(turntable, table_choice(o, protocol));
  if (!table) return std::unexpected(table.error());
  rig->devices.header.turntable = TurntableInfo{protocol, (*table)->describe()};
  // What the cameras granted differently from what was asked, in session.json's notes.
  for (const auto* cam : {rig->devices.color.get(), rig->devices.depth.get()})
    if (cam)
      for (const auto& w : cam->warnings()) rig->devices.header.notes.push_back(w);
  rig->devices.table = std::move(*table);
  return rig;
}

std::vector<std::string> list_capture_devices() {
  std::vector<std::string> out;
  for (auto& l : list_v4l2_devices()) out.push_back("v4l2      " + l);
  for (auto& l : list_libcamera_cameras()) out.push_back("libcamera " + l);
  std::error_code ec;
  std::vector<std::string> ports;
  for (const auto& e : fs::directory_iterator("/dev", ec)) {
    const std::string n = e.path().filename().string();
    if (n.rfind("ttyUSB", 0) == 0 || n.rfind("ttyACM", 0) == 0) ports.push_back(e.path().string());
  }
  for (const auto& e : fs::directory_iterator("/dev/serial/by-id", ec))
    ports.push_back(e.path().string() + " -> " + fs::read_symlink(e.path(), ec).filename().string());
  std::sort(ports.begin(), ports.end());
  for (auto& p : ports) out.push_back("serial    " + p + " (a GRBL turntable is probed at 115200 baud by s2r capture)");
  if (out.empty()) out.push_back("no cameras, depth cameras or serial ports found");
  return out;
}

}  // namespace s2r
