#include "mspace/feature.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

namespace mspace {

bool FeatureDrawing::direction_only() const {
  return !items.empty() &&
         std::all_of(items.begin(), items.end(), [](const DrawingItem& i) { return i.kind == DrawingItem::Kind::Direction; });
}

DrawingItem direction_item(const Eigen::Vector2d& shown_at, double angle, std::string label) {
  DrawingItem item{DrawingItem::Kind::Direction, Eigen::Matrix2Xd(2, 2), std::move(label)};
  item.points.col(0) = shown_at;
  item.points.col(1) = Eigen::Vector2d(std::cos(angle), std::sin(angle));
  return item;
}

Eigen::MatrixXd Feature::share_block(int, const Eigen::VectorXd&) {
  throw std::logic_error("this feature type does not implement Feature::share_block()");
}

std::optional<FeatureSample> FeatureType::sample(int, std::uint64_t) const {
  throw std::logic_error("this feature type does not implement FeatureType::sample(), so it cannot be checked");
}

std::optional<SampleObservation> FeatureType::sample_observation(int, std::uint64_t, int) const {
  return std::nullopt;
}

std::unique_ptr<Feature> FeatureType::restore(const SavedFeature&) const {
  throw std::logic_error("this feature type does not implement FeatureType::restore()");
}

}  // namespace mspace
