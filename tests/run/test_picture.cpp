// test_picture.cpp — map.png draws a feature as its Feature::drawing() asks
// (picture.hpp): a polygon is closed, segments are drawn pairwise only.
#include <gtest/gtest.h>

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

}  // namespace
}  // namespace mspace::kernel
