// mspace/state.hpp — the run-time state of a plugin object, for checkpoints
// (docs/persistence.md §3).
//
// A plugin object with state beyond its parameters (an estimator's
// covariance, a simulator's random generators and position) writes it as
// named matrices and byte strings through a StateWriter and reads it back
// through a StateReader; the kernel frames, versions and checksums them
// (kernel/src/persistence.cpp). Doubles cross as their IEEE-754 bits, so a
// restored object goes on exactly as the saved one would have. Integers are
// stored as doubles (exact up to 2^53); text such as a random engine's state
// goes in a byte string.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace mspace {

class StateWriter {
 public:
  /// Stores a named matrix (names are unique within one object's state).
  virtual void put(const std::string& name, const Eigen::MatrixXd& value) = 0;
  /// Stores a named byte string.
  virtual void put_bytes(const std::string& name, const std::string& bytes) = 0;

 protected:
  ~StateWriter() = default;
};

class StateReader {
 public:
  virtual bool has(const std::string& name) const = 0;
  /// The named matrix; std::invalid_argument naming it when absent.
  virtual const Eigen::MatrixXd& get(const std::string& name) const = 0;
  /// The named byte string; std::invalid_argument naming it when absent.
  virtual const std::string& get_bytes(const std::string& name) const = 0;

 protected:
  ~StateReader() = default;
};

// ---- Helpers (inline: no ABI surface) ----------------------------------------

/// The named matrix, which must be rows × cols (a negative size is not
/// checked); std::invalid_argument "<context>: saved array '<name>' is r × c,
/// expected …" otherwise.
inline const Eigen::MatrixXd& get_state(const StateReader& in, const std::string& name, Eigen::Index rows,
                                        Eigen::Index cols, const std::string& context) {
  const Eigen::MatrixXd& m = in.get(name);
  if ((rows >= 0 && m.rows() != rows) || (cols >= 0 && m.cols() != cols))
    throw std::invalid_argument(context + ": saved array '" + name + "' is " + std::to_string(m.rows()) + " x " +
                                std::to_string(m.cols()) + ", expected " +
                                (rows >= 0 ? std::to_string(rows) : std::string("any")) + " x " +
                                (cols >= 0 ? std::to_string(cols) : std::string("any")));
  return m;
}

/// A list of integers as one column.
template <class Int>
void put_ints(StateWriter& out, const std::string& name, const std::vector<Int>& values) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(values.size()), 1);
  for (std::size_t i = 0; i < values.size(); ++i) m(static_cast<Eigen::Index>(i), 0) = static_cast<double>(values[i]);
  out.put(name, m);
}

/// A column written by put_ints; every entry must be an integer in [lo, hi].
template <class Int>
std::vector<Int> get_ints(const StateReader& in, const std::string& name, double lo, double hi,
                          const std::string& context) {
  const Eigen::MatrixXd& m = in.get(name);
  if (m.cols() != 1 && m.size() != 0)
    throw std::invalid_argument(context + ": saved array '" + name + "' must have one column");
  std::vector<Int> values;
  values.reserve(static_cast<std::size_t>(m.size()));
  for (Eigen::Index i = 0; i < m.size(); ++i) {
    const double v = m(i, 0);
    if (!(v >= lo && v <= hi) || v != static_cast<double>(static_cast<std::int64_t>(v)))
      throw std::invalid_argument(context + ": saved array '" + name + "' entry " + std::to_string(i) + " (" +
                                  std::to_string(v) + ") is not an integer in [" + std::to_string(lo) + ", " +
                                  std::to_string(hi) + "]");
    values.push_back(static_cast<Int>(v));
  }
  return values;
}

}  // namespace mspace
