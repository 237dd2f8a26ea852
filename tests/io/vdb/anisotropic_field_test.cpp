// The anisotropic field (io/src/vdb/anisotropic.h) finds each particle's neighbours through a
// dense table of cells when the particles' box holds few cells per particle, else through a hash
// of the occupied cells: both give the same field, bit for bit. Its neighbour sums' lanes are
// added in vector operations in the same order as one addition at a time, a kernel added to a
// row of voxels in vector operations is the one-voxel loop's, and the velocity sampler's squared
// distances and list of candidates within its radius in vector operations are the plain loop's
// (lanes.h).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <vector>

#include "vdb/anisotropic.h"
#include "vdb/lanes.h"

namespace {

using slurry::io::PointCloud;
using slurry::io::detail::anisotropic_field;
using slurry::io::detail::FieldBlocks;

constexpr double dx = 0.02, s = 0.01;  // 8 particles per cell, on voxels of dx

/// A jittered 0.3 x 0.2 x 0.3 m block of particles at spacing s, with a hole (so that some
/// particles are deep and some are not).
PointCloud block() {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.3f * float(s), 0.3f * float(s));
  PointCloud c;
  for (double x = 0.5 * s; x < 0.3; x += s)
    for (double y = 0.5 * s; y < 0.2; y += s)
      for (double z = 0.5 * s; z < 0.3; z += s) {
        const double r2 = (x - 0.15) * (x - 0.15) + (y - 0.1) * (y - 0.1) + (z - 0.15) * (z - 0.15);
        if (r2 < 0.05 * 0.05) continue;
        c.position.push_back({float(x) + u(rng), float(y) + u(rng), float(z) + u(rng)});
      }
  return c;
}

std::map<std::array<std::int32_t, 3>, const float*> by_origin(const FieldBlocks& f) {
  std::map<std::array<std::int32_t, 3>, const float*> m;
  for (std::size_t b = 0; b < f.origin.size(); ++b) m[f.origin[b]] = f.value.data() + b * 512;
  return m;
}

TEST(AnisotropicField, DenseAndHashedCellTablesGiveTheSameField) {
  const PointCloud near = block();
  // One particle 8 m away on each axis: the box of neighbourhood cells (side 2 s) grows to
  // about 400^3, far over 4 per particle, so the cells are hashed.
  PointCloud far = near;
  far.position.push_back({8.0f, 8.0f, 8.0f});
  const FieldBlocks dense = anisotropic_field(near, dx, s), hashed = anisotropic_field(far, dx, s);
  ASSERT_GT(hashed.origin.size(), dense.origin.size()) << "the lone particle's blocks";
  const auto a = by_origin(dense), b = by_origin(hashed);
  std::size_t deep = 0;
  for (std::size_t i = 0; i < near.size(); ++i) {
    ASSERT_EQ(dense.neighbours[i], hashed.neighbours[i]) << "particle " << i;
    deep += dense.neighbours[i] == 255;
  }
  EXPECT_GT(deep, 0u);
  EXPECT_LT(deep, near.size());
  for (const auto& [origin, values] : a) {
    const auto it = b.find(origin);
    ASSERT_NE(it, b.end());
    EXPECT_EQ(std::memcmp(values, it->second, 512 * sizeof(float)), 0)
        << "block at " << origin[0] << " " << origin[1] << " " << origin[2];
  }
}

// The lanes' total in vector operations (lanes.h, on machines with AVX-512) adds in the tree's
// order: the same double, bit for bit, as the tree one addition at a time.
TEST(LaneTotal, VectorTreeIsTheScalarTree) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::uniform_int_distribution<int> e(-30, 30);
  int differ = 0;
  for (int k = 0; k < 100000; ++k) {
    float lanes[slurry::io::detail::kLanes];
    for (float& l : lanes) l = std::ldexp(u(rng), e(rng));  // magnitudes far apart: order shows
    const double a = slurry::io::detail::lane_total(lanes), b = slurry::io::detail::lane_total_scalar(lanes);
    differ += std::memcmp(&a, &b, sizeof a) != 0;
  }
  EXPECT_EQ(differ, 0);
}

// A kernel added to a row of 8 voxels in vector operations (lanes.h, on machines with AVX2 and
// FMA) gives the one-voxel loop's row bit for bit: for kernels of every shape and size, at every
// offset, over every range of the row (empty ones too), onto rows already holding values.
TEST(SplatRow, VectorRowIsTheScalarRow) {
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::uniform_int_distribution<int> lane(0, 7), origin(-40, 40);
  int touched = 0;
  for (int k = 0; k < 200000; ++k) {
    const std::int32_t o = 8 * origin(rng);
    const float centre = float(o) + 8.0f * (0.5f + u(rng)), scale = std::ldexp(1.0f, lane(rng) - 4);
    const float a[3] = {u(rng), u(rng), u(rng)}, m[3] = {scale * u(rng), scale * u(rng), scale * u(rng)};
    const float weight = 0.3f + u(rng) * 0.2f;
    int first = lane(rng), last = lane(rng);
    if (k % 10 == 0) std::swap(first, last);  // some ranges empty, most not
    float x[8], y[8];
    for (int l = 0; l < 8; ++l) x[l] = y[l] = 2.0f + u(rng);
    slurry::io::detail::splat_row(x, o, first, last, centre, a, m, weight);
    slurry::io::detail::splat_row_scalar(y, o, first, last, centre, a, m, weight);
    ASSERT_EQ(std::memcmp(x, y, sizeof x), 0) << "row " << k;
    float alone[8] = {};
    slurry::io::detail::splat_row_scalar(alone, o, first, last, centre, a, m, weight);
    for (const float w : alone) touched += w > 0;
  }
  // Voxels inside the kernels and voxels outside, both in numbers (of 1.6 M).
  EXPECT_GT(touched, 50000);
  EXPECT_LT(touched, 800000);
}

// The squared distances and the list of points within a radius in vector operations (lanes.h, on
// machines with AVX-512) are the one-point loop's bit for bit, for every length (whole vectors and
// a partial one), with points on the radius (not within) among them.
TEST(ListWithin, VectorListIsTheScalarList) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  const float q[3] = {0.31f, -0.12f, 0.57f};
  const double limit = 0.25;
  std::size_t listed = 0, compared = 0;
  for (std::size_t m = 0; m <= 40; ++m)
    for (int trial = 0; trial < 100; ++trial) {
      std::vector<float> px(m), py(m), pz(m);
      for (std::size_t j = 0; j < m; ++j) {
        px[j] = q[0] + u(rng), py[j] = q[1] + u(rng), pz[j] = q[2] + u(rng);
        if (j % 7 == 3) px[j] = q[0] + 0.5f, py[j] = q[1], pz[j] = q[2];  // on the radius: 0.5^2 = limit
      }
      std::vector<double> ra(m), rb(m);
      std::vector<std::uint32_t> a(m + 8), b(m + 8);
      const std::size_t ka =
          slurry::io::detail::list_within(px.data(), py.data(), pz.data(), m, q, limit, ra.data(), a.data());
      const std::size_t kb =
          slurry::io::detail::list_within_scalar(px.data(), py.data(), pz.data(), m, q, limit, rb.data(), b.data());
      ASSERT_EQ(ka, kb) << "length " << m;
      ASSERT_EQ(std::memcmp(ra.data(), rb.data(), m * sizeof(double)), 0) << "length " << m;
      for (std::size_t k = 0; k < ka; ++k) {
        ASSERT_EQ(a[k], b[k]) << "length " << m << ", entry " << k;
        ASSERT_LT(rb[b[k]], limit);
      }
      listed += ka, compared += m;
    }
  // About a sixth of the random points (a ball of radius 0.5 in a cube of side 2) are listed.
  EXPECT_GT(listed, compared / 20);
  EXPECT_LT(listed, compared / 3);
}

}  // namespace
