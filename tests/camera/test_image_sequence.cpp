// Tests of the image_sequence source on a short rendered sequence: steps,
// odometry increments, ground truth, readings, and the error messages for
// broken folders.
#include "image_sequence/image_sequence.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <numbers>

#include "camera_test_support.hpp"

namespace mspace {
namespace {

namespace fs = std::filesystem;
using image_sequence::ImageSequence;

constexpr std::size_t kFrames = 15;

/// A rendered 15-frame sequence (made once per test program).
const fs::path& sequence_folder() {
  static const fs::path dir = [] {
    const fs::path d = camera_test::scratch_dir("sequence");
    ceiling_render::SequenceSettings s;
    s.max_frames = kFrames;
    ceiling_render::write_sequence(s, d.string());
    return d;
  }();
  return dir;
}

/// A copy of the sequence to break.
fs::path broken_copy(const std::string& name) {
  const fs::path dir = camera_test::scratch_dir(name);
  fs::copy(sequence_folder(), dir, fs::copy_options::recursive);
  return dir;
}

void write_file(const fs::path& path, const std::string& text) {
  std::ofstream(path) << text;
}

std::string error_of(const fs::path& folder) {
  try {
    ImageSequence source(folder.string(), "camera");
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(ImageSequence, IncrementBetweenInvertsApplyIncrement) {
  const Eigen::Vector3d from(1.0, -2.0, 3.0);
  const planar_odometry::Increment x_d(0.3, -0.1, 0.2);
  const Pose6 to = planar_odometry::apply_increment(make_pose2d(1.0, -2.0, 3.0), x_d);
  const Eigen::Vector3d back =
      image_sequence::increment_between(from, {to[kX], to[kY], to[kTheta]});
  EXPECT_NEAR((back - x_d).norm(), 0.0, 1e-14);
}

TEST(ImageSequence, DeliversEveryFrameWithOdometryGroundTruthAndCamera) {
  ceiling_render::SequenceSettings s;
  s.max_frames = kFrames;
  const fs::path dir = camera_test::scratch_dir("sequence_check");
  const ceiling_render::SequenceSummary summary = ceiling_render::write_sequence(s, dir.string());

  ImageSequence source(dir.string(), "cam");
  EXPECT_EQ(source.size_hint(), kFrames);
  EXPECT_EQ(source.initial_pose(), Pose6::Zero());
  EXPECT_EQ(source.camera().fx, 260.0);
  EXPECT_NEAR(source.camera().mount[kZ], 0.4, 1e-15);

  DataStep step;
  Pose6 dead_reckoned = source.initial_pose();
  for (std::size_t k = 0; k < kFrames; ++k) {
    ASSERT_TRUE(source.next(step));
    EXPECT_NEAR(step.t, 0.1 * static_cast<double>(k), 1e-12);
    ASSERT_EQ(step.odometry.size(), k == 0 ? 0 : 3);
    if (k > 0) dead_reckoned = planar_odometry::apply_increment(dead_reckoned, step.odometry);
    // The increments rebuild odometry.csv's poses (rounding only).
    EXPECT_NEAR((dead_reckoned.head<2>() - summary.odometry_poses[k].head<2>()).norm(), 0.0,
                1e-12);
    EXPECT_NEAR(wrap_angle(dead_reckoned[kTheta] - summary.odometry_poses[k][2]), 0.0, 1e-12);
    ASSERT_TRUE(step.ground_truth.has_value());
    EXPECT_NEAR((*step.ground_truth - summary.true_poses[k]).norm(), 0.0, 1e-12);
    ASSERT_EQ(step.readings.size(), 2u);  // the image and the laser scan
    const SensorReading& r = step.readings[0];
    EXPECT_EQ(r.channel, "cam");
    EXPECT_EQ(r.t, step.t);
    EXPECT_TRUE(fs::is_regular_file(r.file));
    EXPECT_EQ(camera::camera_from_reading(r).cx, 159.5);
    const SensorReading& scan = step.readings[1];
    EXPECT_EQ(scan.channel, "laser");
    EXPECT_EQ(scan.t, step.t);
    ASSERT_EQ(scan.values.rows(), 181);
    ASSERT_EQ(scan.values.cols(), 2);
    EXPECT_NEAR(scan.values(0, 1), -0.5 * std::numbers::pi, 1e-12);
    EXPECT_NEAR(scan.values(180, 1), 0.5 * std::numbers::pi, 1e-12);
  }
  EXPECT_FALSE(source.next(step));
}

TEST(ImageSequence, LaserScansSeeTheCorridorWalls) {
  ImageSequence source(sequence_folder().string(), "camera");
  DataStep step;
  ASSERT_TRUE(source.next(step));  // at the origin, heading along the corridor (y = ±1 m walls)
  ASSERT_EQ(step.readings.size(), 2u);
  const Eigen::MatrixXd& scan = step.readings[1].values;
  // Beams ±90° hit the walls 1 m away (range noise σ = 1 cm); the one ahead
  // sees the corridor's end 10 m away, beyond max_range: no return.
  EXPECT_NEAR(scan(0, 0), 1.0, 0.04);
  EXPECT_NEAR(scan(180, 0), 1.0, 0.04);
  EXPECT_EQ(scan(90, 0), 0.0);
  EXPECT_NEAR(source.laser().mount[kZ], 0.3, 1e-15);
}

TEST(ImageSequence, ALaserFileWithoutItsPartnerIsAnError) {
  const fs::path dir = broken_copy("no_laser_yaml");
  fs::remove(dir / "laser.yaml");
  EXPECT_EQ(error_of(dir), (dir / "laser.yaml").string() +
                               ": missing laser description (laser.yaml)");
}

TEST(ImageSequence, InterpolatesOdometryBetweenStamps) {
  const std::vector<image_sequence::StampedPose2> poses = {
      {0.0, {0.0, 0.0, 3.0}}, {1.0, {2.0, -1.0, -3.0}}};
  const Eigen::Vector3d mid = image_sequence::interpolate(poses, 0.25);
  EXPECT_NEAR(mid[0], 0.5, 1e-15);
  EXPECT_NEAR(mid[1], -0.25, 1e-15);
  // 3 → −3 rad is a turn of 2π − 6 ≈ +0.283 rad the short way round.
  EXPECT_NEAR(mid[2], wrap_angle(3.0 + 0.25 * (2 * std::numbers::pi - 6.0)), 1e-15);
}

TEST(ImageSequence, MissingFilesAreNamed) {
  const fs::path dir = broken_copy("no_camera");
  fs::remove(dir / "camera.yaml");
  EXPECT_EQ(error_of(dir), (dir / "camera.yaml").string() +
                               ": missing camera description (camera.yaml)");

  const fs::path dir2 = broken_copy("no_odometry");
  fs::remove(dir2 / "odometry.csv");
  EXPECT_EQ(error_of(dir2), (dir2 / "odometry.csv").string() + ": missing odometry (odometry.csv)");
}

TEST(ImageSequence, MissingAndUnreadableImagesNameFileAndLine) {
  const fs::path dir = broken_copy("no_image");
  fs::remove(dir / "images/000003.png");
  // frames.csv: 2 header lines, frame k on line k + 3.
  EXPECT_EQ(error_of(dir), (dir / "frames.csv").string() + ":6: image '" +
                               (dir / "images/000003.png").string() + "' does not exist");

  const fs::path dir2 = broken_copy("bad_image");
  write_file(dir2 / "images/000004.png", "this is not a PNG");
  EXPECT_EQ(error_of(dir2), (dir2 / "frames.csv").string() + ":7: image '" +
                                (dir2 / "images/000004.png").string() +
                                "' is not a readable image (PNG or JPEG expected)");
}

TEST(ImageSequence, NonIncreasingStampsNameFileAndLine) {
  const fs::path dir = broken_copy("stamps");
  write_file(dir / "frames.csv",
             "t_s,image\n0,images/000000.png\n0.2,images/000001.png\n# comment\n"
             "0.1,images/000002.png\n");
  EXPECT_EQ(error_of(dir), (dir / "frames.csv").string() +
                               ":5: time stamp 0.100000 s is not after the previous one "
                               "(0.200000 s); stamps must increase");

  const fs::path dir2 = broken_copy("odometry_stamps");
  write_file(dir2 / "odometry.csv", "t_s,x_m,y_m,theta_rad\n0,0,0,0\n0.1,0,0,0\n0.1,1,0,0\n");
  EXPECT_EQ(error_of(dir2), (dir2 / "odometry.csv").string() +
                                ":4: time stamp 0.100000 s is not after the previous one "
                                "(0.100000 s); stamps must increase");
}

TEST(ImageSequence, MalformedLinesAndKeysAreNamed) {
  const fs::path dir = broken_copy("bad_number");
  write_file(dir / "odometry.csv", "0,0,0,0\n0.1,0,zero,0\n");
  EXPECT_EQ(error_of(dir),
            (dir / "odometry.csv").string() + ":2: 'zero' is not a finite number (y_m)");

  const fs::path dir2 = broken_copy("bad_camera");
  write_file(dir2 / "camera.yaml",
             "width: 320\nheight: 240\nfx: 260\nfy: 260\ncx: 160\ncy: 120\n"
             "distortion: [0, 0, 0, 0]\nmount: [0, 0, 0, 0, 0, 0]\n");
  EXPECT_EQ(error_of(dir2),
            (dir2 / "camera.yaml").string() + ":7: 'distortion' needs 5 numbers, has 4");
}

TEST(ImageSequence, MountIsReadAsRollPitchYawInDegrees) {
  const fs::path dir = broken_copy("mount");
  write_file(dir / "camera.yaml",
             "width: 320\nheight: 240\nfx: 260\nfy: 250\ncx: 160\ncy: 120\n"
             "distortion: [0, 0, 0, 0, 0]\nmount: [0.1, 0.2, 0.3, 10, 20, 30]\n");
  const camera::CameraModel c = image_sequence::read_camera_yaml((dir / "camera.yaml").string());
  const double deg = std::numbers::pi / 180.0;
  EXPECT_NEAR((c.mount - make_pose(0.1, 0.2, 0.3, 30 * deg, 20 * deg, 10 * deg)).norm(), 0.0,
              1e-15);
}

}  // namespace
}  // namespace mspace
