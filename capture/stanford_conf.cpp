#include "capture/stanford_conf.h"

#include <cstdio>
#include <fstream>
#include <sstream>

#include "core/atomic_file.h"
#include "core/paths.h"

namespace s2r {
namespace fs = std::filesystem;

Eigen::Quaterniond conf_quaternion(const Eigen::Matrix3d& r) { return Eigen::Quaterniond(r).conjugate(); }
Eigen::Matrix3d conf_rotation(const Eigen::Quaterniond& q) { return q.conjugate().toRotationMatrix(); }

Result<StanfordConf> read_stanford_conf(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return fail("'" + path.string() + "': cannot open .conf");
  StanfordConf conf;
  std::string line;
  int lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    StanfordConf::Line l{line, -1};
    std::istringstream ls(line);
    std::string kind;
    if ((ls >> kind) && kind == "bmesh") {
      StanfordConf::Scan s;
      double t[3], q[4];
      std::string extra;
      if (!(ls >> s.file >> t[0] >> t[1] >> t[2] >> q[0] >> q[1] >> q[2] >> q[3]) || (ls >> extra))
        return fail(path.string() + ": line " + std::to_string(lineno) +
                    ": expected 'bmesh FILE tx ty tz qx qy qz qw'");
      const Eigen::Quaterniond quat(q[3], q[0], q[1], q[2]);
      if (!(quat.norm() > 0.99 && quat.norm() < 1.01) || !Eigen::Vector3d(t[0], t[1], t[2]).allFinite())
        return fail(path.string() + ": line " + std::to_string(lineno) +
                    ": quaternion is not unit length or translation is not finite");
      if (auto inside = resolve_inside(path.has_parent_path() ? path.parent_path() : fs::path("."), s.file); !inside)
        return fail(path.string() + ": line " + std::to_string(lineno) + ": scan file: " + inside.error().message);
      s.as_read = quat.normalized();
      s.world_from_scan.linear() = conf_rotation(s.as_read);
      s.world_from_scan.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
      l.scan = static_cast<int>(conf.scans.size());
      conf.scans.push_back(std::move(s));
    }
    conf.lines.push_back(std::move(l));
  }
  if (conf.scans.empty()) return fail(path.string() + ": no 'bmesh' lines");
  return conf;
}

Status write_stanford_conf(const fs::path& path, const StanfordConf& conf) {
  std::string text;
  for (const auto& l : conf.lines) {
    if (l.scan < 0) {
      text += l.text + "\n";
      continue;
    }
    const auto& s = conf.scans.at(static_cast<size_t>(l.scan));
    Eigen::Quaterniond q = conf_quaternion(s.world_from_scan.rotation());
    if (q.coeffs().dot(s.as_read.coeffs()) < 0) q.coeffs() = -q.coeffs();
    const Eigen::Vector3d t = s.world_from_scan.translation() + Eigen::Vector3d::Zero();
    q.coeffs() += Eigen::Vector4d::Zero();  // -0 prints as 0
    char buf[512];
    std::snprintf(buf, sizeof buf, "bmesh %s %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n", s.file.c_str(), t.x(),
                  t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
    text += buf;
  }
  return write_file_atomic(path, text);
}

}  // namespace s2r
