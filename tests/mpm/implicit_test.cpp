// The linearly implicit MPM grid update (engine/src/mpm/implicit_update.h): the stiffness operator is
// symmetric, positive semidefinite after the definiteness fix and the exact linearization of the
// explicit stress force (finite differences through the P2G/G2P transfers); the implicit step
// agrees with the explicit one at small dt and stays stable far beyond the explicit limit.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>
#include <random>
#include <utility>
#include <vector>

#include "mpm/implicit_update.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"
#include "slurry/transfer/transfers.h"
#include "slurry/io/scene_file.h"

namespace {

using slurry::Scene;

// ------------------------------------------------------------------------------------------
// The operator on a free-standing set of deformed particles
// ------------------------------------------------------------------------------------------

struct Range {
  int material;
  std::int64_t begin, end;
};

/// How the particles are deformed: F_p = R_p (I + a B_p) with B_p symmetric random in [-1, 1]
/// and a = `strain`, or compressed: singular values in [0.55, 0.8].
enum class State { Generic, Stretched, Compressed };

template <int Dim>
struct Cloud {
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Mat = Eigen::Matrix<double, Dim, Dim>;
  using Grid = slurry::transfer::DenseGrid<double, Dim>;
  slurry::Particles<double, Dim> P;
  Grid grid;
  std::vector<slurry::Material<double, Dim>> materials;
  std::vector<Range> ranges;
  slurry::TransferKind transfer;
  slurry::KernelKind kernel;
};

template <int Dim>
Eigen::Matrix<double, Dim, Dim> rotation(std::mt19937& rng) {
  std::normal_distribution<double> n;
  if constexpr (Dim == 2) {
    return Eigen::Rotation2Dd(n(rng)).toRotationMatrix();
  } else {
    return Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
  }
}

template <int Dim>
Cloud<Dim> make_cloud(slurry::TransferKind transfer, slurry::KernelKind kernel, slurry::MaterialParams mp,
                      State state, unsigned seed = 7) {
  using S = Cloud<Dim>;
  using Vec = typename S::Vec;
  using Mat = typename S::Mat;
  S s;
  s.transfer = transfer;
  s.kernel = kernel;
  const double dx = 1.0 / 16;
  s.grid.resize(Vec::Zero(), dx, Eigen::Matrix<int, Dim, 1>::Constant(17));
  mp.name = "m";
  s.materials = {slurry::make_material<double, Dim>(mp)};
  s.P.channels.F = true;
  s.P.channels.plastic = mp.plasticity != slurry::PlasticModel::None;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1), sym(-1, 1);
  const int n = Dim == 2 ? 120 : 150;
  const double vol = std::pow(dx, Dim) / 4;
  for (int p = 0; p < n; ++p) {
    Vec x;
    for (int d = 0; d < Dim; ++d) x[d] = 0.35 + 0.3 * u(rng);
    s.P.push_back(x, Vec::Zero(), mp.density * vol, vol, 0, 0.9 + 0.2 * u(rng));  // Jp for snow
    Mat F;
    if (state == State::Compressed) {
      Vec sigma;
      for (int d = 0; d < Dim; ++d) sigma[d] = 0.55 + 0.25 * u(rng);
      F = rotation<Dim>(rng) * sigma.asDiagonal() * rotation<Dim>(rng);
    } else {
      Mat B;
      for (int i = 0; i < Dim; ++i)
        for (int j = 0; j <= i; ++j) B(i, j) = B(j, i) = sym(rng);
      if (state == State::Stretched) B = B * B.transpose() + 0.2 * Mat::Identity();  // positive: stretch
      F = rotation<Dim>(rng) * (Mat::Identity() + (state == State::Stretched ? 0.01 : 0.15) * B);
    }
    s.P.F.back() = F;
  }
  s.ranges = {{0, 0, std::int64_t(s.P.size())}};
  // P2G of the masses only: the unknowns are the nodes with mass.
  auto p2g = [&](auto order) {
    constexpr int O = decltype(order)::value;
    slurry::transfer::particles_to_grid<O, slurry::transfer::Scheme::PIC>(
        s.grid, s.P.x.data(), s.P.v.data(), s.P.m.read_base(), nullptr, nullptr, 0, n,
        std::int64_t(s.P.m.read_mask()));
  };
  if (kernel == slurry::KernelKind::Linear) p2g(std::integral_constant<int, 1>{});
  if (kernel == slurry::KernelKind::Quadratic) p2g(std::integral_constant<int, 2>{});
  if (kernel == slurry::KernelKind::Cubic) p2g(std::integral_constant<int, 3>{});
  return s;
}

template <int Dim>
slurry::ImplicitUpdate<double, Dim> make_operator(Cloud<Dim>& s, bool definite) {
  typename slurry::ImplicitUpdate<double, Dim>::Options o;
  o.definite = definite;
  slurry::ImplicitUpdate<double, Dim> op(s.kernel, s.transfer, o);
  op.collect_unknowns(s.grid);
  op.linearize(s.P, s.materials, s.ranges);
  return op;
}

slurry::MaterialParams material(slurry::ElasticModel model, slurry::PlasticModel plastic = slurry::PlasticModel::None) {
  slurry::MaterialParams m;
  m.model = model;
  m.plasticity = plastic;
  m.E = 1e5;
  m.nu = 0.3;
  m.density = 1000;
  return m;
}

Eigen::VectorXd random_vector(Eigen::Index n, std::mt19937& rng) {
  std::normal_distribution<double> g;
  Eigen::VectorXd v(n);
  for (Eigen::Index i = 0; i < n; ++i) v[i] = g(rng);
  return v;
}

/// The explicit stress force at grid displacement delta, through the transfers the explicit step
/// uses: G2P (dt = 1) gives each particle's displacement gradient (the MLS one for MLS), the
/// first Piola stress at F^ = (I + grad delta) F goes in as the P2G stress impulse
/// K_p = -V_p P(F^) F^T, and P2G (zero velocity) returns f_i = -sum_p V_p P(F^_p) F_p^T g_ip.
template <int Order, int Dim>
Eigen::VectorXd explicit_force(const Cloud<Dim>& s, const slurry::ImplicitUpdate<double, Dim>& op,
                               const Eigen::VectorXd& delta) {
  using Vec = typename Cloud<Dim>::Vec;
  using Mat = typename Cloud<Dim>::Mat;
  using slurry::transfer::Scheme;
  const bool mls = s.transfer == slurry::TransferKind::MLS;
  const std::int64_t n = std::int64_t(s.P.size());
  typename Cloud<Dim>::Grid g(s.grid.origin(), s.grid.dx(), s.grid.res());
  for (std::int64_t i = 0; i < op.unknowns(); ++i) g.node(op.node(i)).template head<Dim>() = delta.segment<Dim>(Dim * i);
  std::vector<Vec> x = s.P.x, v = s.P.v;
  std::vector<Mat> C(std::size_t(n), Mat::Zero()), grad(std::size_t(n), Mat::Zero());
  const Vec lo = Vec::Constant(-1e9), hi = Vec::Constant(1e9);
  auto state = [&](std::int64_t p, const Mat& gv) { grad[std::size_t(p)] = gv; };
  if (mls) {
    if constexpr (Order > 1)
      slurry::transfer::grid_to_particles<Order, Scheme::MLS>(g, x.data(), v.data(), C.data(), 1.0, 0.0, lo, hi, 0, n, state);
  } else {
    slurry::transfer::grid_to_particles<Order, Scheme::APIC>(g, x.data(), v.data(), C.data(), 1.0, 0.0, lo, hi, 0, n, state);
  }
  std::vector<Mat> K(std::size_t(n), Mat::Zero());
  const auto& mat = s.materials[0];
  mat.visit_elastic([&](const auto& model) {
    for (std::int64_t p = 0; p < n; ++p) {
      const Mat& F = s.P.F[std::size_t(p)];
      const Mat Fh = (Mat::Identity() + grad[std::size_t(p)]) * F;
      const double h = s.P.plastic.empty() ? 1.0 : mat.hardening_factor(s.P.plastic[std::size_t(p)]);
      K[std::size_t(p)] = -s.P.vol0[std::size_t(p)] * model.scaled(h).piola(Fh) * F.transpose();
    }
  });
  typename Cloud<Dim>::Grid f(s.grid.origin(), s.grid.dx(), s.grid.res());
  const std::vector<Vec> zero(std::size_t(n), Vec::Zero());
  std::vector<Mat> Czero(std::size_t(n), Mat::Zero());
  if (mls) {
    if constexpr (Order > 1)
      slurry::transfer::particles_to_grid<Order, Scheme::MLS>(
          f, s.P.x.data(), zero.data(), s.P.m.read_base(), Czero.data(), K.data(), 0, n,
          std::int64_t(s.P.m.read_mask()));
  } else {
    slurry::transfer::particles_to_grid<Order, Scheme::APIC>(
        f, s.P.x.data(), zero.data(), s.P.m.read_base(), Czero.data(), K.data(), 0, n,
        std::int64_t(s.P.m.read_mask()));
  }
  Eigen::VectorXd out(Dim * op.unknowns());
  for (std::int64_t i = 0; i < op.unknowns(); ++i) out.segment<Dim>(Dim * i) = f.node(op.node(i)).template head<Dim>();
  return out;
}

/// max over a few random directions u of ||(f(eps u) - f(-eps u)) / (2 eps) + H u|| / ||H u||.
template <int Order, int Dim>
double linearization_error(slurry::TransferKind transfer, slurry::KernelKind kernel, const slurry::MaterialParams& mp,
                           State state, bool definite) {
  Cloud<Dim> s = make_cloud<Dim>(transfer, kernel, mp, state);
  auto op = make_operator<Dim>(s, definite);
  std::mt19937 rng(3);
  double worst = 0;
  for (int trial = 0; trial < 3; ++trial) {
    const Eigen::VectorXd u = random_vector(Dim * op.unknowns(), rng);
    Eigen::VectorXd Hu;
    op.apply_stiffness(u, Hu);
    const double eps = 1e-6 * s.grid.dx();
    const Eigen::VectorXd fd = (explicit_force<Order>(s, op, eps * u) - explicit_force<Order>(s, op, -eps * u)) / (2 * eps);
    worst = std::max(worst, (fd + Hu).norm() / Hu.norm());
  }
  return worst;
}

TEST(ImplicitOperator, ForceLinearizationMatchesFiniteDifferences) {
  using slurry::ElasticModel;
  using slurry::KernelKind;
  using slurry::TransferKind;
  struct Case {
    const char* name;
    double err;
  };
  const auto fc = material(ElasticModel::FixedCorotated);
  const std::vector<Case> cases = {
      {"2D MLS quadratic, fixed corotated", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, fc, State::Generic, false)},
      {"2D MLS cubic, fixed corotated", linearization_error<3, 2>(TransferKind::MLS, KernelKind::Cubic, fc, State::Generic, false)},
      {"2D APIC quadratic, fixed corotated", linearization_error<2, 2>(TransferKind::APIC, KernelKind::Quadratic, fc, State::Generic, false)},
      {"2D APIC linear, fixed corotated", linearization_error<1, 2>(TransferKind::APIC, KernelKind::Linear, fc, State::Generic, false)},
      {"2D FLIP cubic, fixed corotated", linearization_error<3, 2>(TransferKind::FLIP, KernelKind::Cubic, fc, State::Generic, false)},
      {"2D PIC quadratic, compressed", linearization_error<2, 2>(TransferKind::PIC, KernelKind::Quadratic, fc, State::Compressed, false)},
      {"2D MLS, neo-Hookean", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, material(ElasticModel::NeoHookean), State::Generic, false)},
      {"2D MLS, StVK", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, material(ElasticModel::StVK), State::Generic, false)},
      {"2D MLS, corotated linear", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, material(ElasticModel::CorotatedLinear), State::Generic, false)},
      {"2D MLS, Hencky StVK", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, material(ElasticModel::HenckyStVK), State::Generic, false)},
      {"2D MLS, snow (hardened)", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, material(ElasticModel::FixedCorotated, slurry::PlasticModel::Snow), State::Generic, false)},
      {"2D MLS, stretched, definiteness fix on", linearization_error<2, 2>(TransferKind::MLS, KernelKind::Quadratic, fc, State::Stretched, true)},
      {"3D MLS quadratic, fixed corotated", linearization_error<2, 3>(TransferKind::MLS, KernelKind::Quadratic, fc, State::Generic, false)},
      {"3D APIC linear, neo-Hookean", linearization_error<1, 3>(TransferKind::APIC, KernelKind::Linear, material(ElasticModel::NeoHookean), State::Generic, false)},
  };
  double worst = 0;
  for (const auto& c : cases) {
    EXPECT_LT(c.err, 1e-6) << c.name;
    worst = std::max(worst, c.err);
  }
  std::printf("[ figure ] implicit operator vs central differences of the P2G stress force: worst relative error %.2e over %zu cases\n",
              worst, cases.size());
}

template <int Dim>
void check_symmetric_semidefinite(slurry::TransferKind transfer, slurry::KernelKind kernel, State state) {
  Cloud<Dim> s = make_cloud<Dim>(transfer, kernel, material(slurry::ElasticModel::FixedCorotated), state);
  auto op = make_operator<Dim>(s, true);
  std::mt19937 rng(11);
  double worst_asym = 0, min_rayleigh = 1e300;
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::VectorXd u = random_vector(Dim * op.unknowns(), rng), w = random_vector(Dim * op.unknowns(), rng);
    Eigen::VectorXd Hu, Hw;
    op.apply_stiffness(u, Hu);
    op.apply_stiffness(w, Hw);
    worst_asym = std::max(worst_asym, std::abs(u.dot(Hw) - w.dot(Hu)) / (u.norm() * Hw.norm()));
    min_rayleigh = std::min(min_rayleigh, u.dot(Hu) / (u.norm() * Hu.norm()));
  }
  EXPECT_LT(worst_asym, 1e-13) << "u^T H w = w^T H u";
  EXPECT_GE(min_rayleigh, -1e-13) << "u^T H u >= 0";
  // Every per-particle K_p is positive semidefinite after the fix.
  double min_eig = 1e300;
  for (std::size_t p = 0; p < s.P.size(); ++p) {
    const auto& K = op.particle_stiffness(std::int64_t(p));
    Eigen::SelfAdjointEigenSolver<std::decay_t<decltype(K)>> eig(K);
    min_eig = std::min(min_eig, eig.eigenvalues().minCoeff() / K.diagonal().cwiseAbs().maxCoeff());
  }
  EXPECT_GE(min_eig, -1e-12);
  // The Jacobi diagonal is the exact diagonal of H.
  Eigen::VectorXd diag;
  op.stiffness_diagonal(diag);
  double worst_diag = 0;
  for (int t = 0; t < 20; ++t) {
    const Eigen::Index k = Eigen::Index(rng() % std::uint32_t(diag.size()));
    Eigen::VectorXd e = Eigen::VectorXd::Zero(diag.size()), He;
    e[k] = 1;
    op.apply_stiffness(e, He);
    worst_diag = std::max(worst_diag, std::abs(He[k] - diag[k]) / std::abs(He[k]));
  }
  EXPECT_LT(worst_diag, 1e-12);
  // The assembled block operator (what CG applies) is the matrix-free one.
  op.build_pattern();
  op.assemble_stiffness();
  double worst_assembled = 0;
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::VectorXd u = random_vector(Dim * op.unknowns(), rng);
    Eigen::VectorXd Hu, Au;
    op.apply_stiffness(u, Hu);
    op.multiply_stiffness(u, Au);
    worst_assembled = std::max(worst_assembled, (Au - Hu).norm() / Hu.norm());
  }
  EXPECT_LT(worst_assembled, 1e-13);
  std::printf("[ figure ] %dD %s: |u.Hw - w.Hu|/(|u||Hw|) <= %.1e, min u.Hu/(|u||Hu|) = %.3e, min eig K_p/|K_p| = %.1e, diagonal error %.1e, "
              "assembled vs matrix-free %.1e (%lld blocks, %lld unknowns)\n",
              Dim, state == State::Compressed ? "compressed" : "generic", worst_asym, min_rayleigh, min_eig, worst_diag,
              worst_assembled, (long long)op.blocks(), (long long)op.unknowns());
}

TEST(ImplicitOperator, SymmetricPositiveSemidefinite2D) {
  check_symmetric_semidefinite<2>(slurry::TransferKind::MLS, slurry::KernelKind::Quadratic, State::Generic);
  check_symmetric_semidefinite<2>(slurry::TransferKind::APIC, slurry::KernelKind::Linear, State::Compressed);
}
TEST(ImplicitOperator, SymmetricPositiveSemidefinite3D) {
  check_symmetric_semidefinite<3>(slurry::TransferKind::APIC, slurry::KernelKind::Cubic, State::Compressed);
}

// Under compression fixed corotated has an indefinite Hessian; the fix removes exactly the
// negative part, and leaves a positive semidefinite K_p untouched.
TEST(ImplicitOperator, DefinitenessFixOnlyActsOnIndefiniteParticles) {
  auto min_eig = [](const auto& op, std::size_t n) {
    double m = 1e300;
    for (std::size_t p = 0; p < n; ++p) {
      const auto& K = op.particle_stiffness(std::int64_t(p));
      Eigen::SelfAdjointEigenSolver<std::decay_t<decltype(K)>> eig(K);
      m = std::min(m, eig.eigenvalues().minCoeff() / K.diagonal().cwiseAbs().maxCoeff());
    }
    return m;
  };
  Cloud<2> c = make_cloud<2>(slurry::TransferKind::MLS, slurry::KernelKind::Quadratic,
                             material(slurry::ElasticModel::FixedCorotated), State::Compressed);
  const auto raw = make_operator<2>(c, false);
  const auto fixed = make_operator<2>(c, true);
  const double raw_min = min_eig(raw, c.P.size()), fixed_min = min_eig(fixed, c.P.size());
  std::printf("[ figure ] compressed fixed corotated: min eig K_p/|K_p| %.3f raw, %.1e after the fix\n", raw_min, fixed_min);
  EXPECT_LT(raw_min, -1e-3) << "the test state should be indefinite";
  EXPECT_GE(fixed_min, -1e-12);

  Cloud<2> s = make_cloud<2>(slurry::TransferKind::MLS, slurry::KernelKind::Quadratic,
                             material(slurry::ElasticModel::FixedCorotated), State::Stretched);
  const auto a = make_operator<2>(s, false);
  const auto b = make_operator<2>(s, true);
  double diff = 0;
  for (std::size_t p = 0; p < s.P.size(); ++p)
    diff = std::max(diff, (a.particle_stiffness(std::int64_t(p)) - b.particle_stiffness(std::int64_t(p))).norm() /
                              a.particle_stiffness(std::int64_t(p)).norm());
  EXPECT_EQ(diff, 0.0) << "a positive semidefinite K_p is left as it is";
}

// ------------------------------------------------------------------------------------------
// Whole simulations
// ------------------------------------------------------------------------------------------

Scene scene(int dim, slurry::TransferKind transfer, const Eigen::Vector3d& max, double dx, double density, double E,
            double nu, slurry::Integrator integrator) {
  Scene s;
  s.source = "test";
  s.solver.dimension = dim;
  s.solver.precision = slurry::Precision::Double;
  s.solver.transfer = transfer;
  s.solver.integrator = integrator;
  s.domain.min = {0, 0, 0};
  s.domain.max = max;
  s.domain.dx = dx;
  slurry::MaterialParams m;
  m.name = "solid";
  m.model = slurry::ElasticModel::FixedCorotated;
  m.density = density;
  m.E = E;
  m.nu = nu;
  s.materials = {m};
  return s;
}

slurry::BodyParams box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double ppc) {
  slurry::BodyParams b;
  b.shape = slurry::Shape::Box;
  b.material = "solid";
  b.min = lo;
  b.max = hi;
  b.particles_per_cell = ppc;
  return b;
}

template <int Dim>
Eigen::Matrix<double, Dim, 1> center_of_mass(const slurry::Particles<double, Dim>& P) {
  Eigen::Matrix<double, Dim, 1> c = Eigen::Matrix<double, Dim, 1>::Zero();
  double m = 0;
  for (std::size_t p = 0; p < P.size(); ++p) c += P.m[p] * P.x[p], m += P.m[p];
  return c / m;
}

// Free fall and rigid translation: H annihilates a uniform velocity field (sum_i g_ip = 0), so
// the implicit step reproduces symplectic Euler exactly and F stays I.
template <int Dim>
void rigid_motion(slurry::TransferKind transfer, slurry::KernelKind kernel, bool gravity) {
  Scene s = scene(Dim, transfer, {1, 1, 1}, Dim == 3 ? 1.0 / 16 : 1.0 / 64, 1000, 1e7, 0.3, slurry::Integrator::Implicit);
  s.solver.kernel = kernel;
  s.bodies = {box({0.4, 0.6, 0.4}, {0.6, 0.8, 0.6}, Dim == 3 ? 8 : 4)};
  if (!gravity) {
    s.solver.gravity = {0, 0, 0};
    s.bodies[0].velocity = {0.5, -0.3, 0.2};
  }
  slurry::MpmSolver<double, Dim> sim(s);
  const auto c0 = center_of_mass<Dim>(sim.particles());
  const double dt = 1e-3, g = gravity ? -9.81 : 0;
  const int n = 100;
  for (int i = 0; i < n; ++i) sim.step(dt);
  const auto c = center_of_mass<Dim>(sim.particles());
  Eigen::Matrix<double, Dim, 1> expected = c0;
  if (gravity) {
    expected[1] += g * dt * dt * n * (n + 1) / 2.0;
  } else {
    expected += n * dt * s.bodies[0].velocity.head<Dim>();
  }
  EXPECT_LT((c - expected).norm(), 1e-9);
  double worst_F = 0;
  for (const auto& F : sim.particles().F) worst_F = std::max(worst_F, (F - std::decay_t<decltype(F)>::Identity()).norm());
  EXPECT_LT(worst_F, 1e-10);
  // Only round-off is left to solve: it grows in an unsolved (explicit) step until it exceeds the
  // round-off floor of the CG tolerance, and a few iterations keep it there.
  const double mean_cg = double(sim.cg_stats().iterations) / double(sim.cg_stats().solves);
  std::printf("[ figure ] %dD rigid motion: centre of mass error %.1e m, max |F - I| %.1e, mean CG iterations %.1f\n", Dim,
              (c - expected).norm(), worst_F, mean_cg);
  EXPECT_LT(mean_cg, 15);
  EXPECT_EQ(sim.cg_stats().solves, n);
  EXPECT_EQ(sim.cg_stats().unconverged, 0);
}

TEST(ImplicitMPM, FreeFallIsExactMLS2D) { rigid_motion<2>(slurry::TransferKind::MLS, slurry::KernelKind::Quadratic, true); }
TEST(ImplicitMPM, FreeFallIsExactAPICLinear2D) { rigid_motion<2>(slurry::TransferKind::APIC, slurry::KernelKind::Linear, true); }
TEST(ImplicitMPM, RigidTranslationIsExactFLIP2D) { rigid_motion<2>(slurry::TransferKind::FLIP, slurry::KernelKind::Quadratic, false); }
TEST(ImplicitMPM, RigidTranslationIsExactMLS3D) { rigid_motion<3>(slurry::TransferKind::MLS, slurry::KernelKind::Quadratic, false); }

// A free-free bar (nu = 0) vibrating in its first axial mode, falling under gravity, run with the
// same small dt explicitly and implicitly. The difference of the two elongation histories is the
// first-order damping of backward Euler, so it must halve with dt; the centre of mass (free
// fall) agrees to round-off.
struct BarHistory {
  std::vector<double> elongation;
  Eigen::Vector2d com;
  std::int64_t cg_iterations = 0;
};

BarHistory vibrating_bar(slurry::Integrator integrator, double dt_factor) {
  const double E = 1e4, rho = 1;
  Scene s = scene(2, slurry::TransferKind::MLS, {2, 1, 0}, 1.0 / 64, rho, E, 0, integrator);
  s.bodies = {box({0.5, 0.6, 0}, {1.5, 0.7, 0}, 4)};
  slurry::MpmSolver<double, 2> sim(s);
  const double L = 1.0, c = std::sqrt(E / rho), period = 2 * L / c, v0 = 0.5;
  auto& P = sim.particles();
  std::vector<bool> left_half(P.size());
  for (std::size_t p = 0; p < P.size(); ++p) {
    P.v[p] = Eigen::Vector2d(v0 * std::cos(M_PI * (P.x[p][0] - 0.5) / L), 0);
    left_half[p] = P.x[p][0] < 1.0;
  }
  const double dt = dt_factor * s.domain.dx / c;
  const int steps = int(std::lround(period / dt));
  BarHistory h;
  for (int i = 0; i < steps; ++i) {
    sim.step(dt);
    if ((i + 1) % std::max(1, steps / 40) == 0) {
      double left = 0, right = 0, nl = 0, nr = 0;
      for (std::size_t p = 0; p < P.size(); ++p) {
        if (left_half[p])
          left += P.x[p][0], nl += 1;
        else
          right += P.x[p][0], nr += 1;
      }
      h.elongation.push_back(right / nr - left / nl);
    }
  }
  h.com = center_of_mass<2>(P);
  h.cg_iterations = sim.cg_stats().iterations;
  return h;
}

TEST(ImplicitMPM, AgreesWithExplicitAtSmallDt) {
  double diff[2] = {0, 0}, amplitude = 0, com_diff = 0;
  std::int64_t iters[2] = {0, 0};
  const double factors[2] = {0.2, 0.1};
  for (int k = 0; k < 2; ++k) {
    const BarHistory e = vibrating_bar(slurry::Integrator::Explicit, factors[k]);
    const BarHistory i = vibrating_bar(slurry::Integrator::Implicit, factors[k]);
    ASSERT_EQ(e.elongation.size(), i.elongation.size());
    const double mean = e.elongation.front();
    for (std::size_t j = 0; j < e.elongation.size(); ++j) {
      diff[k] = std::max(diff[k], std::abs(e.elongation[j] - i.elongation[j]));
      amplitude = std::max(amplitude, std::abs(e.elongation[j] - mean));
    }
    com_diff = std::max(com_diff, (e.com - i.com).norm());
    iters[k] = i.cg_iterations;
  }
  std::printf("[ figure ] bar elongation, implicit vs explicit over one period: max difference %.3e m at dt = 0.2 dx/c, "
              "%.3e m at 0.1 dx/c (amplitude %.3e m, ratio %.2f); centre of mass %.1e m; CG iterations %lld, %lld\n",
              diff[0], diff[1], amplitude, diff[0] / diff[1], com_diff, (long long)iters[0], (long long)iters[1]);
  EXPECT_GT(amplitude, 5e-4) << "the bar vibrates";
  EXPECT_LT(diff[1], 0.05 * amplitude) << "within 5% of the vibration amplitude at dt = 0.1 dx/c";
  EXPECT_GT(diff[0] / diff[1], 1.6) << "the difference is first order in dt";
  EXPECT_LT(diff[0] / diff[1], 2.4) << "the difference is first order in dt";
  EXPECT_LT(com_diff, 1e-9);
}

// A stiff block (E = 1e7 Pa, c = 116 m/s) in its first bending/breathing motion at 10x the
// explicit elastic limit: the implicit run stays bounded with total energy never growing, the
// explicit run at the same dt is stopped by the health check.
template <int Dim>
void stiff_body(double factor) {
  auto make = [&](slurry::Integrator integrator) {
    Scene s = scene(Dim, slurry::TransferKind::MLS, {1, 1, 1}, Dim == 3 ? 1.0 / 16 : 1.0 / 64, 1000, 1e7, 0.3, integrator);
    s.solver.gravity = {0, 0, 0};
    s.bodies = {box({0.3, 0.4, 0.4}, {0.7, 0.6, 0.6}, Dim == 3 ? 8 : 4)};
    return s;
  };
  auto init = [](slurry::MpmSolver<double, Dim>& sim) {
    // A squeeze-and-shear velocity field with zero mean: v = 0.5 m/s (y - yc, -(x - xc), ...) / 0.1 m
    auto& P = sim.particles();
    const auto c = center_of_mass<Dim>(P);
    for (std::size_t p = 0; p < P.size(); ++p) {
      const auto r = P.x[p] - c;
      P.v[p].setZero();
      P.v[p][0] = 5.0 * r[0];
      P.v[p][1] = -5.0 * r[1] + 3.0 * r[0];
    }
  };
  slurry::MpmSolver<double, Dim> imp(make(slurry::Integrator::Implicit)), exp(make(slurry::Integrator::Explicit));
  init(imp);
  init(exp);
  const double dt = factor * exp.stable_dt();
  const double e0 = imp.kinetic_energy() + imp.elastic_energy();
  double max_ratio = 0;
  const int steps = 60;
  for (int i = 0; i < steps; ++i) {
    imp.step(dt);
    max_ratio = std::max(max_ratio, (imp.kinetic_energy() + imp.elastic_energy()) / e0);
  }
  const double final_ratio = (imp.kinetic_energy() + imp.elastic_energy()) / e0;
  std::printf("[ figure ] %dD stiff block, dt = %.0fx explicit limit (%.2e s), %d steps: max E(t)/E(0) = %.4f, final %.4f, "
              "mean CG iterations %.1f\n",
              Dim, factor, dt, steps, max_ratio, final_ratio, double(imp.cg_stats().iterations) / steps);
  EXPECT_LE(max_ratio, 1.0 + 1e-6) << "total energy never grows";
  EXPECT_LT(final_ratio, 1.0);
  EXPECT_GT(final_ratio, 0.05) << "and the block still moves (not frozen by the solve)";
  EXPECT_EQ(imp.cg_stats().unconverged, 0);
  EXPECT_THROW(
      {
        for (int i = 0; i < steps; ++i) exp.step(dt);
      },
      slurry::SimulationError);
}

// The three preconditioners solve the same system: 10 substeps of the 3D stiff block at 10x the
// explicit limit end at the same positions up to the CG tolerance, IC(0) needs far fewer
// iterations than Jacobi, and the IC(0) run is bit for bit the same on one and two threads
// (the assembled operator is summed in particle order, its product row by row).
TEST(ImplicitMPM, PreconditionersAgreeAndAreThreadIndependent) {
  using Sim = slurry::MpmSolver<double, 3>;
  auto run = [](slurry::ImplicitPreconditioner pre, int threads) {
    slurry::parallel::ThreadLimit limit(threads);
    Scene s = scene(3, slurry::TransferKind::MLS, {1, 1, 1}, 1.0 / 16, 1000, 1e7, 0.3, slurry::Integrator::Implicit);
    s.solver.gravity = {0, 0, 0};
    s.solver.implicit_preconditioner = pre;
    s.bodies = {box({0.3, 0.4, 0.4}, {0.7, 0.6, 0.6}, 8)};
    Sim sim(s);
    auto& P = sim.particles();
    const auto c = center_of_mass<3>(P);
    for (std::size_t p = 0; p < P.size(); ++p) {
      const auto r = P.x[p] - c;
      P.v[p] = Eigen::Vector3d(5.0 * r[0], -5.0 * r[1] + 3.0 * r[0], 0);
    }
    s.solver.integrator = slurry::Integrator::Explicit;
    const double dt = 10 * Sim(s).stable_dt();
    for (int i = 0; i < 10; ++i) sim.step(dt);
    return std::make_pair(sim.particles().x, sim.cg_stats());
  };
  using Pre = slurry::ImplicitPreconditioner;
  const auto jacobi = run(Pre::Jacobi, 1), block = run(Pre::BlockJacobi, 1), ic0 = run(Pre::IC0, 1), ic0_2 = run(Pre::IC0, 2);
  auto max_diff = [](const auto& a, const auto& b) {
    double d = 0;
    for (std::size_t p = 0; p < a.size(); ++p) d = std::max(d, (a[p] - b[p]).norm());
    return d;
  };
  const double d_jacobi = max_diff(jacobi.first, ic0.first), d_block = max_diff(block.first, ic0.first);
  const double d_threads = max_diff(ic0.first, ic0_2.first);
  std::printf("[ figure ] 3D stiff block, 10 substeps at 10x the explicit limit: CG iterations Jacobi %lld, block Jacobi %lld, "
              "IC(0) %lld; max position difference to IC(0): Jacobi %.1e m, block Jacobi %.1e m; IC(0) 1 vs 2 threads %.1e m\n",
              (long long)jacobi.second.iterations, (long long)block.second.iterations, (long long)ic0.second.iterations,
              d_jacobi, d_block, d_threads);
  const double dx = 1.0 / 16;
  EXPECT_LT(d_jacobi, 1e-6 * dx);
  EXPECT_LT(d_block, 1e-6 * dx);
  EXPECT_EQ(d_threads, 0.0);
  EXPECT_EQ(ic0.second.iterations, ic0_2.second.iterations);
  EXPECT_LT(2 * ic0.second.iterations, jacobi.second.iterations);
  EXPECT_LE(block.second.iterations, jacobi.second.iterations);
  EXPECT_EQ(ic0.second.unconverged + jacobi.second.unconverged + block.second.unconverged, 0);
}

TEST(ImplicitMPM, StiffBodyStableAtTenTimesExplicitLimit2D) { stiff_body<2>(10); }
TEST(ImplicitMPM, StiffBodyStableAtTenTimesExplicitLimit3D) { stiff_body<3>(10); }

// The elastic limit is dropped from the time step; CFL and max_dt remain.
TEST(ImplicitMPM, StableDtIgnoresElasticLimit) {
  Scene s = scene(2, slurry::TransferKind::MLS, {1, 1, 0}, 1.0 / 64, 1000, 1e7, 0.3, slurry::Integrator::Implicit);
  s.bodies = {box({0.4, 0.4, 0}, {0.6, 0.6, 0}, 4)};
  s.solver.max_dt = 2e-3;
  using Sim = slurry::MpmSolver<double, 2>;
  EXPECT_DOUBLE_EQ(Sim(s).stable_dt(), 2e-3);
  s.bodies[0].velocity = {4, 0, 0};
  EXPECT_NEAR(Sim(s).stable_dt(), 0.5 / 64 / 4, 1e-12);
  s.solver.integrator = slurry::Integrator::Explicit;
  const double c = std::sqrt((1e7 * 0.3 / (1.3 * 0.4) + 1e7 / 1.3) / 1000);
  EXPECT_NEAR(Sim(s).stable_dt(), 0.5 / 64 / c, 1e-12);
}

// A block dropped on a floor at a large step, for each wall condition: it lands, stays above
// the wall band, and comes to rest; sticky walls hold their nodes still.
TEST(ImplicitMPM, BlockLandsOnFloorWithEachWallCondition) {
  for (auto walls : {slurry::Condition::Sticky, slurry::Condition::Slip, slurry::Condition::Separate}) {
    Scene s = scene(2, slurry::TransferKind::APIC, {1, 1, 0}, 1.0 / 64, 1000, 1e7, 0.3, slurry::Integrator::Implicit);
    s.bodies = {box({0.4, 0.1, 0}, {0.6, 0.2, 0}, 4)};
    s.boundaries.walls = walls;
    if (walls == slurry::Condition::Separate) s.boundaries.friction = 0.3;
    s.solver.max_dt = 2e-3;  // 30x the explicit elastic limit of 6.7e-5 s
    slurry::MpmSolver<double, 2> sim(s);
    const auto c0 = center_of_mass<2>(sim.particles());
    double peak = 0;
    for (int f = 1; f <= 20; ++f) {
      sim.advance_to(f * 0.025);
      peak = std::max(peak, sim.kinetic_energy());
    }
    const auto c = center_of_mass<2>(sim.particles());
    double ymin = 1;
    for (const auto& x : sim.particles().x) ymin = std::min(ymin, x[1]);
    std::printf("[ figure ] landing block, walls %d: KE %.2e of peak, ymin %.4f m, x drift %.1e m, %lld substeps, %lld CG iterations\n",
                int(walls), sim.kinetic_energy() / peak, ymin, c[0] - c0[0], (long long)sim.steps(),
                (long long)sim.cg_stats().iterations);
    EXPECT_LT(sim.kinetic_energy(), 0.02 * peak);
    EXPECT_GT(ymin, 1.0 / 64) << "above the wall band";
    EXPECT_LT(ymin, 4.0 / 64) << "resting on the floor";
    EXPECT_NEAR(c[0], c0[0], 1e-6) << "symmetric: no drift";
    EXPECT_EQ(sim.cg_stats().unconverged, 0);
  }
}

// CG that hits its cap is not silent: it is counted, and when the under-solved state then blows
// up (here: one iteration at 15x the explicit limit of a stiff body) the diagnosis names it.
TEST(ImplicitMPM, UnconvergedSolvesAreRecordedAndNamed) {
  Scene s = scene(2, slurry::TransferKind::MLS, {1, 1, 0}, 1.0 / 64, 1000, 1e7, 0.3, slurry::Integrator::Implicit);
  s.bodies = {box({0.4, 0.1, 0}, {0.6, 0.2, 0}, 4)};
  s.solver.cg_max_iterations = 1;
  slurry::MpmSolver<double, 2> sim(s);
  auto& P = sim.particles();
  for (std::size_t p = 0; p < P.size(); ++p) P.v[p] = Eigen::Vector2d(5 * (P.x[p][1] - 0.15), 0);  // shear
  std::string message;
  try {
    for (int i = 0; i < 50; ++i) sim.step(1e-3);
  } catch (const slurry::SimulationError& e) {
    message = e.what();
  }
  std::printf("[ figure ] CG capped at 1 iteration: %lld of %lld solves unconverged, then: %s\n",
              (long long)sim.cg_stats().unconverged, (long long)sim.cg_stats().solves, message.c_str());
  EXPECT_EQ(sim.cg_stats().unconverged, sim.cg_stats().solves);
  EXPECT_EQ(sim.last_cg_iterations(), 1);
  EXPECT_GT(sim.cg_stats().last_residual, 1e-6);
  EXPECT_NE(message.find("the implicit CG solve missed solver.cg_tolerance in "), std::string::npos) << message;
}

// ------------------------------------------------------------------------------------------
// Scene keys
// ------------------------------------------------------------------------------------------

const char* kScene = R"({
  "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
  "solver": {"dimension": 2, "integrator": "implicit", "cg_tolerance": 1e-5, "cg_max_iterations": 200},
  "materials": [{"name": "jelly", "E": 1e7}],
  "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"}]
})";

TEST(ImplicitScene, KeysAreReadAndValidated) {
  const Scene s = slurry::parse_scene(kScene, "s.json");
  EXPECT_EQ(s.solver.integrator, slurry::Integrator::Implicit);
  EXPECT_DOUBLE_EQ(s.solver.cg_tolerance, 1e-5);
  EXPECT_EQ(s.solver.cg_max_iterations, 200);
  EXPECT_EQ(s.solver.implicit_preconditioner, slurry::ImplicitPreconditioner::IC0);  // the default
  auto message = [](std::string text) {
    try {
      slurry::parse_scene(text, "bad.json");
    } catch (const slurry::SceneError& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  auto replace = [](std::string s, const std::string& from, const std::string& to) {
    return s.replace(s.find(from), from.size(), to);
  };
  const std::string t = kScene;
  EXPECT_EQ(message(replace(t, "\"cg_tolerance\": 1e-5", "\"cg_tolerance\": 0")),
            "bad.json: solver.cg_tolerance: expected a number in (0, 1), got 0");
  EXPECT_EQ(message(replace(t, "\"cg_max_iterations\": 200", "\"cg_max_iterations\": 0")),
            "bad.json: solver.cg_max_iterations: expected an integer >= 1, got 0");
  EXPECT_EQ(message(replace(t, "{\"name\": \"jelly\", \"E\": 1e7}", "{\"name\": \"water\", \"model\": \"fluid\"}")),
            "bad.json: solver.integrator: \"implicit\" is for solids; materials[0] (\"water\") is a \"fluid\", which "
            "runs with \"explicit\" only");
  const std::string with_key = replace(t, "\"cg_max_iterations\": 200", "\"cg_max_iterations\": 200, \"implicit_preconditioner\": \"jacobi\"");
  EXPECT_EQ(slurry::parse_scene(with_key, "s.json").solver.implicit_preconditioner, slurry::ImplicitPreconditioner::Jacobi);
  EXPECT_EQ(slurry::parse_scene(replace(with_key, "\"jacobi\"", "\"block_jacobi\""), "s.json").solver.implicit_preconditioner,
            slurry::ImplicitPreconditioner::BlockJacobi);
  const std::string bad = message(replace(with_key, "\"jacobi\"", "\"multigrid\""));
  EXPECT_NE(bad.find("solver.implicit_preconditioner"), std::string::npos) << bad;
  EXPECT_NE(bad.find("\"ic0\""), std::string::npos) << bad;
}

TEST(ImplicitScene, ExampleSceneLoads) {
  for (const char* name : {"stiff_bar_implicit_2d.json", "stiff_bar_implicit_3d.json"}) {
    const Scene s = slurry::load_scene(std::string(SLURRY_EXAMPLES_DIR) + "/" + name);
    EXPECT_EQ(s.solver.integrator, slurry::Integrator::Implicit) << name;
  }
}

}  // namespace
