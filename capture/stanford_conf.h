// Stanford range-scan alignment files (".conf", as written by scanalyze):
//
//   camera tx ty tz qx qy qz qw
//   bmesh FILE tx ty tz qx qy qz qw
//
// Each bmesh line places one scan: p_world = R p_scan + t. The quaternion's
// reading was established by measuring where the bunny's ring scans agree
// (reconstruct/stanford_conf_test.cpp): R is the rotation of the conjugate of
// (qx, qy, qz, qw), i.e. the file's qw has the opposite sign of the usual
// convention. Under it, overlapping ring scans agree to 0.42-0.49 mm median
// (67-92 % overlap); read the usual way, they lie 2.4-3.0 mm apart where they
// overlap at all (0-10 %). bun045 is turned by about 34 deg, not 45. Lines
// are kept verbatim so the file can be written back in exactly its own
// conventions.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/result.h"

namespace s2r {

struct StanfordConf {
  struct Line {
    std::string text;     // the line as read (non-bmesh lines are written back as they were)
    int scan = -1;        // index into scans, for bmesh lines
  };
  struct Scan {
    std::string file;
    Eigen::Isometry3d world_from_scan = Eigen::Isometry3d::Identity();
    // The quaternion as the file writes it, Quaterniond(qw, qx, qy, qz). A
    // written pose takes the sign (q or -q) nearer to it, so an unchanged
    // pose is written as it was.
    Eigen::Quaterniond as_read = Eigen::Quaterniond::Identity();
  };
  std::vector<Line> lines;
  std::vector<Scan> scans;
};

Result<StanfordConf> read_stanford_conf(const std::filesystem::path& path);
// Writes `conf` with each bmesh line's pose replaced by scans[i].world_from_scan,
// in the same line format and quaternion convention (atomic).
// The file's quaternion for a rotation, and back (the convention above).
Eigen::Quaterniond conf_quaternion(const Eigen::Matrix3d& world_from_scan_rotation);
Eigen::Matrix3d conf_rotation(const Eigen::Quaterniond& file_q);

Status write_stanford_conf(const std::filesystem::path& path, const StanfordConf& conf);

}  // namespace s2r
