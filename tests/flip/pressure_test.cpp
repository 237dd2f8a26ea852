// FLIP pressure projection: Poisson convergence orders (Dirichlet, Neumann, ghost-fluid free
// surface), preconditioner iteration counts, divergence after projection, solids with face
// fractions (hydrostatic rest in a curved container, moving collider), velocity extrapolation,
// thread-count independence, and the subcell free surface (its placement and sliver faces).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "slurry/engine/flip/extrapolate.h"
#include "slurry/engine/flip/level_set.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/pressure.h"
#include "slurry/transfer/parallel.h"

namespace {

using namespace slurry::flip;
constexpr double kPi = 3.14159265358979323846;

template <int Dim>
using Grid = MacGrid<double, Dim>;
template <int Dim>
using Vec = Eigen::Matrix<double, Dim, 1>;
template <int Dim>
using IVec = Eigen::Matrix<int, Dim, 1>;

/// Slope of the least-squares line through (log h, log e).
double fitted_order(const std::vector<double>& h, const std::vector<double>& e) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  const double n = double(h.size());
  for (std::size_t i = 0; i < h.size(); ++i) {
    const double x = std::log(h[i]), y = std::log(e[i]);
    sx += x, sy += y, sxx += x * x, sxy += x * y;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

double report_order(const std::string& name, const std::vector<double>& h, const std::vector<double>& e) {
  const double p = fitted_order(h, e);
  std::printf("[ figure ] %s: order %.3f; (h, max error):", name.c_str(), p);
  for (std::size_t i = 0; i < h.size(); ++i) std::printf(" (%.5g, %.3e)", h[i], e[i]);
  std::printf("\n");
  return p;
}

template <int Dim>
void for_each_cell(const Grid<Dim>& g, const std::function<void(std::int64_t, const IVec<Dim>&)>& fn) {
  for (std::int64_t c = 0; c < g.num_cells(); ++c) fn(c, g.cell_coord(c));
}

ProjectionOptions tight(Preconditioner p = Preconditioner::MIC0, double tol = 1e-11) {
  ProjectionOptions o;
  o.preconditioner = p;
  o.tolerance = tol;
  o.max_iterations = 5000;
  return o;
}

// ---------------------------------------------------------------------------------------------
// Manufactured solutions: A p = -dx^2 lap p = dx^2 f on the assembled system.

/// A grid with its right-hand side and exact solution.
template <int Dim>
struct PoissonSystem {
  Grid<Dim> g;
  std::vector<double> b, exact;
};

/// -lap p = f on [0, 1]^Dim, p = prod sin(pi x_a) = 0 on the box surface, which lies half a cell
/// beyond the outermost fluid centres (ghost fluid theta = 1/2).
template <int Dim>
PoissonSystem<Dim> dirichlet_box_system(int n) {
  PoissonSystem<Dim> sys;
  Grid<Dim>& g = sys.g;
  const double dx = 1.0 / n;
  g.resize(IVec<Dim>::Constant(n + 2), dx, Vec<Dim>::Constant(-dx));
  std::vector<double>& b = sys.b;
  std::vector<double>& exact = sys.exact;
  b.assign(std::size_t(g.num_cells()), 0.0), exact.assign(b.size(), 0.0);
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const Vec<Dim> x = g.cell_center(i);
    double phi = -1e9, p = 1;
    for (int a = 0; a < Dim; ++a) phi = std::max(phi, std::max(-x[a], x[a] - 1)), p *= std::sin(kPi * x[a]);
    g.phi[std::size_t(c)] = phi;
    const bool inside = phi < 0;
    g.label[std::size_t(c)] = inside ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    if (inside) b[std::size_t(c)] = dx * dx * Dim * kPi * kPi * p, exact[std::size_t(c)] = p;
  });
  return sys;
}

/// Max error of dirichlet_box_system solved with `prec`.
template <int Dim>
double dirichlet_box_error(int n, Preconditioner prec = Preconditioner::MIC0, int* iterations = nullptr,
                           double tol = 1e-11) {
  const PoissonSystem<Dim> sys = dirichlet_box_system<Dim>(n);
  const auto& b = sys.b;
  const auto& exact = sys.exact;
  PressureSolver<double, Dim> solver;
  solver.prepare_for(prec);
  solver.assemble(sys.g, true);
  std::vector<double> x;
  const ProjectionReport rep = solver.solve(b, x, tight(prec, tol));
  EXPECT_TRUE(rep.converged) << "residual " << rep.relative_residual;
  if (iterations) *iterations = rep.iterations;
  double err = 0;
  for (std::size_t c = 0; c < x.size(); ++c) err = std::max(err, std::abs(x[c] - exact[c]));
  return err;
}

/// -lap p = f on [0, 1]^Dim with closed walls (dp/dn = 0), p = prod cos(pi x_a); the mean is
/// fixed by the solver (closed component) and removed from the exact solution too.
template <int Dim>
PoissonSystem<Dim> neumann_box_system(int n) {
  PoissonSystem<Dim> sys;
  Grid<Dim>& g = sys.g;
  const double dx = 1.0 / n;
  g.resize(IVec<Dim>::Constant(n), dx, Vec<Dim>::Zero());
  std::vector<double>& b = sys.b;
  std::vector<double>& exact = sys.exact;
  b.assign(std::size_t(g.num_cells()), 0.0), exact.assign(b.size(), 0.0);
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const Vec<Dim> x = g.cell_center(i);
    double p = 1;
    for (int a = 0; a < Dim; ++a) p *= std::cos(kPi * x[a]);
    g.label[std::size_t(c)] = Grid<Dim>::Fluid;
    g.phi[std::size_t(c)] = -1;
    b[std::size_t(c)] = dx * dx * Dim * kPi * kPi * p;
    exact[std::size_t(c)] = p;
  });
  return sys;
}

template <int Dim>
double neumann_box_error(int n) {
  const PoissonSystem<Dim> sys = neumann_box_system<Dim>(n);
  const auto& b = sys.b;
  const auto& exact = sys.exact;
  PressureSolver<double, Dim> solver;
  solver.assemble(sys.g, true);
  EXPECT_EQ(solver.closed_components(), 1);
  std::vector<double> x;
  const ProjectionReport rep = solver.solve(b, x, tight());
  EXPECT_TRUE(rep.converged) << "residual " << rep.relative_residual;
  double mean_x = 0, mean_e = 0;
  for (std::size_t c = 0; c < x.size(); ++c) mean_x += x[c], mean_e += exact[c];
  mean_x /= double(x.size()), mean_e /= double(x.size());
  EXPECT_NEAR(mean_x, 0.0, 1e-12) << "mean fixed to zero";
  double err = 0;
  for (std::size_t c = 0; c < x.size(); ++c) err = std::max(err, std::abs((x[c] - mean_x) - (exact[c] - mean_e)));
  return err;
}

/// -lap p = f inside a ball of radius R (centre off the grid symmetry), p = 0 on its surface:
/// p = (R^2 - r^2)(1 + x), f = 2 Dim (1 + x) + 4 (x - c_x). phi = r - R is exact.
template <int Dim>
PoissonSystem<Dim> ball_system(int n) {
  PoissonSystem<Dim> sys;
  Grid<Dim>& g = sys.g;
  const double dx = 1.0 / n, R = 0.37;
  const Vec<Dim> centre = Vec<Dim>::Constant(0.503);
  g.resize(IVec<Dim>::Constant(n), dx, Vec<Dim>::Zero());
  std::vector<double>& b = sys.b;
  std::vector<double>& exact = sys.exact;
  b.assign(std::size_t(g.num_cells()), 0.0), exact.assign(b.size(), 0.0);
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const Vec<Dim> x = g.cell_center(i);
    const double r = (x - centre).norm();
    g.phi[std::size_t(c)] = r - R;
    g.label[std::size_t(c)] = r < R ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    if (r < R) {
      exact[std::size_t(c)] = (R * R - r * r) * (1 + x[0]);
      b[std::size_t(c)] = dx * dx * (2 * Dim * (1 + x[0]) + 4 * (x[0] - centre[0]));
    }
  });
  return sys;
}

template <int Dim>
double ball_error(int n, bool ghost) {
  const PoissonSystem<Dim> sys = ball_system<Dim>(n);
  const auto& b = sys.b;
  const auto& exact = sys.exact;
  PressureSolver<double, Dim> solver;
  solver.assemble(sys.g, ghost);
  std::vector<double> x;
  const ProjectionReport rep = solver.solve(b, x, tight());
  EXPECT_TRUE(rep.converged);
  double err = 0;
  for (std::size_t c = 0; c < x.size(); ++c) err = std::max(err, std::abs(x[c] - exact[c]));
  return err;
}

TEST(PressurePoisson, DirichletSecondOrder2D) {
  std::vector<double> h, e;
  for (int n : {16, 32, 64, 128}) h.push_back(1.0 / n), e.push_back(dirichlet_box_error<2>(n));
  EXPECT_GT(report_order("Poisson Dirichlet 2D", h, e), 1.8);
}

TEST(PressurePoisson, DirichletSecondOrder3D) {
  std::vector<double> h, e;
  for (int n : {8, 16, 32, 64}) h.push_back(1.0 / n), e.push_back(dirichlet_box_error<3>(n));
  EXPECT_GT(report_order("Poisson Dirichlet 3D", h, e), 1.8);
}

TEST(PressurePoisson, NeumannMeanFixedSecondOrder2D) {
  std::vector<double> h, e;
  for (int n : {16, 32, 64, 128}) h.push_back(1.0 / n), e.push_back(neumann_box_error<2>(n));
  EXPECT_GT(report_order("Poisson Neumann 2D", h, e), 1.8);
}

TEST(PressurePoisson, NeumannMeanFixedSecondOrder3D) {
  std::vector<double> h, e;
  for (int n : {8, 16, 32, 64}) h.push_back(1.0 / n), e.push_back(neumann_box_error<3>(n));
  EXPECT_GT(report_order("Poisson Neumann 3D", h, e), 1.8);
}

TEST(PressurePoisson, GhostFluidCurvedSurface2D) {
  std::vector<double> h, eg, e1;
  for (int n : {32, 64, 128, 256}) {
    h.push_back(1.0 / n);
    eg.push_back(ball_error<2>(n, true));
    e1.push_back(ball_error<2>(n, false));
  }
  EXPECT_GT(report_order("circle free surface, ghost fluid", h, eg), 1.8);
  const double p1 = report_order("circle free surface, p = 0 at air centres", h, e1);
  EXPECT_GT(p1, 0.7);
  EXPECT_LT(p1, 1.3);
}

TEST(PressurePoisson, GhostFluidCurvedSurface3D) {
  std::vector<double> h, eg, e1;
  for (int n : {16, 32, 64}) {
    h.push_back(1.0 / n);
    eg.push_back(ball_error<3>(n, true));
    e1.push_back(ball_error<3>(n, false));
  }
  EXPECT_GT(report_order("sphere free surface, ghost fluid", h, eg), 1.8);
  const double p1 = report_order("sphere free surface, p = 0 at air centres", h, e1);
  EXPECT_GT(p1, 0.7);
  EXPECT_LT(p1, 1.3);
}

// ---------------------------------------------------------------------------------------------
// Preconditioners on one system: all reach the tolerance (checked on the true residual),
// MIC(0) needs fewer iterations than Jacobi-PCG and plain CG.

TEST(PressureSolver, Mic0FewerIterationsThanCG) {
  constexpr int Dim = 3;
  const int n = 40;
  Grid<Dim> g;
  const double dx = 1.0 / n;
  g.resize(IVec<Dim>::Constant(n + 2), dx, Vec<Dim>::Constant(-dx));
  std::vector<double> b(std::size_t(g.num_cells()), 0.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> noise(-1, 1);
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const Vec<Dim> x = g.cell_center(i);
    double phi = -1e9;
    for (int a = 0; a < Dim; ++a) phi = std::max(phi, std::max(-x[a], x[a] - 1));
    g.phi[std::size_t(c)] = phi;
    g.label[std::size_t(c)] = phi < 0 ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    b[std::size_t(c)] = phi < 0 ? noise(rng) : 0.0;
  });
  const double tol = 1e-6;
  int iters[5];
  const Preconditioner kinds[5] = {Preconditioner::None, Preconditioner::Jacobi, Preconditioner::MIC0,
                                   Preconditioner::MIC0, Preconditioner::Multigrid};
  for (int k = 0; k < 5; ++k) {
    PressureSolver<double, Dim> solver;
    ProjectionOptions opt = tight(kinds[k], tol);
    opt.mic_blocks = k == 3 ? 4 : 0;  // the slab-parallel variant
    solver.prepare_for(kinds[k], opt.mic_blocks);
    solver.assemble(g, true);
    std::vector<double> x, ax;
    const ProjectionReport rep = solver.solve(b, x, opt);
    EXPECT_TRUE(rep.converged) << to_string(kinds[k]);
    solver.apply(x, ax);
    double rr = 0, bb = 0;
    for (std::size_t c = 0; c < b.size(); ++c)
      if (solver.is_unknown(std::int64_t(c))) rr += (b[c] - ax[c]) * (b[c] - ax[c]), bb += b[c] * b[c];
    const double true_residual = std::sqrt(rr / bb);
    EXPECT_LE(true_residual, 1.01 * tol) << to_string(kinds[k]);
    iters[k] = rep.iterations;
    std::printf("[ figure ] %d^3 Dirichlet box, random rhs, tol %g: %s%s %d iterations, true residual %.3e\n", n, tol,
                to_string(kinds[k]), k == 3 ? " (4 slabs)" : "", rep.iterations, true_residual);
  }
  EXPECT_LT(iters[2], iters[0]);
  EXPECT_LT(iters[2], iters[1]);
  EXPECT_LT(iters[3], iters[0]);
  EXPECT_LE(iters[2], iters[3]) << "cutting the slab couplings cannot help";
  EXPECT_LT(iters[4], iters[2]) << "multigrid needs fewer iterations than MIC(0)";
}

// ---------------------------------------------------------------------------------------------
// Projection of velocity fields.

/// Exact fraction of [lo, hi] (a segment or square face) inside / outside a ball, by sampling
/// k^(Dim-1) points (the hydrostatic check is exact for any weights, so sampling is enough).
template <int Dim>
double face_fraction(const Grid<Dim>& g, int d, const IVec<Dim>& f, const std::function<bool(const Vec<Dim>&)>& inside) {
  const int k = 8;
  const Vec<Dim> x0 = g.face_position(d, f);
  int in = 0, total = 0;
  const int samples = Dim == 2 ? k : k * k;
  for (int s = 0; s < samples; ++s) {
    Vec<Dim> x = x0;
    int t = s;
    for (int a = 0; a < Dim; ++a) {
      if (a == d) continue;
      x[a] += g.dx * ((t % k + 0.5) / k - 0.5);
      t /= k;
    }
    in += inside(x);
    ++total;
  }
  return double(in) / total;
}

/// Max |div U| over unknown cells, U = w u + (1 - w) u_solid, and its 2-norm; computed here
/// independently of the solver.
template <int Dim>
std::pair<double, double> divergence(const Grid<Dim>& g) {
  double mx = 0, l2 = 0;
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    if (g.label[std::size_t(c)] != Grid<Dim>::Fluid) return;
    double s = 0;
    bool open = false;
    for (int d = 0; d < Dim; ++d)
      for (int side = 0; side < 2; ++side) {
        IVec<Dim> f = i;
        f[d] += side;
        const double w = g.open_weight(d, f);
        open |= w > 0;
        const auto k = std::size_t(g.face(d, f));
        s += (side ? 1 : -1) * (w * g.u[d][k] + (1 - w) * g.u_solid[d][k]);
      }
    if (!open) return;
    s /= g.dx;
    mx = std::max(mx, std::abs(s));
    l2 += s * s;
  });
  return {mx, std::sqrt(l2)};
}

template <int Dim>
void random_velocity(Grid<Dim>& g, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int d = 0; d < Dim; ++d)
    for (auto& v : g.u[d]) v = u(rng);
}

/// Fluid below 0.6 along `surface_axis` (y by default) in a unit box with closed walls, a moving
/// ball obstacle of radius 0.2 cut by the grid (face weights = open fraction outside the ball),
/// random velocities.
template <int Dim>
Grid<Dim> obstacle_scene(int n, const Vec<Dim>& ball_velocity, int surface_axis = 1) {
  Grid<Dim> g;
  g.resize(IVec<Dim>::Constant(n), 1.0 / n, Vec<Dim>::Zero());
  const Vec<Dim> centre = Vec<Dim>::Constant(0.47);
  const auto fluid_side = [&](const Vec<Dim>& x) { return (x - centre).norm() > 0.2; };
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      const IVec<Dim> fi = g.face_coord(d, f);
      g.weight[d][std::size_t(f)] = face_fraction<Dim>(g, d, fi, fluid_side);
      g.u_solid[d][std::size_t(f)] = ball_velocity[d];
    }
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    bool open = false;
    for (int d = 0; d < Dim; ++d)
      for (int side = 0; side < 2; ++side) {
        IVec<Dim> f = i;
        f[d] += side;
        open |= g.weight[d][std::size_t(g.face(d, f))] > 0;
      }
    g.phi[std::size_t(c)] = g.cell_center(i)[surface_axis] - 0.6;
    g.label[std::size_t(c)] = !open ? Grid<Dim>::Solid : g.phi[std::size_t(c)] < 0 ? Grid<Dim>::Fluid : Grid<Dim>::Air;
  });
  random_velocity(g, 11);
  return g;
}

template <int Dim>
void check_projection_divergence(int n) {
  Vec<Dim> v = Vec<Dim>::Zero();
  v[0] = 0.7, v[1] = -0.4;
  Grid<Dim> g = obstacle_scene<Dim>(n, v);
  const auto before = divergence(g);
  const ProjectionOptions opt = tight(Preconditioner::MIC0, 1e-8);
  const ProjectionReport rep = project(g, 0.01, opt);
  const auto after = divergence(g);
  std::printf("[ figure ] %dD %d^%d moving ball obstacle: %d MIC(0) iterations, max |div u| %.3e -> %.3e (1/s), "
              "||div||_2 ratio %.3e (tolerance %g)\n",
              Dim, n, Dim, rep.iterations, before.first, after.first, after.second / before.second, opt.tolerance);
  EXPECT_TRUE(rep.converged);
  // ||D_after|| = (dt / (rho dx)) ||r|| <= tol ||D_before||.
  EXPECT_LE(after.second, opt.tolerance * before.second * 1.01);
  EXPECT_NEAR(rep.max_divergence, after.first, 1e-9 * before.first);
  // Closed faces carry the solid velocity exactly.
  int closed = 0;
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f)
      if (g.open_weight(d, g.face_coord(d, f)) == 0) {
        ++closed;
        EXPECT_EQ(g.u[d][std::size_t(f)], g.u_solid[d][std::size_t(f)]);
      }
  EXPECT_GT(closed, 0);
}

TEST(PressureProjection, DivergenceBelowToleranceWithMovingCutCollider2D) { check_projection_divergence<2>(64); }
TEST(PressureProjection, DivergenceBelowToleranceWithMovingCutCollider3D) { check_projection_divergence<3>(32); }

/// Liquid at rest below y = h in a round container (a disk / ball of radius 0.45; the grid cuts
/// it, face weights = open fraction inside), gravity applied as u_y = -g dt: the projection must
/// return the hydrostatic pressure rho g (h - y) and zero velocity on open fluid faces.
template <int Dim>
void check_hydrostatic(int n) {
  Grid<Dim> g;
  g.resize(IVec<Dim>::Constant(n), 1.0 / n, Vec<Dim>::Zero());
  const Vec<Dim> centre = Vec<Dim>::Constant(0.5);
  const double radius = 0.45, h = 0.55, grav = 9.81, dt = 0.01, rho = 1000;
  const auto inside = [&](const Vec<Dim>& x) { return (x - centre).norm() < radius; };
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      g.weight[d][std::size_t(f)] = face_fraction<Dim>(g, d, g.face_coord(d, f), inside);
      g.u[d][std::size_t(f)] = d == 1 ? -grav * dt : 0.0;
    }
  int cut = 0;
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    bool open = false, partial = false;
    for (int d = 0; d < Dim; ++d)
      for (int side = 0; side < 2; ++side) {
        IVec<Dim> f = i;
        f[d] += side;
        const double w = g.weight[d][std::size_t(g.face(d, f))];
        open |= w > 0;
        partial |= w > 0 && w < 1;
      }
    g.phi[std::size_t(c)] = g.cell_center(i)[1] - h;  // extended into the solid: no free surface there
    g.label[std::size_t(c)] = !open ? Grid<Dim>::Solid : g.phi[std::size_t(c)] < 0 ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    cut += partial && g.label[std::size_t(c)] == Grid<Dim>::Fluid;
  });
  ProjectionOptions opt = tight(Preconditioner::MIC0, 1e-10);
  opt.density = rho;
  const ProjectionReport rep = project(g, dt, opt);
  EXPECT_TRUE(rep.converged);
  double p_err = 0, u_max = 0, depth = 0;
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    if (g.label[std::size_t(c)] != Grid<Dim>::Fluid) return;
    const double exact = rho * grav * (h - g.cell_center(i)[1]);
    depth = std::max(depth, exact);
    p_err = std::max(p_err, std::abs(g.pressure[std::size_t(c)] - exact));
  });
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f)
      if (g.valid[d][std::size_t(f)]) u_max = std::max(u_max, std::abs(g.u[d][std::size_t(f)]));
  std::printf("[ figure ] %dD hydrostatic in a round container (%d cut fluid cells): max |p - rho g (h - y)| / "
              "(rho g depth) = %.3e, max |u| on fluid faces / (g dt) = %.3e, %d iterations\n",
              Dim, cut, p_err / depth, u_max / (grav * dt), rep.iterations);
  EXPECT_GT(cut, 0);
  EXPECT_LT(p_err / depth, 1e-7);
  EXPECT_LT(u_max / (grav * dt), 1e-7);
}

TEST(PressureProjection, HydrostaticInCurvedContainer2D) { check_hydrostatic<2>(64); }
TEST(PressureProjection, HydrostaticInCurvedContainer3D) { check_hydrostatic<3>(32); }

// ---------------------------------------------------------------------------------------------
// Multigrid-preconditioned CG: same systems, same solutions as MIC(0), fewer iterations.

/// ||b - A x|| / ||b|| over the unknowns, recomputed from x (not PCG's recursive residual).
template <int Dim>
double true_residual(PressureSolver<double, Dim>& solver, const std::vector<double>& b, const std::vector<double>& x) {
  std::vector<double> ax;
  solver.apply(x, ax);
  double rr = 0, bb = 0;
  for (std::size_t c = 0; c < b.size(); ++c)
    if (solver.is_unknown(std::int64_t(c))) rr += (b[c] - ax[c]) * (b[c] - ax[c]), bb += b[c] * b[c];
  return std::sqrt(rr / bb);
}

/// Solves sys with MIC(0) and with multigrid to tol: both converge (true residual), and the
/// solutions agree to within what the tolerance allows (checked as max |x_mg - x_mic| <= 1e-6
/// max |x| at tol 1e-10; the condition number of these systems is below 1e4).
template <int Dim>
void check_multigrid_matches_mic0(const char* name, const PoissonSystem<Dim>& sys, bool ghost) {
  const double tol = 1e-10;
  std::vector<double> x[2];
  int iterations[2];
  const Preconditioner kinds[2] = {Preconditioner::MIC0, Preconditioner::Multigrid};
  for (int k = 0; k < 2; ++k) {
    PressureSolver<double, Dim> solver;
    solver.prepare_for(kinds[k]);
    solver.assemble(sys.g, ghost);
    const ProjectionReport rep = solver.solve(sys.b, x[k], tight(kinds[k], tol));
    EXPECT_TRUE(rep.converged) << name << " " << to_string(kinds[k]) << " residual " << rep.relative_residual;
    EXPECT_LE(true_residual(solver, sys.b, x[k]), 1.01 * tol) << name << " " << to_string(kinds[k]);
    iterations[k] = rep.iterations;
  }
  double diff = 0, size = 0;
  for (std::size_t c = 0; c < x[0].size(); ++c)
    diff = std::max(diff, std::abs(x[1][c] - x[0][c])), size = std::max(size, std::abs(x[0][c]));
  std::printf("[ figure ] %s, tol %g: MIC(0) %d iterations, multigrid %d; max |x_mg - x_mic0| / max |x| = %.2e\n",
              name, tol, iterations[0], iterations[1], diff / size);
  EXPECT_LT(diff, 1e-6 * size) << name;
  EXPECT_LT(iterations[1], iterations[0]) << name;
}

TEST(PressureMultigrid, SameSolutionAsMic0) {
  check_multigrid_matches_mic0<3>("3D 32^3 Dirichlet box", dirichlet_box_system<3>(32), true);
  check_multigrid_matches_mic0<3>("3D 32^3 Neumann box (mean fixed)", neumann_box_system<3>(32), true);
  check_multigrid_matches_mic0<3>("3D 48^3 ghost-fluid sphere", ball_system<3>(48), true);
  check_multigrid_matches_mic0<3>("3D 48^3 sphere, p = 0 at air centres", ball_system<3>(48), false);
  check_multigrid_matches_mic0<2>("2D 128^2 ghost-fluid circle", ball_system<2>(128), true);
  check_multigrid_matches_mic0<2>("2D 128^2 Neumann box (mean fixed)", neumann_box_system<2>(128), true);
}

/// The cut moving collider: project() with multigrid leaves the divergence below the tolerance
/// and the same pressure as MIC(0).
template <int Dim>
void check_multigrid_collider(int n) {
  Vec<Dim> v = Vec<Dim>::Zero();
  v[0] = 0.7, v[1] = -0.4;
  Grid<Dim> g[2] = {obstacle_scene<Dim>(n, v), obstacle_scene<Dim>(n, v)};
  const auto before = divergence(g[0]);
  const double tol = 1e-10;
  ProjectionReport rep[2];
  const Preconditioner kinds[2] = {Preconditioner::MIC0, Preconditioner::Multigrid};
  for (int k = 0; k < 2; ++k) rep[k] = project(g[k], 0.01, tight(kinds[k], tol));
  const auto after = divergence(g[1]);
  double diff = 0, size = 0;
  for (std::size_t c = 0; c < g[0].pressure.size(); ++c)
    diff = std::max(diff, std::abs(g[1].pressure[c] - g[0].pressure[c])), size = std::max(size, std::abs(g[0].pressure[c]));
  std::printf("[ figure ] %dD %d^%d moving cut collider, tol %g: MIC(0) %d iterations, multigrid %d; ||div||_2 ratio "
              "%.2e; max |p_mg - p_mic0| / max |p| = %.2e\n",
              Dim, n, Dim, tol, rep[0].iterations, rep[1].iterations, after.second / before.second, diff / size);
  EXPECT_TRUE(rep[1].converged);
  EXPECT_LE(after.second, tol * before.second * 1.01);
  EXPECT_LT(diff, 1e-6 * size);
  EXPECT_LT(rep[1].iterations, rep[0].iterations);
}

TEST(PressureMultigrid, CutColliderProjection) {
  check_multigrid_collider<3>(40);
  check_multigrid_collider<2>(128);
}

/// A tank with closed walls, liquid below 3/4 of the height (flat free surface), a smooth plus
/// random right-hand side: multigrid iterations barely grow from 32^3 to 64^3, MIC(0)'s double.
int tank_iterations(int n, Preconditioner prec) {
  constexpr int Dim = 3;
  Grid<Dim> g;
  g.resize(IVec<Dim>::Constant(n), 1.0 / n, Vec<Dim>::Zero());
  std::vector<double> b(std::size_t(g.num_cells()), 0.0);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> noise(-1, 1);
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const Vec<Dim> x = g.cell_center(i);
    g.phi[std::size_t(c)] = x[1] - 0.75;
    g.label[std::size_t(c)] = x[1] < 0.75 ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    b[std::size_t(c)] = std::sin(5 * x[0]) * std::cos(3 * x[2] + x[1]) + 0.1 * noise(rng);
  });
  PressureSolver<double, Dim> solver;
  solver.prepare_for(prec);
  solver.assemble(g, true);
  std::vector<double> x;
  const ProjectionReport rep = solver.solve(b, x, tight(prec, 1e-6));
  EXPECT_TRUE(rep.converged);
  return rep.iterations;
}

TEST(PressureMultigrid, IterationsNearlyIndependentOfResolution) {
  const int mg32 = tank_iterations(32, Preconditioner::Multigrid), mg64 = tank_iterations(64, Preconditioner::Multigrid);
  const int mic32 = tank_iterations(32, Preconditioner::MIC0), mic64 = tank_iterations(64, Preconditioner::MIC0);
  std::printf("[ figure ] tank (free surface at 3/4 height), tol 1e-6: multigrid %d -> %d iterations, MIC(0) %d -> %d "
              "iterations (32^3 -> 64^3)\n",
              mg32, mg64, mic32, mic64);
  EXPECT_LE(mg64, 1.5 * mg32);
  EXPECT_LT(mg64, mic64);
}

// ---------------------------------------------------------------------------------------------
// Extrapolation.

TEST(PressureExtrapolation, FillsLayersAndReproducesLinearField) {
  constexpr int Dim = 3;
  Grid<Dim> g;
  const int n = 24;
  g.resize(IVec<Dim>::Constant(n), 1.0 / n, Vec<Dim>::Zero());
  const Vec<Dim> normal = Vec<Dim>(0.5, 1.0, 0.3).normalized();
  const auto field = [](int d, const Vec<Dim>& x) { return 0.3 + d - 1.7 * x[0] + 0.9 * x[1] + 2.3 * x[2]; };
  const int layers = 3;
  std::int64_t expected_filled = 0;
  for (int d = 0; d < Dim; ++d) {
    const IVec<Dim> fr = g.face_res(d);
    std::vector<int> dist(std::size_t(g.num_faces(d)), -1);
    std::vector<std::int64_t> queue;
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      const Vec<Dim> x = g.face_position(d, g.face_coord(d, f));
      const bool valid = normal.dot(x - Vec<Dim>::Constant(0.4)) < 0;
      g.valid[d][std::size_t(f)] = valid;
      g.u[d][std::size_t(f)] = valid ? field(d, x) : 1e3;  // garbage where unknown
      if (valid && g.open_weight(d, g.face_coord(d, f)) > 0) dist[std::size_t(f)] = 0, queue.push_back(f);
    }
    // Reference BFS distance over the face grid (open faces only; walls are closed).
    for (std::size_t head = 0; head < queue.size(); ++head) {
      const std::int64_t f = queue[head];
      const IVec<Dim> fi = g.face_coord(d, f);
      for (int a = 0; a < Dim; ++a)
        for (int s = -1; s <= 1; s += 2) {
          IVec<Dim> j = fi;
          j[a] += s;
          if (j[a] < 0 || j[a] >= fr[a] || g.open_weight(d, j) <= 0) continue;
          const std::int64_t k = g.face(d, j);
          if (dist[std::size_t(k)] >= 0) continue;
          dist[std::size_t(k)] = dist[std::size_t(f)] + 1;
          queue.push_back(k);
        }
    }
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      const int k = dist[std::size_t(f)];
      if (k >= 1 && k <= layers && g.open_weight(d, g.face_coord(d, f)) > 0 && !g.valid[d][std::size_t(f)]) ++expected_filled;
    }
  }
  const Grid<Dim> before = g;
  const std::int64_t filled = extrapolate(g, layers, Extrapolation::Linear);
  double err = 0, err_edge = 0;
  std::int64_t valid_after = 0, open_unreached = 0;
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      const IVec<Dim> fi = g.face_coord(d, f);
      if (g.open_weight(d, fi) <= 0) {
        EXPECT_EQ(g.u[d][std::size_t(f)], g.u_solid[d][std::size_t(f)]);
        continue;
      }
      if (g.valid[d][std::size_t(f)]) {
        ++valid_after;
        // Next to the domain edge a face may lack a pair of known faces behind it and take the
        // constant rule; the error of that spreads at most one face per layer. Exactness is
        // asserted at least layers + 2 faces from the edges.
        const double e = std::abs(g.u[d][std::size_t(f)] - field(d, g.face_position(d, fi)));
        const IVec<Dim> fr = g.face_res(d);
        bool interior = true;
        for (int a = 0; a < Dim; ++a) interior &= fi[a] >= layers + 2 && fi[a] < fr[a] - layers - 2;
        (interior ? err : err_edge) = std::max(interior ? err : err_edge, e);
      } else {
        ++open_unreached;
        EXPECT_EQ(g.u[d][std::size_t(f)], 1e3);
      }
    }
  std::int64_t valid_before = 0;
  for (int d = 0; d < Dim; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f)
      valid_before += before.valid[d][std::size_t(f)] && g.open_weight(d, g.face_coord(d, f)) > 0;
  std::printf("[ figure ] extrapolation of a linear field, %d layers: %lld faces filled (BFS reference %lld), "
              "max error %.3e (within %d faces of the domain edge: %.3e), %lld open faces left beyond\n",
              layers, (long long)filled, (long long)expected_filled, err, layers + 2, err_edge,
              (long long)open_unreached);
  EXPECT_EQ(filled, expected_filled);
  EXPECT_EQ(valid_after, valid_before + filled);
  EXPECT_GT(open_unreached, 0) << "the test must leave faces beyond the layers";
  EXPECT_LT(err, 1e-11);
}

TEST(PressureExtrapolation, ConstantRuleAveragesNeighbours) {
  constexpr int Dim = 2;
  Grid<Dim> g;
  g.resize(IVec<Dim>::Constant(8), 1.0, Vec<Dim>::Zero());
  // One valid x-face in the middle; after one layer its 4 neighbours copy it, after two the
  // 8 faces at distance 2 do too; nothing else changes.
  const IVec<Dim> mid(4, 4);
  const std::int64_t m = g.face(0, mid);
  g.valid[0][std::size_t(m)] = 1;
  g.u[0][std::size_t(m)] = 2.5;
  const std::int64_t filled = extrapolate(g, 2, Extrapolation::Constant);
  int count = 0;
  for (std::int64_t f = 0; f < g.num_faces(0); ++f) {
    const IVec<Dim> fi = g.face_coord(0, f);
    const int dist = std::abs(fi[0] - mid[0]) + std::abs(fi[1] - mid[1]);
    if (dist <= 2 && g.open_weight(0, fi) > 0) {
      EXPECT_EQ(g.valid[0][std::size_t(f)], 1);
      EXPECT_EQ(g.u[0][std::size_t(f)], 2.5);
      ++count;
    } else if (g.open_weight(0, fi) > 0) {
      EXPECT_EQ(g.valid[0][std::size_t(f)], 0);
    }
  }
  EXPECT_EQ(filled + 1, count);
  EXPECT_EQ(count, 13);  // 1 + 4 + 8 faces within Manhattan distance 2
}

// ---------------------------------------------------------------------------------------------
// Thread-count independence: the whole projection plus extrapolation, bitwise.

template <int Dim>
void check_threads(Preconditioner prec, int n, int mic_blocks = 0, int surface_axis = 1) {
  Vec<Dim> v = Vec<Dim>::Zero();
  v[0] = 0.3;
  const Grid<Dim> start = obstacle_scene<Dim>(n, v, surface_axis);
  Grid<Dim> g1 = start, g2 = start;
  ProjectionOptions opt = tight(prec, 1e-6);
  opt.mic_blocks = mic_blocks;
  ProjectionReport r1, r2;
  {
    slurry::parallel::ThreadLimit limit(1);
    r1 = project(g1, 0.01, opt);
    extrapolate(g1, 3);
  }
  {
    slurry::parallel::ThreadLimit limit(2);
    r2 = project(g2, 0.01, opt);
    extrapolate(g2, 3);
  }
  std::printf("[ figure ] %dD %s (mic_blocks %d), threads 1 vs 2: %d vs %d iterations, residual %.17g vs %.17g\n",
              Dim, to_string(prec), mic_blocks, r1.iterations, r2.iterations, r1.relative_residual,
              r2.relative_residual);
  EXPECT_EQ(r1.iterations, r2.iterations);
  EXPECT_EQ(std::memcmp(&r1.relative_residual, &r2.relative_residual, sizeof(double)), 0);
  EXPECT_EQ(std::memcmp(g1.pressure.data(), g2.pressure.data(), g1.pressure.size() * sizeof(double)), 0);
  for (int d = 0; d < Dim; ++d)
    EXPECT_EQ(std::memcmp(g1.u[d].data(), g2.u[d].data(), g1.u[d].size() * sizeof(double)), 0);
}

TEST(PressureThreads, BitwiseIndependentOfThreadCount) {
  // Small grids: every PCG iteration here is tens of parallel regions, slow on a busy machine.
  check_threads<3>(Preconditioner::MIC0, 20);
  check_threads<3>(Preconditioner::Jacobi, 16);
  check_threads<3>(Preconditioner::None, 16);
  check_threads<3>(Preconditioner::MIC0, 20, 4);
  // Liquid in every row along axis 1, up to both walls: the packed rows' neighbours along it
  // must stop at the walls, or the wavefront's sweeps read rows another tile is writing (the
  // ThreadSanitizer build, preset tsan, reports that race).
  check_threads<3>(Preconditioner::MIC0, 20, 0, 2);
  check_threads<2>(Preconditioner::MIC0, 48);
  // Level 0 runs in parallel from 32768 cells on (MultigridPreconditioner::kParallelCells).
  check_threads<3>(Preconditioner::Multigrid, 40);
  check_threads<2>(Preconditioner::Multigrid, 192);
}

TEST(PressureOptions, ValidateNamesTheField) {
  ProjectionOptions o;
  o.tolerance = 0;
  try {
    o.validate();
    FAIL() << "expected SceneError";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("pressure.tolerance"), std::string::npos);
  }
  EXPECT_EQ(parse_preconditioner("mic0"), Preconditioner::MIC0);
  EXPECT_EQ(parse_preconditioner("multigrid"), Preconditioner::Multigrid);
  for (Preconditioner p : {Preconditioner::None, Preconditioner::Jacobi, Preconditioner::MIC0, Preconditioner::Multigrid})
    EXPECT_EQ(parse_preconditioner(to_string(p)), p);
  EXPECT_THROW(parse_preconditioner("ilu"), slurry::SceneError);
  try {
    parse_preconditioner("amg");
    FAIL() << "expected SceneError";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("\"multigrid\""), std::string::npos) << "lists the allowed values";
  }
  const auto expect_rejected = [](ProjectionOptions o, const char* key) {
    try {
      o.validate();
      ADD_FAILURE() << key << ": expected SceneError";
    } catch (const slurry::SceneError& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("pressure.") + key), std::string::npos) << e.what();
    }
  };
  ProjectionOptions m;
  m.multigrid_smoothing = 0;
  expect_rejected(m, "multigrid_smoothing");
  m = ProjectionOptions();
  m.multigrid_boundary_smoothing = -1;
  expect_rejected(m, "multigrid_boundary_smoothing");
  m = ProjectionOptions();
  m.multigrid_smoothing = 3, m.multigrid_boundary_smoothing = 0;
  EXPECT_NO_THROW(m.validate());
}

// ---------------------------------------------------------------------------------------------
// The subcell free surface (solver.free_surface): placed inside the liquid's surface cells
// (level_set.h), and the nearly empty faces that gives left unprojected where liquid behind them
// holds the cell.

/// A flat liquid surface at height h (in cells) on an 8^Dim grid of unit cells: rows whose
/// centre is below `fluid_top` are Fluid (phi = -1/2, as label_cells gives them), the others
/// Air with phi = max(y - h, 0.01), the distance to the surface as label_cells gives it.
template <int Dim>
Grid<Dim> flat_surface(double h, double fluid_top) {
  Grid<Dim> g;
  g.resize(IVec<Dim>::Constant(8), 1.0, Vec<Dim>::Zero());
  for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
    const double y = g.cell_center(i)[1];
    const bool fluid = y < fluid_top;
    g.label[std::size_t(c)] = fluid ? Grid<Dim>::Fluid : Grid<Dim>::Air;
    g.phi[std::size_t(c)] = fluid ? -0.5 : std::max(y - h, 0.01);
  });
  return g;
}

template <int Dim>
void check_surface_placement() {
  // h: the surface above the top fluid row's centre (3.5), at it, and below it (its particles
  // all in the row's lower half: the centre is outside the liquid, and phi keeps the label's sign).
  for (const double h : {4.4, 3.8, 3.5, 3.3}) {
    Grid<Dim> g = flat_surface<Dim>(h, 4.0);
    place_surface_in_fluid_cells(g);
    double worst_top = 0, worst_inner = 0;
    for_each_cell<Dim>(g, [&](std::int64_t c, const IVec<Dim>& i) {
      const double phi = g.phi[std::size_t(c)];
      if (i[1] == 3) worst_top = std::max(worst_top, std::abs(phi - std::min(3.5 - h, -0.01)));
      if (i[1] < 3) worst_inner = std::max(worst_inner, std::abs(phi + 0.5));
    });
    std::printf("[ figure ] %dD flat surface at %.1f cells: surface cells' phi off by %.2g, inner cells' by %.2g\n", Dim, h,
                worst_top, worst_inner);
    EXPECT_LT(worst_top, 1e-12) << "the surface cells' phi is the distance to the surface, kept <= -0.01";
    EXPECT_EQ(worst_inner, 0.0) << "cells without an air neighbour keep -1/2";
  }
}

TEST(SubcellSurface, PlacedInsideTheSurfaceCellsFromTheAirBeside2D) { check_surface_placement<2>(); }
TEST(SubcellSurface, PlacedInsideTheSurfaceCellsFromTheAirBeside3D) { check_surface_placement<3>(); }

/// Projects the flat surface's grid (surface at h, fluid up to row fluid_rows - 1) with the
/// surface placed inside the cells (set_subcell_surface) or not, with the surface pressure 1
/// everywhere or none, and counts the faces from the top fluid row to air that the projection
/// updated (valid) and those it left; `reported` and `actual` receive the report's max |div u|
/// and the largest over every fluid cell (divergence()).
template <int Dim>
std::pair<int, int> projected_surface_faces(double h, int fluid_rows, bool subcell, bool surface_pressure,
                                            double* reported = nullptr, double* actual = nullptr) {
  Grid<Dim> g = flat_surface<Dim>(h, double(fluid_rows));
  place_surface_in_fluid_cells(g);
  random_velocity(g, 5);
  const std::vector<double> sigma_kappa(std::size_t(g.num_cells()), 1.0);
  PressureSolver<double, Dim> solver;
  solver.set_subcell_surface(subcell);
  solver.set_surface_pressure(surface_pressure ? sigma_kappa.data() : nullptr);
  ProjectionOptions opt = tight();
  opt.density = 1;
  const ProjectionReport rep = solver.project(g, 0.01, opt);
  if (reported) *reported = rep.max_divergence;
  if (actual) *actual = divergence(g).first;
  int valid = 0, left = 0;
  for (std::int64_t f = 0; f < g.num_faces(1); ++f)
    if (g.face_coord(1, f)[1] == fluid_rows && g.open_weight(1, g.face_coord(1, f)) > 0)
      (g.valid[1][std::size_t(f)] ? valid : left) += 1;
  return {valid, left};
}

template <int Dim>
void check_sliver_faces() {
  const int faces = Dim == 2 ? 8 : 64;
  // theta = 0.1 / (0.1 + 0.9) on the top faces of a pool 4 cells deep: left unprojected with the
  // subcell surface, with or without a surface pressure; projected without the subcell surface.
  EXPECT_EQ(projected_surface_faces<Dim>(3.6, 4, true, true), std::make_pair(0, faces));
  EXPECT_EQ(projected_surface_faces<Dim>(3.6, 4, true, false), std::make_pair(0, faces));
  // The report's max |div u| leaves out the cells whose faces were left: the rest is projected.
  double reported = 0, actual = 0, projected = 0;
  projected_surface_faces<Dim>(3.6, 4, true, false, &reported, &actual);
  projected_surface_faces<Dim>(3.6, 4, false, false, nullptr, &projected);
  std::printf("[ figure ] %dD pool under sliver faces: max |div u| reported %.3g 1/s, over every fluid cell %.3g "
              "(every face projected: %.3g)\n", Dim, reported, actual, projected);
  EXPECT_LT(reported, 1e-3 * actual);
  EXPECT_LT(reported, 1e-2 * projected + 1e-9);
  EXPECT_EQ(projected_surface_faces<Dim>(3.6, 4, false, true), std::make_pair(faces, 0));
  EXPECT_EQ(projected_surface_faces<Dim>(3.6, 4, false, false), std::make_pair(faces, 0));
  // theta = 0.3: projected.
  EXPECT_EQ(projected_surface_faces<Dim>(3.8, 4, true, true), std::make_pair(faces, 0));
  // A film one cell thick (every fluid cell beside air): projected, however thin.
  EXPECT_EQ(projected_surface_faces<Dim>(0.6, 1, true, true), std::make_pair(faces, 0));
}

TEST(SubcellSurface, NearlyEmptyFacesAreLeftUnprojectedOnlyWithLiquidBehindThem2D) { check_sliver_faces<2>(); }
TEST(SubcellSurface, NearlyEmptyFacesAreLeftUnprojectedOnlyWithLiquidBehindThem3D) { check_sliver_faces<3>(); }

}  // namespace
