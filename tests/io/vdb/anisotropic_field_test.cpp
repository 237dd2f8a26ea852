// The anisotropic field (io/src/vdb/anisotropic.h) finds each particle's neighbours through a
// dense table of cells when the particles' box holds few cells per particle, else through a hash
// of the occupied cells: both give the same field, bit for bit. Its neighbour sums' lanes are
// added in vector operations in the same order as one addition at a time, a kernel added to a
// row of voxels in vector operations is the one-voxel loop's, and the velocity sampler's squared
// distances and list of candidates within its radius in vector operations are the plain loop's
// (lanes.h). The kernels shaped four particles at a time are those shaped one at a time, and
// they are the Cholesky factor of the scaled inverse covariance (kernel_shape.h).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <vector>

#include "vdb/anisotropic.h"
#include "vdb/kernel_shape.h"
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

/// Neighbour sums of n particles: neighbourhoods of 0 to 40 neighbours within R, spread along
/// random axes from round to flat (a sheet, a filament), some all at one point.
slurry::io::detail::NeighbourSums random_sums(std::size_t n, double R, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0), unit(0.0, 1.0);
  slurry::io::detail::NeighbourSums sums;
  sums.resize(n);
  for (std::size_t p = 0; p < n; ++p) {
    const int count = int(rng() % 41);
    const double axis[3] = {R, R * std::pow(unit(rng), 2), R * std::pow(unit(rng), 4)};
    const Eigen::Matrix3d Q = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
    const bool stacked = rng() % 50 == 0;  // every neighbour at the particle: C = 0
    double W = 1, m[3] = {}, sec[6] = {};   // the particle itself: weight 1, offset 0
    for (int j = 0; j < count; ++j) {
      const Eigen::Vector3d d = stacked ? Eigen::Vector3d::Zero()
                                        : Eigen::Vector3d(Q * Eigen::Vector3d(u(rng) * axis[0], u(rng) * axis[1], u(rng) * axis[2]));
      const double r = std::min(d.norm() / R, 1.0), w = 1 - r * r * r;
      W += w;
      for (int a = 0; a < 3; ++a) m[a] += w * d[a];
      sec[0] += w * d[0] * d[0], sec[1] += w * d[1] * d[1], sec[2] += w * d[2] * d[2];
      sec[3] += w * d[0] * d[1], sec[4] += w * d[0] * d[2], sec[5] += w * d[1] * d[2];
    }
    sums.W[p] = W;
    for (int a = 0; a < 3; ++a) sums.m[a][p] = m[a], sums.x[a][p] = float(u(rng));
    for (int k = 0; k < 6; ++k) sums.s[k][p] = sec[k];
    sums.neighbours[p] = count;
    sums.index[p] = std::uint32_t(n - 1 - p);  // written out of order
  }
  return sums;
}

slurry::io::detail::ShapeConstants shape_constants(double spacing) {
  slurry::io::detail::ShapeConstants k;
  const double R = 2 * spacing;
  k.s_bulk = 0.15 * R * R;
  k.support = 2 * spacing;
  k.volume = spacing * spacing * spacing;
  k.normalisation = 315.0 / (64.0 * M_PI);
  return k;
}

TEST(KernelShape, FourAtATimeIsOneAtATime) {
  using slurry::io::detail::Kernel;
  const std::size_t n = 100003;  // not a multiple of 4: the last ones one at a time
  const auto k = shape_constants(s);
  auto vector_sums = random_sums(n, 2 * s, 5), scalar_sums = vector_sums;
  std::vector<Kernel> vector_kernels(n), scalar_kernels(n);
  std::memset(vector_kernels.data(), 0, n * sizeof(Kernel));
  std::memset(scalar_kernels.data(), 0, n * sizeof(Kernel));
  slurry::io::detail::shape_kernels(vector_sums, k, vector_kernels.data());
  slurry::io::detail::shape_kernels_scalar(scalar_sums, k, scalar_kernels.data());
  std::size_t shaped = 0;
  for (std::size_t p = 0; p < n; ++p) {
    ASSERT_EQ(vector_sums.shaped[p], scalar_sums.shaped[p]) << p;
    for (int a = 0; a < 3; ++a) ASSERT_EQ(std::memcmp(&vector_sums.mean[a][p], &scalar_sums.mean[a][p], sizeof(double)), 0) << p;
    shaped += scalar_sums.shaped[p];
  }
  EXPECT_EQ(std::memcmp(vector_kernels.data(), scalar_kernels.data(), n * sizeof(Kernel)), 0);
  // Both outcomes are covered: kernels shaped here, and kernels left to the eigendecomposition.
  EXPECT_GT(shaped, n / 10);
  EXPECT_LT(shaped, n * 9 / 10);
}

TEST(KernelShape, MapIsTheCholeskyFactorOfTheScaledInverse) {
  using slurry::io::detail::Kernel;
  const std::size_t n = 20000;
  const auto k = shape_constants(s);
  auto sums = random_sums(n, 2 * s, 9);
  std::vector<Kernel> kernels(n);
  slurry::io::detail::shape_kernels(sums, k, kernels.data());
  const double H = k.support, kr2 = k.max_stretch * k.max_stretch;
  std::size_t shaped = 0, clamped = 0;
  for (std::size_t p = 0; p < n; ++p) {
    const Kernel& ker = kernels[sums.index[p]];
    Eigen::Vector3d mean;
    for (int a = 0; a < 3; ++a) {
      mean[a] = sums.m[a][p] / sums.W[p];
      ASSERT_EQ(sums.mean[a][p], mean[a]);
      ASSERT_NEAR(ker.centre[std::size_t(a)], sums.x[a][p] + k.smoothing * mean[a], 1e-6);
    }
    if (sums.neighbours[p] < k.min_neighbours) {
      ASSERT_FALSE(sums.shaped[p]);
      continue;
    }
    Eigen::Matrix3d C;
    const int at[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) C(a, b) = sums.s[at[a][b]][p] / sums.W[p] - mean[a] * mean[b];
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    const Eigen::Vector3d ev = es.eigenvalues();
    // Shaped exactly when no eigenvalue needs a clamp, up to the bounds' slack: a clear case
    // either way is decided as the definition says.
    const bool clear_inside = ev[0] > 0 && ev[2] * 1.8 < kr2 * ev[0] && ev[2] * 1.8 < kr2 * k.s_bulk;
    const bool clear_outside = ev[2] > kr2 * ev[0] * 1.001 || ev[2] > kr2 * k.s_bulk * 1.001 || ev[0] <= 0;
    if (clear_inside) {
      ASSERT_TRUE(sums.shaped[p]) << p;
    }
    if (clear_outside) {
      ASSERT_FALSE(sums.shaped[p]) << p;
    }
    if (!sums.shaped[p]) {
      clamped += 1;
      continue;
    }
    shaped += 1;
    // map^T map = (s_bulk / H^2) C^-1, within float rounding.
    Eigen::Matrix3f M;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) M(r, c) = ker.map[std::size_t(3 * r + c)];
    ASSERT_EQ(M(1, 0), 0.0f);
    ASSERT_EQ(M(2, 0), 0.0f);
    ASSERT_EQ(M(2, 1), 0.0f);
    const Eigen::Matrix3d form = (k.s_bulk / (H * H)) * C.inverse();
    const Eigen::Matrix3d got = M.cast<double>().transpose() * M.cast<double>();
    ASSERT_LT((got - form).norm(), 1e-5 * form.norm()) << p;
    const double weight = k.volume * k.normalisation / (H * H * H * std::sqrt(C.determinant() / std::pow(k.s_bulk, 3)));
    ASSERT_NEAR(ker.weight, weight, 1e-6 * weight) << p;
    ASSERT_GE(double(ker.reach) * (1 + 1e-6), H * std::sqrt(ev[2] / k.s_bulk)) << "the reach bounds the longest axis";
  }
  EXPECT_GT(shaped, n / 10);
  EXPECT_GT(clamped, n / 10);
}

}  // namespace
