// test_picture.cpp — map.png draws a feature as its Feature::drawing() asks
// (picture.hpp): a polygon is closed, segments are drawn pairwise only, and a
// direction known without a position is a glyph of fixed pixel size in its
// own (dashed) style, placed nowhere but where it is shown.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <numbers>

#include <opencv2/core.hpp>

#include "picture.hpp"

namespace mspace::kernel {
namespace {

/// A 10 m × 10 m view, 20 px per metre, on a white image.
struct Canvas {
  View view{0.0, 0.0, 20.0, 240, 20};
  cv::Mat img = cv::Mat(240, 240, CV_8UC3, cv::Scalar(255, 255, 255));
  /// Whether anything was drawn within 1 px of map point (x, y).
  bool inked(double x, double y) const {
    const cv::Point p = view.px(x, y);
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        if (img.at<cv::Vec3b>(p.y + dy, p.x + dx) != cv::Vec3b(255, 255, 255)) return true;
    return false;
  }
};

/// The corners of the square (1, 1)–(9, 9) in order, as one item of `kind`.
DrawingItem square(DrawingItem::Kind kind) {
  DrawingItem item{kind, Eigen::Matrix2Xd(2, 4), ""};
  item.points << 1, 9, 9, 1,  //
      1, 1, 9, 9;
  return item;
}

TEST(Picture, PolygonIsClosed) {
  Canvas c;
  draw_feature_drawing(c.img, c.view, FeatureDrawing{{square(DrawingItem::Kind::Polygon)}}, {200, 0, 0});
  EXPECT_TRUE(c.inked(5, 1));  // first edge
  EXPECT_TRUE(c.inked(9, 5));
  EXPECT_TRUE(c.inked(5, 9));
  EXPECT_TRUE(c.inked(1, 5));  // the closing edge, last point → first
  EXPECT_FALSE(c.inked(5, 5));
}

TEST(Picture, SegmentsArePairs) {
  Canvas c;
  draw_feature_drawing(c.img, c.view, FeatureDrawing{{square(DrawingItem::Kind::Segments)}}, {200, 0, 0});
  EXPECT_TRUE(c.inked(5, 1));   // points 0–1
  EXPECT_TRUE(c.inked(5, 9));   // points 2–3
  EXPECT_FALSE(c.inked(9, 5));  // 1–2 is no segment
  EXPECT_FALSE(c.inked(1, 5));  // nor 3–0
}

TEST(Picture, PointsAndLabel) {
  Canvas c;
  DrawingItem points = square(DrawingItem::Kind::Points);
  points.label = "door";
  draw_feature_drawing(c.img, c.view, FeatureDrawing{{points}}, {200, 0, 0});
  EXPECT_TRUE(c.inked(1, 1));
  EXPECT_TRUE(c.inked(9, 9));
  EXPECT_FALSE(c.inked(5, 1));  // no line between points
  // The label is written up and to the right of the first point.
  bool label = false;
  const cv::Point p = c.view.px(1, 1);
  for (int y = p.y - 12; y < p.y - 4; ++y)
    for (int x = p.x + 6; x < p.x + 30; ++x) label = label || c.img.at<cv::Vec3b>(y, x) != cv::Vec3b(255, 255, 255);
  EXPECT_TRUE(label);
}

/// The inked pixels' bounding box, relative to the pixel of map point (x, y).
cv::Rect inked_box(const Canvas& c, double x, double y) {
  int lo_x = 1 << 20, lo_y = 1 << 20, hi_x = -1, hi_y = -1;
  for (int r = 0; r < c.img.rows; ++r)
    for (int col = 0; col < c.img.cols; ++col)
      if (c.img.at<cv::Vec3b>(r, col) != cv::Vec3b(255, 255, 255))
        lo_x = std::min(lo_x, col), lo_y = std::min(lo_y, r), hi_x = std::max(hi_x, col), hi_y = std::max(hi_y, r);
  const cv::Point p = c.view.px(x, y);
  return {lo_x - p.x, lo_y - p.y, hi_x - lo_x + 1, hi_y - lo_y + 1};
}

TEST(Picture, DirectionItemHoldsPlaceAndUnitDirection) {
  const DrawingItem item = direction_item({2.0, 3.0}, std::numbers::pi / 2, "line");
  EXPECT_EQ(item.kind, DrawingItem::Kind::Direction);
  ASSERT_EQ(item.points.cols(), 2);
  EXPECT_EQ(item.points.col(0), Eigen::Vector2d(2.0, 3.0));
  EXPECT_NEAR(item.points(0, 1), 0.0, 1e-15);
  EXPECT_NEAR(item.points(1, 1), 1.0, 1e-15);
  EXPECT_EQ(item.label, "line");
}

TEST(Picture, DirectionOnlyMeansEveryItemIsADirection) {
  const DrawingItem direction = direction_item({1.0, 1.0}, 0.3);
  EXPECT_TRUE((FeatureDrawing{{direction}}.direction_only()));
  EXPECT_TRUE((FeatureDrawing{{direction, direction}}.direction_only()));
  EXPECT_FALSE((FeatureDrawing{{direction, square(DrawingItem::Kind::Segments)}}.direction_only()));
  EXPECT_FALSE((FeatureDrawing{{square(DrawingItem::Kind::Points)}}.direction_only()));
  EXPECT_FALSE(FeatureDrawing{}.direction_only());  // nothing asked: the generic drawing places the feature
}

// A direction is drawn where it is shown, at the same size in pixels
// whatever the scale (it spans no known length), and dashed: along its axis
// the ink has gaps, where a placed segment of the same length is solid.
TEST(Picture, DirectionIsAGlyphOfFixedSizeAndDashed) {
  Canvas fine;  // 20 px/m
  draw_feature_drawing(fine.img, fine.view, FeatureDrawing{{direction_item({5.0, 5.0}, 0.0)}}, {200, 0, 0});
  Canvas coarse;
  coarse.view.scale = 2.0;  // 2 px/m: 10 times smaller
  draw_feature_drawing(coarse.img, coarse.view, FeatureDrawing{{direction_item({5.0, 5.0}, 0.0)}}, {200, 0, 0});
  const cv::Rect a = inked_box(fine, 5.0, 5.0), b = inked_box(coarse, 5.0, 5.0);
  // Centred where it is shown, give or take the one pixel anti-aliasing may
  // add on one side.
  EXPECT_LE(std::abs(2 * a.x + a.width - 1), 1) << "not centred where it is shown: " << a;
  EXPECT_LE(std::abs(2 * a.y + a.height - 1), 1) << a;
  EXPECT_EQ(a, b) << "the glyph's size changed with the scale";
  EXPECT_GE(a.width, 20);  // a visible arrow along x …
  EXPECT_LE(a.width, 40);  // … of a fixed size, not a line's extent
  EXPECT_LE(a.height, 12);
  EXPECT_FALSE(fine.inked(5.0 + 1.0, 5.0));  // 20 px away along the direction: nothing

  // Along the axis (outside the ring about the place) the dashes leave gaps.
  const cv::Point p = fine.view.px(5.0, 5.0);
  auto gaps_along_axis = [&](const Canvas& c) {
    int gaps = 0;
    for (int dx = 5; dx <= 10; ++dx)
      gaps += c.img.at<cv::Vec3b>(p.y, p.x + dx) == cv::Vec3b(255, 255, 255) ? 1 : 0;
    return gaps;
  };
  EXPECT_GT(gaps_along_axis(fine), 0);
  Canvas segment;
  DrawingItem solid{DrawingItem::Kind::Segments, Eigen::Matrix2Xd(2, 2), ""};
  solid.points << 5.0 - 0.7, 5.0 + 0.7,  //
      5.0, 5.0;
  draw_feature_drawing(segment.img, segment.view, FeatureDrawing{{solid}}, {200, 0, 0});
  EXPECT_EQ(gaps_along_axis(segment), 0);
}

// The glyph turns with the direction: vertical for π/2, and θ + π (the same
// undirected line) draws the same pixels.
TEST(Picture, DirectionGlyphFollowsTheDirectionAndHasNoSense) {
  Canvas up, down;
  draw_feature_drawing(up.img, up.view, FeatureDrawing{{direction_item({5.0, 5.0}, std::numbers::pi / 2)}},
                       {200, 0, 0});
  draw_feature_drawing(down.img, down.view, FeatureDrawing{{direction_item({5.0, 5.0}, -std::numbers::pi / 2)}},
                       {200, 0, 0});
  const cv::Rect box = inked_box(up, 5.0, 5.0);
  EXPECT_GT(box.height, 2 * box.width);
  EXPECT_EQ(box, inked_box(down, 5.0, 5.0));
  cv::Mat diff;
  cv::absdiff(up.img, down.img, diff);
  EXPECT_LE(cv::sum(diff)[0] + cv::sum(diff)[1] + cv::sum(diff)[2], 0.02 * 255 * 3 * box.area())
      << "an arrow in one sense only";
}

}  // namespace
}  // namespace mspace::kernel
