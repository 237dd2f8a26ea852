// Sleeping material (solver.sleep): a scene where most of the material rests. A 3D layer of sand
// (Drucker-Prager, the sand_column example's material) 0.1 m deep over a 0.9 x 0.9 m floor, 72 k
// particles at dx = 1/48 m, settles; a jelly ball (radius 0.05 m) dropped from 0.9 m lands on it
// at about t = 0.4 s. Untimed: the first 0.35 s (settling, the blocks fall asleep). Timed: 0.35 s
// to 0.65 s, the impact and what follows, with sleeping off and on (speed 1 cm/s, 100 calm
// substeps). Counters: particle-steps/s (all particles, asleep or not, per substep), substeps,
// and the blocks asleep at the end.
//
//   build/release/bin/bench_sleep --benchmark_counters_tabular=true --benchmark_repetitions=3
// Arguments: sleeping (0 off, 1 on), threads.
#include <benchmark/benchmark.h>

#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"
#include "slurry/io/scene_file.h"

namespace {

slurry::Scene pile_scene(bool sleep) {
  slurry::Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.020833333333333332},
    "solver": {"dimension": 3, "transfer": "apic", "kernel": "quadratic", "max_dt": 0.001},
    "materials": [
      {"name": "sand", "model": "hencky_stvk", "density": 2200, "E": 350000.0, "nu": 0.3, "plasticity": "drucker_prager", "friction_angle": 30},
      {"name": "ball", "model": "fixed_corotated", "density": 1000, "E": 100000.0, "nu": 0.3}
    ],
    "bodies": [
      {"shape": "box", "min": [0.05, 0.0, 0.05], "max": [0.95, 0.1, 0.95], "material": "sand", "sampling": "jittered", "seed": 3},
      {"shape": "sphere", "center": [0.5, 0.9, 0.5], "radius": 0.05, "material": "ball"}
    ],
    "boundaries": {"walls": "separate", "friction": 0.5}
  })",
                                        "bench_sleep");
  if (sleep) s.solver.sleep.speed = 0.01;
  return s;
}

void BM_SleepingPile(benchmark::State& state) {
  const bool sleep = state.range(0) != 0;
  slurry::parallel::ThreadLimit threads(int(state.range(1)));
  double n = 0, substeps = 0, asleep = 0;
  for (auto _ : state) {
    state.PauseTiming();
    slurry::MpmSolver<float, 3> sim(pile_scene(sleep));
    sim.advance_to(0.35);
    state.ResumeTiming();
    substeps += double(sim.advance_to(0.65));
    n = double(sim.particle_count());
    asleep = double(sim.sleeping_blocks());
  }
  state.counters["particles"] = n;
  state.counters["substeps"] = substeps / double(state.iterations());
  state.counters["blocks asleep"] = asleep;
  state.counters["particle-steps/s"] =
      benchmark::Counter(n * substeps, benchmark::Counter::kIsRate);
}

}  // namespace

BENCHMARK(BM_SleepingPile)
    ->ArgsProduct({{0, 1}, {1, 2}})
    ->Iterations(1)
    ->Unit(benchmark::kSecond)
    ->UseRealTime();

BENCHMARK_MAIN();
