// FLIP pressure projection throughput: one PressureSolver::project() (assembly, PCG to a 1e-6
// relative residual, velocity update) per iteration, wall-clock time.
//
// Cases (3D, double):
// - Tank/<prec>/<N>/<threads>: N^3 cells, closed walls, liquid below 3/4 of the height (a flat
//   free surface), velocity = gravity step plus a smooth swirl of 0.5 m/s; cold start (p = 0).
// - DamBreak/<prec>/<warm>/<threads>: 150 x 100 x 75 cells of dx = 1/100 m, liquid in
//   x < 100, y < 75 cells (half the cells), the same velocity field; warm = 1 starts from the
//   pressure of a solve whose swirl was shifted by 0.1 rad (as between two frames).
// Counters: cells/s (fluid cells x solves / s, wall), iterations, s/solve (wall), cpu_s/solve
// (CPU time of the whole process, all threads, from std::clock).
#include <benchmark/benchmark.h>

#include <cmath>
#include <ctime>

#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/pressure.h"
#include "slurry/transfer/parallel.h"

namespace {

using namespace slurry::flip;
using Grid = MacGrid<double, 3>;

void set_velocity(Grid& g, double phase) {
  const double dt = 1.0 / 30, grav = 9.81;
  for (int d = 0; d < 3; ++d)
    for (std::int64_t f = 0; f < g.num_faces(d); ++f) {
      const Eigen::Vector3d x = g.face_position(d, g.face_coord(d, f));
      const double s = 0.5 * std::sin(6.0 * x[(d + 1) % 3] + phase) * std::cos(5.0 * x[(d + 2) % 3] - phase);
      g.u[d][std::size_t(f)] = s + (d == 1 ? -grav * dt : 0.0);
    }
}

/// Liquid where cell i < fluid_hi (per axis), flat free surface at the top of the block.
Grid make_grid(const Eigen::Vector3i& res, double dx, const Eigen::Vector3i& fluid_hi) {
  Grid g;
  g.resize(res, dx, Eigen::Vector3d::Zero());
  for (std::int64_t c = 0; c < g.num_cells(); ++c) {
    const Eigen::Vector3i i = g.cell_coord(c);
    const Eigen::Vector3d x = g.cell_center(i);
    const Eigen::Vector3d top = fluid_hi.cast<double>() * dx;
    // Signed distance to the block [0, top] (walls outside the grid do not count).
    double phi = -1e9;
    for (int a = 0; a < 3; ++a)
      if (fluid_hi[a] < res[a]) phi = std::max(phi, x[a] - top[a]);
    g.phi[std::size_t(c)] = phi;
    g.label[std::size_t(c)] = phi < 0 ? Grid::Fluid : Grid::Air;
  }
  set_velocity(g, 0.0);
  return g;
}

/// 0 none, 1 jacobi, 2 exact MIC(0) (level-scheduled), 3 MIC(0) on 8 slabs, 4 on 16 slabs,
/// 5 multigrid (default options).
Preconditioner prec_of(int k) {
  return k == 0 ? Preconditioner::None : k == 1 ? Preconditioner::Jacobi : k == 5 ? Preconditioner::Multigrid : Preconditioner::MIC0;
}
int blocks_of(int k) { return k == 3 ? 8 : k == 4 ? 16 : 0; }

void run(benchmark::State& state, Grid& g, int prec_index, int threads, bool warm) {
  const Preconditioner prec = prec_of(prec_index);
  slurry::parallel::ThreadLimit limit(threads);
  ProjectionOptions opt;
  opt.preconditioner = prec;
  opt.tolerance = 1e-6;
  opt.max_iterations = 5000;
  opt.mic_blocks = blocks_of(prec_index);
  PressureSolver<double, 3> solver;
  std::vector<double> warm_pressure;
  if (warm) {
    set_velocity(g, 0.1);
    solver.project(g, 1.0 / 30, opt);
    warm_pressure = g.pressure;
  }
  ProjectionReport rep;
  std::int64_t solves = 0, iterations = 0;
  double cpu = 0;
  for (auto _ : state) {
    state.PauseTiming();
    set_velocity(g, 0.0);
    if (warm)
      g.pressure = warm_pressure;
    else
      std::fill(g.pressure.begin(), g.pressure.end(), 0.0);
    state.ResumeTiming();
    const std::clock_t c0 = std::clock();
    rep = solver.project(g, 1.0 / 30, opt);
    cpu += double(std::clock() - c0) / CLOCKS_PER_SEC;
    ++solves;
    iterations += rep.iterations;
  }
  state.counters["cells/s"] = benchmark::Counter(double(rep.unknowns) * double(solves), benchmark::Counter::kIsRate);
  state.counters["iterations"] = double(iterations) / double(solves);
  state.counters["s/solve"] = benchmark::Counter(double(solves), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["cpu_s/solve"] = cpu / double(solves);
  state.counters["fluid_cells"] = double(rep.unknowns);
  state.counters["converged"] = rep.converged;
  state.SetLabel(std::string(to_string(prec)) + (opt.mic_blocks ? "/" + std::to_string(opt.mic_blocks) + " slabs" : "") +
                 (warm ? " warm" : " cold"));
}

void BM_Tank(benchmark::State& state) {
  const int n = int(state.range(1));
  Grid g = make_grid(Eigen::Vector3i::Constant(n), 1.0 / n, Eigen::Vector3i(n, 3 * n / 4, n));
  run(state, g, int(state.range(0)), int(state.range(2)), false);
}

void BM_DamBreak(benchmark::State& state) {
  Grid g = make_grid(Eigen::Vector3i(150, 100, 75), 0.01, Eigen::Vector3i(100, 75, 75));
  run(state, g, int(state.range(0)), int(state.range(2)), state.range(1) != 0);
}

}  // namespace

BENCHMARK(BM_Tank)
    ->ArgNames({"prec", "N", "threads"})
    ->ArgsProduct({{0, 1, 2, 3, 4, 5}, {64, 128}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond)
    ->MinTime(0.5);
BENCHMARK(BM_DamBreak)
    ->ArgNames({"prec", "warm", "threads"})
    ->ArgsProduct({{0, 1, 2, 3, 4, 5}, {0, 1}, {1, 2}})
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond)
    ->MinTime(0.5);

BENCHMARK_MAIN();
