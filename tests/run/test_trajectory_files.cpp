// The pose files: trajectory.tum (write_tum) and trajectory.partial.tum
// (TrajectoryStream) format every number as printf("%.*f") does (6 decimals
// for the time, 9 for the rest), the stream writes the same lines as the
// final file, and a flush puts every pose appended so far on disk
// (docs/reliability.md: a killed run loses at most the last flush interval).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "build_path.hpp"
#include "outputs.hpp"

namespace mspace::kernel {
namespace {

std::filesystem::path fresh_dir(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::path(MSPACE_BINARY_DIR) / "test_trajectory_files" / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

/// The lines of `file` that are not '#' comments.
std::vector<std::string> pose_lines(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);)
    if (!line.empty() && line[0] != '#') lines.push_back(line);
  return lines;
}

std::string printf_line(const StampedPose& p) {
  const Eigen::Vector4d q = quaternion_xyzw(p.pose);
  char buf[2048];
  std::snprintf(buf, sizeof buf, "%.6f %.9f %.9f %.9f %.9f %.9f %.9f %.9f", p.t, p.pose[kX], p.pose[kY], p.pose[kZ],
                q[0], q[1], q[2], q[3]);
  return buf;
}

/// Values that round in every way: halfway cases, negative numbers that
/// round to zero, large and tiny magnitudes, angles at ±π.
std::vector<StampedPose> awkward_poses() {
  const double pi = std::numbers::pi;
  const std::vector<std::vector<double>> rows = {
      {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
      {1.5, 0.0000000005, -0.0000000004, 1e15, pi / 2, 0.0, 0.0},
      {1e9 + 0.0000005, 123.456789012345, -98765.4321098765, 2.5e-10, -pi, 0.1, -0.2},
      {-3.25, -1e-300, 1e300, 0.0000000015, pi, -pi / 2 + 1e-12, 1.0 / 3.0},
      {1234567.1234565, 6.02214076e23, -2.0 / 3.0, 0.1 + 0.2, 0.7, 0.3, -0.9},
  };
  std::vector<StampedPose> poses;
  for (const auto& r : rows) {
    StampedPose p;
    p.t = r[0];
    p.pose << r[1], r[2], r[3], r[4], r[5], r[6];
    poses.push_back(p);
  }
  return poses;
}

TEST(TrajectoryFiles, EveryNumberIsFormattedAsPrintfFormatsIt) {
  const std::filesystem::path file = fresh_dir("printf") / "trajectory.tum";
  const std::vector<StampedPose> poses = awkward_poses();
  write_tum(file, poses, "test frame");
  const std::vector<std::string> lines = pose_lines(file);
  ASSERT_EQ(lines.size(), poses.size());
  for (std::size_t i = 0; i < poses.size(); ++i) EXPECT_EQ(lines[i], printf_line(poses[i])) << "pose " << i;
}

TEST(TrajectoryFiles, EachFlushPutsEveryPoseSoFarOnDiskAsTheFinalFileHasIt) {
  const std::filesystem::path dir = fresh_dir("flush");
  const std::vector<StampedPose> all = awkward_poses();
  write_tum(dir / "final.tum", all, "test frame");
  const std::vector<std::string> final_lines = pose_lines(dir / "final.tum");
  TrajectoryStream stream(dir, /*flush_seconds=*/0.0, "test frame");
  std::vector<StampedPose> poses;
  for (std::size_t k = 0; k < all.size(); ++k) {
    poses.push_back(all[k]);
    stream.append(poses);
    EXPECT_EQ(stream.written(), k + 1);
    const std::vector<std::string> on_disk = pose_lines(dir / "trajectory.partial.tum");
    EXPECT_EQ(on_disk, std::vector<std::string>(final_lines.begin(), final_lines.begin() + static_cast<long>(k + 1)))
        << "after " << k + 1 << " appends";
  }
  stream.discard();
  EXPECT_FALSE(std::filesystem::exists(dir / "trajectory.partial.tum"));
}

TEST(TrajectoryFiles, PosesNotYetFlushedReachTheFileWhenTheStreamEnds) {
  const std::filesystem::path dir = fresh_dir("end");
  const std::vector<StampedPose> poses = awkward_poses();
  {
    TrajectoryStream stream(dir, /*flush_seconds=*/3600.0, "test frame");
    stream.append(poses);
  }
  const std::vector<std::string> lines = pose_lines(dir / "trajectory.partial.tum");
  ASSERT_EQ(lines.size(), poses.size());
  for (std::size_t i = 0; i < poses.size(); ++i) EXPECT_EQ(lines[i], printf_line(poses[i])) << "pose " << i;
}

}  // namespace
}  // namespace mspace::kernel
