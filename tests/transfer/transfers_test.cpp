// Conservation properties of the transfers (Jiang et al. 2015, sec. 5): P2G conserves mass and
// linear momentum to round-off for every scheme; APIC and MLS conserve angular momentum through
// a P2G/G2P round trip and reproduce an affine velocity field exactly; PIC does not.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Geometry>

#include "slurry/transfer/grid.h"
#include "slurry/transfer/transfers.h"

namespace {

using namespace slurry::transfer;

template <int Dim>
const Eigen::Matrix<double, Dim, Dim>* const kNoStress = nullptr;

template <int Dim>
struct Cloud {
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  std::vector<Vec> x, v;
  std::vector<double> m;
  std::vector<Mat> C;
  DenseGrid<double, Dim> grid;

  explicit Cloud(int n, unsigned seed) {
    const double dx = 0.1;
    grid.resize(Vec::Zero(), dx, Eigen::Matrix<int, Dim, 1>::Constant(24));
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> U(0.8, 1.5), M(0.5, 2.0), V(-1.0, 1.0);
    for (int p = 0; p < n; ++p) {
      Vec xp, vp;
      for (int d = 0; d < Dim; ++d) xp[d] = U(rng), vp[d] = V(rng);
      x.push_back(xp);
      v.push_back(vp);
      m.push_back(M(rng));
      Mat c;
      for (int i = 0; i < Dim * Dim; ++i) c.data()[i] = V(rng);
      C.push_back(c);
    }
  }
  /// Grid nodes' mass, momentum and angular momentum (about the origin; z component in 2D).
  void grid_totals(double& mass, Vec& mom, Eigen::Vector3d& ang) const {
    mass = 0;
    mom.setZero();
    ang.setZero();
    for (std::size_t k = 0; k < grid.size(); ++k) {
      const auto& n = grid.node(std::int64_t(k));
      if (n[Dim] == 0) continue;
      mass += n[Dim];
      const Vec p = n.template head<Dim>();
      mom += p;
      ang += cross(grid.position(grid.coord(std::int64_t(k))), p);
    }
  }
  static Eigen::Vector3d cross(const Vec& a, const Vec& b) {
    if constexpr (Dim == 3)
      return a.cross(b);
    else
      return Eigen::Vector3d(0, 0, a[0] * b[1] - a[1] * b[0]);
  }
  /// Particle angular momentum sum_p x_p x m_p v_p, plus the APIC spin term m_p (C_p^T : eps) D_p
  /// (Jiang et al. 2015, eq. 21), which for constant D_p = dx^2/k I is m_p D eps : C_p^T.
  Eigen::Vector3d particle_angular(bool affine, double Dscalar) const {
    Eigen::Vector3d L = Eigen::Vector3d::Zero();
    for (std::size_t p = 0; p < x.size(); ++p) {
      L += cross(x[p], m[p] * v[p]);
      if (affine) {
        const Mat B = C[p] * Dscalar;  // B = C D
        if constexpr (Dim == 3)
          L += m[p] * Eigen::Vector3d(B(2, 1) - B(1, 2), B(0, 2) - B(2, 0), B(1, 0) - B(0, 1));
        else
          L += m[p] * Eigen::Vector3d(0, 0, B(1, 0) - B(0, 1));
      }
    }
    return L;
  }
};

template <int Dim, int Order, Scheme S>
void check_p2g_conserves(unsigned seed) {
  Cloud<Dim> c(300, seed);
  using Vec = typename Cloud<Dim>::Vec;
  particles_to_grid<Order, S>(c.grid, c.x.data(), c.v.data(), c.m.data(),
                              carries_affine(S) ? c.C.data() : nullptr, kNoStress<Dim>, 0, std::int64_t(c.x.size()));
  double mass = 0, pm = 0;
  Vec mom, pmom = Vec::Zero();
  Eigen::Vector3d ang;
  c.grid_totals(mass, mom, ang);
  for (std::size_t p = 0; p < c.x.size(); ++p) pm += c.m[p], pmom += c.m[p] * c.v[p];
  EXPECT_NEAR(mass, pm, 1e-12 * pm);
  EXPECT_NEAR((mom - pmom).norm(), 0.0, 1e-12 * pm);
  if constexpr (carries_affine(S) && Order > 1) {
    // Angular momentum too: grid L equals particle L including the affine spin term.
    const double D = 1.0 / BSpline<Order>::inverse_inertia(c.grid.dx());
    EXPECT_NEAR((ang - c.particle_angular(true, D)).norm(), 0.0, 1e-11 * pm);
  }
}

TEST(Transfers, P2GConservesMassAndMomentumPIC2D) { check_p2g_conserves<2, 2, Scheme::PIC>(1); }
TEST(Transfers, P2GConservesMassAndMomentumAPIC2D) { check_p2g_conserves<2, 2, Scheme::APIC>(2); }
TEST(Transfers, P2GConservesMassAndMomentumMLS3D) { check_p2g_conserves<3, 2, Scheme::MLS>(3); }
TEST(Transfers, P2GConservesMassAndMomentumAPICCubic3D) { check_p2g_conserves<3, 3, Scheme::APIC>(4); }
TEST(Transfers, P2GConservesMassAndMomentumLinear3D) { check_p2g_conserves<3, 1, Scheme::PIC>(5); }

// With stress impulses K_p, P2G adds sum_p K_p grad w_ip to the grid momentum: the total is
// sum_p K_p sum_i grad w_ip = 0, so internal forces conserve linear momentum.
TEST(Transfers, StressImpulseConservesMomentum) {
  Cloud<3> c(200, 9);
  std::vector<Eigen::Matrix3d> K(c.x.size());
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(-1, 1);
  for (auto& k : K)
    for (int i = 0; i < 9; ++i) k.data()[i] = U(rng);
  particles_to_grid<2, Scheme::APIC>(c.grid, c.x.data(), c.v.data(), c.m.data(), c.C.data(), K.data(), 0,
                                      std::int64_t(c.x.size()));
  double mass;
  Eigen::Vector3d mom, ang, pmom = Eigen::Vector3d::Zero();
  c.grid_totals(mass, mom, ang);
  for (std::size_t p = 0; p < c.x.size(); ++p) pmom += c.m[p] * c.v[p];
  EXPECT_NEAR((mom - pmom).norm(), 0.0, 1e-11);
}

// One mass for every particle, read through mass_mask 0 from a single value, scatters bitwise
// what the same mass stored per particle scatters (the engine's uniform mass, particles.h).
template <int Dim, int Order, Scheme S>
void check_mass_mask() {
  Cloud<Dim> a(150, 7), b(150, 7);
  const double one = 1.25;
  a.m.assign(a.m.size(), one);
  std::vector<Eigen::Matrix<double, Dim, Dim>> K(a.x.size(),
                                                 Eigen::Matrix<double, Dim, Dim>::Identity());
  const auto n = std::int64_t(a.x.size());
  particles_to_grid<Order, S>(a.grid, a.x.data(), a.v.data(), a.m.data(),
                              carries_affine(S) ? a.C.data() : nullptr, K.data(), 0, n);
  particles_to_grid<Order, S>(b.grid, b.x.data(), b.v.data(), &one,
                              carries_affine(S) ? b.C.data() : nullptr, K.data(), 0, n, 0);
  for (std::size_t k = 0; k < a.grid.size(); ++k)
    ASSERT_TRUE(a.grid.node(std::int64_t(k)) == b.grid.node(std::int64_t(k))) << "node " << k;
}

TEST(Transfers, UniformMassThroughTheMaskScattersBitwiseAsPerParticle) {
  check_mass_mask<2, 2, Scheme::APIC>();
  check_mass_mask<3, 2, Scheme::MLS>();
  check_mass_mask<3, 1, Scheme::PIC>();
  check_mass_mask<3, 3, Scheme::APIC>();
}

/// P2G, grid momentum -> velocity, G2P; returns the cloud afterwards.
template <int Dim, int Order, Scheme S>
Cloud<Dim> round_trip(Cloud<Dim> c) {
  using Vec = typename Cloud<Dim>::Vec;
  using Mat = typename Cloud<Dim>::Mat;
  particles_to_grid<Order, S>(c.grid, c.x.data(), c.v.data(), c.m.data(), carries_affine(S) ? c.C.data() : nullptr,
                              kNoStress<Dim>, 0, std::int64_t(c.x.size()));
  for (std::size_t k = 0; k < c.grid.size(); ++k) {
    auto& n = c.grid.node(std::int64_t(k));
    if (n[Dim] > 0) n.template head<Dim>() /= n[Dim];
  }
  const Vec lo = Vec::Constant(-1e9), hi = Vec::Constant(1e9);
  grid_to_particles<Order, S>(c.grid, c.x.data(), c.v.data(), carries_affine(S) ? c.C.data() : nullptr, 0.0, 0.0,
                              lo, hi, 0, std::int64_t(c.x.size()), [](std::int64_t, const Mat&) {});
  return c;
}

// An affine field v(x) = a + A x carried by APIC particles (C_p = A) survives P2G+G2P exactly.
template <int Dim, int Order, Scheme S>
void check_affine_exact() {
  using Vec = typename Cloud<Dim>::Vec;
  using Mat = typename Cloud<Dim>::Mat;
  Cloud<Dim> c(400, 11);  // dense enough that every node's stencil is well covered
  Mat A;
  for (int i = 0; i < Dim * Dim; ++i) A.data()[i] = 0.3 * (i + 1) - 1.0;
  const Vec a = Vec::Constant(0.5);
  // The channel holds C_p = A, except for the linear kernel, where it holds B_p = A D_p.
  auto stored = [&](const Vec& x) -> Mat {
    if constexpr (Order > 1) {
      return A;
    } else {
      const Stencil<double, Dim, 1> s(x, 1 / c.grid.dx(), c.grid.dx());
      Mat D = Mat::Zero();
      for_each_node(s, [&](int, int, int, double w, const Vec&, const Vec& off) { D += w * off * off.transpose(); });
      return A * D;
    }
  };
  for (std::size_t p = 0; p < c.x.size(); ++p) c.v[p] = a + A * c.x[p], c.C[p] = stored(c.x[p]);
  const Cloud<Dim> out = round_trip<Dim, Order, S>(c);
  double err = 0;
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    err = std::max(err, (out.v[p] - (a + A * c.x[p])).norm());
    err = std::max(err, (out.C[p] - stored(c.x[p])).norm());
  }
  EXPECT_LT(err, 1e-10);
}

TEST(Transfers, APICReproducesAffineFieldQuadratic2D) { check_affine_exact<2, 2, Scheme::APIC>(); }
TEST(Transfers, APICReproducesAffineFieldCubic3D) { check_affine_exact<3, 3, Scheme::APIC>(); }
TEST(Transfers, APICReproducesAffineFieldLinear3D) { check_affine_exact<3, 1, Scheme::APIC>(); }
TEST(Transfers, MLSReproducesAffineFieldQuadratic3D) { check_affine_exact<3, 2, Scheme::MLS>(); }

// Angular momentum through a full round trip: APIC keeps it (including the spin term), PIC
// loses a measurable part of a rigid rotation.
template <Scheme S>
double angular_momentum_change() {
  using Vec = Eigen::Vector2d;
  Cloud<2> c(300, 13);
  const Vec center(1.15, 1.15);
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    const Vec r = c.x[p] - center;
    c.v[p] = Vec(-r[1], r[0]);  // rigid rotation, omega = 1
    c.C[p] << 0, -1, 1, 0;
  }
  const double D = 1.0 / BSpline<2>::inverse_inertia(0.1);
  const double before = c.particle_angular(carries_affine(S), D)[2];
  const Cloud<2> out = round_trip<2, 2, S>(c);
  const double after = out.particle_angular(carries_affine(S), D)[2];
  return std::abs(after - before) / std::abs(before);
}

TEST(Transfers, APICConservesAngularMomentumPICLosesIt) {
  const double apic = angular_momentum_change<Scheme::APIC>();
  const double pic = angular_momentum_change<Scheme::PIC>();
  EXPECT_LT(apic, 1e-12);
  EXPECT_GT(pic, 1e-3) << "PIC should dissipate rotation (Jiang et al. 2015, fig. 2)";
}

// Float 3D MLS takes packed paths where the machine has AVX2 and FMA (transfers.h: two nodes or
// two sums per 256-bit register, C stored from registers, the state update queued a batch
// behind), written to do the generic form's arithmetic, which double runs. The two precisions
// must agree to float round-off: the grid's mass and momentum after P2G with stress impulses,
// then v, x and C after G2P; and the state update must see each particle once, with its new C.
template <int Order>
void check_float_mls3d_matches_double(unsigned seed) {
  using Vecf = Eigen::Vector3f;
  using Matf = Eigen::Matrix3f;
  Cloud<3> c(300, seed);
  const auto n = std::int64_t(c.x.size());
  std::vector<Eigen::Matrix3d> K(c.x.size());
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<double> U(-1, 1);
  for (auto& k : K)
    for (int i = 0; i < 9; ++i) k.data()[i] = 1e-3 * U(rng);
  std::vector<Vecf> xf, vf;
  std::vector<float> mf;
  std::vector<Matf> Cf, Kf;
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    xf.push_back(c.x[p].cast<float>());
    vf.push_back(c.v[p].cast<float>());
    mf.push_back(float(c.m[p]));
    Cf.push_back(c.C[p].cast<float>());
    Kf.push_back(K[p].cast<float>());
  }
  DenseGrid<float, 3> gf;
  gf.resize(Vecf::Zero(), 0.1f, Eigen::Vector3i::Constant(24));
  particles_to_grid<Order, Scheme::MLS>(c.grid, c.x.data(), c.v.data(), c.m.data(), c.C.data(), K.data(), 0, n);
  particles_to_grid<Order, Scheme::MLS>(gf, xf.data(), vf.data(), mf.data(), Cf.data(), Kf.data(), 0, n);
  double mmax = 0, pmax = 0, merr = 0, perr = 0;
  for (std::size_t k = 0; k < c.grid.size(); ++k) {
    const auto& nd = c.grid.node(std::int64_t(k));
    const auto& nf = gf.node(std::int64_t(k));
    mmax = std::max(mmax, std::abs(nd[3]));
    pmax = std::max(pmax, nd.head<3>().norm());
    merr = std::max(merr, std::abs(double(nf[3]) - nd[3]));
    perr = std::max(perr, (nf.head<3>().cast<double>() - nd.head<3>()).norm());
  }
  ASSERT_GT(pmax, 0.1);
  EXPECT_LT(merr, 1e-5 * mmax);
  EXPECT_LT(perr, 1e-5 * pmax);

  // G2P from the double grid's velocities, copied to the float grid.
  for (std::size_t k = 0; k < c.grid.size(); ++k) {
    auto& nd = c.grid.node(std::int64_t(k));
    if (nd[3] > 0) nd.head<3>() /= nd[3];
    gf.node(std::int64_t(k)) = nd.cast<float>();
  }
  const double dt = 0.01;
  const Eigen::Vector3d lo = Eigen::Vector3d::Constant(-1e9), hi = Eigen::Vector3d::Constant(1e9);
  gather_particles<Order, Scheme::MLS>(c.grid, c.x.data(), c.v.data(), c.C.data(), dt, 0.0, lo, hi, nullptr, 0, n,
                                       [](std::int64_t, const Eigen::Matrix3d&) {});
  std::vector<int> seen(c.x.size(), 0);
  int wrong_grad = 0;
  const Vecf lof = lo.cast<float>(), hif = hi.cast<float>();
  gather_particles<Order, Scheme::MLS>(gf, xf.data(), vf.data(), Cf.data(), float(dt), 0.0f, lof, hif, nullptr, 0, n,
                                       [&](std::int64_t p, const Matf& g) {
                                         ++seen[std::size_t(p)];
                                         wrong_grad += !(g.array() == Cf[std::size_t(p)].array()).all();
                                       });
  double vmax = 0, cmax = 0, verr = 0, cerr = 0, xerr = 0;
  for (std::size_t p = 0; p < c.x.size(); ++p) {
    vmax = std::max(vmax, c.v[p].norm());
    cmax = std::max(cmax, c.C[p].norm());
    verr = std::max(verr, (vf[p].cast<double>() - c.v[p]).norm());
    cerr = std::max(cerr, (Cf[p].cast<double>() - c.C[p]).norm());
    xerr = std::max(xerr, (xf[p].cast<double>() - c.x[p]).norm());
    EXPECT_EQ(seen[p], 1) << "particle " << p;
  }
  EXPECT_EQ(wrong_grad, 0);
  ASSERT_GT(cmax, 0.1);
  EXPECT_LT(verr, 1e-5 * vmax);
  EXPECT_LT(cerr, 1e-4 * cmax);
  EXPECT_LT(xerr, 1e-6);
}

TEST(Transfers, FloatMLSMatchesDoubleQuadratic3D) { check_float_mls3d_matches_double<2>(31); }
TEST(Transfers, FloatMLSMatchesDoubleCubic3D) { check_float_mls3d_matches_double<3>(32); }

}  // namespace
