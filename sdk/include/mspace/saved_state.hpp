// mspace/saved_state.hpp — helpers for a feature's save()/restore() (see
// SavedFeature in mspace/feature.hpp and docs/persistence.md).
//
// Dense information is usually a list of records of one fixed size (an
// observation: v, C_v and the sensor view it was taken from). A plugin saves
// such a list as one array with a record per column (Eigen is column-major, so
// a record is contiguous) and reads it back with the same offsets. Everything
// is a double: integers (sensor index, flags, counts) are exact up to 2^53.
// Header-only: nothing here adds to the SDK ABI.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <initializer_list>
#include <stdexcept>
#include <string>

#include "mspace/feature.hpp"
#include "mspace/measurement.hpp"

namespace mspace::saved {

/// Numbers of a packed SensorView: t, sensor, path_distance, x_ms (6), C_ms (36, column-major).
inline constexpr int kViewSize = 45;

/// Writes `view` into rows [at, at + kViewSize) of `record`.
inline void put_view(Eigen::Ref<Eigen::VectorXd> record, int at, const SensorView& view) {
  record[at] = view.t;
  record[at + 1] = view.sensor;
  record[at + 2] = view.path_distance;
  record.segment<6>(at + 3) = view.x_ms;
  record.segment<36>(at + 9) = view.C_ms.reshaped();
}

/// Reads a view written by put_view. Throws std::invalid_argument when the
/// sensor index is not a non-negative integer.
inline SensorView get_view(const Eigen::Ref<const Eigen::VectorXd>& record, int at) {
  SensorView view;
  view.t = record[at];
  const double sensor = record[at + 1];
  if (!(sensor >= 0.0 && sensor <= 1e9 && std::floor(sensor) == sensor))
    throw std::invalid_argument("saved sensor view: the sensor index is not a non-negative integer");
  view.sensor = static_cast<int>(sensor);
  view.path_distance = record[at + 2];
  view.x_ms = record.segment<6>(at + 3);
  view.C_ms = record.segment<36>(at + 9).reshaped(6, 6);
  return view;
}

/// Writes a fixed-size matrix column-major into rows [at, at + size) of `record`.
template <class M>
void put_matrix(Eigen::Ref<Eigen::VectorXd> record, int at, const Eigen::MatrixBase<M>& m) {
  record.segment(at, m.size()) = m.derived().reshaped();
}

/// Reads a rows × cols matrix written by put_matrix.
inline Eigen::MatrixXd get_matrix(const Eigen::Ref<const Eigen::VectorXd>& record, int at, int rows, int cols) {
  return record.segment(at, static_cast<Eigen::Index>(rows) * cols).reshaped(rows, cols);
}

/// The array `name` of `saved`, which must have `rows` rows (any number of
/// columns: records). An absent array is an empty list (rows × 0). Throws
/// std::invalid_argument naming `who` (the plugin) otherwise.
inline Eigen::MatrixXd records(const SavedFeature& saved, const std::string& name, int rows, const std::string& who) {
  const Eigen::MatrixXd* a = saved.find(name);
  if (a == nullptr) return Eigen::MatrixXd(rows, 0);
  if (a->rows() != rows || !a->allFinite())
    throw std::invalid_argument(who + ": saved array '" + name + "' must have " + std::to_string(rows) +
                                " finite rows per record (got " + std::to_string(a->rows()) + ")");
  return *a;
}

/// The rows × cols array `name` of `saved`, or `fallback` when absent.
inline Eigen::MatrixXd fixed(const SavedFeature& saved, const std::string& name, int rows, int cols,
                             const Eigen::MatrixXd& fallback, const std::string& who) {
  const Eigen::MatrixXd* a = saved.find(name);
  if (a == nullptr) return fallback;
  if (a->rows() != rows || a->cols() != cols || !a->allFinite())
    throw std::invalid_argument(who + ": saved array '" + name + "' must be " + std::to_string(rows) + "×" +
                                std::to_string(cols) + " and finite");
  return *a;
}

/// Throws std::invalid_argument naming `who` when `saved.version` is
/// neither `version` nor 0, or when `saved` holds an array not listed in
/// `known`. Version 0 is the state of a feature without dense information
/// (x_f, dimension, extra and no arrays), as hand-written saved states and
/// samples have it.
inline void expect_layout(const SavedFeature& saved, int version, std::initializer_list<const char*> known,
                          const std::string& who) {
  if (saved.version != version && saved.version != 0)
    throw std::invalid_argument(who + ": saved state has version " + std::to_string(saved.version) +
                                ", this plugin reads version " + std::to_string(version));
  if (saved.version == 0 && !saved.arrays.empty())
    throw std::invalid_argument(who + ": saved state of version 0 has no arrays");
  for (const SavedArray& a : saved.arrays) {
    bool ok = false;
    for (const char* k : known) ok = ok || a.name == k;
    if (!ok) throw std::invalid_argument(who + ": unknown saved array '" + a.name + "'");
  }
}

}  // namespace mspace::saved
