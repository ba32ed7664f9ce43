#include "mspace/feature.hpp"

#include <stdexcept>

namespace mspace {

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
