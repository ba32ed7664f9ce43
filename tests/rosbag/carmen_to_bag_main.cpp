// mspace-carmen-to-bag — writes a CARMEN log (or the Intel merged table) as a
// ROS 1 bag with rosbag_storage: /scan (sensor_msgs/LaserScan), /odom
// (nav_msgs/Odometry) or /tf, /tf_static (the log's laser offset) and
// /ground_truth (geometry_msgs/PoseStamped) when the log has corrected poses.
//
//   mspace-carmen-to-bag LOG OUT.bag [--tf] [--no-return M]
#include <cstdlib>
#include <exception>
#include <iostream>
#include <string>

#include "bag_writer.hpp"
#include "carmen_reader.hpp"

int main(int argc, char** argv) {
  if (argc < 3) {
    std::cerr << "usage: mspace-carmen-to-bag LOG OUT.bag [--tf] [--no-return M]\n"
                 "  --tf           odometry as /tf odom -> base_link (default: nav_msgs/Odometry on /odom)\n"
                 "  --no-return M  ranges at or beyond M metres are no return (default: from the log)\n";
    return 2;
  }
  mspace::carmen_log::ReaderOptions reader;
  reader.no_return_range = 0.0;
  mspace::rosbag_test::WriteOptions options;
  for (int i = 3; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--tf") {
      options.odometry_on_tf = true;
    } else if (arg == "--no-return" && i + 1 < argc) {
      reader.no_return_range = std::strtod(argv[++i], nullptr);
    } else {
      std::cerr << "mspace-carmen-to-bag: unknown argument " << arg << "\n";
      return 2;
    }
  }
  try {
    const mspace::carmen_log::LogContents log = mspace::carmen_log::read_log(argv[1], reader);
    options.static_mount = log.laser.offset;
    options.ground_truth = !log.scans.empty() && log.scans.front().ground_truth.has_value();
    mspace::rosbag_test::write_bag(log, argv[2], options);
    std::cout << argv[2] << ": " << log.scans.size() << " scans" << (options.ground_truth ? ", ground truth" : "")
              << (options.static_mount ? ", /tf_static mount" : "") << "\n";
  } catch (const std::exception& e) {
    std::cerr << "mspace-carmen-to-bag: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
