// bearings.cpp — see bearings.hpp.
#include "bearings.hpp"

#include <algorithm>
#include <utility>

namespace mspace::scan_matching {

BearingIndex::BearingIndex(std::vector<double> sorted) : bearings_(std::move(sorted)) {
  if (bearings_.empty()) return;
  // One bucket per bearing on average over the span they cover.
  const std::size_t buckets = bearings_.size();
  origin_ = bearings_.front();
  const double span = bearings_.back() - origin_;
  buckets_per_radian_ = span > 0.0 ? static_cast<double>(buckets) / span : 0.0;
  first_.assign(buckets + 1, bearings_.size());
  // The bucket is a non-decreasing function of the bearing: walking the
  // sorted bearings backwards leaves in first_[k] the first of bucket k;
  // an empty bucket then takes the first of the next one up.
  for (std::size_t i = bearings_.size(); i-- > 0;) first_[bucket_of(bearings_[i])] = i;
  for (std::size_t k = buckets; k-- > 0;) first_[k] = std::min(first_[k], first_[k + 1]);
}

}  // namespace mspace::scan_matching
