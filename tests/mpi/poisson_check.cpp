// The distributed pressure solve (Communicator::solve_spd: PETSc's CG with hypre's BoomerAMG),
// run under mpirun -np 1 to 4 (ctest label "mpi"). A liquid's pressure Poisson system of the
// FLIP discretisation (flip/pressure.h: the 7-point Laplacian scaled by dx^2, Neumann at the
// tank's walls, p = 0 in air cells) on an n^3 tank, its liquid cells split over the processes as
// the MPM split cuts its grid blocks (domain_split.h: boxes of 4^3 cells balanced by liquid
// cells), numbered rank after rank. Every process also assembles the whole system and solves it
// alone (Eigen's CG to 1e-13), and each compares its rows of the distributed solution with that
// reference. Two liquids: a sloshing surface (Dirichlet rows) and a full closed tank (the
// constant null space). Exit status 0 when every case agrees and converged; the table on rank 0
// gives the iterations per resolution and process count.
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "mpm/domain_split.h"
#include "slurry/mpi/mpi.h"

namespace {

using slurry::DistributedSystem;

struct Case {
  const char* name;
  int n;
  bool closed;
};

int run(slurry::mpi::Session& mpi, const Case& c, double rtol, double tolerance) {
  const int n = c.n, ranks = mpi.size(), rank = mpi.rank();
  auto index = [n](int i, int j, int k) { return (std::int64_t(i) * n + j) * n + k; };
  // Liquid below a sloshing surface (y < h(x, z)), or everywhere in a closed tank.
  std::vector<std::uint8_t> liquid(std::size_t(n) * n * n, 0);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        const double x = (i + 0.5) / n, y = (j + 0.5) / n, z = (k + 0.5) / n;
        const double h = 0.55 + 0.2 * std::sin(6.0 * x) * std::cos(4.0 * z);
        liquid[std::size_t(index(i, j, k))] = c.closed || y < h;
      }
  // The split: boxes of 4^3-cell blocks, cut by liquid cells per block.
  constexpr int block = 4;
  const int nb = (n + block - 1) / block;
  const Eigen::Vector3i lattice(nb, nb, nb);
  const auto per_axis = slurry::detail::process_grid<3>(ranks, lattice);
  if (per_axis.empty()) {
    std::fprintf(stderr, "%s: no split of %d blocks per axis over %d processes\n", c.name, nb, ranks);
    return 1;
  }
  slurry::detail::BoxSplit<3> split(lattice, per_axis);
  std::vector<double> counts(std::size_t(nb) * nb * nb, 0.0);
  auto block_index = [nb](const Eigen::Vector3i& b) { return (std::size_t(b[0]) * nb + b[1]) * nb + b[2]; };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k)
        if (liquid[std::size_t(index(i, j, k))]) counts[block_index(Eigen::Vector3i(i, j, k) / block)] += 1;
  split.cut(counts);
  // Global numbering: rank after rank, each rank's liquid cells in lexicographic order.
  std::vector<int> owner(liquid.size(), -1);
  std::vector<std::int64_t> per_rank(std::size_t(ranks) + 1, 0), number(liquid.size(), -1);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k)
        if (liquid[std::size_t(index(i, j, k))]) {
          const int r = split.owner(Eigen::Vector3i(i, j, k) / block);
          owner[std::size_t(index(i, j, k))] = r;
          ++per_rank[std::size_t(r) + 1];
        }
  for (int r = 0; r < ranks; ++r) per_rank[std::size_t(r) + 1] += per_rank[std::size_t(r)];
  std::vector<std::int64_t> next(per_rank.begin(), per_rank.end() - 1);
  for (std::size_t q = 0; q < liquid.size(); ++q)
    if (owner[q] >= 0) number[q] = next[std::size_t(owner[q])]++;
  const std::int64_t total = per_rank.back();
  // The rows: diagonal = open neighbours (liquid or air), -1 per liquid neighbour; rhs a random
  // divergence (the same on every rank), its mean removed in the closed tank.
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<double> rhs(static_cast<std::size_t>(total));
  for (auto& v : rhs) v = u(rng);
  if (c.closed) {
    double mean = 0;
    for (const auto v : rhs) mean += v;
    mean /= double(total);
    for (auto& v : rhs) v -= mean;
  }
  std::vector<Eigen::Triplet<double, std::int64_t>> all;
  DistributedSystem S;
  S.first = per_rank[std::size_t(rank)];
  S.constant_null_space = c.closed;
  std::vector<std::int64_t> mine;  // cell of each of this rank's rows
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        const auto q = std::size_t(index(i, j, k));
        if (owner[q] < 0) continue;
        const std::int64_t row = number[q];
        double diagonal = 0;
        std::vector<std::pair<std::int64_t, double>> entries;
        const int nbr[6][3] = {{i - 1, j, k}, {i + 1, j, k}, {i, j - 1, k}, {i, j + 1, k}, {i, j, k - 1}, {i, j, k + 1}};
        for (const auto& m : nbr) {
          if (m[0] < 0 || m[0] >= n || m[1] < 0 || m[1] >= n || m[2] < 0 || m[2] >= n) continue;  // wall
          diagonal += 1;
          const auto p = std::size_t(index(m[0], m[1], m[2]));
          if (owner[p] >= 0) entries.emplace_back(number[p], -1.0);
        }
        entries.emplace_back(row, diagonal);
        for (const auto& [col, v] : entries) all.emplace_back(row, col, v);
        if (owner[q] != rank) continue;
        for (const auto& [col, v] : entries) S.columns.push_back(col), S.values.push_back(v);
        S.row_start.push_back(std::int64_t(S.columns.size()));
        S.rhs.push_back(rhs[std::size_t(row)]);
      }
  std::vector<double> x;
  const auto solve = mpi.solve_spd(S, x, rtol, 500);
  // The reference: the whole system in this process.
  Eigen::SparseMatrix<double, Eigen::RowMajor, std::int64_t> A(total, total);
  A.setFromTriplets(all.begin(), all.end());
  Eigen::ConjugateGradient<decltype(A), Eigen::Lower | Eigen::Upper> cg;
  cg.setTolerance(1e-13);
  cg.setMaxIterations(20000);
  cg.compute(A);
  Eigen::VectorXd b = Eigen::Map<const Eigen::VectorXd>(rhs.data(), Eigen::Index(total));
  Eigen::VectorXd reference = cg.solve(b);
  if (c.closed) reference.array() -= reference.mean();
  double diff = 0, norm = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double r = reference[Eigen::Index(S.first + std::int64_t(i))];
    diff += (x[i] - r) * (x[i] - r), norm += r * r;
  }
  double sums[2] = {diff, norm};
  mpi.sum(sums, 2);
  const double error = std::sqrt(sums[0] / sums[1]);
  double bad = (!solve.converged || solve.residual > rtol * 1.0001 || !(error <= tolerance)) ? 1 : 0;
  mpi.max(&bad, 1);
  if (rank == 0)
    std::printf("| %s | %d^3 | %lld | %d (%d x %d x %d) | %d | %.2e | %.2e | %s |\n", c.name, n, (long long)total, ranks,
                per_axis[0], per_axis[1], per_axis[2], solve.iterations, solve.residual, error,
                bad ? "FAIL" : "ok");
  return bad ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  slurry::mpi::Session mpi(argc, argv);
  // Relative residual 1e-10; the solution within 1e-6 of the reference (the systems' condition
  // numbers, about n^2, bound the error by a few 1e-7).
  const double rtol = 1e-10, tolerance = 1e-6;
  if (mpi.rank() == 0) {
    std::printf("| liquid | cells | unknowns | processes | CG + BoomerAMG iterations | residual | error vs one process |  |\n");
    std::printf("| --- | --- | --- | --- | --- | --- | --- | --- |\n");
  }
  int failed = 0;
  for (const Case& c : {Case{"sloshing surface", 16, false}, Case{"sloshing surface", 32, false},
                        Case{"closed tank", 24, true}})
    failed += run(mpi, c, rtol, tolerance);
  return failed ? 1 : 0;
}
