// Slurry against the 88-line MLS-MPM reference (the 2D bar: >= 2x its
// particle-steps/s on one thread). The scene, benchmarks/scenes/mls88_snow_2d.json, is the
// reference's high-resolution set-up: Hu et al. 2018, "A moving least squares material point
// method with displacement discontinuity and two-way rigid body coupling", 88-line version
// (github.com/yuanming-hu/taichi_mpm, mls-mpm88.cpp, v1.4) with its FAQ's settings: grid n = 320
// over the unit square, dt = 1e-5 fixed, E = 2e4, nu = 0.2, hardening 10, snow clamp window
// [1 - 2.5e-2, 1 + 7.5e-3], particle mass = volume = 1 (density 1), gravity -200, quadratic
// B-spline, MLS transfer, float; three squares of side 0.16 centred at (0.55, 0.45),
// (0.45, 0.65), (0.55, 0.85), 8000 random particles each (24 000); nodes within 0.05 of the box
// sticky at the sides and top, separating at the bottom. Slurry seeds the reference's density
// on a jittered lattice: 89 x 89 per square, 23 763 particles (-1.0%). Differences that remain:
// Slurry caps the hardening factor at 20 (Jp >= 0.7) where the reference clamps Jp to
// [0.6, 20]; the reference draws its particles uniformly at random.
//
// Like the reference's timing harness (RESULTS.md: a fixed number of substeps from the start,
// no output), each case builds the simulation, takes `warm` untimed substeps, then times 2000
// substeps of dt = solver.max_dt. Counters: particle-steps/s, ms per phase and the particles'
// mean height at the end (to hold against the reference's, same warm-up and substeps).
//
//   OMP_WAIT_POLICY=passive build/release/bin/bench_mls88 --benchmark_counters_tabular=true
// Arguments: threads, untimed substeps before the timed 2000.
#include <benchmark/benchmark.h>

#include <string>

#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"
#include "slurry/io/scene_file.h"

#ifndef SLURRY_BENCH_SCENES_DIR
#define SLURRY_BENCH_SCENES_DIR "benchmarks/scenes"
#endif

namespace {

constexpr int kTimedSubsteps = 2000;

void BM_Mls88(benchmark::State& state) {
  slurry::parallel::ThreadLimit threads(int(state.range(0)));
  const int warm = int(state.range(1));
  const slurry::Scene scene =
      slurry::load_scene(std::string(SLURRY_BENCH_SCENES_DIR) + "/mls88_snow_2d.json");
  const float dt = float(scene.solver.max_dt);
  double n = 0, mean_y = 0;
  slurry::PhaseTimes spent;
  for (auto _ : state) {
    state.PauseTiming();
    slurry::MpmSolver<float, 2> sim(scene);
    for (int i = 0; i < warm; ++i) sim.step(dt);
    const slurry::PhaseTimes before = sim.phase_times();
    state.ResumeTiming();
    for (int i = 0; i < kTimedSubsteps; ++i) sim.step(dt);
    state.PauseTiming();
    const slurry::PhaseTimes& after = sim.phase_times();
    spent.binning += after.binning - before.binning;
    spent.reorder += after.reorder - before.reorder;
    spent.p2g += after.p2g - before.p2g;
    spent.grid += after.grid - before.grid;
    spent.g2p += after.g2p - before.g2p;
    spent.plasticity += after.plasticity - before.plasticity;
    n = double(sim.particle_count());
    mean_y = 0;
    for (const auto& x : sim.particles().x) mean_y += double(x[1]);
    mean_y /= n;
    state.ResumeTiming();
  }
  const double steps = double(kTimedSubsteps) * double(state.iterations());
  state.counters["particles"] = n;
  state.counters["substeps"] = double(kTimedSubsteps);
  state.counters["particle-steps/s"] = benchmark::Counter(n * steps, benchmark::Counter::kIsRate);
  state.counters["ms_bin"] = 1e3 * spent.binning / steps;
  state.counters["ms_reorder"] = 1e3 * spent.reorder / steps;
  state.counters["ms_p2g"] = 1e3 * spent.p2g / steps;
  state.counters["ms_grid"] = 1e3 * spent.grid / steps;
  state.counters["ms_g2p"] = 1e3 * spent.g2p / steps;
  state.counters["ms_plastic"] = 1e3 * spent.plasticity / steps;
  state.counters["mean_y"] = mean_y;
}

}  // namespace

// From the start (free fall) and after all three squares have landed (t = 0.1 s).
BENCHMARK(BM_Mls88)
    ->ArgsProduct({{1, 2}, {0, 10000}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();
