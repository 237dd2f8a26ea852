// Throughput of one full explicit MLS-MPM substep (binning, stress update fused into P2G, grid update, G2P),
// quadratic kernel, fixed corotated elasticity, 8 particles per cell, a cube of particles
// filling the middle half of the unit domain along each axis (res^3 particles for res cells per
// axis), sparse grid. Counters: particle-steps/s of the full step and of P2G and G2P alone
// (from the simulation's phase timers), engine bytes per particle and the process's peak
// resident memory per particle of this case (peak_rss.h).
//
//   build/release/bin/bench_mpm_step --benchmark_counters_tabular=true
// Arguments: cells per axis, threads.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <string>
#include <vector>

#include "block_scene.h"
#include "peak_rss.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"

namespace {

template <class T, int Dim>
void run_steps(benchmark::State& state, int threads_wanted, const slurry::Scene& scene, std::string label = {}) {
  slurry::parallel::ThreadLimit threads(threads_wanted);
  const bool reset = slurry::bench::reset_peak_rss();
  slurry::MpmSolver<T, Dim> sim(scene);
  const T dt = T(0.2) * sim.stable_dt();
  for (int i = 0; i < 3; ++i) sim.step(dt);  // warm up: grid blocks and particle order settle
  const slurry::PhaseTimes before = sim.phase_times();
  for (auto _ : state) sim.step(dt);
  const double n = double(sim.particle_count());
  const double steps = double(state.iterations());
  const auto& after = sim.phase_times();
  state.counters["particles"] = n;
  state.counters["particle-steps/s"] = benchmark::Counter(n * steps, benchmark::Counter::kIsRate);
  state.counters["P2G p-steps/s"] = n * steps / (after.p2g - before.p2g);
  state.counters["G2P p-steps/s"] = n * steps / (after.g2p - before.g2p);
  // Milliseconds per step in each phase: where the 2-thread speed-up is won or lost.
  state.counters["ms_bin"] = 1e3 * (after.binning - before.binning) / steps;
  state.counters["ms_reorder"] = 1e3 * (after.reorder - before.reorder) / steps;
  state.counters["ms_p2g"] = 1e3 * (after.p2g - before.p2g) / steps;
  state.counters["ms_grid"] = 1e3 * (after.grid - before.grid) / steps;
  state.counters["ms_g2p"] = 1e3 * (after.g2p - before.g2p) / steps;
  state.counters["ms_plastic"] = 1e3 * (after.plasticity - before.plasticity) / steps;
  state.counters["bytes/particle"] = double(sim.bytes()) / n;
  // This case's peak (the process's baseline of about 4 MB included), see peak_rss.h.
  state.counters["peakRSS/particle"] = slurry::bench::peak_rss_bytes() / n;
  if (!reset) label += label.empty() ? "peakRSS of the process" : ", peakRSS of the process";
  if (!label.empty()) state.SetLabel(label);
}

template <class T, int Dim>
void BM_MlsStep(benchmark::State& state) {
  run_steps<T, Dim>(state, int(state.range(1)), slurry::bench::block_scene(Dim, int(state.range(0)), std::is_same_v<T, double>));
}

// The issue-15 bar "snow and sand within 25% of jelly": the same 1 M-particle block, 3D float MLS,
// of jelly (0), snow (1) or sand (2) (block_scene.h). The block moves as a whole and is barely
// deformed, so snow's window test skips nearly every SVD (its best case) while sand's Hencky
// strain always takes one. Arguments: material, threads.
void BM_Material(benchmark::State& state) {
  const auto material = slurry::bench::BlockMaterial(state.range(0));
  run_steps<float, 3>(state, int(state.range(1)), slurry::bench::block_scene(3, 100, false, 1, material),
                      material == slurry::bench::BlockMaterial::Jelly  ? "jelly"
                      : material == slurry::bench::BlockMaterial::Snow ? "snow"
                                                                       : "sand");
}

// With --benchmark_repetitions, the fastest repetition: on a shared machine the noise only ever
// slows a run down, so the minimum is the least disturbed estimate (see RESULTS.md). Every counter
// gets the same statistic: the time counters (ms_*) should be read as their minimum; the rate
// counters are then the minimum rate, the conservative side.
double fastest(const std::vector<double>& v) { return v.empty() ? 0.0 : *std::min_element(v.begin(), v.end()); }

// res^3 particles: 31 -> 30 k (the small-scene bar), 47 -> 104 k, 100 -> 1.0 M, 159 -> 4.0 M.
void Args3D(benchmark::internal::Benchmark* b) {
  for (int res : {31, 47, 100, 159})
    for (int t : {1, 2}) b->Args({res, t});
  b->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0)->ComputeStatistics("min", fastest);
}
// 2D: 4 res^2 / 4 = res^2 particles.
void Args2D(benchmark::internal::Benchmark* b) {
  for (int res : {512, 1024})
    for (int t : {1, 2}) b->Args({res, t});
  b->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
}

BENCHMARK_TEMPLATE(BM_MlsStep, float, 3)->Apply(Args3D);
BENCHMARK(BM_Material)->ArgsProduct({{0, 1, 2}, {1, 2}})->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
BENCHMARK_TEMPLATE(BM_MlsStep, double, 3)->Apply(Args3D);
BENCHMARK_TEMPLATE(BM_MlsStep, float, 2)->Apply(Args2D);
BENCHMARK_TEMPLATE(BM_MlsStep, double, 2)->Apply(Args2D);

}  // namespace

int main(int argc, char** argv) {
  slurry::bench::fresh_process_malloc();  // peak_rss.h
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
