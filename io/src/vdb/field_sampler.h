#pragma once
// Trilinear samples of the anisotropic field's blocks (anisotropic.h) at world positions, without
// building or walking an OpenVDB tree: the arithmetic of OpenVDB 10's BoxSampler
// (tools/Interpolation.h) on a grid of these blocks under Transform::createLinearTransform(h), so
// the same float for the same point, bit for bit (field_sampler_tests checks it against OpenVDB):
//  - index coordinates x / h as the scale map computes them, x * (1.0 / h) in double;
//  - the corner voxel i = floor of each, the fractions u = x - i in double;
//  - lerp(a, b, u) = a + float((b - a) * u), along z, then y, then x.
// A voxel outside every block reads 0, the grid's background.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "vdb/anisotropic.h"

namespace slurry::io::detail {

class FieldSampler {
 public:
  /// Looks blocks up in a table over the box of blocks when that box holds at most 64 times as
  /// many blocks as there are (and 2^24 in all); otherwise usable() is false and the caller
  /// samples the tree instead.
  FieldSampler(const FieldBlocks& field, double h) : field_(field), inverse_h_(1.0 / h) {
    if (field.origin.empty()) return;
    std::array<std::int32_t, 3> lo = field.origin.front(), hi = lo;
    for (const auto& o : field.origin)
      for (std::size_t d = 0; d < 3; ++d) {
        lo[d] = std::min(lo[d], o[d]);
        hi[d] = std::max(hi[d], o[d]);
      }
    double cells = 1;
    for (std::size_t d = 0; d < 3; ++d) {
      lo_[d] = lo[d] / B;  // origins are multiples of B
      dims_[d] = (hi[d] - lo[d]) / B + 1;
      cells *= double(dims_[d]);
    }
    if (cells > 64.0 * double(field.origin.size()) || cells > double(1 << 24)) return;
    table_.assign(std::size_t(cells), -1);
    for (std::size_t b = 0; b < field.origin.size(); ++b) {
      const auto& o = field.origin[b];
      table_[std::size_t(slot(o[0] / B, o[1] / B, o[2] / B))] = std::int32_t(b);
    }
  }

  bool usable() const { return !table_.empty() || field_.origin.empty(); }

  /// The field at world position p (BoxSampler's value there).
  float sample(const std::array<float, 3>& p) const {
    float v[2][2][2];
    double u[3];
    corners(p, v, u);
    return interpolate(v, u);
  }

  /// Whether double(sample(p)) < bound, for bound >= 0; without the interpolation where the
  /// eight corners decide it: each interpolation lies between its two values up to its roundings
  /// (a few float ulps of the larger), so corners all at least bound + 1e-4 of the largest give
  /// a sample of at least bound.
  bool below(const std::array<float, 3>& p, double bound) const {
    float v[2][2][2];
    double u[3];
    corners(p, v, u);
    float lo = v[0][0][0], hi = v[0][0][0];
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int c = 0; c < 2; ++c) lo = std::min(lo, v[a][b][c]), hi = std::max(hi, v[a][b][c]);
    if (double(lo) >= bound + 1e-4 * double(hi)) return false;
    return double(interpolate(v, u)) < bound;
  }

 private:
  static constexpr int B = FieldBlocks::kSize;
  static constexpr int kLog2 = 3;
  static_assert(B == 1 << kLog2);

  /// The values v at the eight voxels around p and p's fractions u between them.
  void corners(const std::array<float, 3>& p, float (&v)[2][2][2], double (&u)[3]) const {
    const double x[3] = {double(p[0]) * inverse_h_, double(p[1]) * inverse_h_, double(p[2]) * inverse_h_};
    const std::int32_t i[3] = {std::int32_t(std::floor(x[0])), std::int32_t(std::floor(x[1])),
                               std::int32_t(std::floor(x[2]))};
    for (int d = 0; d < 3; ++d) u[d] = x[d] - i[d];
    const std::int32_t m = B - 1;
    if ((i[0] & m) != m && (i[1] & m) != m && (i[2] & m) != m) {
      // The eight corners in one block (7 times in 8 per axis).
      const float* block = find(i[0] >> kLog2, i[1] >> kLog2, i[2] >> kLog2);
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
          for (int c = 0; c < 2; ++c)
            v[a][b][c] = block ? block[(((i[0] + a) & m) * B + ((i[1] + b) & m)) * B + ((i[2] + c) & m)] : 0.0f;
    } else {
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
          for (int c = 0; c < 2; ++c) v[a][b][c] = voxel(i[0] + a, i[1] + b, i[2] + c);
    }
  }
  /// BoxSampler's interpolation of the corners: along z, then y, then x.
  static float interpolate(const float (&v)[2][2][2], const double (&u)[3]) {
    const auto lerp = [](float a, float b, double w) { return a + float(double(b - a) * w); };
    return lerp(lerp(lerp(v[0][0][0], v[0][0][1], u[2]), lerp(v[0][1][0], v[0][1][1], u[2]), u[1]),
                lerp(lerp(v[1][0][0], v[1][0][1], u[2]), lerp(v[1][1][0], v[1][1][1], u[2]), u[1]), u[0]);
  }

  std::int64_t slot(std::int32_t bx, std::int32_t by, std::int32_t bz) const {
    return (std::int64_t(bx - lo_[0]) * dims_[1] + (by - lo_[1])) * dims_[2] + (bz - lo_[2]);
  }
  /// Block (bx, by, bz)'s values (blocks of B voxels: voxel i lies in block i >> kLog2), or null.
  const float* find(std::int32_t bx, std::int32_t by, std::int32_t bz) const {
    if (table_.empty() || bx < lo_[0] || by < lo_[1] || bz < lo_[2] || bx >= lo_[0] + dims_[0] ||
        by >= lo_[1] + dims_[1] || bz >= lo_[2] + dims_[2])
      return nullptr;
    const std::int32_t b = table_[std::size_t(slot(bx, by, bz))];
    return b < 0 ? nullptr : field_.value.data() + std::size_t(b) * B * B * B;
  }
  float voxel(std::int32_t x, std::int32_t y, std::int32_t z) const {
    const float* block = find(x >> kLog2, y >> kLog2, z >> kLog2);
    const std::int32_t m = B - 1;
    return block ? block[((x & m) * B + (y & m)) * B + (z & m)] : 0.0f;
  }

  const FieldBlocks& field_;
  double inverse_h_;
  std::array<std::int32_t, 3> lo_{}, dims_{};
  std::vector<std::int32_t> table_;  ///< block index per block of the box, -1 where none
};

}  // namespace slurry::io::detail
