// Throughput of the ceiling-camera extractors at 320×240 (issue 6 target:
// ≥ 1000 images/s per core each). Single-threaded; the images are rendered
// once (route poses spread over corridor — with its tile grid — and rooms)
// and the extractors run on them in memory. The *_FromPng variants include
// decoding the PNG file, as extract() on a reading does.
//
//   ./bin/bench_camera --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "ceiling_lines/ceiling_lines.hpp"
#include "ceiling_render/ceiling_renderer.hpp"
#include "image_sequence/camera_model.hpp"
#include "lamps/lamps.hpp"
#include "sim_world/route.hpp"

namespace {

using namespace mspace;

constexpr std::size_t kImages = 32;

struct Images {
  camera::CameraModel camera = ceiling_render::default_camera();
  std::vector<ceiling_render::GreyImage> images;
  std::vector<std::string> files;
};

/// kImages frames spread evenly along the renderer's route, in memory and as PNG files.
const Images& images() {
  static const Images set = [] {
    Images s;
    const ceiling_render::SequenceSettings settings;
    const ceiling_render::CeilingWorld world(settings.seed);
    const ceiling_render::CeilingRenderer renderer(world, settings.render, settings.seed);
    const auto trajectory = sim_world::drive_route(
        ceiling_render::CeilingWorld::route_waypoints(),
        {1, settings.speed, settings.dt, settings.max_turn_rate});
    const std::filesystem::path dir =
        std::filesystem::temp_directory_path() / "mspace_bench_camera";
    std::filesystem::create_directories(dir);
    for (std::size_t i = 0; i < kImages; ++i) {
      const std::size_t k = i * trajectory.poses.size() / kImages;
      s.images.push_back(renderer.render(trajectory.poses[k], k));
      const auto& img = s.images.back();
      const std::string file = (dir / (std::to_string(i) + ".png")).string();
      cv::imwrite(file, cv::Mat(img.height, img.width, CV_8UC1,
                                const_cast<std::uint8_t*>(img.pixels.data())));
      s.files.push_back(file);
    }
    return s;
  }();
  return set;
}

template <class Extractor, class Config>
void run_in_memory(benchmark::State& state) {
  const Images& set = images();
  Extractor extractor{Config{}};
  std::vector<Measurement> out;
  std::size_t i = 0, found = 0;
  for (auto _ : state) {
    out.clear();
    extractor.extract_image(set.images[i++ % kImages].view(), set.camera, out);
    found += out.size();
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
  state.counters["features_per_image"] =
      static_cast<double>(found) / static_cast<double>(state.iterations());
}

template <class Extractor, class Config>
void run_from_png(benchmark::State& state) {
  const Images& set = images();
  Extractor extractor{Config{}};
  SensorReading reading;
  reading.channel = "camera";
  reading.values = camera::reading_row(set.camera);
  std::vector<Measurement> out;
  std::size_t i = 0;
  for (auto _ : state) {
    out.clear();
    reading.file = set.files[i++ % kImages];
    extractor.extract(reading, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
}

void BM_CeilingLines(benchmark::State& s) {
  run_in_memory<ceiling_lines::CeilingLineExtractor, ceiling_lines::LineConfig>(s);
}
void BM_Lamps(benchmark::State& s) { run_in_memory<lamps::LampExtractor, lamps::LampConfig>(s); }
void BM_CeilingLines_FromPng(benchmark::State& s) {
  run_from_png<ceiling_lines::CeilingLineExtractor, ceiling_lines::LineConfig>(s);
}
void BM_Lamps_FromPng(benchmark::State& s) {
  run_from_png<lamps::LampExtractor, lamps::LampConfig>(s);
}

BENCHMARK(BM_CeilingLines)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Lamps)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_CeilingLines_FromPng)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Lamps_FromPng)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
