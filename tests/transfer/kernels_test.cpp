// B-spline kernel identities (Jiang et al. 2016 course notes, sec. 9.1): for every kernel, at
// random positions, in 2D and 3D:
//   sum_i w_ip = 1, sum_i w_ip x_i = x_p, sum_i grad w_ip = 0, sum_i grad w_ip (x) x_i = I,
// and each derivative matches a finite difference of its weight.
#include <gtest/gtest.h>

#include <Eigen/LU>
#include <random>
#include <vector>
#include <algorithm>

#include "slurry/transfer/kernels.h"

namespace {

using namespace slurry::transfer;

template <int Dim, int Order>
void check_identities(unsigned seed) {
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> U(3.0, 9.0);
  const double dx = 0.37;
  for (int trial = 0; trial < 200; ++trial) {
    Vec xp;
    for (int d = 0; d < Dim; ++d) xp[d] = U(rng) * dx;
    const Stencil<double, Dim, Order> s(xp, 1.0 / dx, dx);
    double sw = 0;
    Vec swx = Vec::Zero(), sg = Vec::Zero();
    Mat sgx = Mat::Zero();
    for_each_node(s, [&](int a, int b, int c, double w, const Vec& g, const Vec& off) {
      Eigen::Matrix<int, Dim, 1> idx;
      idx[0] = s.base[0] + a;
      idx[1] = s.base[1] + b;
      if constexpr (Dim == 3) idx[2] = s.base[2] + c;
      const Vec xi = dx * idx.template cast<double>();
      EXPECT_NEAR((xi - xp - off).norm(), 0.0, 1e-12);
      sw += w;
      swx += w * xi;
      sg += g;
      sgx += g * xi.transpose();
    });
    EXPECT_NEAR(sw, 1.0, 1e-13) << "partition of unity, order " << Order;
    EXPECT_NEAR((swx - xp).norm(), 0.0, 1e-12) << "linear reproduction, order " << Order;
    EXPECT_NEAR(sg.norm(), 0.0, 1e-12) << "sum of gradients, order " << Order;
    EXPECT_NEAR((sgx - Mat::Identity()).norm(), 0.0, 1e-12) << "gradient reproduction, order " << Order;
  }
}

TEST(Kernels, IdentitiesLinear2D) { check_identities<2, 1>(1); }
TEST(Kernels, IdentitiesQuadratic2D) { check_identities<2, 2>(2); }
TEST(Kernels, IdentitiesCubic2D) { check_identities<2, 3>(3); }
TEST(Kernels, IdentitiesLinear3D) { check_identities<3, 1>(4); }
TEST(Kernels, IdentitiesQuadratic3D) { check_identities<3, 2>(5); }
TEST(Kernels, IdentitiesCubic3D) { check_identities<3, 3>(6); }

// dN/df from eval() against a central difference of N itself, away from the knots.
template <int Order>
void check_derivatives() {
  constexpr int N = BSpline<Order>::support;
  std::mt19937 rng(Order);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (int trial = 0; trial < 100; ++trial) {
    const double x = 5.0 + U(rng);
    const int base = BSpline<Order>::template base<double>(x);
    const double f = x - base, h = 1e-6;
    double w[N], dw[N], wp[N], wm[N], scratch[N];
    BSpline<Order>::eval(f, w, dw);
    BSpline<Order>::eval(f + h, wp, scratch);
    BSpline<Order>::eval(f - h, wm, scratch);
    for (int a = 0; a < N; ++a) EXPECT_NEAR(dw[a], (wp[a] - wm[a]) / (2 * h), 1e-7);
  }
}

TEST(Kernels, DerivativesMatchFiniteDifferences) {
  check_derivatives<1>();
  check_derivatives<2>();
  check_derivatives<3>();
}

// D_p = sum_i w_ip (x_i - x_p)(x_i - x_p)^T equals dx^2/4 I (quadratic) and dx^2/3 I (cubic), the
// constants behind inverse_inertia (Jiang et al. 2015, sec. 5.3).
template <int Order>
void check_inertia() {
  using Vec = Eigen::Vector3d;
  const double dx = 0.1;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> U(1.0, 2.0);
  for (int t = 0; t < 50; ++t) {
    const Vec xp(U(rng), U(rng), U(rng));
    const Stencil<double, 3, Order> s(xp, 1 / dx, dx);
    Eigen::Matrix3d D = Eigen::Matrix3d::Zero();
    for_each_node(s, [&](int, int, int, double w, const Vec&, const Vec& off) { D += w * off * off.transpose(); });
    EXPECT_NEAR((D.inverse() - BSpline<Order>::inverse_inertia(dx) * Eigen::Matrix3d::Identity()).norm(), 0.0,
                1e-8 / (dx * dx));
  }
}

TEST(Kernels, InertiaTensorIsConstantForQuadraticAndCubic) {
  check_inertia<2>();
  check_inertia<3>();
}

// StencilBatch gives each particle the Stencil constructor's stencil, and, with a clamp on the
// bases, a particle whose base falls one node outside the range (as a base computed with other
// roundings can, near a cell face) gets the range's base with the same weights on the same nodes
// to round-off, never nodes outside the range.
template <int Order>
void check_batch() {
  using Vec = Eigen::Vector2f;
  using St = slurry::transfer::Stencil<float, 2, Order>;
  using Batch = slurry::transfer::StencilBatch<float, 2, Order>;
  constexpr int N = St::N;
  const float dx = 1.0f / 64, inv_dx = 64.0f;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.2f, 0.8f);
  std::vector<Vec> x(40);
  for (auto& p : x) p = Vec(u(rng), u(rng));
  Batch batch;
  for (int i0 = 0; i0 < 40; i0 += Batch::size) {
    const int count = std::min(Batch::size, 40 - i0);
    batch.compute(x.data(), nullptr, i0, count, Vec::Zero(), inv_dx, dx);
    for (int k = 0; k < count; ++k) {
      const St want(x[std::size_t(i0 + k)], inv_dx, dx), got = batch.get(k);
      for (int d = 0; d < 2; ++d) {
        EXPECT_EQ(got.base[std::size_t(d)], want.base[std::size_t(d)]);
        for (int a = 0; a < N; ++a) EXPECT_NEAR(got.w[d][a], want.w[d][a], 1e-6f);
      }
    }
  }
  // Clamped: every base into [b + 1, b + 1] where b is the unclamped base (one node up), or
  // [b - 1, b - 1] (one down), for particles 1e-4 cells from the face where the base flips: the
  // pieces of the B-spline agree there to O(1e-8).
  const float shift = Order == 2 ? 0.5f : 0.0f;
  for (int side = -1; side <= 1; side += 2) {
    std::vector<Vec> y;
    for (int c = 10; c < 26; ++c) {
      const float at = (float(c) + shift + float(side) * 1e-4f) * dx;  // just below or above a face
      y.push_back(Vec(at, 0.5f));
    }
    batch.compute(y.data(), nullptr, 0, Batch::size, Vec::Zero(), inv_dx, dx);
    Batch clamped;
    for (int k = 0; k < Batch::size; ++k) {
      const St free = batch.get(k);
      const int lo[2] = {free.base[0] - side, free.base[1]}, hi[2] = {free.base[0] - side, free.base[1]};
      clamped.compute(y.data(), nullptr, k, 1, Vec::Zero(), inv_dx, dx, lo, hi);
      const St got = clamped.get(0);
      ASSERT_EQ(got.base[0], free.base[0] - side);
      // The same weight on the same node: node base + a of `got` is node base - side + a.
      for (int a = 0; a < N; ++a) {
        const int j = a - side;  // index of that node in `free`
        const float w_free = j >= 0 && j < N ? free.w[0][j] : 0.0f;
        EXPECT_NEAR(got.w[0][a], w_free, 1e-5f) << "order " << Order << " side " << side << " node " << a;
      }
    }
  }
}
TEST(Kernels, StencilBatchMatchesStencilAndClampsByRoundOff) {
  check_batch<2>();
  check_batch<3>();
}

}  // namespace
