// Tests of slurry/engine/numerics/finite_differences.h: observed orders by refinement, the
// assembled Poisson problems with manufactured solutions, and the 1D 8-node matrices entry by
// entry.
#include "slurry/engine/numerics/finite_differences.h"

#include <gtest/gtest.h>

#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>
#include <cmath>
#include <functional>
#include <vector>

#include "numerics/convergence.h"
#include "slurry/engine/numerics/pcg.h"

namespace sn = slurry::numerics;
using Eigen::VectorXd;
using slurry::numerics::test::report_order;

namespace {

const double kPi = 3.14159265358979323846;

// Orders are fitted over refinements that are already in the asymptotic range (errors well above
// round-off, h small enough that the next term in the error expansion is < 10% of the leading
// one), so a deviation beyond 0.2 from the theoretical order means a wrong stencil.
constexpr double kOrderTolerance = 0.2;

std::vector<double> halvings(double h0, int count) {
  std::vector<double> h;
  for (int k = 0; k < count; ++k) h.push_back(h0 / std::pow(2.0, k));
  return h;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Difference quotients of a callable
// ---------------------------------------------------------------------------------------------

TEST(FiniteDifferences, CallableOrders) {
  const auto f = [](double x) { return std::sin(x) + 0.5 * std::exp(x); };
  const double x = 0.7;
  const double d1 = std::cos(x) + 0.5 * std::exp(x);
  const double d2 = -std::sin(x) + 0.5 * std::exp(x);
  const std::vector<double> hs = halvings(0.1, 4);
  std::vector<double> ef, eb, ec, e2;
  for (double h : hs) {
    ef.push_back(std::abs(sn::forward_difference(f, x, h) - d1));
    eb.push_back(std::abs(sn::backward_difference(f, x, h) - d1));
    ec.push_back(std::abs(sn::central_difference(f, x, h) - d1));
    e2.push_back(std::abs(sn::second_difference(f, x, h) - d2));
  }
  EXPECT_NEAR(report_order("callable_forward", hs, ef), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("callable_backward", hs, eb), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("callable_central", hs, ec), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("callable_second", hs, e2), 2.0, kOrderTolerance);
}

TEST(FiniteDifferences, ArrayOrdersIncludingEnds) {
  // f on [0, 1]; the error is the max over all nodes, ends (one-sided stencils) included.
  const auto f = [](double x) { return std::sin(2.0 * x) + x * x * x; };
  const auto d1 = [](double x) { return 2.0 * std::cos(2.0 * x) + 3.0 * x * x; };
  const auto d2 = [](double x) { return -4.0 * std::sin(2.0 * x) + 6.0 * x; };
  std::vector<double> hs, ef, eb, ec, e2;
  for (int cells : {10, 20, 40, 80}) {
    const double h = 1.0 / cells;
    VectorXd v(cells + 1), exact1(cells + 1), exact2(cells + 1);
    for (int i = 0; i <= cells; ++i) {
      v[i] = f(i * h);
      exact1[i] = d1(i * h);
      exact2[i] = d2(i * h);
    }
    hs.push_back(h);
    ef.push_back((sn::forward_difference(v, h) - exact1).lpNorm<Eigen::Infinity>());
    eb.push_back((sn::backward_difference(v, h) - exact1).lpNorm<Eigen::Infinity>());
    ec.push_back((sn::central_difference(v, h) - exact1).lpNorm<Eigen::Infinity>());
    e2.push_back((sn::second_difference(v, h) - exact2).lpNorm<Eigen::Infinity>());
  }
  EXPECT_NEAR(report_order("array_forward", hs, ef), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("array_backward", hs, eb), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("array_central", hs, ec), 2.0, kOrderTolerance);
  EXPECT_NEAR(report_order("array_second", hs, e2), 2.0, kOrderTolerance);
}

TEST(FiniteDifferences, UpwindPicksTheUpwindSideAndIsFirstOrder) {
  const auto f = [](double x) { return std::cos(3.0 * x); };
  const auto fx = [](double x) { return -3.0 * std::sin(3.0 * x); };
  std::vector<double> hs, e_pos, e_neg, e_var;
  for (int cells : {20, 40, 80, 160}) {
    const double h = 1.0 / cells;
    const int n = cells + 1;
    VectorXd v(n), u_var(n), exact_pos(n), exact_neg(n), exact_var(n);
    for (int i = 0; i < n; ++i) {
      const double x = i * h;
      v[i] = f(x);
      u_var[i] = x - 0.5;  // changes sign mid-domain
      exact_pos[i] = 1.5 * fx(x);
      exact_neg[i] = -1.5 * fx(x);
      exact_var[i] = u_var[i] * fx(x);
    }
    const VectorXd pos = sn::upwind_advection(v, 1.5, h);
    const VectorXd neg = sn::upwind_advection(v, -1.5, h);
    // u > 0 takes the backward difference, u < 0 the forward one (same stencils as above,
    // so the results agree to the last bit up to the multiplication by u).
    const VectorXd back = sn::backward_difference(v, h), fwd = sn::forward_difference(v, h);
    for (int i = 1; i < n - 1; ++i) {
      EXPECT_DOUBLE_EQ(pos[i], 1.5 * back[i]);
      EXPECT_DOUBLE_EQ(neg[i], -1.5 * fwd[i]);
    }
    hs.push_back(h);
    e_pos.push_back((pos - exact_pos).lpNorm<Eigen::Infinity>());
    e_neg.push_back((neg - exact_neg).lpNorm<Eigen::Infinity>());
    e_var.push_back((sn::upwind_advection(v, u_var, h) - exact_var).lpNorm<Eigen::Infinity>());
  }
  EXPECT_NEAR(report_order("upwind_u_positive", hs, e_pos), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("upwind_u_negative", hs, e_neg), 1.0, kOrderTolerance);
  EXPECT_NEAR(report_order("upwind_u_varying", hs, e_var), 1.0, kOrderTolerance);
}

// ---------------------------------------------------------------------------------------------
// Grid Laplacian
// ---------------------------------------------------------------------------------------------

TEST(FiniteDifferences, Laplacian2DAnd3DSecondOrder) {
  // 2D: u = exp(x) sin(2y) + x^2 y, Lap u = -3 exp(x) sin(2y) + 2y.
  std::vector<double> hs2, e2;
  for (int cells : {8, 16, 32, 64}) {
    const double h = 1.0 / cells;
    const Eigen::Vector2i nodes(cells + 1, cells + 1);
    VectorXd u(sn::grid_size<2>(nodes)), exact(u.size());
    for (Eigen::Index p = 0; p < u.size(); ++p) {
      const Eigen::Vector2d x = h * sn::grid_coords<2>(p, nodes).cast<double>();
      u[p] = std::exp(x.x()) * std::sin(2 * x.y()) + x.x() * x.x() * x.y();
      exact[p] = -3.0 * std::exp(x.x()) * std::sin(2 * x.y()) + 2.0 * x.y();
    }
    const VectorXd lap = sn::laplacian<double, 2>(u, nodes, h);
    double err = 0;
    for (Eigen::Index p = 0; p < u.size(); ++p) {
      const Eigen::Vector2i ij = sn::grid_coords<2>(p, nodes);
      const bool interior = ij.minCoeff() > 0 && ij.maxCoeff() < cells;
      if (interior)
        err = std::max(err, std::abs(lap[p] - exact[p]));
      else
        EXPECT_EQ(lap[p], 0.0);
    }
    hs2.push_back(h);
    e2.push_back(err);
  }
  EXPECT_NEAR(report_order("laplacian_2d", hs2, e2), 2.0, kOrderTolerance);

  // 3D: u = sin(x + 2y) cos(z), Lap u = -6 u.
  std::vector<double> hs3, e3;
  for (int cells : {8, 16, 32}) {
    const double h = 1.0 / cells;
    const Eigen::Vector3i nodes(cells + 1, cells + 1, cells + 1);
    VectorXd u(sn::grid_size<3>(nodes));
    for (Eigen::Index p = 0; p < u.size(); ++p) {
      const Eigen::Vector3d x = h * sn::grid_coords<3>(p, nodes).cast<double>();
      u[p] = std::sin(x.x() + 2 * x.y()) * std::cos(x.z());
    }
    const VectorXd lap = sn::laplacian<double, 3>(u, nodes, h);
    double err = 0;
    for (Eigen::Index p = 0; p < u.size(); ++p) {
      const Eigen::Vector3i ijk = sn::grid_coords<3>(p, nodes);
      if (ijk.minCoeff() > 0 && ijk.maxCoeff() < cells)
        err = std::max(err, std::abs(lap[p] + 6.0 * u[p]));
    }
    hs3.push_back(h);
    e3.push_back(err);
  }
  EXPECT_NEAR(report_order("laplacian_3d", hs3, e3), 2.0, kOrderTolerance);
}

// ---------------------------------------------------------------------------------------------
// The 1D matrices on 8 nodes, entry by entry
// ---------------------------------------------------------------------------------------------

namespace {

void expect_matrix_equal(const Eigen::SparseMatrix<double>& actual,
                         const Eigen::MatrixXd& expected) {
  ASSERT_EQ(actual.rows(), expected.rows());
  ASSERT_EQ(actual.cols(), expected.cols());
  const Eigen::MatrixXd dense = Eigen::MatrixXd(actual);
  for (Eigen::Index i = 0; i < expected.rows(); ++i)
    for (Eigen::Index j = 0; j < expected.cols(); ++j)
      // Entries are k / h^2 = 49 k with small integers k, computed as k * (1 / h^2): <= 1 ulp.
      EXPECT_NEAR(dense(i, j), expected(i, j), 1e-12) << "entry (" << i << ", " << j << ")";
}

}  // namespace

TEST(PoissonMatrix1D, EightNodesDirichletBothEnds) {
  // Nodes 0..7 on [0, 1], h = 1/7. Dirichlet nodes 0 and 7 are eliminated: 6 unknowns.
  const double h = 1.0 / 7.0, s = 1.0 / (h * h);
  Eigen::MatrixXd expected(6, 6);
  // clang-format off
  expected << 2, -1, 0, 0, 0, 0,
             -1, 2, -1, 0, 0, 0,
              0, -1, 2, -1, 0, 0,
              0, 0, -1, 2, -1, 0,
              0, 0, 0, -1, 2, -1,
              0, 0, 0, 0, -1, 2;
  // clang-format on
  expected *= s;
  expect_matrix_equal(
      sn::poisson_matrix_1d<double>(8, h, sn::Boundary::kDirichlet, sn::Boundary::kDirichlet),
      expected);
}

TEST(PoissonMatrix1D, EightNodesNeumannLeftDirichletRight) {
  const double h = 1.0 / 7.0, s = 1.0 / (h * h);
  // Unknowns: nodes 0..6. Symmetrized ghost-node row for node 0: [1, -1] / h^2.
  Eigen::MatrixXd sym(7, 7);
  // clang-format off
  sym << 1, -1, 0, 0, 0, 0, 0,
        -1, 2, -1, 0, 0, 0, 0,
         0, -1, 2, -1, 0, 0, 0,
         0, 0, -1, 2, -1, 0, 0,
         0, 0, 0, -1, 2, -1, 0,
         0, 0, 0, 0, -1, 2, -1,
         0, 0, 0, 0, 0, -1, 2;
  // clang-format on
  sym *= s;
  expect_matrix_equal(
      sn::poisson_matrix_1d<double>(8, h, sn::Boundary::kNeumann, sn::Boundary::kDirichlet), sym);

  // Plain ghost-node row: [2, -2] / h^2 (not symmetric).
  Eigen::MatrixXd ghost(7, 7);
  // clang-format off
  ghost << 2, -2, 0, 0, 0, 0, 0,
          -1, 2, -1, 0, 0, 0, 0,
           0, -1, 2, -1, 0, 0, 0,
           0, 0, -1, 2, -1, 0, 0,
           0, 0, 0, -1, 2, -1, 0,
           0, 0, 0, 0, -1, 2, -1,
           0, 0, 0, 0, 0, -1, 2;
  // clang-format on
  ghost *= s;
  expect_matrix_equal(
      sn::poisson_matrix_1d<double>(8, h, sn::Boundary::kNeumann, sn::Boundary::kDirichlet,
                                    sn::NeumannRows::kGhostNode),
      ghost);

  // The mirror image: Dirichlet left, Neumann right, symmetrized: last row [-1, 1] / h^2.
  Eigen::MatrixXd mirrored = sym.reverse();
  expect_matrix_equal(
      sn::poisson_matrix_1d<double>(8, h, sn::Boundary::kDirichlet, sn::Boundary::kNeumann),
      mirrored);

  // SPD: all eigenvalues of the symmetrized matrix are positive.
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(sym);
  EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
}

TEST(PoissonMatrix1D, BoundaryRightHandSides) {
  // f = 1, g = 3 on the Neumann end (x = 0) and u = 5 on the Dirichlet end (x = 1), h = 1/7.
  const double h = 1.0 / 7.0;
  sn::PoissonGrid<double, 1> grid;
  grid.nodes[0] = 8;
  grid.spacing = h;
  grid.faces = {sn::Boundary::kNeumann, sn::Boundary::kDirichlet};
  const auto f = [](const Eigen::Matrix<double, 1, 1>&) { return 1.0; };
  const auto g = [](const Eigen::Matrix<double, 1, 1>&, int face) { return face == 0 ? 3.0 : 5.0; };
  const auto sys = sn::assemble_poisson(grid, f, g);
  ASSERT_EQ(sys.unknowns(), 7);
  EXPECT_NEAR(sys.rhs[0], 0.5 * 1.0 + 3.0 / h, 1e-12);  // f / 2 + g / h (symmetrized)
  for (int i = 1; i < 6; ++i) EXPECT_NEAR(sys.rhs[i], 1.0, 1e-12);
  EXPECT_NEAR(sys.rhs[6], 1.0 + 5.0 / (h * h), 1e-10);  // f + g_D / h^2 (eliminated neighbour)
  EXPECT_FALSE(sys.singular);
  EXPECT_EQ(sys.to_grid(VectorXd::Zero(7))[7], 5.0);

  grid.neumann_rows = sn::NeumannRows::kGhostNode;
  EXPECT_NEAR(sn::assemble_poisson(grid, f, g).rhs[0], 1.0 + 2.0 * 3.0 / h, 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Manufactured solutions
// ---------------------------------------------------------------------------------------------

namespace {

template <int Dim>
using Vec = Eigen::Matrix<double, Dim, 1>;

// Max-norm error of the discrete solution on the grid of `cells` cells per axis on [0, 1]^Dim.
// With fix_mean, both the discrete and the exact solution have their nodal mean removed.
template <int Dim>
double poisson_error(int cells, const std::array<sn::Boundary, 2 * Dim>& faces,
                     sn::NeumannRows rows, const std::function<double(const Vec<Dim>&)>& u,
                     const std::function<Vec<Dim>(const Vec<Dim>&)>& grad_u,
                     const std::function<double(const Vec<Dim>&)>& minus_lap_u) {
  sn::PoissonGrid<double, Dim> grid;
  grid.nodes = Eigen::Matrix<int, Dim, 1>::Constant(cells + 1);
  grid.spacing = 1.0 / cells;
  grid.faces = faces;
  grid.neumann_rows = rows;
  const auto g = [&](const Vec<Dim>& x, int face) {
    if (faces[static_cast<size_t>(face)] == sn::Boundary::kDirichlet) return u(x);
    const double sign = face % 2 == 0 ? -1.0 : 1.0;  // outward normal along axis face / 2
    return sign * grad_u(x)[face / 2];
  };
  auto sys = sn::assemble_poisson(grid, minus_lap_u, g);
  VectorXd sol;
  if (sys.singular) {
    sys.make_rhs_compatible();
    sn::PcgOptions<double> opt;
    opt.tolerance = 1e-13;
    opt.max_iterations = 20000;
    const auto res =
        sn::pcg(sys.matrix, sys.rhs, sol, sn::JacobiPreconditioner<double>(sys.matrix), opt);
    EXPECT_TRUE(res.converged) << "relative residual " << res.relative_residual;
  } else if (rows == sn::NeumannRows::kSymmetrized && Dim == 3) {
    // Sparse LDLT fills in badly in 3D; IC(0)-PCG to a residual far below the O(h^2) error.
    sn::PcgOptions<double> opt;
    opt.tolerance = 1e-12;
    const auto res =
        sn::pcg(sys.matrix, sys.rhs, sol, sn::IncompleteCholesky0<double>(sys.matrix), opt);
    EXPECT_TRUE(res.converged) << "relative residual " << res.relative_residual;
  } else if (rows == sn::NeumannRows::kSymmetrized) {
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(sys.matrix);
    EXPECT_EQ(ldlt.info(), Eigen::Success);  // SPD
    sol = ldlt.solve(sys.rhs);
  } else {
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu(sys.matrix);
    sol = lu.solve(sys.rhs);
  }
  VectorXd full = sys.to_grid(sol);
  VectorXd exact(full.size());
  for (Eigen::Index p = 0; p < full.size(); ++p)
    exact[p] = u(grid.position(sn::grid_coords<Dim>(p, grid.nodes)));
  if (sys.singular) {
    full.array() -= full.mean();
    exact.array() -= exact.mean();
  }
  return (full - exact).template lpNorm<Eigen::Infinity>();
}

template <int Dim>
double poisson_order(const std::string& name, const std::vector<int>& cells,
                     const std::array<sn::Boundary, 2 * Dim>& faces, sn::NeumannRows rows,
                     const std::function<double(const Vec<Dim>&)>& u,
                     const std::function<Vec<Dim>(const Vec<Dim>&)>& grad_u,
                     const std::function<double(const Vec<Dim>&)>& minus_lap_u) {
  std::vector<double> hs, errs;
  for (int c : cells) {
    hs.push_back(1.0 / c);
    errs.push_back(poisson_error<Dim>(c, faces, rows, u, grad_u, minus_lap_u));
  }
  return report_order(name, hs, errs);
}

}  // namespace

TEST(PoissonConvergence, OneDimensional) {
  using V = Vec<1>;
  // u = sin(3x) + x^2: not symmetric about any point, nonzero slopes at both ends.
  const auto u = [](const V& x) { return std::sin(3 * x[0]) + x[0] * x[0]; };
  const auto du = [](const V& x) { return V(3 * std::cos(3 * x[0]) + 2 * x[0]); };
  const auto f = [](const V& x) { return 9 * std::sin(3 * x[0]) - 2.0; };
  const std::vector<int> cells = {8, 16, 32, 64};
  using B = sn::Boundary;
  const auto sym = sn::NeumannRows::kSymmetrized;
  EXPECT_NEAR(poisson_order<1>("poisson_1d_dirichlet", cells, {B::kDirichlet, B::kDirichlet}, sym,
                               u, du, f),
              2.0, kOrderTolerance);
  EXPECT_NEAR(poisson_order<1>("poisson_1d_neumann_dirichlet", cells, {B::kNeumann, B::kDirichlet},
                               sym, u, du, f),
              2.0, kOrderTolerance);
  EXPECT_NEAR(poisson_order<1>("poisson_1d_neumann_dirichlet_ghost", cells,
                               {B::kNeumann, B::kDirichlet}, sn::NeumannRows::kGhostNode, u, du, f),
              2.0, kOrderTolerance);
  EXPECT_NEAR(poisson_order<1>("poisson_1d_pure_neumann_mean_fixed", cells,
                               {B::kNeumann, B::kNeumann}, sym, u, du, f),
              2.0, kOrderTolerance);
}

TEST(PoissonConvergence, TwoDimensional) {
  using V = Vec<2>;
  // u = cos(pi x) cos(pi y) + x^2 / 2 - y^3 / 4 + x y: every face has nonzero, varying flux.
  const auto u = [](const V& x) {
    return std::cos(kPi * x[0]) * std::cos(kPi * x[1]) + 0.5 * x[0] * x[0] -
           0.25 * x[1] * x[1] * x[1] + x[0] * x[1];
  };
  const auto du = [](const V& x) {
    return V(-kPi * std::sin(kPi * x[0]) * std::cos(kPi * x[1]) + x[0] + x[1],
             -kPi * std::cos(kPi * x[0]) * std::sin(kPi * x[1]) - 0.75 * x[1] * x[1] + x[0]);
  };
  const auto f = [](const V& x) {
    return 2 * kPi * kPi * std::cos(kPi * x[0]) * std::cos(kPi * x[1]) - 1.0 + 1.5 * x[1];
  };
  const std::vector<int> cells = {8, 16, 32, 64};
  using B = sn::Boundary;
  const auto sym = sn::NeumannRows::kSymmetrized;
  EXPECT_NEAR(
      poisson_order<2>("poisson_2d_dirichlet", cells,
                       {B::kDirichlet, B::kDirichlet, B::kDirichlet, B::kDirichlet}, sym, u, du, f),
      2.0, kOrderTolerance);
  EXPECT_NEAR(
      poisson_order<2>("poisson_2d_mixed", cells,
                       {B::kNeumann, B::kDirichlet, B::kNeumann, B::kDirichlet}, sym, u, du, f),
      2.0, kOrderTolerance);
  EXPECT_NEAR(poisson_order<2>("poisson_2d_pure_neumann_mean_fixed", cells,
                               {B::kNeumann, B::kNeumann, B::kNeumann, B::kNeumann}, sym, u, du, f),
              2.0, kOrderTolerance);
}

TEST(PoissonConvergence, ThreeDimensionalMixed) {
  using V = Vec<3>;
  const auto u = [](const V& x) {
    return std::sin(x[0] + 2 * x[1]) * std::cos(x[2]) + x[0] * x[2];
  };
  const auto du = [](const V& x) {
    return V(std::cos(x[0] + 2 * x[1]) * std::cos(x[2]) + x[2],
             2 * std::cos(x[0] + 2 * x[1]) * std::cos(x[2]),
             -std::sin(x[0] + 2 * x[1]) * std::sin(x[2]) + x[0]);
  };
  const auto f = [](const V& x) { return 6 * std::sin(x[0] + 2 * x[1]) * std::cos(x[2]); };
  using B = sn::Boundary;
  // Neumann on two faces as well, to exercise edges and corners where two Neumann faces meet.
  EXPECT_NEAR(poisson_order<3>("poisson_3d_mixed", {8, 16, 32},
                               {B::kNeumann, B::kDirichlet, B::kNeumann, B::kDirichlet,
                                B::kDirichlet, B::kDirichlet},
                               sn::NeumannRows::kSymmetrized, u, du, f),
              2.0, kOrderTolerance);
}

TEST(PoissonAssembly, SymmetrizedMatrixIsSymmetricWithNeumannCorners) {
  sn::PoissonGrid<double, 2> grid;
  grid.nodes = Eigen::Vector2i(5, 4);
  grid.spacing = 0.25;
  grid.faces = {sn::Boundary::kNeumann, sn::Boundary::kNeumann, sn::Boundary::kNeumann,
                sn::Boundary::kDirichlet};
  const auto zero = [](const Eigen::Vector2d&) { return 0.0; };
  const auto zero_g = [](const Eigen::Vector2d&, int) { return 0.0; };
  const auto sys = sn::assemble_poisson(grid, zero, zero_g);
  EXPECT_EQ(sys.unknowns(), 5 * 3);  // the top row of nodes is Dirichlet
  const Eigen::MatrixXd a = Eigen::MatrixXd(sys.matrix);
  EXPECT_LT((a - a.transpose()).norm(), 1e-12 * a.norm());
  // Corner (0, 0), Neumann on both faces: row (u - u_x / 2 - u_y / 2) / h^2.
  const double s = 16.0;
  EXPECT_NEAR(a(0, 0), 1.0 * s, 1e-12);
  EXPECT_NEAR(a(0, 1), -0.5 * s, 1e-12);
  EXPECT_NEAR(a(0, 5), -0.5 * s, 1e-12);
  // Edge node (2, 0): (2 u - u_in - u_left / 2 - u_right / 2) / h^2.
  EXPECT_NEAR(a(2, 2), 2.0 * s, 1e-12);
  EXPECT_NEAR(a(2, 7), -1.0 * s, 1e-12);
  EXPECT_NEAR(a(2, 1), -0.5 * s, 1e-12);
  EXPECT_NEAR(a(2, 3), -0.5 * s, 1e-12);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(a);
  EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
}
