// pose_files.cpp — the pose files a run writes (TUM format) and the '#'
// header lines that say which body frame their poses are of and in which
// frame they are expressed. A third-party tool (evo, the TUM scripts) reads
// the header as comments; a user reads which file to compare with which:
// the run's ATE is that of the evaluated file (trajectory.tum, or
// trajectory_<sensor>.tum when evaluation.ground_truth_sensor is set) against
// ground_truth.tum, poses paired by time stamp, after SE(2) alignment.
#include <cmath>
#include <numbers>
#include <sstream>

#include "outputs.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

std::string robot_frame_name(const RunConfig& c) {
  return c.output.robot_frame.empty() ? std::string("robot base") : c.output.robot_frame;
}

/// "[x, y, z, theta, phi, psi]" in m and degrees, as the YAML writes a mount.
std::string pose_text(const Pose6& p) {
  const double deg = 180.0 / std::numbers::pi;
  std::ostringstream s;
  s << "[" << p[kX] << ", " << p[kY] << ", " << p[kZ] << ", " << p[kTheta] * deg << ", " << p[kPhi] * deg << ", "
    << p[kPsi] * deg << "]";
  return s.str();
}

/// The evaluated sensor's configuration, or nullptr.
const SensorConfig* evaluated_sensor(const RunConfig& c) {
  for (const SensorConfig& s : c.sensors)
    if (s.name == c.evaluation.ground_truth_sensor) return &s;
  return nullptr;
}

std::string sensor_frame_text(const SensorConfig& s) {
  return "sensor '" + s.name + "' (x_r ⊕ x_rs, eq. 17; mount x_rs = " + pose_text(s.mount) +
         " m/deg, relative to the robot frame)";
}

std::string map_frame_text(const Slam& slam) {
  const RunConfig& c = slam.config();
  if (const auto m = slam.map_session_report(); m && m->searched) {  // initial_pose: search
    if (m->localized)
      return "map frame: the frame of the loaded map " + m->file + "; the run found its pose there at step " +
             std::to_string(m->localized->step) + " (initial_pose: search) and its earlier poses are moved there too";
    return "frame of the run's first pose: the run did not find itself in the loaded map " + m->file +
           " (initial_pose: search), so these poses are NOT in the map's frame";
  }
  std::string text = "map frame: the frame the run starts in; ";
  if (!c.initial_pose.isZero())
    text += "the robot's initial pose there is initial_pose " + pose_text(c.initial_pose) + " of " +
            c.file.filename().string();
  else
    text += "the robot's initial pose there is the one source '" + c.source.instance + "' (plugin '" +
            c.source.plugin + "') gives";
  return text;
}

}  // namespace

std::string pose_file_frame(const Slam& slam, PoseFile which) {
  const RunConfig& c = slam.config();
  const SensorConfig* sensor = evaluated_sensor(c);
  const std::string robot = "robot frame: " + robot_frame_name(c) + " (the pose the motion model '" +
                            c.motion.plugin + "' moves; sensor mounts are relative to it)";
  std::ostringstream h;
  switch (which) {
    case PoseFile::Robot:
      h << "poses of the " << robot << "\n" << "in the " << map_frame_text(slam) << "\n";
      if (sensor != nullptr)
        h << "ground_truth.tum is of sensor '" << sensor->name << "': compare trajectory_" << sensor->name
          << ".tum with it, not this file\n";
      break;
    case PoseFile::EvaluatedSensor:
      h << "poses of the " << (sensor != nullptr ? sensor_frame_text(*sensor) : robot) << "\n"
        << "(" << robot << ")\n"
        << "in the " << map_frame_text(slam) << "\n"
        << "the run's ATE is this file against ground_truth.tum: poses paired by time stamp, SE(2) alignment\n";
      break;
    case PoseFile::DeadReckoning:
      h << "dead reckoning: the source's odometry increments through the motion model '" << c.motion.plugin
        << "' from the run's start, no update (summary.yaml's dead_reckoning figures; odometry: "
        << slam.odometry_description() << ")\n"
        << "poses of the " << robot << "\n" << "in the " << map_frame_text(slam) << "\n";
      break;
    case PoseFile::Reference: {
      h << "reference poses from source '" << c.source.instance << "' (plugin '" << c.source.plugin << "') of the "
        << (sensor != nullptr ? sensor_frame_text(*sensor) : robot) << "\n"
        << "in the reference's own frame (the run's ATE aligns the estimate to it by SE(2))\n";
      const auto& truth = slam.ground_truth();
      if (!truth.empty() && (truth.front().known & (1u << kTheta)) == 0)
        h << "positions only: the orientation is unknown (written as the identity quaternion)\n";
      if (!truth.empty() && (truth.front().known & (1u << kZ)) == 0) h << "the height z is unknown (written as 0)\n";
      h << "compare with " << (sensor != nullptr ? "trajectory_" + sensor->name + ".tum" : std::string("trajectory.tum"))
        << "\n";
      break;
    }
  }
  return h.str();
}

std::vector<std::filesystem::path> write_pose_files(const std::filesystem::path& dir, const Slam& slam) {
  namespace fs = std::filesystem;
  std::vector<fs::path> written;
  auto write = [&](const fs::path& file, const std::vector<StampedPose>& poses, PoseFile which) {
    write_atomically(file, [&](const fs::path& f) { write_tum(f, poses, pose_file_frame(slam, which)); });
    written.push_back(file);
  };
  write(dir / "trajectory.tum", slam.trajectory(), PoseFile::Robot);
  if (!slam.dead_reckoning().empty()) write(dir / "dead_reckoning.tum", slam.dead_reckoning(), PoseFile::DeadReckoning);
  if (slam.ground_truth().empty()) return written;
  write(dir / "ground_truth.tum", slam.ground_truth(), PoseFile::Reference);
  const std::string& sensor = slam.config().evaluation.ground_truth_sensor;
  if (!sensor.empty())
    write(dir / ("trajectory_" + sensor + ".tum"), slam.evaluated_trajectory(), PoseFile::EvaluatedSensor);
  return written;
}

}  // namespace mspace::kernel
