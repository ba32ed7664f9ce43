// picture.cpp — a top view of a run drawn with OpenCV: true landmarks, the
// map's features shaded by M-space dimension (with 3σ ellipses of their point
// blocks), the estimated and the true trajectory, a scale bar and a legend.
// Generic: a feature is drawn as it asks (Feature::drawing: polygons,
// segments, labelled points in map coordinates, or directions known without
// a position) or, by default, from its coordinate blocks only (a point block
// as a dot, several point blocks as a polyline through them). When features
// have 3-D points off the ground plane (e.g. on a ceiling) a side view
// (x against height) is added under the top view, and single such points are
// drawn as squares. The occupancy grid's picture (grid.png) draws the same
// features over the grid. MapFrames draws the top view every N steps of a
// run in one fixed view, with the loop closures so far.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>
#include <sstream>
#include <stdexcept>

#include <Eigen/Eigenvalues>
#include <png.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "occupancy_grid.hpp"
#include "outputs.hpp"
#include "picture.hpp"
#include "slam.hpp"

namespace mspace::kernel {
namespace {

/// The side view under the top view: x as in the top view, height z upwards.
struct SideView {
  const View* top = nullptr;
  double min_z = 0;
  int bottom = 0;  ///< image row of min_z
  cv::Point px(double x, double z) const {
    return {top->px(x, 0).x, bottom - static_cast<int>(std::lround((z - min_z) * top->scale))};
  }
};

/// xyz of every 3-D point block of a feature.
std::vector<Eigen::Vector3d> point3d_blocks(const Feature& f) {
  std::vector<Eigen::Vector3d> pts;
  const CoordLayout& layout = f.layout();
  for (int b = 0; b < layout.num_blocks(); ++b)
    if (layout.kind(b) == BlockKind::Point3D) pts.push_back(f.coords().segment<3>(layout.offset(b)));
  return pts;
}

/// Features with 3-D points off the ground plane (e.g. on a ceiling) get a
/// side view; a single such point is drawn as a square.
constexpr double kOffGround = 0.05;  // m

bool off_ground(const Feature& f) {
  for (const Eigen::Vector3d& p : point3d_blocks(f))
    if (std::abs(p.z()) > kOffGround) return true;
  return false;
}

/// xy of every point block of a feature.
std::vector<Eigen::Vector2d> point_blocks(const Feature& f) {
  std::vector<Eigen::Vector2d> pts;
  const CoordLayout& layout = f.layout();
  for (int b = 0; b < layout.num_blocks(); ++b) {
    if (layout.kind(b) == BlockKind::Scalar) continue;
    pts.emplace_back(f.coords()[layout.offset(b)], f.coords()[layout.offset(b) + 1]);
  }
  return pts;
}

/// Shade by M-space dimension relative to the type's maximum: tentative
/// features light grey, then from light to dark blue-violet.
cv::Scalar dim_colour(int dim, int max_dim) {
  if (dim == 0) return {200, 200, 200};
  const double f = max_dim > 0 ? static_cast<double>(dim) / max_dim : 1.0;
  return {static_cast<double>(230 - 150 * f), static_cast<double>(160 - 140 * f), static_cast<double>(120 - 100 * f)};
}

/// Whether the feature has a position to draw: not when all it asks to be
/// drawn as is directions (FeatureDrawing::direction_only), e.g. a line
/// whose M-space holds its direction only; its coordinates are then a guess.
bool placed(const Feature& f) {
  const std::optional<FeatureDrawing> drawing = f.drawing();
  return !(drawing && drawing->direction_only());
}

/// Where a direction-only feature's glyphs are shown (the first column of
/// each pair of its Direction items).
std::vector<Eigen::Vector2d> direction_places(const Feature& f) {
  std::vector<Eigen::Vector2d> places;
  if (const std::optional<FeatureDrawing> drawing = f.drawing())
    for (const DrawingItem& item : drawing->items)
      if (item.kind == DrawingItem::Kind::Direction)
        for (Eigen::Index i = 0; i + 1 < item.points.cols(); i += 2) places.emplace_back(item.points.col(i));
  return places;
}

/// The glyph of a direction known without a position: a dashed double-headed
/// arrow of fixed length in pixels (not to scale: it spans no known extent)
/// through a small ring at the place it is shown at (where it was seen from).
/// Dashed and thin, unlike every placed item (solid, 2 px).
void draw_direction_glyph(cv::Mat& img, const cv::Point& at, const Eigen::Vector2d& direction,
                          const cv::Scalar& colour) {
  constexpr double kRing = 3.0, kHalf = 16.0, kDash = 4.0, kGap = 4.0, kHead = 5.0;  // px
  const double norm = direction.norm();
  if (!(norm > 0.0)) return;
  const cv::Point2d d(direction.x() / norm, -direction.y() / norm);  // image rows grow downwards
  const cv::Point2d c(at.x, at.y);
  auto pt = [](const cv::Point2d& p) {
    return cv::Point(static_cast<int>(std::lround(p.x)), static_cast<int>(std::lround(p.y)));
  };
  // Dashes and heads the same on both sides of the ring (-d draws the same
  // glyph): an open head at each end, the line's sense is not known either.
  for (const double sign : {-1.0, 1.0}) {
    for (double s = kRing + 1.0; s < kHalf; s += kDash + kGap)
      cv::line(img, pt(c + d * (sign * s)), pt(c + d * (sign * std::min(s + kDash, kHalf))), colour, 1, cv::LINE_AA);
    const cv::Point2d tip = c + d * (sign * kHalf);
    const cv::Point2d back = d * (-sign * kHead), side(-d.y * kHead * 0.6, d.x * kHead * 0.6);
    cv::line(img, pt(tip), pt(tip + back + side), colour, 1, cv::LINE_AA);
    cv::line(img, pt(tip), pt(tip + back - side), colour, 1, cv::LINE_AA);
  }
  cv::circle(img, at, static_cast<int>(kRing), colour, 1, cv::LINE_AA);
}

void draw_ellipse(cv::Mat& img, const View& v, const Eigen::Vector2d& c, const Eigen::Matrix2d& cov,
                  const cv::Scalar& colour) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  if (es.info() != Eigen::Success || es.eigenvalues().minCoeff() < 0) return;
  const double k = 3.0;  // 3σ
  const Eigen::Vector2d major = es.eigenvectors().col(1);
  const double angle = -std::atan2(major.y(), major.x()) * 180.0 / std::numbers::pi;
  const cv::Size axes(std::max(1, static_cast<int>(k * std::sqrt(es.eigenvalues()[1]) * v.scale)),
                      std::max(1, static_cast<int>(k * std::sqrt(es.eigenvalues()[0]) * v.scale)));
  cv::ellipse(img, v.px(c.x(), c.y()), axes, angle, 0, 360, colour, 1, cv::LINE_AA);
}

/// The map's features over a top view: as their drawing() asks, or point
/// blocks as dots (to scale when the feature has a footprint), several point
/// blocks as a polyline, shaded by M-space dimension, with 3σ ellipses of
/// placed features; shared coordinates as squares.
void draw_features(cv::Mat& img, const View& v, const Slam& slam) {
  bool covariances_readable = true;
  for (const MapFeature& f : slam.features()) {
    const int dim = f.feature->mspace_dim();
    const int max_dim = slam.feature_types()[f.type].type->max_mspace_dim();
    const cv::Scalar colour = dim_colour(dim, max_dim);
    const std::vector<Eigen::Vector2d> pts = point_blocks(*f.feature);
    const std::optional<FeatureDrawing> drawing = f.feature->drawing();
    if (drawing) {
      draw_feature_drawing(img, v, *drawing, colour);
    } else if (pts.size() >= 2) {
      for (std::size_t i = 0; i + 1 < pts.size(); ++i)
        cv::line(img, v.px(pts[i].x(), pts[i].y()), v.px(pts[i + 1].x(), pts[i + 1].y()), colour, 2, cv::LINE_AA);
    } else if (pts.size() == 1) {
      const std::optional<double> radius = f.feature->footprint_radius();
      if (off_ground(*f.feature)) {
        const cv::Point q = v.px(pts[0].x(), pts[0].y());
        cv::rectangle(img, q - cv::Point(3, 3), q + cv::Point(3, 3), colour, cv::FILLED, cv::LINE_AA);
      } else if (radius && *radius * v.scale >= 2.0)  // drawn to scale when it shows
        cv::circle(img, v.px(pts[0].x(), pts[0].y()), static_cast<int>(std::lround(*radius * v.scale)), colour, 2,
                   cv::LINE_AA);
      else
        cv::circle(img, v.px(pts[0].x(), pts[0].y()), dim > 0 ? 3 : 2, colour, cv::FILLED, cv::LINE_AA);
    }
    // No ellipses where no position is known: they would sit at guessed points.
    if (dim == 0 || (drawing && drawing->direction_only()) || !covariances_readable) continue;
    // Covariance of x_f implied by the M-space covariance: B̃ P B̃ᵀ (eq. 11).
    // A run stopped by a broken estimator may have none to give: the map is
    // drawn without ellipses then.
    Eigen::MatrixXd P;
    try {
      P = slam.feature_covariance(f);
    } catch (const std::exception&) {
      covariances_readable = false;
      continue;
    }
    const Eigen::MatrixXd Bd = f.feature->B_dual();
    const Eigen::MatrixXd C = Bd * P * Bd.transpose();
    const CoordLayout& layout = f.feature->layout();
    for (int b = 0, p = 0; b < layout.num_blocks(); ++b) {
      if (layout.kind(b) == BlockKind::Scalar) continue;
      const int o = layout.offset(b);
      draw_ellipse(img, v, pts[p++], C.block<2, 2>(o, o), colour);
    }
  }

  // Shared coordinates (e.g. a corner two features meet at) as squares.
  for (const SharedCoordinate& c : slam.shared_coordinates()) {
    const Eigen::VectorXd p = slam.shared_value(c);
    if (p.size() < 2) continue;
    const cv::Point q = v.px(p[0], p[1]);
    cv::rectangle(img, q - cv::Point(4, 4), q + cv::Point(4, 4), {0, 0, 200}, 2, cv::LINE_AA);
  }
}

/// An axis-aligned extent in the map (metres).
struct Box {
  double lo_x = 1e300, lo_y = 1e300, hi_x = -1e300, hi_y = -1e300;
  bool empty() const { return lo_x > hi_x; }
  void grow(double x, double y) {
    lo_x = std::min(lo_x, x), lo_y = std::min(lo_y, y), hi_x = std::max(hi_x, x), hi_y = std::max(hi_y, y);
  }
  void grow(const Box& b) {
    if (!b.empty()) grow(b.lo_x, b.lo_y), grow(b.hi_x, b.hi_y);
  }
  bool contains(const Box& b) const {
    return b.empty() || (b.lo_x >= lo_x && b.lo_y >= lo_y && b.hi_x <= hi_x && b.hi_y <= hi_y);
  }
  /// The same, `margin` metres wider on every side.
  Box padded(double margin) const { return {lo_x - margin, lo_y - margin, hi_x + margin, hi_y + margin}; }
  double span() const { return std::max(hi_x - lo_x, hi_y - lo_y); }
};

/// Everything a top view draws: the paths, the placed features in the
/// map, where direction-only ones are shown, the true landmarks.
Box content_box(const Slam& slam) {
  Box box;
  for (const StampedPose& p : slam.trajectory()) box.grow(p.pose[kX], p.pose[kY]);
  for (const StampedPose& p : slam.ground_truth()) box.grow(p.pose[kX], p.pose[kY]);
  for (const MapFeature& f : slam.features()) {
    if (f.feature->mspace_dim() == 0) continue;
    for (const Eigen::Vector2d& p : placed(*f.feature) ? point_blocks(*f.feature) : direction_places(*f.feature))
      box.grow(p.x(), p.y());
  }
  const Eigen::MatrixXd truth = slam.true_landmarks();
  for (Eigen::Index i = 0; i < truth.cols(); ++i) box.grow(truth(0, i), truth(1, i));
  return box;
}

/// The square view of size_px pixels centred on `box` (at least 1 m across).
View square_view(Box box, int size_px) {
  if (box.empty()) box = {-1, -1, 1, 1};
  View v;
  v.size = size_px;
  const double span = std::max(box.span(), 1.0);
  v.scale = (size_px - 2.0 * v.margin) / span;
  v.min_x = box.lo_x - 0.5 * (span - (box.hi_x - box.lo_x));
  v.min_y = box.lo_y - 0.5 * (span - (box.hi_y - box.lo_y));
  return v;
}

/// The metres a square view spans inside its margins.
double view_span(const View& v) { return (v.size - 2.0 * v.margin) / v.scale; }

/// What a frame adds to the top view.
struct FrameMarks {
  std::int64_t step = 0;
  const std::vector<std::size_t>* closures = nullptr;  ///< trajectory indices of the loop closures so far
};

/// The top view in the square of `v` (rows 0 … v.size of img): grid, true
/// landmarks, paths, features, a frame's loop closures, scale bar, legend
/// and title.
void draw_top_view(cv::Mat& img, const View& v, const Slam& slam, const FrameMarks* frame) {
  const double span = view_span(v);
  // Grid every 10 m (or 1 m for small worlds).
  const double grid = span > 30 ? 10.0 : 1.0;
  for (double gx = std::floor(v.min_x / grid) * grid; gx <= v.min_x + span; gx += grid)
    cv::line(img, v.px(gx, v.min_y), v.px(gx, v.min_y + span), {235, 235, 235}, 1);
  for (double gy = std::floor(v.min_y / grid) * grid; gy <= v.min_y + span; gy += grid)
    cv::line(img, v.px(v.min_x, gy), v.px(v.min_x + span, gy), {235, 235, 235}, 1);

  const Eigen::MatrixXd truth = slam.true_landmarks();
  for (Eigen::Index i = 0; i < truth.cols(); ++i)
    cv::drawMarker(img, v.px(truth(0, i), truth(1, i)), {120, 120, 120}, cv::MARKER_CROSS, 9, 1, cv::LINE_AA);

  // A path, broken where consecutive poses are much farther apart in time
  // than usual (more than 1 s and 5 times the median interval): gaps in a
  // reference such as GPS are not joined by straight lines, while a log with
  // one pose every few seconds is still drawn as a path.
  auto polyline = [&](const std::vector<StampedPose>& poses, const cv::Scalar& colour, int width) {
    std::vector<double> dts;
    for (std::size_t i = 1; i < poses.size(); ++i) dts.push_back(poses[i].t - poses[i - 1].t);
    double gap = 1.0;
    if (!dts.empty()) {
      std::nth_element(dts.begin(), dts.begin() + static_cast<long>(dts.size() / 2), dts.end());
      gap = std::max(gap, 5.0 * dts[dts.size() / 2]);
    }
    std::vector<cv::Point> pts;
    for (std::size_t i = 0; i <= poses.size(); ++i) {
      if (i == poses.size() || (i > 0 && poses[i].t - poses[i - 1].t > gap)) {
        if (pts.size() > 1) cv::polylines(img, pts, false, colour, width, cv::LINE_AA);
        pts.clear();
      }
      if (i < poses.size()) pts.push_back(v.px(poses[i].pose[kX], poses[i].pose[kY]));
    }
  };
  // Position-only references (e.g. GPS fixes) as dots, full poses as a path.
  const auto& truth_poses = slam.ground_truth();
  const bool positions_only =
      !truth_poses.empty() && (truth_poses.front().known & (1u << kTheta)) == 0;
  if (positions_only)
    for (const StampedPose& p : truth_poses) cv::circle(img, v.px(p.pose[kX], p.pose[kY]), 1, {60, 170, 60}, cv::FILLED);
  else
    polyline(truth_poses, {60, 170, 60}, 2);
  polyline(slam.trajectory(), {200, 80, 30}, 1);

  draw_features(img, v, slam);

  // A frame's loop closures: a ring where the robot was when each closed,
  // at that pose's current estimate.
  const cv::Scalar closure_colour(220, 0, 220);  // magenta: unlike the paths, features and shared coordinates
  int closures = 0;
  if (frame != nullptr && frame->closures != nullptr)
    for (const std::size_t i : *frame->closures) {
      if (i >= slam.trajectory().size()) continue;
      const Pose6& p = slam.trajectory()[i].pose;
      cv::circle(img, v.px(p[kX], p[kY]), 10, closure_colour, 3, cv::LINE_AA);
      ++closures;
    }

  // initial_pose: search — where the run found itself in the map (the poses
  // before it were moved there with it): an orange ring and tick along the heading.
  const cv::Scalar found_colour(0, 140, 255);
  std::optional<Slam::MapSessionReport::Localization> found;
  if (const auto m = slam.map_session_report(); m && m->localized) found = m->localized;
  if (found) {
    const cv::Point at = v.px(found->x, found->y);
    cv::circle(img, at, 9, found_colour, 3, cv::LINE_AA);
    cv::line(img, at, at + cv::Point(static_cast<int>(std::lround(18 * std::cos(found->theta))),
                                      -static_cast<int>(std::lround(18 * std::sin(found->theta)))),
             found_colour, 3, cv::LINE_AA);
  }

  // Scale bar and legend.
  const double bar = grid;
  const cv::Point bar0(v.margin, v.size - v.margin / 2);  // under the top view
  cv::line(img, bar0, bar0 + cv::Point(static_cast<int>(bar * v.scale), 0), {0, 0, 0}, 2);
  cv::putText(img, std::to_string(static_cast<int>(bar)) + " m", bar0 + cv::Point(5, -6), cv::FONT_HERSHEY_SIMPLEX,
              0.45, {0, 0, 0}, 1, cv::LINE_AA);
  int row = 20;
  auto legend_text = [&](const std::string& text, int x = 36) {
    cv::putText(img, text, {x, row}, cv::FONT_HERSHEY_SIMPLEX, 0.45, {0, 0, 0}, 1, cv::LINE_AA);
    row += 18;
  };
  auto legend = [&](const std::string& text, const cv::Scalar& colour) {
    cv::line(img, {10, row - 4}, {30, row - 4}, colour, 3);
    legend_text(text);
  };
  legend("estimated trajectory", {200, 80, 30});
  if (!slam.ground_truth().empty()) {
    // A reference that is not the truth (evaluation.reference) is named as what it is.
    const std::string& reference = slam.config().evaluation.reference;
    std::string label = positions_only ? "reference positions (dots)" : "true trajectory";
    if (!reference.empty()) label = "reference: " + reference + (positions_only ? " (dots)" : "");
    legend(label, {60, 170, 60});
  }
  if (truth.cols() > 0) legend("true landmarks (+)", {120, 120, 120});
  legend("features, darker = higher M-space dim; 3-sigma ellipses", dim_colour(1, 1));
  // One line per feature type: how many, and at which M-space dimensions.
  bool any_direction_only = false;
  for (std::size_t t = 0; t < slam.feature_types().size(); ++t) {
    int count = 0, lowest = 1 << 30, highest = -1;
    for (const MapFeature& f : slam.features()) {
      if (f.type != static_cast<int>(t) || f.feature->mspace_dim() == 0) continue;
      ++count;
      lowest = std::min(lowest, f.feature->mspace_dim());
      highest = std::max(highest, f.feature->mspace_dim());
      any_direction_only = any_direction_only || !placed(*f.feature);
    }
    if (count == 0) continue;
    const FeatureTypeSlot& slot = slam.feature_types()[t];
    std::ostringstream text;  // (not string + string: GCC 12 warns falsely on that here)
    text << "  " << slot.instance << " (" << slot.plugin << "): " << count << ", M-space dim " << lowest;
    if (highest > lowest) text << "-" << highest;
    legend(text.str(), dim_colour(highest, highest));
  }
  if (any_direction_only) {
    draw_direction_glyph(img, {19, row - 4}, {1.0, 0.0}, {0, 0, 0});
    legend_text("direction only, position unknown: shown where last seen from, not to scale", 42);
  }
  if (!slam.shared_coordinates().empty()) legend("shared coordinates (squares)", {0, 0, 200});
  if (closures > 0) {
    cv::circle(img, {20, row - 4}, 6, closure_colour, 3, cv::LINE_AA);
    legend_text("loop closed here (" + std::to_string(closures) + ")");
  }
  if (found) {
    cv::circle(img, {20, row - 4}, 6, found_colour, 3, cv::LINE_AA);
    legend_text("found in the map here at step " + std::to_string(found->step) + " (initial_pose: search)");
  }
  std::string title = slam.config().name;
  if (frame != nullptr) title += ", step " + std::to_string(frame->step);
  int baseline = 0;
  const int title_width = cv::getTextSize(title, cv::FONT_HERSHEY_SIMPLEX, 0.5, 1, &baseline).width;
  cv::putText(img, title, {std::min(v.size - 220, v.size - 10 - title_width), 20}, cv::FONT_HERSHEY_SIMPLEX, 0.5,
              {0, 0, 0}, 1, cv::LINE_AA);
}

/// Writes img (BGR) as a PNG.
void encode_png(const std::filesystem::path& file, const cv::Mat& img) {
  if (file.has_parent_path()) std::filesystem::create_directories(file.parent_path());
  // Encoded with libpng's simplified API rather than OpenCV's imgcodecs, whose
  // dependencies (GDAL, codecs, …) would add ~0.2 s of start-up to every run.
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  png.width = static_cast<png_uint_32>(img.cols);
  png.height = static_cast<png_uint_32>(img.rows);
  png.format = PNG_FORMAT_BGR;
  png.flags = PNG_IMAGE_FLAG_FAST;  // faster compression; a map picture is mostly flat colour
  if (png_image_write_to_file(&png, file.string().c_str(), 0, img.data, static_cast<png_int_32>(img.step), nullptr) == 0)
    throw std::runtime_error("cannot write picture '" + file.string() + "': " + png.message);
}

}  // namespace

void draw_feature_drawing(cv::Mat& img, const View& v, const FeatureDrawing& drawing, const cv::Scalar& colour) {
  for (const DrawingItem& item : drawing.items) {
    const Eigen::Index n = item.points.cols();
    if (n == 0) continue;
    auto at = [&](Eigen::Index i) { return v.px(item.points(0, i), item.points(1, i)); };
    switch (item.kind) {
      case DrawingItem::Kind::Polygon:  // closed: the last point joins the first
        for (Eigen::Index i = 0; i < n; ++i) cv::line(img, at(i), at((i + 1) % n), colour, 2, cv::LINE_AA);
        break;
      case DrawingItem::Kind::Segments:
        for (Eigen::Index i = 0; i + 1 < n; i += 2) cv::line(img, at(i), at(i + 1), colour, 2, cv::LINE_AA);
        break;
      case DrawingItem::Kind::Points:
        for (Eigen::Index i = 0; i < n; ++i) cv::circle(img, at(i), 3, colour, cv::FILLED, cv::LINE_AA);
        break;
      case DrawingItem::Kind::Direction:  // (place, direction) pairs
        for (Eigen::Index i = 0; i + 1 < n; i += 2) draw_direction_glyph(img, at(i), item.points.col(i + 1), colour);
        break;
    }
    if (!item.label.empty())
      cv::putText(img, item.label, at(0) + cv::Point(5, -5), cv::FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv::LINE_AA);
  }
}

void write_picture(const std::filesystem::path& file, const Slam& slam, int size_px) {
  const View v = square_view(content_box(slam), size_px);
  const double span = view_span(v);
  // Heights of the placed features off the ground plane, for the side view.
  double lo_z = 0.0, hi_z = 0.0;
  bool side = false;
  for (const MapFeature& f : slam.features()) {
    if (f.feature->mspace_dim() == 0 || !off_ground(*f.feature) || !placed(*f.feature)) continue;
    side = true;
    for (const Eigen::Vector3d& p : point3d_blocks(*f.feature)) lo_z = std::min(lo_z, p.z()), hi_z = std::max(hi_z, p.z());
  }
  const int side_px = side ? static_cast<int>(std::lround((hi_z - lo_z) * v.scale)) + 2 * v.margin : 0;
  cv::Mat img(size_px + side_px, size_px, CV_8UC3, cv::Scalar(255, 255, 255));
  SideView sv{&v, lo_z, size_px + side_px - v.margin};

  draw_top_view(img, v, slam, nullptr);

  if (side) {
    // Side view: x against height, the ground (z = 0) and the path on it.
    cv::line(img, {0, size_px}, {size_px, size_px}, {180, 180, 180}, 1);
    cv::line(img, sv.px(v.min_x, 0), sv.px(v.min_x + span, 0), {235, 235, 235}, 1);
    for (double gz = std::ceil(lo_z); gz <= hi_z; gz += 1.0)
      if (gz != 0.0) cv::line(img, sv.px(v.min_x, gz), sv.px(v.min_x + span, gz), {235, 235, 235}, 1);
    for (const StampedPose& p : slam.trajectory()) img.at<cv::Vec3b>(sv.px(p.pose[kX], 0)) = {200, 80, 30};
    for (const MapFeature& f : slam.features()) {
      const int dim = f.feature->mspace_dim();
      if (dim == 0 || !off_ground(*f.feature) || !placed(*f.feature)) continue;
      const cv::Scalar colour = dim_colour(dim, slam.feature_types()[f.type].type->max_mspace_dim());
      const std::vector<Eigen::Vector3d> pts = point3d_blocks(*f.feature);
      for (std::size_t i = 0; i + 1 < pts.size(); ++i)
        cv::line(img, sv.px(pts[i].x(), pts[i].z()), sv.px(pts[i + 1].x(), pts[i + 1].z()), colour, 2, cv::LINE_AA);
      if (pts.size() == 1) {
        const cv::Point q = sv.px(pts[0].x(), pts[0].z());
        cv::rectangle(img, q - cv::Point(3, 3), q + cv::Point(3, 3), colour, cv::FILLED, cv::LINE_AA);
      }
    }
    cv::putText(img, "side view: x (m) against height z (m), grid every 1 m", {10, size_px + 18},
                cv::FONT_HERSHEY_SIMPLEX, 0.45, {0, 0, 0}, 1, cv::LINE_AA);
  }
  encode_png(file, img);
}

void write_grid_picture(const std::filesystem::path& file, const Slam& slam, const OccupancyGrid& grid, int size_px) {
  // The grid's extent, its longer side size_px pixels wide. View::px counts
  // rows from v.size, the image's height.
  View v;
  v.margin = 10;
  const int cells = std::max(grid.width, grid.height);
  const int inner = std::max(size_px, 64) - 2 * v.margin;
  v.scale = inner / (cells * grid.resolution);
  v.min_x = grid.origin.x();
  v.min_y = grid.origin.y();
  const int cols = static_cast<int>(std::lround(grid.width * grid.resolution * v.scale)) + 2 * v.margin;
  v.size = static_cast<int>(std::lround(grid.height * grid.resolution * v.scale)) + 2 * v.margin + 20;  // + title
  cv::Mat img(v.size, cols, CV_8UC3, cv::Scalar(255, 255, 255));
  // Each pixel shows the cell under its centre: occupied black, free white,
  // unknown grey (as map_server reads grid.pgm).
  for (int row = 0; row < img.rows; ++row)
    for (int col = 0; col < img.cols; ++col) {
      const Eigen::Vector2d p(v.min_x + (col - v.margin + 0.5) / v.scale, v.min_y + (v.size - v.margin - row - 0.5) / v.scale);
      const Eigen::Vector2i c = grid.cell_of(p);
      if (!grid.contains(c.x(), c.y())) continue;
      const OccupancyGrid::Cell cell = grid.cell(c.x(), c.y());
      const unsigned char g = cell == OccupancyGrid::Cell::Occupied ? 0 : cell == OccupancyGrid::Cell::Free ? 255 : 205;
      img.at<cv::Vec3b>(row, col) = {g, g, g};
    }
  std::vector<cv::Point> path;
  for (const StampedPose& p : slam.trajectory()) path.push_back(v.px(p.pose[kX], p.pose[kY]));
  if (path.size() > 1) cv::polylines(img, path, false, {200, 80, 30}, 1, cv::LINE_AA);
  draw_features(img, v, slam);
  cv::putText(img, slam.config().name + ": occupancy grid (" + std::to_string(grid.width) + " x " +
                       std::to_string(grid.height) + " cells), features, path",
              {10, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.45, {0, 0, 200}, 1, cv::LINE_AA);
  encode_png(file, img);
}

// ---- Frames ---------------------------------------------------------------------

struct MapFrames::Impl {
  FramesReport report;
  int size_px = 1000;
  std::optional<Box> view;  ///< the view's extent (m), fixed once the first frame is drawn
  std::int64_t last_step = -1;
  std::int64_t closures_seen = 0;
  std::vector<std::size_t> closures;  ///< trajectory index of each loop closure

  /// The frame's file: the step zero-padded to 6 digits, so that the names
  /// sort by step (a glob in ffmpeg or ImageMagick takes them in order).
  static std::string file_name(std::int64_t step) {
    char name[40];
    std::snprintf(name, sizeof name, "frame_%06lld.png", static_cast<long long>(step));
    return name;
  }

  /// The view for what there is to draw now: the first call sets it, later
  /// ones only widen it when something drawn would fall outside.
  void fit(const Slam& slam) {
    const Box content = content_box(slam);
    if (!view) {
      // The world's extent when the source knows it (true landmarks): the
      // view is then final from the first frame unless the paths leave it.
      const bool world_known = slam.true_landmarks().cols() > 0;
      const double margin = (world_known ? 0.1 : 0.25) * std::max(content.empty() ? 0.0 : content.span(), 1.0);
      Box box = content.empty() ? Box{-1, -1, 1, 1} : content.padded(margin);
      if (!world_known && box.span() < 10.0) box = box.padded(0.5 * (10.0 - box.span()));
      view = box;
    } else if (!view->contains(content)) {
      Box box = *view;
      box.grow(content);
      view = box.padded(0.25 * box.span());
      ++report.view_changes;
    }
  }

  void write(const Slam& slam) {
    const auto t0 = std::chrono::steady_clock::now();
    fit(slam);
    cv::Mat img(size_px, size_px, CV_8UC3, cv::Scalar(255, 255, 255));
    const FrameMarks marks{slam.steps_done(), &closures};
    draw_top_view(img, square_view(*view, size_px), slam, &marks);
    const std::string name = file_name(slam.steps_done());
    write_atomically(report.folder / name, [&](const std::filesystem::path& f) { encode_png(f, img); });
    if (report.written++ == 0) report.first = name;
    report.last = name;
    last_step = slam.steps_done();
    report.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
};

MapFrames::MapFrames(const std::filesystem::path& output_dir, std::int64_t every, int size_px, const Slam& slam)
    : impl_(std::make_unique<Impl>()) {
  if (every < 1) throw std::invalid_argument("MapFrames: a frame every " + std::to_string(every) + " steps");
  impl_->report.folder = output_dir / "frames";
  impl_->report.every = every;
  impl_->size_px = size_px;
  impl_->closures_seen = slam.stats().loop_closures;  // a resumed run's earlier closures are not marked
  const std::int64_t first_step = slam.steps_done();
  namespace fs = std::filesystem;
  fs::create_directories(impl_->report.folder);
  // An earlier run's frames past this run's start (a resumed run keeps those
  // before it), and temporaries a killed run left.
  for (const fs::directory_entry& e : fs::directory_iterator(impl_->report.folder)) {
    const std::string name = e.path().filename().string();
    long long step = 0;
    char rest[16] = {};
    if (std::sscanf(name.c_str(), "frame_%lld%15s", &step, rest) != 2) continue;
    const std::string suffix = rest;
    if ((suffix == ".png" && step > first_step) || suffix == ".writing.png") fs::remove(e.path());
  }
}

MapFrames::~MapFrames() = default;

void MapFrames::after_step(const Slam& slam) {
  Impl& m = *impl_;
  if (slam.stats().loop_closures > m.closures_seen && !slam.trajectory().empty())
    m.closures.push_back(slam.trajectory().size() - 1);  // the pose of the step that closed it
  m.closures_seen = slam.stats().loop_closures;
  if (slam.steps_done() % m.report.every == 0) m.write(slam);
}

void MapFrames::finish(const Slam& slam) {
  if (slam.steps_done() > 0 && slam.steps_done() != impl_->last_step) impl_->write(slam);
}

const FramesReport& MapFrames::report() const { return impl_->report; }

}  // namespace mspace::kernel
