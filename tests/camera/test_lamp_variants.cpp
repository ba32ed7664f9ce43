// Lamp detection on renderings unlike the one the detector was first written
// for: other lamp shapes and sizes, halos, fixture rings, unsaturated and
// unequal lamps, bright panels, resolution, vignetting, noise, blur and JPEG —
// each on three seeds (each seed moves the lamps and changes the greys and the
// noise). Recall and precision are measured against the renderer's true lamps
// (lamp_scoring.hpp). And the detector must not fire on ceilings without
// lamps: light panels, tile lines, wall/ceiling joints.
//
// MSPACE_LAMP_STRIDE=<n> scores every n-th frame of the route instead of the
// test's sparse sample (the figures of docs/ceiling-camera.md use 15).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <numbers>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "image_sequence/read_grey.hpp"
#include "lamp_scoring.hpp"
#include "lamps/lamps.hpp"

namespace mspace {
namespace {

using ceiling_render::CeilingRenderer;
using ceiling_render::CeilingWorld;
using ceiling_render::LampShape;
using camera_test::RenderVariant;

/// The sweep of lamps and cameras the detector has to generalise to.
std::vector<RenderVariant> lamp_variants() {
  std::vector<RenderVariant> v;
  auto add = [&](const char* name, auto&& change) {
    RenderVariant r{name};
    change(r);
    v.push_back(r);
  };
  add("default", [](RenderVariant&) {});
  // A square's circularity 4π·area/perimeter² is π/4 at most.
  add("square lamps 0.24 m", [](RenderVariant& r) {
    r.lamp_shape = LampShape::Square;
    r.lamp_radius = 0.12;
  });
  add("rounded rectangles 1.6:1", [](RenderVariant& r) {
    r.lamp_shape = LampShape::RoundedSquare;
    r.lamp_aspect = 1.6;
    r.lamp_radius = 0.08;
  });
  // Lamps 50-80 px across: several times the first renderer's areas in px².
  add("960x720 camera", [](RenderVariant& r) {
    r.scale = 3.0;
    r.supersampling = 1;
  });
  add("0.4 m square panels, 640x480", [](RenderVariant& r) {
    r.scale = 2.0;
    r.supersampling = 1;
    r.lamp_shape = LampShape::Square;
    r.lamp_radius = 0.2;
  });
  add("halo (+60 grey, 0.12 m)", [](RenderVariant& r) {
    r.halo_grey = 60.0;
    r.halo_width = 0.12;
  });
  add("dark fixture ring 3 cm", [](RenderVariant& r) {
    r.ring_width = 0.03;
    r.ring_grey = 60.0;
  });
  add("unsaturated (225, rim 20 % dimmer)", [](RenderVariant& r) {
    r.lamp_grey = 225.0;
    r.lamp_falloff = 0.2;
  });
  // Lamps between 225 and 255 next to panels brighter than any of them.
  add("unequal lamps, white panels", [](RenderVariant& r) {
    r.lamp_grey_spread = 0.12;
    r.panel_grey = 255.0;
  });
  add("JPEG quality 30, blur 1.5 px", [](RenderVariant& r) {
    r.jpeg_quality = 30;
    r.blur = 1.5;
  });
  // Known failures (kKnownFailures), the last two. Seed 1: a stretch of
  // ceiling or panel that strong vignetting lifts above its surroundings
  // passes as a lamp on a few frames (precision 0.86 on the sparse sample).
  add("vignetting 0.5, noise 8", [](RenderVariant& r) {
    r.vignetting = 0.5;
    r.noise = 8.0;
  });
  // A glow on a vignetting slope pulls the
  // half-maximum contour towards the image centre, up to 0.6° off.
  add("all: rounded, halo, unequal, vignetting, noise, JPEG, 640x480", [](RenderVariant& r) {
    r.scale = 2.0;
    r.supersampling = 1;
    r.lamp_shape = LampShape::RoundedSquare;
    r.lamp_aspect = 1.3;
    r.lamp_radius = 0.09;
    r.halo_grey = 30.0;
    r.lamp_grey_spread = 0.1;
    r.gain = 0.9;
    r.vignetting = 0.3;
    r.noise = 5.0;
    r.jpeg_quality = 50;
  });
  return v;
}

/// Every `stride`-th frame of the route: sparse in the test, denser for the
/// documented figures (MSPACE_LAMP_STRIDE).
std::size_t frame_stride() {
  const char* env = std::getenv("MSPACE_LAMP_STRIDE");
  return env ? static_cast<std::size_t>(std::max(1, std::atoi(env))) : 60;
}

/// The last this many variants of lamp_variants() are open problems: the
/// detector does not yet meet the bounds on them (docs/ceiling-camera.md has
/// the figures). Their cases are instantiated DISABLED_, with the same
/// bounds, to be run with --gtest_also_run_disabled_tests.
constexpr std::size_t kKnownFailures = 2;

using VariantAndSeed = std::tuple<std::size_t, std::uint64_t>;
class LampVariants : public ::testing::TestWithParam<VariantAndSeed> {};

// Bounds on every variant: at least 90 % of the lamps wholly in view found
// within 0.5° of their true bearing, at least 90 % of the detections at a
// lamp, and a mean bearing error under 0.15° (3× the default rendering's
// worst).
TEST_P(LampVariants, RecallAndPrecisionAgainstTheTrueLamps) {
  const auto [index, seed] = GetParam();
  const RenderVariant variant = lamp_variants()[index];
  const CeilingWorld world(seed, variant.appearance());
  const CeilingRenderer renderer(world, variant.settings(), seed);
  lamps::LampExtractor extractor{lamps::LampConfig{}};
  const camera_test::LampScore s = camera_test::score_lamps(world, renderer, extractor, frame_stride());
  camera_test::print_score((std::string(variant.name) + ", seed " + std::to_string(seed)).c_str(), s);
  EXPECT_GE(s.expected, 10);  // the sample sees lamps at all
  EXPECT_GE(s.recall(), 0.9);
  EXPECT_GE(s.precision(), 0.9);
  EXPECT_LE(s.mean_error(), 0.15 * camera_test::kDegree);
}

std::string variant_name(const ::testing::TestParamInfo<VariantAndSeed>& info) {
  std::string name = lamp_variants()[std::get<0>(info.param)].name;
  for (char& c : name)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return name + "_seed" + std::to_string(std::get<1>(info.param));
}

const std::size_t kVariants = lamp_variants().size();
INSTANTIATE_TEST_SUITE_P(RenderedCeilings, LampVariants,
                         ::testing::Combine(::testing::Range<std::size_t>(0, kVariants - kKnownFailures),
                                            ::testing::Values<std::uint64_t>(1, 2, 3)),
                         variant_name);
INSTANTIATE_TEST_SUITE_P(DISABLED_KnownFailures, LampVariants,
                         ::testing::Combine(::testing::Range<std::size_t>(kVariants - kKnownFailures, kVariants),
                                            ::testing::Values<std::uint64_t>(1, 2, 3)),
                         variant_name);

/// The route's ceiling without lamps: light panels as bright as lamps (full
/// white), tile lines 60 grey darker, wall/ceiling joints; `vignetting` as
/// given. Returns the detections on every 20th frame.
int detections_without_lamps(double vignetting) {
  RenderVariant variant{"no lamps, white panels"};
  variant.lamps = false;
  variant.panel_grey = 255.0;
  variant.vignetting = vignetting;
  variant.tile_darkening = 60.0;
  const CeilingWorld world(1, variant.appearance());
  EXPECT_TRUE(world.lamps().empty());
  const CeilingRenderer renderer(world, variant.settings(), 1);
  lamps::LampExtractor extractor{lamps::LampConfig{}};
  const camera_test::LampScore s = camera_test::score_lamps(world, renderer, extractor, 20);
  camera_test::print_score(vignetting > 0 ? "no lamps, white panels, vignetting" : "no lamps, white panels", s);
  return s.detections;
}

TEST(LampVariants, NoDetectionsOnPanelsAndLines) { EXPECT_EQ(detections_without_lamps(0.0), 0); }

// With vignetting the middle of the ceiling is brighter than its edges; a
// patch of it framed by tile lines or walls, or the part of a panel nearer
// the centre, must not pass as a lamp.
TEST(LampVariants, NoDetectionsOnPanelsAndLinesWithVignetting) { EXPECT_EQ(detections_without_lamps(0.4), 0); }

// A synthetic ceiling: bright bars of aspect 2.5 to 8 (light panels, seen
// at any angle) and bright lines are not lamps; a disc and a square of the
// same brightness in the same image are (so the test is not passed by a
// detector that finds nothing).
TEST(LampVariants, ElongatedPanelsAndLinesAreNotLamps) {
  cv::Mat1b image(480, 640, static_cast<std::uint8_t>(150));
  const auto bar = [&](cv::Point2f centre, float length, float width, float angle_deg) {
    const cv::RotatedRect r(centre, {length, width}, angle_deg);
    cv::Point2f corners[4];
    r.points(corners);
    std::vector<cv::Point> poly(corners, corners + 4);
    cv::fillConvexPoly(image, poly, 250, cv::LINE_AA);
  };
  bar({100, 80}, 100, 40, 0);    // aspect 2.5
  bar({300, 90}, 120, 30, 30);   // 4
  bar({500, 100}, 160, 20, 75);  // 8
  bar({120, 380}, 90, 30, 135);  // 3
  cv::line(image, {250, 300}, {420, 420}, 250, 3, cv::LINE_AA);
  cv::line(image, {20, 250}, {620, 240}, 250, 2, cv::LINE_AA);
  cv::circle(image, {560, 380}, 22, 250, cv::FILLED, cv::LINE_AA);
  cv::rectangle(image, cv::Rect(300, 180, 40, 40), 250, cv::FILLED);
  cv::GaussianBlur(image, image, {0, 0}, 0.8);

  camera::CameraModel cam = ceiling_render::default_camera();
  cam = ceiling_render::scaled_camera(cam, 2.0);
  cam.distortion = {0, 0, 0, 0, 0};
  lamps::LampExtractor extractor{lamps::LampConfig{}};
  std::vector<Measurement> seen;
  extractor.extract_image({image.cols, image.rows, image.data, image.step}, cam, seen);
  std::vector<Eigen::Vector2d> centres;
  for (const Measurement& m : seen) centres.push_back(cam.pixel_from_normalised(m.v.head<2>() / m.v.z()));
  ASSERT_EQ(centres.size(), 2u);
  std::sort(centres.begin(), centres.end(), [](const auto& a, const auto& b) { return a.x() < b.x(); });
  // The square's centre is (319.5, 199.5): pixels 300–339 and 180–219.
  EXPECT_NEAR((centres[0] - Eigen::Vector2d(319.5, 199.5)).norm(), 0.0, 0.3);
  EXPECT_NEAR((centres[1] - Eigen::Vector2d(560, 380)).norm(), 0.0, 0.3);
}

// A 12-bit camera's images in 16-bit PNGs (0–4095): OpenCV's plain 8-bit
// conversion divides by 256 and leaves 16 grey levels, in which no lamp has
// the contrast the detector needs. read_grey() takes the bit depth into
// account: the image read is the 8-bit rendering to within a grey level, and
// the lamps of the 8-bit rendering are found in it.
TEST(LampVariants, TwelveBitImagesInSixteenBitFilesAreReadToFullRange) {
  const CeilingWorld world(1);
  ceiling_render::RenderSettings settings{ceiling_render::default_camera()};
  settings.bit_depth = 12;
  const CeilingRenderer renderer(world, settings, 1);
  const std::filesystem::path dir = camera_test::scratch_dir("twelve_bit");
  int lamps_found = 0;
  std::size_t frame = 0;
  for (const Pose6& x_mr : camera_test::route_poses(200)) {
    const std::vector<float> levels = renderer.render_levels(x_mr, frame);
    cv::Mat deep;
    cv::Mat1f(settings.camera.height, settings.camera.width, const_cast<float*>(levels.data()))
        .convertTo(deep, CV_16U, 4095.0 / 255.0);
    cv::min(deep, 4095.0, deep);
    SensorReading reading;
    reading.channel = "camera";
    reading.file = (dir / ("frame" + std::to_string(frame) + ".png")).string();
    ASSERT_TRUE(cv::imwrite(reading.file, deep));
    double plain_max = 0.0;  // what OpenCV's 8-bit conversion makes of it
    cv::minMaxLoc(cv::imread(reading.file, cv::IMREAD_GRAYSCALE), nullptr, &plain_max);
    EXPECT_LE(plain_max, 16.0);
    const cv::Mat read = camera::read_grey(reading, settings.camera);
    ASSERT_EQ(read.type(), CV_8UC1);
    const ceiling_render::GreyImage eight = renderer.render(x_mr, frame);
    double worst = 0.0;
    cv::minMaxLoc(cv::abs(read - cv::Mat(eight.height, eight.width, CV_8UC1, const_cast<std::uint8_t*>(eight.pixels.data()))),
                  nullptr, &worst);
    EXPECT_LE(worst, 1.0) << reading.file;

    lamps::LampExtractor extractor{lamps::LampConfig{}};
    std::vector<Measurement> from_file, from_memory;
    extractor.extract_image({read.cols, read.rows, read.data, read.step}, settings.camera, from_file);
    extractor.extract_image(eight.view(), settings.camera, from_memory);
    ASSERT_EQ(from_file.size(), from_memory.size()) << reading.file;
    lamps_found += static_cast<int>(from_file.size());
    ++frame;
  }
  EXPECT_GE(lamps_found, 4);  // the frames sampled show lamps
}

}  // namespace
}  // namespace mspace
