// Throughput of the co-rotated linear FEM step (fem/corotated_fem.h) on a clamped 3D beam
// meshed with five tetrahedra per cell (cells: 10 n x n x n), double precision: symplectic
// Euler at 0.9 of its stability limit, and the linearly implicit step (warped stiffness, PCG
// with IC(0) to 1e-8) at 0.005 s, about 100 times that limit. Counters: element-steps/s,
// simulated seconds per wall second, PCG iterations per implicit step.
//
//   build/release/bin/bench_fem --benchmark_counters_tabular=true
// Arguments: elements across the beam n, threads.
#include <benchmark/benchmark.h>

#include "slurry/engine/fem/corotated_fem.h"
#include "slurry/transfer/parallel.h"

namespace {

using Fem = slurry::fem::CorotatedFem<double, 3>;

struct Clamp {
  std::vector<char> held;
  bool pin(int i, const Eigen::Vector3d&, Eigen::Vector3d& vb) const {
    vb.setZero();
    return held[std::size_t(i)] != 0;
  }
  void apply(int i, const Eigen::Vector3d&, Eigen::Vector3d& v) const {
    if (held[std::size_t(i)]) v.setZero();
  }
};

Fem beam(int n, Clamp& clamp) {
  const auto mesh = slurry::fem::box_mesh<3>(Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0.1, 0.1), Eigen::Vector3i(10 * n, n, n));
  Fem fem(mesh, slurry::fem::FemMaterial<double>::from_young(1e7, 0.3, 1000));
  clamp.held.resize(fem.vertex_count());
  for (std::size_t i = 0; i < fem.vertex_count(); ++i) clamp.held[i] = fem.rest()[i][0] < 1e-12;
  return fem;
}

void BM_FemExplicit(benchmark::State& state) {
  slurry::parallel::ThreadLimit threads(int(state.range(1)));
  Clamp clamp;
  Fem fem = beam(int(state.range(0)), clamp);
  const double dt = fem.explicit_dt(0.9);
  const Eigen::Vector3d g(0, -9.81, 0);
  for (auto _ : state) fem.step_symplectic(dt, g, clamp);
  const double ne = double(fem.element_count());
  state.counters["elements"] = ne;
  state.counters["element-steps/s"] = benchmark::Counter(ne * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["sim-s/s"] = benchmark::Counter(dt * double(state.iterations()), benchmark::Counter::kIsRate);
}

void BM_FemImplicit(benchmark::State& state) {
  slurry::parallel::ThreadLimit threads(int(state.range(1)));
  Clamp clamp;
  Fem fem = beam(int(state.range(0)), clamp);
  const double dt = 0.005;
  const Eigen::Vector3d g(0, -9.81, 0);
  double iterations = 0;
  for (auto _ : state) iterations += fem.step_implicit(dt, g, clamp).iterations;
  const double ne = double(fem.element_count());
  state.counters["elements"] = ne;
  state.counters["element-steps/s"] = benchmark::Counter(ne * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["sim-s/s"] = benchmark::Counter(dt * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["pcg-iterations"] = iterations / double(state.iterations());
  state.counters["dt/explicit-limit"] = dt / fem.explicit_dt(1.0);
}

void Args(benchmark::internal::Benchmark* b) {
  for (int n : {4, 8})
    for (int t : {1, 2}) b->Args({n, t});
  b->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
}

BENCHMARK(BM_FemExplicit)->Apply(Args);
BENCHMARK(BM_FemImplicit)->Apply(Args);

}  // namespace

BENCHMARK_MAIN();
