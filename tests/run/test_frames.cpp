// test_frames.cpp — pictures of the map as a run goes (output.frames,
// `--frames N`; MapFrames in outputs.hpp) on short runs of the built-in
// simulated world (config/sim_points.yaml), and the timing of the source's
// loading (Slam::source_load_seconds) in the summary.
#include <gtest/gtest.h>

#include <png.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "build_path.hpp"
#include "config.hpp"
#include "logging.hpp"
#include "outputs.hpp"
#include "plugin_registry.hpp"
#include "runner.hpp"
#include "slam.hpp"
#include "test_paths.hpp"

namespace {

using namespace mspace;
using namespace mspace::kernel;
namespace fs = std::filesystem;

/// A PNG read back with libpng: its size and its pixels (BGR, rows packed).
struct Png {
  int width = 0, height = 0;
  std::vector<unsigned char> pixels;
};

std::optional<Png> read_png(const fs::path& file) {
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  if (png_image_begin_read_from_file(&image, file.string().c_str()) == 0) return std::nullopt;
  image.format = PNG_FORMAT_BGR;
  Png png;
  png.width = static_cast<int>(image.width);
  png.height = static_cast<int>(image.height);
  png.pixels.resize(PNG_IMAGE_SIZE(image));
  if (png_image_finish_read(&image, nullptr, png.pixels.data(), 0, nullptr) == 0) return std::nullopt;
  return png;
}

/// The files in `dir`, sorted by name.
std::vector<std::string> files_in(const fs::path& dir) {
  std::set<std::string> names;
  for (const fs::directory_entry& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  return {names.begin(), names.end()};
}

class Frames : public ::testing::Test {
 protected:
  void SetUp() override {
    registry_.add_search_dir(MSPACE_PLUGIN_DIR);
    set_log_level(LogLevel::Warn);
    out_ = test::scratch_dir("frames", "out");
  }

  RunConfig config(std::int64_t steps, std::int64_t every) {
    RunConfig c = load_config(test::config_file("sim_points.yaml"), registry_);
    c.output.dir = out_.string();
    c.output.picture_size = 300;
    c.max_steps = steps;
    c.output.frames = every;
    return c;
  }

  RunResult run(const RunConfig& c) {
    Slam slam(c, registry_);
    RunOptions options;
    options.progress = false;
    return run_to_end(slam, options);
  }

  PluginRegistry registry_;
  fs::path out_;
};

// 650 steps, a frame every 100: frames at steps 100 … 600 and the last step
// (650), each a valid PNG of the configured size, one size for all; the map
// grows between frames, so no two consecutive frames are the same picture;
// the simulator knows its world (true landmarks), so the view is fixed from
// the first frame on.
TEST_F(Frames, ShortRunWritesValidFramesOfOneSizeThatChangeAsTheMapGrows) {
  const RunResult result = run(config(650, 100));
  ASSERT_TRUE(result.frames.has_value());
  const FramesReport& report = *result.frames;
  const std::vector<std::string> expected = {"frame_000100.png", "frame_000200.png", "frame_000300.png",
                                             "frame_000400.png", "frame_000500.png", "frame_000600.png",
                                             "frame_000650.png"};
  EXPECT_EQ(files_in(out_ / "frames"), expected);  // nothing else: no temporaries left
  EXPECT_EQ(report.written, 7);
  EXPECT_EQ(report.every, 100);
  EXPECT_EQ(report.folder, out_ / "frames");
  EXPECT_EQ(report.first, "frame_000100.png");
  EXPECT_EQ(report.last, "frame_000650.png");
  EXPECT_EQ(report.view_changes, 0);
  EXPECT_GT(report.seconds, 0.0);

  std::vector<Png> frames;
  for (const std::string& name : expected) {
    const std::optional<Png> png = read_png(out_ / "frames" / name);
    ASSERT_TRUE(png.has_value()) << name << " is not a PNG libpng can read";
    EXPECT_EQ(png->width, 300) << name;
    EXPECT_EQ(png->height, 300) << name;
    frames.push_back(*png);
  }
  for (std::size_t i = 1; i < frames.size(); ++i)
    EXPECT_NE(frames[i].pixels, frames[i - 1].pixels) << expected[i] << " is the same picture as " << expected[i - 1];
  // The final map.png is written as before, beside the frames.
  EXPECT_TRUE(fs::exists(out_ / "map.png"));
}

// A run ending on a multiple of N writes that frame once; frames of an
// earlier run in the folder past this run's start are removed, so the folder
// holds this run's frames only.
TEST_F(Frames, EndingOnAMultipleWritesItOnceAndOldFramesAreRemoved) {
  fs::create_directories(out_ / "frames");
  std::ofstream(out_ / "frames" / "frame_009900.png") << "an earlier, longer run's frame";
  std::ofstream(out_ / "frames" / "frame_000100.writing.png") << "a killed run's temporary";
  std::ofstream(out_ / "frames" / "notes.txt") << "the user's";
  const RunResult result = run(config(300, 150));
  ASSERT_TRUE(result.frames.has_value());
  EXPECT_EQ(result.frames->written, 2);
  EXPECT_EQ(files_in(out_ / "frames"),
            (std::vector<std::string>{"frame_000150.png", "frame_000300.png", "notes.txt"}));
}

// Off by default: no frames folder, no report.
TEST_F(Frames, NoneUnlessAsked) {
  const RunResult result = run(config(50, 0));
  EXPECT_FALSE(result.frames.has_value());
  EXPECT_FALSE(fs::exists(out_ / "frames"));
}

// output.frames is read and checked like the other output keys.
TEST_F(Frames, TheYamlKeyIsReadAndANegativeCountIsAnErrorNamingIt) {
  std::ifstream in(test::config_file("sim_points.yaml"));
  std::stringstream text;
  text << in.rdbuf();
  const std::string base = text.str();  // (it ends with its output section)
  EXPECT_EQ(parse_config(base + "  frames: 25\n", "frames.yaml", registry_).output.frames, 25);
  EXPECT_EQ(parse_config(base, "frames.yaml", registry_).output.frames, 0);
  try {
    parse_config(base + "  frames: -5\n", "frames.yaml", registry_);
    FAIL() << "output.frames: -5 was accepted";
  } catch (const ConfigError& e) {
    // file:line:column: key: problem
    EXPECT_NE(std::string(e.what()).find("frames.yaml:74:11: output.frames: -5 is out of range"), std::string::npos)
        << e.what();
  }
  // And it survives the resolved configuration (what a checkpoint stores).
  const RunConfig c = parse_config(base + "  frames: 25\n", "frames.yaml", registry_);
  EXPECT_EQ(parse_config(effective_config_yaml(c), "again.yaml", registry_).output.frames, 25);
}

// The source's loading (plugin and construction) is timed on its own: a
// positive figure in the run summary, in summary.yaml's timings_seconds as
// source_load, and on the printed time line.
TEST_F(Frames, SourceLoadingIsTimedInTheSummary) {
  RunConfig c = config(20, 0);
  Slam slam(c, registry_);
  EXPECT_GT(slam.source_load_seconds(), 0.0);
  RunOptions options;
  options.progress = false;
  const RunResult result = run_to_end(slam, options);
  EXPECT_EQ(result.summary.source_load_seconds, slam.source_load_seconds());
  const YAML::Node timings = YAML::LoadFile((out_ / "summary.yaml").string())["timings_seconds"];
  ASSERT_TRUE(timings && timings["source_load"]) << "summary.yaml has no timings_seconds.source_load";
  EXPECT_GT(timings["source_load"].as<double>(), 0.0);
  const std::string printed = format_summary(result.summary, slam);
  EXPECT_NE(printed.find("time: source load "), std::string::npos) << printed;
}

}  // namespace
