// Tests of slurry/engine/numerics/pcg.h on 2D Poisson systems from finite_differences.h.
#include "slurry/engine/numerics/pcg.h"

#include <gtest/gtest.h>

#include <Eigen/SparseCholesky>
#include <cmath>
#include <iostream>

#include "slurry/engine/numerics/finite_differences.h"

namespace sn = slurry::numerics;
using Eigen::VectorXd;

namespace {

const double kPi = 3.14159265358979323846;

// -Lap u = f on [0, 1]^2 with `cells` cells per axis. Mixed conditions (Neumann on the low x and
// low y faces) make the diagonal vary (4, 2 and 1 times 1/h^2 after symmetrization), so Jacobi
// scaling is not a multiple of the identity.
sn::PoissonSystem<double> poisson_2d(int cells, bool mixed) {
  sn::PoissonGrid<double, 2> grid;
  grid.nodes = Eigen::Vector2i(cells + 1, cells + 1);
  grid.spacing = 1.0 / cells;
  if (mixed) grid.faces[0] = grid.faces[2] = sn::Boundary::kNeumann;
  const auto f = [](const Eigen::Vector2d& x) {
    return std::sin(kPi * x.x()) * std::exp(x.y()) + 1.0;
  };
  const auto g = [](const Eigen::Vector2d& x, int face) { return face < 2 ? x.y() : 0.5 * x.x(); };
  return sn::assemble_poisson(grid, f, g);
}

double true_relative_residual(const Eigen::SparseMatrix<double>& a, const VectorXd& b,
                              const VectorXd& x) {
  return (b - a * x).norm() / b.norm();
}

}  // namespace

TEST(Pcg, SolvesPoissonToToleranceAndOrdersPreconditioners) {
  for (const bool mixed : {false, true}) {
    SCOPED_TRACE(mixed ? "mixed Dirichlet/Neumann" : "Dirichlet");
    const auto sys = poisson_2d(64, mixed);
    const auto& a = sys.matrix;
    sn::PcgOptions<double> opt;
    opt.tolerance = 1e-10;
    opt.max_iterations = 5000;

    VectorXd x_cg, x_jac, x_ic;
    const auto r_cg = sn::conjugate_gradient(a, sys.rhs, x_cg, opt);
    const auto r_jac = sn::pcg(a, sys.rhs, x_jac, sn::JacobiPreconditioner<double>(a), opt);
    const auto r_ic = sn::pcg(a, sys.rhs, x_ic, sn::IncompleteCholesky0<double>(a), opt);
    std::cout << "[pcg] 2D Poisson, " << a.rows() << " unknowns ("
              << (mixed ? "mixed" : "Dirichlet") << "): iterations CG " << r_cg.iterations
              << ", Jacobi " << r_jac.iterations << ", IC(0) " << r_ic.iterations << "\n";
    ::testing::Test::RecordProperty(mixed ? "iterations_mixed" : "iterations_dirichlet",
                                    std::to_string(r_cg.iterations) + "/" +
                                        std::to_string(r_jac.iterations) + "/" +
                                        std::to_string(r_ic.iterations));
    for (const auto* r : {&r_cg, &r_jac, &r_ic}) {
      EXPECT_TRUE(r->converged);
      EXPECT_LE(r->relative_residual, opt.tolerance);
    }
    // The recursively updated residual drifts from the true one by ~ iterations * eps * cond;
    // the true residual stays within 10x the tolerance.
    for (const VectorXd* x : {&x_cg, &x_jac, &x_ic})
      EXPECT_LT(true_relative_residual(a, sys.rhs, *x), 10 * opt.tolerance);

    // Against a direct solve: error <= cond(A) * residual ~ 2e3 * 1e-10.
    const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(a);
    const VectorXd x_direct = ldlt.solve(sys.rhs);
    EXPECT_LT((x_ic - x_direct).norm() / x_direct.norm(), 1e-6);
    EXPECT_LT((x_cg - x_direct).norm() / x_direct.norm(), 1e-6);

    EXPECT_LT(r_ic.iterations, r_jac.iterations);
    // With all-Dirichlet conditions the diagonal is the constant 4 / h^2 = 2^14 (h = 1/64), so
    // Jacobi is a scaling by a power of two: its iterates equal CG's bit for bit and the counts
    // tie. With mixed conditions the varying diagonal makes Jacobi strictly better.
    EXPECT_LE(r_jac.iterations, r_cg.iterations);
    if (mixed) {
      EXPECT_LT(r_jac.iterations, r_cg.iterations);
    }
  }
}

TEST(Pcg, MatrixFreeOverloadGivesTheSameSolution) {
  const auto sys = poisson_2d(48, true);
  const auto& a = sys.matrix;
  sn::PcgOptions<double> opt;
  opt.tolerance = 1e-10;
  const sn::IncompleteCholesky0<double> ic(a);

  VectorXd x_sparse;
  const auto r_sparse = sn::pcg(a, sys.rhs, x_sparse, ic, opt);

  // Callables in both supported forms: value-returning A and out-parameter preconditioner.
  const auto apply_a = [&a](const VectorXd& x) -> VectorXd { return a * x; };
  const auto apply_m = [&ic](const VectorXd& r, VectorXd& z) { ic(r, z); };
  VectorXd x_free;
  const auto r_free = sn::pcg(apply_a, sys.rhs, x_free, apply_m, opt);
  EXPECT_TRUE(r_free.converged);
  EXPECT_EQ(r_free.iterations, r_sparse.iterations);  // same arithmetic, same sequence
  EXPECT_LT((x_free - x_sparse).norm() / x_sparse.norm(), 1e-12);
}

TEST(Pcg, MatrixFreeStencilOperatorMatchesAssembledMatrix) {
  // Zero Dirichlet data: the operator is -Lap of the unknowns embedded in a grid of zeros,
  // applied with laplacian() and no matrix at all.
  const int cells = 32;
  const Eigen::Vector2i nodes(cells + 1, cells + 1);
  sn::PoissonGrid<double, 2> grid;
  grid.nodes = nodes;
  grid.spacing = 1.0 / cells;
  const auto f = [](const Eigen::Vector2d& x) { return x.x() * (1 - x.y()) + 1.0; };
  const auto zero_g = [](const Eigen::Vector2d&, int) { return 0.0; };
  const auto sys = sn::assemble_poisson(grid, f, zero_g);
  const auto apply_a = [&](const VectorXd& u, VectorXd& out) {
    const VectorXd lap = sn::laplacian<double, 2>(sys.to_grid(u), nodes, grid.spacing);
    out.resize(u.size());
    for (Eigen::Index k = 0; k < u.size(); ++k)
      out[k] = -lap[sys.node_of_unknown[static_cast<size_t>(k)]];
  };
  sn::PcgOptions<double> opt;
  opt.tolerance = 1e-11;
  VectorXd x_free, x_sparse;
  const auto r_free = sn::pcg(apply_a, sys.rhs, x_free, sn::IdentityPreconditioner{}, opt);
  const auto r_sparse = sn::conjugate_gradient(sys.matrix, sys.rhs, x_sparse, opt);
  EXPECT_TRUE(r_free.converged);
  EXPECT_TRUE(r_sparse.converged);
  // Both converge to 1e-11 relative residual on a matrix with cond ~ 5e2: solutions within 1e-8.
  EXPECT_LT((x_free - x_sparse).norm() / x_sparse.norm(), 1e-8);
}

TEST(IncompleteCholesky0, ExactOnTridiagonalAndMatchesAOnItsPattern) {
  // 1D Poisson is tridiagonal: its Cholesky factor has no fill, so IC(0) is exact and PCG
  // converges in one iteration.
  const auto a1 =
      sn::poisson_matrix_1d<double>(50, 0.02, sn::Boundary::kNeumann, sn::Boundary::kDirichlet);
  const sn::IncompleteCholesky0<double> ic1(a1);
  const Eigen::MatrixXd l1(ic1.factor());
  const Eigen::MatrixXd d1(a1);
  // Entries are O(1e4) (1 / h^2 = 2500 times small integers): relative 1e-13 is round-off.
  EXPECT_LT((l1 * l1.transpose() - d1).norm(), 1e-13 * d1.norm());
  VectorXd x;
  const auto r = sn::pcg(a1, VectorXd::LinSpaced(a1.rows(), 1.0, 2.0).eval(), x, ic1);
  EXPECT_TRUE(r.converged);
  EXPECT_EQ(r.iterations, 1);

  // 2D: (L L^T)_ij = A_ij on the sparsity pattern of A (the defining property of IC(0)), while
  // L L^T has fill elsewhere.
  const auto sys = poisson_2d(10, true);
  const sn::IncompleteCholesky0<double> ic2(sys.matrix);
  const Eigen::MatrixXd l2(ic2.factor());
  const Eigen::MatrixXd llt = l2 * l2.transpose();
  const Eigen::MatrixXd d2(sys.matrix);
  double max_on_pattern = 0, max_off_pattern = 0;
  for (Eigen::Index i = 0; i < d2.rows(); ++i)
    for (Eigen::Index j = 0; j < d2.cols(); ++j) {
      const double diff = std::abs(llt(i, j) - d2(i, j));
      if (d2(i, j) != 0.0)
        max_on_pattern = std::max(max_on_pattern, diff);
      else
        max_off_pattern = std::max(max_off_pattern, diff);
    }
  EXPECT_LT(max_on_pattern, 1e-12 * d2.norm());
  EXPECT_GT(max_off_pattern, 1.0);  // the dropped fill is O(1/h^2) = O(100)
}

TEST(Pcg, ReportsNonConvergenceAndHandlesZeroRhs) {
  const auto sys = poisson_2d(32, false);
  sn::PcgOptions<double> opt;
  opt.tolerance = 1e-12;
  opt.max_iterations = 5;
  VectorXd x;
  const auto r = sn::conjugate_gradient(sys.matrix, sys.rhs, x, opt);
  EXPECT_FALSE(r.converged);
  EXPECT_EQ(r.iterations, 5);
  EXPECT_GT(r.relative_residual, opt.tolerance);

  VectorXd x0 = VectorXd::Ones(sys.rhs.size());
  const auto r0 = sn::conjugate_gradient(sys.matrix, VectorXd::Zero(sys.rhs.size()).eval(), x0);
  EXPECT_TRUE(r0.converged);
  EXPECT_EQ(r0.iterations, 0);
  EXPECT_EQ(x0.norm(), 0.0);

  opt.tolerance = -1.0;
  EXPECT_THROW(sn::conjugate_gradient(sys.matrix, sys.rhs, x, opt), std::invalid_argument);
}
