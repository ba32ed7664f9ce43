// Tests of the `rosbag` source's camera bags (image_topic): a rendered
// ceiling sequence written as a bag with ROS's own library replays as the
// sequence folder does through `image_sequence` — step for step, and as a
// whole run of config/ceiling_both.yaml (lines and lamps) to 1e-9 — each
// encoding reaches the extractors' file with its pixels, and bad image
// topics get errors naming the bag, topic, message and stamp.
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <functional>
#include <numbers>
#include <set>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "bag_writer.hpp"
#include "build_path.hpp"
#include "ceiling_render/ceiling_renderer.hpp"
#include "config.hpp"
#include "image_sequence/image_sequence.hpp"
#include "logging.hpp"
#include "plugin_registry.hpp"
#include "rosbag_source.hpp"
#include "slam.hpp"

namespace mspace::rosbag_test {
namespace {

namespace fs = std::filesystem;

constexpr const char* kTopic = "/camera/image_raw";

/// An empty folder under the build tree, private to this process (CTest runs
/// the cases of one executable as parallel processes).
fs::path scratch(const std::string& name) {
  const fs::path dir = fs::path(MSPACE_BINARY_DIR) / "test_tmp" / "rosbag" / (name + "-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// A rendered ceiling sequence (camera only), once per test process: 140
/// frames at 0.4 m/s, 5.6 m along the corridor, where lines and lamps enter
/// the map.
const fs::path& sequence() {
  static const fs::path dir = [] {
    const fs::path d = scratch("sequence");
    ceiling_render::SequenceSettings s;
    s.max_frames = 140;
    s.laser.enabled = false;
    ceiling_render::write_sequence(s, d.string());
    return d;
  }();
  return dir;
}

/// A grey (or 16-bit grey, or BGR) image as an Image message of `encoding`,
/// rows padded to `step` bytes (0: no padding).
CameraFrame frame_of(const cv::Mat& image, double t, const std::string& encoding, std::uint32_t step = 0,
                     bool big_endian = false) {
  CameraFrame f;
  f.t = t;
  f.width = static_cast<std::uint32_t>(image.cols);
  f.height = static_cast<std::uint32_t>(image.rows);
  f.encoding = encoding;
  f.big_endian = big_endian;
  cv::Mat pixels;  // a new buffer for rgb8: `image` stays as the caller's
  if (encoding == "rgb8") cv::cvtColor(image, pixels, cv::COLOR_BGR2RGB);
  else pixels = image;
  const std::size_t row_bytes = static_cast<std::size_t>(pixels.cols) * pixels.elemSize();
  f.step = step == 0 ? static_cast<std::uint32_t>(row_bytes) : step;
  f.data.assign(std::size_t{f.step} * f.height, 0xAB);  // padding bytes that are not pixels
  for (int r = 0; r < pixels.rows; ++r) {
    const std::uint8_t* row = pixels.ptr<std::uint8_t>(r);
    std::uint8_t* out = f.data.data() + static_cast<std::size_t>(r) * f.step;
    if (pixels.depth() == CV_16U) {
      for (int c = 0; c < pixels.cols; ++c) {
        const std::uint16_t v = pixels.at<std::uint16_t>(r, c);
        out[2 * c + (big_endian ? 0 : 1)] = static_cast<std::uint8_t>(v >> 8);
        out[2 * c + (big_endian ? 1 : 0)] = static_cast<std::uint8_t>(v & 0xFF);
      }
    } else {
      std::copy(row, row + row_bytes, out);
    }
  }
  return f;
}

std::array<double, 4> quaternion_of(const Pose6& mount) {
  const Eigen::Quaterniond q(rotation(mount));
  return {q.x(), q.y(), q.z(), q.w()};
}

/// The folder as a bag: its PNGs as mono8 Images, odometry.csv on /odom,
/// groundtruth.tum on /ground_truth, camera.yaml's mount on /tf_static.
CameraBag bag_of(const fs::path& folder) {
  records::MalformedRecords strict("error");
  CameraBag bag;
  for (const image_sequence::Frame& f :
       image_sequence::read_frames_csv((folder / "frames.csv").string(), folder.string(), strict)) {
    const cv::Mat grey = cv::imread(f.image, cv::IMREAD_UNCHANGED);
    EXPECT_EQ(grey.type(), CV_8UC1) << f.image;
    bag.frames.push_back(frame_of(grey, f.t, "mono8"));
  }
  for (const image_sequence::StampedPose2& p :
       image_sequence::read_odometry_csv((folder / "odometry.csv").string(), strict))
    bag.odometry.push_back({p.t, p.pose});
  for (const image_sequence::StampedPose6& p : image_sequence::read_tum((folder / "groundtruth.tum").string()))
    bag.ground_truth.push_back({p.t, {p.pose[kX], p.pose[kY], p.pose[kTheta]}});
  const Pose6 mount = image_sequence::read_camera_yaml((folder / "camera.yaml").string()).mount;
  bag.mount = {{mount.head<3>(), quaternion_of(mount)}};
  return bag;
}

PluginArgs camera_args(const fs::path& bag, const fs::path& camera_yaml) {
  PluginArgs a;
  a.instance_name = "source";
  a.params = Params::defaults(rosbag_source::RosbagSource::param_specs());
  a.params.set("file", bag.string());
  a.params.set("image_topic", std::string(kTopic));
  a.params.set("camera_yaml", camera_yaml.string());
  return a;
}

cv::Mat read_unchanged(const std::string& file) {
  const cv::Mat image = cv::imread(file, cv::IMREAD_UNCHANGED);
  EXPECT_FALSE(image.empty()) << file;
  return image;
}

bool same_pixels(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0.0;
}

TEST(RosbagCamera, StepsAreTheSequenceFoldersStepForStep) {
  const fs::path dir = scratch("steps");
  const fs::path bag = dir / "ceiling.bag";
  write_camera_bag(bag_of(sequence()), bag);
  PluginArgs args = camera_args(bag, sequence() / "camera.yaml");
  args.params.set("ground_truth_topic", std::string("/ground_truth"));

  image_sequence::ImageSequence folder(sequence().string(), "camera");
  std::string last_file;
  {
    rosbag_source::RosbagSource from_bag(args);
    EXPECT_EQ(from_bag.size_hint(), folder.size_hint());
    EXPECT_LT((from_bag.initial_pose() - folder.initial_pose()).norm(), 1e-12);
    const std::vector<RecordedMount> mounts = from_bag.recorded_mounts();
    ASSERT_EQ(mounts.size(), 1U);
    EXPECT_EQ(mounts[0].channel, "camera");
    EXPECT_EQ(mounts[0].mount, folder.recorded_mounts().at(0).mount);
    EXPECT_EQ(mounts[0].origin, (sequence() / "camera.yaml").string());

    DataStep a, b;
    std::size_t steps = 0;
    while (folder.next(a)) {
      ASSERT_TRUE(from_bag.next(b)) << "the bag ends at step " << steps;
      // ros::Time keeps nanoseconds: the stamps are the CSV's to 1e-9 s.
      ASSERT_NEAR(a.t, b.t, 1e-9) << "step " << steps;
      ASSERT_EQ(a.odometry.size(), b.odometry.size()) << "step " << steps;
      if (a.odometry.size() > 0) {
        ASSERT_LT((a.odometry - b.odometry).cwiseAbs().maxCoeff(), 1e-12) << "step " << steps;
      }
      ASSERT_TRUE(a.ground_truth.has_value() && b.ground_truth.has_value()) << "step " << steps;
      ASSERT_LT((*a.ground_truth - *b.ground_truth).norm(), 1e-12) << "step " << steps;
      ASSERT_EQ(b.readings.size(), 1U);
      const SensorReading& ra = a.readings.at(0);
      const SensorReading& rb = b.readings.at(0);
      EXPECT_EQ(ra.channel, rb.channel);
      EXPECT_NEAR(ra.t, rb.t, 1e-9);
      ASSERT_EQ(ra.values, rb.values) << "step " << steps << ": the intrinsics row";
      ASSERT_TRUE(same_pixels(read_unchanged(ra.file), read_unchanged(rb.file))) << "step " << steps;
      // One image file at a time: the previous step's is gone.
      if (!last_file.empty()) {
        EXPECT_FALSE(fs::exists(last_file)) << last_file;
      }
      last_file = rb.file;
      ++steps;
    }
    EXPECT_FALSE(from_bag.next(b)) << "the bag has more steps than the folder's " << steps;
    EXPECT_EQ(steps, 140U);
    ASSERT_TRUE(fs::exists(last_file));
  }
  EXPECT_FALSE(fs::exists(fs::path(last_file).parent_path())) << "the source's image folder outlives it";
}

/// What a run leaves: the trajectory and the map.
struct RunResult {
  std::vector<kernel::StampedPose> trajectory;
  struct Feature {
    int id = 0, type = 0, dim = 0;
    Eigen::VectorXd coords;
  };
  std::vector<Feature> map;
};

RunResult run_ceiling_both(const std::vector<std::string>& overrides) {
  kernel::set_log_level(LogLevel::Warn);
  kernel::PluginRegistry registry;
  registry.add_search_dir(MSPACE_PLUGIN_DIR);
  const kernel::RunConfig config =
      kernel::load_config(fs::path(MSPACE_SOURCE_DIR) / "config" / "ceiling_both.yaml", registry, overrides);
  kernel::Slam slam(config, registry);
  while (slam.step()) {
  }
  RunResult out;
  out.trajectory = slam.trajectory();
  for (const kernel::MapFeature& f : slam.features()) {
    RunResult::Feature feature;
    feature.id = f.id;
    feature.type = f.type;
    feature.dim = static_cast<int>(f.feature->mspace_dim());
    feature.coords = f.feature->coords();
    out.map.push_back(std::move(feature));
  }
  return out;
}

TEST(RosbagCamera, RunOfTheBagEqualsTheRunOfTheFolder) {
  const fs::path dir = scratch("run");
  const fs::path bag = dir / "ceiling.bag";
  write_camera_bag(bag_of(sequence()), bag);
  const RunResult folder = run_ceiling_both(
      {"source.folder=" + sequence().string(), "output.dir=" + (dir / "out_folder").string()});
  const RunResult from_bag = run_ceiling_both(
      {"source={plugin: rosbag, file: '" + bag.string() + "', image_topic: " + kTopic + ", camera_yaml: '" +
           (sequence() / "camera.yaml").string() + "', ground_truth_topic: /ground_truth}",
       "output.dir=" + (dir / "out_bag").string()});

  ASSERT_EQ(folder.trajectory.size(), from_bag.trajectory.size());
  ASSERT_GT(folder.trajectory.size(), 100U);
  double largest_pose = 0.0, largest_coord = 0.0;
  for (std::size_t k = 0; k < folder.trajectory.size(); ++k) {
    ASSERT_NEAR(folder.trajectory[k].t, from_bag.trajectory[k].t, 1e-9) << "pose " << k;
    const double d = (folder.trajectory[k].pose - from_bag.trajectory[k].pose).cwiseAbs().maxCoeff();
    ASSERT_LT(d, 1e-9) << "pose " << k;
    largest_pose = std::max(largest_pose, d);
  }
  // The map is not empty: both extractors found what they feed (line and lamp).
  ASSERT_EQ(folder.map.size(), from_bag.map.size());
  std::set<int> types;
  for (const RunResult::Feature& f : folder.map)
    if (f.dim > 0) types.insert(f.type);
  EXPECT_EQ(types.size(), 2U) << "expected lines and lamps in the map, found " << types.size() << " type(s)";
  for (std::size_t i = 0; i < folder.map.size(); ++i) {
    const RunResult::Feature& a = folder.map[i];
    const RunResult::Feature& b = from_bag.map[i];
    ASSERT_EQ(a.id, b.id);
    ASSERT_EQ(a.type, b.type) << "feature " << a.id;
    ASSERT_EQ(a.dim, b.dim) << "feature " << a.id;
    ASSERT_EQ(a.coords.size(), b.coords.size()) << "feature " << a.id;
    const double d = (a.coords - b.coords).cwiseAbs().maxCoeff();
    ASSERT_LT(d, 1e-9) << "feature " << a.id;
    largest_coord = std::max(largest_coord, d);
  }
  std::cout << "bag and folder runs: " << folder.trajectory.size() << " poses, " << folder.map.size()
            << " features; largest differences " << largest_pose << " (pose), " << largest_coord
            << " (feature coordinates)\n";
}

// --- encodings ----------------------------------------------------------

/// A camera.yaml of a w × h camera with the given mount (camera.yaml's order).
fs::path write_camera_yaml(const fs::path& dir, int w, int h, const std::string& mount = "[0.1, 0, 0.4, 0, 0, 0]") {
  const fs::path file = dir / "camera.yaml";
  std::ofstream(file) << "width: " << w << "\nheight: " << h
                      << "\nfx: 10\nfy: 10\ncx: 4\ncy: 3\ndistortion: [0, 0, 0, 0, 0]\nmount: " << mount << "\n";
  return file;
}

/// Frames `images` at 100.0, 100.1, … with odometry along x around them.
CameraBag small_bag(const std::vector<CameraFrame>& images) {
  CameraBag bag;
  bag.frames = images;
  for (int i = -1; i <= static_cast<int>(images.size()); ++i)
    bag.odometry.push_back({100.0 + 0.1 * i, Eigen::Vector3d(0.01 * i, 0.0, 0.0)});
  return bag;
}

/// A 8 × 6 image of type `type` whose every pixel and channel differs.
cv::Mat test_image(int type) {
  cv::Mat image(6, 8, type);
  cv::randu(image, 0, type == CV_16UC1 ? 65536 : 256);
  return image;
}

/// The image files the source delivers for the bag's frames.
std::vector<cv::Mat> delivered(const CameraBag& contents, const std::string& name) {
  const fs::path dir = scratch(name);
  write_camera_bag(contents, dir / "b.bag");
  rosbag_source::RosbagSource source(camera_args(dir / "b.bag", write_camera_yaml(dir, 8, 6)));
  std::vector<cv::Mat> out;
  DataStep step;
  while (source.next(step)) out.push_back(read_unchanged(step.readings.at(0).file));
  return out;
}

TEST(RosbagCamera, EachEncodingKeepsItsPixels) {
  cv::theRNG().state = 7;
  const cv::Mat grey = test_image(CV_8UC1), colour = test_image(CV_8UC3), deep = test_image(CV_16UC1);
  const std::vector<cv::Mat> images = delivered(
      small_bag({frame_of(grey, 100.0, "mono8"), frame_of(grey, 100.1, "mono8", 11),  // rows padded to 11 bytes
                 frame_of(colour, 100.2, "bgr8"), frame_of(colour, 100.3, "rgb8"),
                 frame_of(deep, 100.4, "mono16", 0, false), frame_of(deep, 100.5, "mono16", 0, true)}),
      "encodings");
  ASSERT_EQ(images.size(), 6U);
  EXPECT_TRUE(same_pixels(images[0], grey));
  EXPECT_TRUE(same_pixels(images[1], grey)) << "padded rows";
  EXPECT_TRUE(same_pixels(images[2], colour)) << "bgr8";
  EXPECT_TRUE(same_pixels(images[3], colour)) << "rgb8 (stored in bgr order)";
  EXPECT_TRUE(same_pixels(images[4], deep)) << "mono16, little-endian";
  EXPECT_TRUE(same_pixels(images[5], deep)) << "mono16, big-endian";
}

// --- bad camera bags ----------------------------------------------------

/// The error of building the source on `contents` (camera.yaml 8 × 6 unless
/// the test changes it); `edit` may change the arguments.
std::string error_of(const CameraBag& contents, const std::string& name, fs::path& bag,
                     const std::function<void(PluginArgs&, const fs::path&)>& edit = {}) {
  const fs::path dir = scratch(name);
  bag = dir / (name + ".bag");
  write_camera_bag(contents, bag);
  PluginArgs args = camera_args(bag, write_camera_yaml(dir, 8, 6));
  if (edit) edit(args, dir);
  try {
    rosbag_source::RosbagSource source(args);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no error)";
}

CameraBag three_grey_frames() {
  const cv::Mat grey = test_image(CV_8UC1);
  return small_bag({frame_of(grey, 100.0, "mono8"), frame_of(grey, 100.1, "mono8"), frame_of(grey, 100.2, "mono8")});
}

TEST(RosbagCameraErrors, MissingImageTopicListsTheBagsTopics) {
  fs::path bag;
  const std::string e = error_of(three_grey_frames(), "missing_image", bag, [](PluginArgs& a, const fs::path&) {
    a.params.set("image_topic", std::string("/camera/color/image_raw"));
  });
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/color/image_raw is not in the bag; its topics:"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("/camera/image_raw (sensor_msgs/Image)"), std::string::npos) << e;
  EXPECT_NE(e.find("/odom (nav_msgs/Odometry)"), std::string::npos) << e;
}

TEST(RosbagCameraErrors, WrongMessageTypeOnTheImageTopic) {
  fs::path bag;
  const std::string e = error_of(three_grey_frames(), "image_wrong_type", bag,
                           [](PluginArgs& a, const fs::path&) { a.params.set("image_topic", std::string("/odom")); });
  EXPECT_NE(e.find(bag.string() + ": image_topic /odom carries nav_msgs/Odometry, expected sensor_msgs/Image"),
            std::string::npos)
      << e;
}

TEST(RosbagCameraErrors, DataSizeNotStepTimesHeightNamesBagAndStamp) {
  CameraBag contents = three_grey_frames();
  contents.frames[1].data.resize(contents.frames[1].data.size() - 8);  // a row short
  fs::path bag;
  const std::string e = error_of(contents, "short_data", bag);
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/image_raw: message 2 (stamp 100.100000000 s) is corrupt: "
                                  "data holds 40 bytes, step x height = 8 x 6 = 48"),
            std::string::npos)
      << e;
}

TEST(RosbagCameraErrors, StepShorterThanARowIsCorrupt) {
  CameraBag contents = three_grey_frames();
  contents.frames[2].step = 7;
  contents.frames[2].data.resize(7 * 6);
  fs::path bag;
  const std::string e = error_of(contents, "short_step", bag);
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/image_raw: message 3 (stamp 100.200000000 s) is corrupt: "
                                  "step 7 bytes is less than width x bytes per pixel = 8 x 1 (mono8)"),
            std::string::npos)
      << e;
}

TEST(RosbagCameraErrors, UnsupportedEncodingIsNamed) {
  CameraBag contents = three_grey_frames();
  contents.frames[0].encoding = "yuv422";
  fs::path bag;
  const std::string e = error_of(contents, "yuv", bag);
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/image_raw: message 1 (stamp 100.000000000 s) has encoding "
                                  "'yuv422'; supported: mono8, mono16, bgr8, rgb8"),
            std::string::npos)
      << e;
}

TEST(RosbagCameraErrors, ImageOfAnotherSizeThanCameraYaml) {
  fs::path bag;
  const std::string e = error_of(three_grey_frames(), "other_size", bag, [](PluginArgs& a, const fs::path& dir) {
    a.params.set("camera_yaml", write_camera_yaml(dir, 16, 12).string());
  });
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/image_raw: message 1 (stamp 100.000000000 s) is 8x6, "),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("camera.yaml says 16x12"), std::string::npos) << e;
}

TEST(RosbagCameraErrors, CameraYamlIsRequired) {
  fs::path bag;
  const std::string e = error_of(three_grey_frames(), "no_camera_yaml", bag, [](PluginArgs& a, const fs::path&) {
    a.params.set("camera_yaml", std::string());
  });
  EXPECT_NE(e.find(bag.string() + ": image_topic /camera/image_raw needs camera_yaml"), std::string::npos) << e;
}

TEST(RosbagCameraErrors, ScanKeysAreRefusedForACameraBag) {
  fs::path bag;
  const std::string e = error_of(three_grey_frames(), "scan_key", bag, [](PluginArgs& a, const fs::path&) {
    a.params.set("odometry", std::string("scan_matched"));
  });
  EXPECT_NE(e.find(bag.string() + ": 'odometry' applies to scans; with image_topic /camera/image_raw"),
            std::string::npos)
      << e;
}

TEST(RosbagCameraErrors, TfStaticMountMustAgreeWithCameraYaml) {
  CameraBag contents = three_grey_frames();
  contents.mount = {{Eigen::Vector3d(0.1, 0.0, 0.4), quaternion_of(make_pose(0, 0, 0, 0.0, 0.0, 0.0))}};
  fs::path bag;
  EXPECT_EQ(error_of(contents, "mount_agrees", bag), "(no error)");
  contents.mount->first.x() = 0.2;
  const std::string e = error_of(contents, "mount_differs", bag);
  EXPECT_NE(e.find(bag.string() + ": /tf_static base_link -> camera places the camera at [0.2, 0, 0.4, 0, 0, 0], "),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("camera.yaml gives mount [0.1, 0, 0.4, 0, 0, 0]"), std::string::npos) << e;
}

}  // namespace
}  // namespace mspace::rosbag_test
