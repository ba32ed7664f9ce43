// picture.hpp — pieces of the top view (picture.cpp) that tests reach:
// map-to-pixel scaling and the drawing of a Feature::drawing(). Includes
// OpenCV: include it only from picture.cpp and its tests.
#pragma once

#include <cmath>

#include <opencv2/core.hpp>

#include "mspace/feature.hpp"

namespace mspace::kernel {

/// Map metres → image pixels of the top view (y up in the map, down in the image).
struct View {
  double min_x = 0, min_y = 0, scale = 1;  // pixels per metre
  int size = 1000, margin = 40;
  cv::Point px(double x, double y) const {
    return {margin + static_cast<int>(std::lround((x - min_x) * scale)),
            size - margin - static_cast<int>(std::lround((y - min_y) * scale))};
  }
};

/// Draws what a feature asked for (Feature::drawing): polygons closed,
/// segments pairwise, points as dots, directions as a dashed double-headed
/// arrow of fixed pixel size through a small ring (not to scale), each item's
/// label beside its first point.
void draw_feature_drawing(cv::Mat& img, const View& v, const FeatureDrawing& drawing, const cv::Scalar& colour);

}  // namespace mspace::kernel
