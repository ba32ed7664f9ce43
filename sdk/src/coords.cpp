#include "mspace/coords.hpp"

namespace mspace {

const char* block_kind_name(BlockKind kind) {
  switch (kind) {
    case BlockKind::Point3D: return "point3d";
    case BlockKind::Point2D: return "point2d";
    case BlockKind::Scalar: return "scalar";
  }
  return "?";
}

CoordLayout::CoordLayout(std::initializer_list<BlockKind> blocks)
    : CoordLayout(std::vector<BlockKind>(blocks)) {}

CoordLayout::CoordLayout(std::vector<BlockKind> blocks) : blocks_(std::move(blocks)) {
  offsets_.reserve(blocks_.size());
  for (BlockKind kind : blocks_) {
    offsets_.push_back(size_);
    size_ += block_size(kind);
  }
}

std::string CoordLayout::describe() const {
  std::string s = "[";
  for (std::size_t i = 0; i < blocks_.size(); ++i) {
    if (i != 0) s += ", ";
    s += block_kind_name(blocks_[i]);
  }
  return s + "]";
}

}  // namespace mspace
