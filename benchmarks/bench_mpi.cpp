// Scaling of the MPM solver split over processes. Run it under mpirun; rank 0
// prints the table:
//
//   mpirun -np N build/release/bin/bench_mpi --benchmark_counters_tabular=true
//
// The scene of bench_mpm_step (3D MLS, quadratic kernel, fixed corotated, float, 8 particles per
// cell, a block filling the middle half of the domain, sparse grid), one worker thread per rank.
// BM_Strong/res: the same res^3 particles on every N (strong scaling). BM_Weak/res: res^3
// particles per rank, the block and the domain stretched along x by N (weak scaling). The split
// is the engine's (domain_split.h process_grid): on 4 processes 2 x 2 x 1 boxes for BM_Strong, 4
// slabs along x for BM_Weak.
//
// A substep's time is the slowest rank's (MPI_Allreduce max; manual time). Counters:
//   particle-steps/s   all ranks' particles x substeps / time
//   kB/substep/rank    payload each rank sends per substep (the grid halo's nodes and migrating
//                      particles, 108 B per 3D float MLS solid particle), mean over ranks
//   kB/substep max     the largest rank's
//   halo kB/substep/rank   of which the grid halo's nodes (benchmarks/mpi/model.py predicts it)
// Fixed iteration counts keep the ranks in step (every substep is collective).
#include <benchmark/benchmark.h>

#include <chrono>
#include <memory>

#include "block_scene.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/mpi/mpi.h"
#include "slurry/transfer/parallel.h"

namespace {

slurry::mpi::Session* g_mpi = nullptr;

void run(benchmark::State& state, bool weak) {
  auto& mpi = *g_mpi;
  const int res = int(state.range(0));
  slurry::parallel::ThreadLimit threads(1);
  slurry::MpmSolver<float, 3> sim(slurry::bench::block_scene(3, res, false, weak ? mpi.size() : 1), &mpi);
  const float dt = 0.2f * sim.stable_dt();
  for (int i = 0; i < 3; ++i) sim.step(dt);  // warm up: grid blocks and particle order settle
  const auto sent = mpi.exchanged_bytes();
  const auto halo_sent = sim.halo_bytes_sent();
  using Clock = std::chrono::steady_clock;
  for (auto _ : state) {
    const auto t0 = Clock::now();
    sim.step(dt);
    double t = std::chrono::duration<double>(Clock::now() - t0).count();
    mpi.max(&t, 1);
    state.SetIterationTime(t);
  }
  const double n = double(sim.particle_count()), steps = double(state.iterations());
  double bytes[3] = {double(mpi.exchanged_bytes() - sent) / steps, 0, double(sim.halo_bytes_sent() - halo_sent) / steps};
  bytes[1] = bytes[0];
  mpi.sum(&bytes[0], 1);
  mpi.sum(&bytes[2], 1);
  mpi.max(&bytes[1], 1);
  const double mean = bytes[0] / mpi.size();
  state.counters["ranks"] = mpi.size();
  state.counters["particles"] = n;
  state.counters["particle-steps/s"] = benchmark::Counter(n * steps, benchmark::Counter::kIsRate);
  state.counters["kB/substep/rank"] = mean / 1e3;
  state.counters["kB/substep max"] = bytes[1] / 1e3;
  state.counters["halo kB/substep/rank"] = bytes[2] / mpi.size() / 1e3;
}

void BM_Strong(benchmark::State& state) {
  run(state, false);
}
void BM_Weak(benchmark::State& state) {
  run(state, true);
}

BENCHMARK(BM_Strong)->Arg(64)->Arg(100)->Iterations(20)->UseManualTime()->Unit(
    benchmark::kMillisecond);
BENCHMARK(BM_Weak)->Arg(64)->Iterations(20)->UseManualTime()->Unit(benchmark::kMillisecond);

/// Ranks other than 0 report nothing.
class Silent : public benchmark::BenchmarkReporter {
 public:
  bool ReportContext(const Context&) override { return true; }
  void ReportRuns(const std::vector<Run>&) override {}
};

}  // namespace

int main(int argc, char** argv) {
  slurry::mpi::Session mpi(argc, argv);
  g_mpi = &mpi;
  benchmark::Initialize(&argc, argv);
  if (mpi.rank() == 0) {
    benchmark::RunSpecifiedBenchmarks();
  } else {
    Silent silent;
    benchmark::RunSpecifiedBenchmarks(&silent);
  }
  benchmark::Shutdown();
  return 0;
}
