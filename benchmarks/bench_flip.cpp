// FLIP/APIC liquid solver throughput.
//
//   build/release/bin/bench_flip --benchmark_counters_tabular=true
//     BM_FlipStep/<res>/<threads>: one full FLIP substep (every phase of FlipSolver::step),
//       APIC, linear kernel, float, a block of liquid filling the lower half of a res^3 box at 8
//       particles per cell, settling under gravity. Counter: particle-steps/s.
//     BM_DamBreakFrame/<threads>: the bar, a 3D dam break on a 150 x 100 x 75 grid
//       (examples/scenes/flip_dam_break_3d.json: ~880 k particles, frames of 1/60 s, one
//       substep each, CFL up to 5, APIC). Counter: seconds per frame, and per phase.
//   build/release/bin/bench_flip --phases SCENE.json FRAMES [THREADS]
//       runs a scene file and prints seconds per frame and the per-phase breakdown.
#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/transfer/parallel.h"
#include "slurry/io/scene_file.h"

namespace {

using Sim3 = slurry::flip::FlipSolver<float, 3>;

slurry::Scene block_scene(int res) {
  slurry::Scene s;
  s.source = "bench";
  s.solver.type = slurry::SolverType::FLIP;
  s.solver.dimension = 3;
  s.solver.transfer = slurry::TransferKind::APIC;
  s.solver.kernel = slurry::KernelKind::Linear;
  s.solver.cfl = 1;
  s.domain.max = {1, 1, 1};
  s.domain.dx = 1.0 / res;
  slurry::MaterialParams m;
  m.name = "water";
  m.model = slurry::ElasticModel::Fluid;
  s.materials = {m};
  slurry::BodyParams b;
  b.min = {0, 0, 0};
  b.max = {1, 0.5, 1};
  b.material = "water";
  b.particles_per_cell = 8;
  s.bodies = {b};
  return s;
}

void report_phases(benchmark::State& state, const Sim3& sim, double frames) {
  const auto& ph = sim.phase_seconds();
  for (int p = 0; p < slurry::flip::kPhaseCount; ++p)
    state.counters[std::string("s_") + slurry::flip::phase_name(p)] = ph[p] / frames;
}

void BM_FlipStep(benchmark::State& state) {
  const int res = int(state.range(0));
  slurry::parallel::ThreadLimit threads(int(state.range(1)));
  Sim3 sim(block_scene(res));
  const float dt = 2e-3f;
  for (int i = 0; i < 3; ++i) sim.step(dt);  // warm up: buffers reach their size
  std::int64_t steps = 0;
  double particle_steps = 0;
  for (auto _ : state) {
    sim.step(dt);
    ++steps;
    particle_steps += double(sim.particle_count());
  }
  state.counters["particles"] = double(sim.particle_count());
  state.counters["particle-steps/s"] = benchmark::Counter(particle_steps, benchmark::Counter::kIsRate);
  state.counters["pcg_iterations"] = sim.last_projection().iterations;
}
BENCHMARK(BM_FlipStep)->Args({64, 1})->Args({64, 2})->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

#ifndef SLURRY_EXAMPLES_DIR
#define SLURRY_EXAMPLES_DIR "examples/scenes"
#endif

void BM_DamBreakFrame(benchmark::State& state) {
  slurry::parallel::ThreadLimit threads(int(state.range(0)));
  const auto scene = slurry::load_scene(std::string(SLURRY_EXAMPLES_DIR) + "/flip_dam_break_3d.json");
  Sim3 sim(scene);
  int frame = 0;
  for (auto _ : state) sim.advance_to(++frame * scene.frame_dt());
  state.counters["particles"] = double(sim.particle_count());
  state.counters["s/frame"] = benchmark::Counter(double(frame), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["substeps/frame"] = double(sim.steps()) / frame;
  state.counters["pcg_iterations"] = sim.last_projection().iterations;
  report_phases(state, sim, frame);
}
BENCHMARK(BM_DamBreakFrame)->Arg(1)->Arg(2)->Unit(benchmark::kSecond)->UseRealTime()->Iterations(10);

/// --phases SCENE FRAMES [THREADS]: per-phase breakdown of any FLIP scene.
template <class T, int Dim>
int run_phases(const slurry::Scene& scene, int frames) {
  slurry::flip::FlipSolver<T, Dim> sim(scene);
  const auto t0 = std::chrono::steady_clock::now();
  int iterations = 0;
  for (int f = 1; f <= frames; ++f) {
    sim.advance_to(f * scene.frame_dt());
    iterations += sim.last_projection().iterations;
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("%s: %d frames, %lld substeps, %zu particles, %.3f s/frame, %.3g particle-steps/s, last PCG %d its\n",
              scene.source.c_str(), frames, static_cast<long long>(sim.steps()), sim.particle_count(), s / frames,
              double(sim.particle_count()) * double(sim.steps()) / s, sim.last_projection().iterations);
  double cpu = 0;
  for (int p = 0; p < slurry::flip::kPhaseCount; ++p) cpu += sim.phase_cpu_seconds()[p];
  std::printf("  %-22s %8s %8s  (s/frame)\n", "phase", "wall", "cpu");
  for (int p = 0; p < slurry::flip::kPhaseCount; ++p)
    std::printf("  %-22s %8.4f %8.4f  %5.1f%% of wall\n", slurry::flip::phase_name(p), sim.phase_seconds()[p] / frames,
                sim.phase_cpu_seconds()[p] / frames, 100 * sim.phase_seconds()[p] / s);
  std::printf("  %-22s %8.4f %8.4f\n", "total", s / frames, cpu / frames);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 4 && std::strcmp(argv[1], "--phases") == 0) {
    const auto scene = slurry::load_scene(argv[2]);
    slurry::parallel::ThreadLimit threads(argc >= 5 ? std::atoi(argv[4]) : 0);
    const int frames = std::atoi(argv[3]);
    const bool dbl = scene.solver.precision == slurry::Precision::Double;
    if (scene.solver.dimension == 2) return dbl ? run_phases<double, 2>(scene, frames) : run_phases<float, 2>(scene, frames);
    return dbl ? run_phases<double, 3>(scene, frames) : run_phases<float, 3>(scene, frames);
  }
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
