#pragma once
// The liquid's volume-fraction field from anisotropic kernels, after Yu & Turk 2013,
// "Reconstructing surfaces of particle-based fluids using anisotropic kernels", ACM TOG 32(1),
// article 5: each particle spreads its volume with a kernel stretched along the principal axes of
// its neighbourhood (flat at a flat surface, a disc in a sheet, round in the bulk and for a lone
// droplet), centred at its Laplacian-smoothed position. A particle deep in the liquid (every
// cell around it filled) takes the round kernel at once, without its neighbour sums. Sampled on 8^3 blocks of voxels (the
// leaf nodes of an OpenVDB tree), without OpenVDB.
#include <array>
#include <cstdint>
#include <vector>

#include "slurry/io/surface.h"
#include "vdb/buffer.h"

namespace slurry::io::detail {

/// What anisotropic_field computes with (the constants of the method, tested in
/// tests/io/vdb/surface_test.cpp).
struct AnisotropyConstants {
  double support = 2.0;          ///< kernel radius in the bulk, in particle spacings (Yu & Turk: 2h)
  double neighbourhood = 2.0;    ///< radius of the neighbourhood whose covariance shapes a kernel, spacings
  double smoothing = 0.5;        ///< lambda of the position smoothing x + lambda (mean - x), [0, 1]
  double max_stretch = 4.0;      ///< largest ratio of a kernel's longest to its shortest axis (k_r)
  int min_neighbours = 6;        ///< fewer neighbours: an isotropic kernel (N_eps)
  double droplet_support = 1.0;  ///< kernel radius of a particle without neighbours, spacings
};

/// Values of the field on blocks of 8^3 voxels: block b covers index-space voxels
/// origin[b] + [0, 8)^3 (origin a multiple of 8), value[512 b + 64 i + 8 j + k] being voxel
/// (i, j, k) of it (OpenVDB's leaf order). Blocks no kernel reaches are absent (value 0).
struct FieldBlocks {
  static constexpr int kSize = 8;
  std::vector<std::array<std::int32_t, 3>> origin;
  UninitVector<float> value;
  /// Per particle: its neighbours within the neighbourhood radius, at most 255 (fewer than
  /// min_neighbours: a round kernel; spray, a droplet, the end of a filament).
  std::vector<std::uint8_t> neighbours;
};

/// The field sum_i V_i W_i(x), V_i = spacing^3, W_i a kernel integrating to 1: about 1 inside the
/// liquid, 0 outside, at the voxel centres (index-space voxel (i, j, k) at world (i, j, k) h).
/// Deterministic: each block is summed by one task over the particles in a fixed order.
/// Throws std::invalid_argument if the points span more than 2^20 neighbourhoods on an axis.
FieldBlocks anisotropic_field(const PointCloud& points, double voxel_size, double spacing,
                              const AnisotropyConstants& constants = {});

}  // namespace slurry::io::detail
