// mspace/coords.hpp — feature coordinates as a list of typed blocks.
//
// T-RO §IV: a feature's coordinates x_f are a list of 3-D points, 2-D points
// (vertical structures, infinite in z; Appendix, eq. 34) and scalars (e.g. a
// radius). Each kind has its own transformation rule into the sensor frame
// (eqs. 7–9, implemented once in transform.hpp), so the layout is all the
// generic code needs to know about a feature's parameterisation.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string>
#include <vector>

namespace mspace {

enum class BlockKind : std::uint8_t {
  Point3D,  ///< (x, y, z), eq. 7
  Point2D,  ///< (x, y) of a vertical line, eq. 8 with the pseudo-rotation of eq. 34
  Scalar,   ///< a frame-independent number, eq. 9
};

/// Number of coordinates in a block of the given kind (3, 2 or 1).
constexpr int block_size(BlockKind kind) {
  return kind == BlockKind::Point3D ? 3 : kind == BlockKind::Point2D ? 2 : 1;
}

/// "point3d", "point2d", "scalar".
const char* block_kind_name(BlockKind kind);

/// The ordered blocks of a feature's coordinate vector x_f.
class CoordLayout {
 public:
  CoordLayout() = default;
  CoordLayout(std::initializer_list<BlockKind> blocks);
  explicit CoordLayout(std::vector<BlockKind> blocks);

  int num_blocks() const { return static_cast<int>(blocks_.size()); }
  BlockKind kind(int block) const { return blocks_[block]; }
  /// Index of the first coordinate of `block` in x_f.
  int offset(int block) const { return offsets_[block]; }
  /// Total number of coordinates (length of x_f).
  int size() const { return size_; }
  const std::vector<BlockKind>& blocks() const { return blocks_; }
  /// E.g. "[point2d, point2d]".
  std::string describe() const;

  bool operator==(const CoordLayout& other) const { return blocks_ == other.blocks_; }

 private:
  std::vector<BlockKind> blocks_;
  std::vector<int> offsets_;
  int size_ = 0;
};

}  // namespace mspace
