#pragma once
// Velocities sampled from particles, shared by the mesh (mesh.cpp) and the velocity grid
// (level_set.cpp); without OpenVDB.
#include <array>
#include <cstdint>
#include <vector>

#include "slurry/io/surface.h"

namespace slurry::io::detail {

/// sample_velocities (surface.h); with `found`, a point with no particle within 1.5 kernel radii
/// is left zero and marked 0 in `found` (1 elsewhere) instead of searching every particle.
std::vector<std::array<float, 3>> sample_velocities_near(const std::vector<std::array<float, 3>>& vertices,
                                                         const PointCloud& points, double spacing,
                                                         std::vector<std::uint8_t>* found);

}  // namespace slurry::io::detail
