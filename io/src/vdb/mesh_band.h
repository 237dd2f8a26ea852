#pragma once
// The unsigned distance from voxel centres to a triangle mesh, on the narrow band of voxels within
// `width` voxels of it, with each voxel's closest triangle: what a narrow-band level set of the
// mesh needs besides the sign. Without OpenVDB (its meshToLevelSet does the same and more, but
// re-counts its trees' leaves for every batch of triangles, which made it most of the surfacing
// time on a liquid's many small triangles).
//
// The method is a closest-triangle transform in two stages (as in Mauch's closest point transform,
// restricted to a band, and as OpenVDB's mesh-to-volume expands its band):
//  1. each triangle gives the exact distance to the voxels within one voxel of its bounding box
//     (every voxel the surface passes through and its neighbours), the smallest kept; a voxel
//     whose distance to the triangle's bounding box already exceeds its best distance (by a
//     margin far above rounding) skips the exact distance, which could not win;
//  2. the band grows a layer of voxels at a time: a voxel not yet reached takes the nearest of its
//     six face neighbours' closest triangles, until `width` voxels; only the voxels beside one
//     reached in the layer before are tried (the others would see the same neighbours again).
// Within one voxel of the mesh the distance is exact (the voxel is seeded by its closest
// triangle). A voxel reached in stage 2 can miss its true closest triangle when none of its
// neighbours has it as theirs; the distance is then an upper bound (on a ball's inside, at most
// 0.2 voxel too far, tested). Deterministic: each block of voxels is written by one task, ties go to the lower
// triangle index, and the layers of stage 2 read only the previous layer.
#include <array>
#include <cstdint>
#include <vector>

#include "vdb/buffer.h"

namespace slurry::io::detail {

/// Distances on blocks of 8^3 voxels (index-space voxel (i, j, k) at world (i, j, k) h, blocks
/// at multiples of 8, values in OpenVDB's leaf order 64 i + 8 j + k), in voxel units; a voxel
/// not reached holds a distance >= width and triangle -1.
struct MeshBand {
  static constexpr int kSize = 8;
  std::vector<std::array<std::int32_t, 3>> origin;
  UninitVector<float> distance;         ///< 512 per block
  UninitVector<std::int32_t> triangle;  ///< 512 per block: the closest triangle, or -1
};

/// The band of `width` voxels around the triangles of (`vertices`, `triangles`) (world
/// coordinates, metres) at voxel size `h`. `exhaustive`: every seed's exact distance, and every
/// voxel not yet reached tried in every layer, with nothing skipped: slower, the same band bit for
/// bit (the reference the skipping is tested against).
MeshBand mesh_band(const std::vector<std::array<float, 3>>& vertices,
                   const std::vector<std::array<std::int32_t, 3>>& triangles, double h, int width,
                   bool exhaustive = false);

}  // namespace slurry::io::detail
