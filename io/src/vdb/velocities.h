#pragma once
// Velocities sampled from particles, shared by the mesh (mesh.cpp) and the velocity grid
// (level_set.cpp); without OpenVDB.
#include <array>
#include <cstdint>
#include <vector>

#include "slurry/io/surface.h"
#include "vdb/buffer.h"

namespace slurry::io::detail {

/// The particles sorted into cells of side 2 spacings (the kernel radius) once, for sampling
/// their velocities at several sets of points (a mesh's vertices, a level set's band).
class VelocitySampler {
 public:
  /// `points` must outlive the sampler.
  VelocitySampler(const PointCloud& points, double spacing);
  /// sample_velocities (surface.h) at `where`; with `found`, a point with no particle within 1.5
  /// kernel radii is left zero and marked 0 in `found` (1 elsewhere) instead of searching every
  /// particle.
  std::vector<std::array<float, 3>> sample(const std::vector<std::array<float, 3>>& where,
                                           std::vector<std::uint8_t>* found) const;

 private:
  const PointCloud& points_;
  double h_ = 0;
  std::array<double, 3> lo_{};
  std::array<std::int64_t, 3> dims_{1, 1, 1};
  UninitVector<std::uint64_t> keys_;  ///< cell keys, sorted
  UninitVector<std::uint32_t> first_;  ///< where each cell starts in keys_ (empty: a binary search)
  UninitVector<float> position_[3];               ///< by coordinate, in cell order
  UninitVector<std::array<float, 3>> velocity_;  ///< in cell order
};

}  // namespace slurry::io::detail
