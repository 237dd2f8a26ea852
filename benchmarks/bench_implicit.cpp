// A stiff body (E = 1e7 Pa, rho = 1000 kg/m^3, nu = 0.3: P-wave speed 116 m/s) dropped from 0.1 m
// onto the floor and simulated for one second of simulated time, explicit (substep at the
// elastic limit 0.5 dx / c) against the linearly implicit grid update (substep max_dt, or the
// CFL limit). Counters: substeps, total and mean CG iterations per substep, particle-steps/s;
// the benchmark's own time is the wall time of the whole second.
//
//   build/release/bin/bench_implicit --benchmark_counters_tabular=true
// Arguments: dimension, integrator (0 explicit, 1 implicit), max_dt in units of 1e-4 s,
// CG tolerance exponent (tolerance 10^-k), threads, preconditioner (0 Jacobi, 1 block Jacobi,
// 2 IC(0)).
#include <benchmark/benchmark.h>

#include <cmath>

#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/transfer/parallel.h"

namespace {

slurry::Scene stiff_body(int dim, bool implicit, double max_dt, double tolerance,
                         slurry::ImplicitPreconditioner pre = slurry::ImplicitPreconditioner::IC0) {
  slurry::Scene s;
  s.source = "bench_implicit";
  s.solver.dimension = dim;
  s.solver.precision = slurry::Precision::Double;
  s.solver.transfer = slurry::TransferKind::MLS;
  s.solver.kernel = slurry::KernelKind::Quadratic;
  s.solver.integrator = implicit ? slurry::Integrator::Implicit : slurry::Integrator::Explicit;
  s.solver.max_dt = max_dt;
  s.solver.cg_tolerance = tolerance;
  s.solver.implicit_preconditioner = pre;
  s.domain.min = {0, 0, 0};
  s.domain.max = {1, 0.5, 0.5};
  s.domain.dx = dim == 2 ? 1.0 / 64 : 1.0 / 32;
  slurry::MaterialParams m;
  m.name = "stiff";
  m.model = slurry::ElasticModel::FixedCorotated;
  m.density = 1000;
  m.E = 1e7;
  m.nu = 0.3;
  s.materials = {m};
  slurry::BodyParams b;
  b.min = {0.35, 0.15, 0.175};
  b.max = {0.65, 0.30, 0.325};
  b.material = "stiff";
  b.particles_per_cell = dim == 2 ? 4 : 8;
  s.bodies = {b};
  s.boundaries.walls = slurry::Condition::Separate;
  s.boundaries.friction = 0.3;
  return s;
}

void BM_StiffBodyOneSecond(benchmark::State& state) {
  const int dim = int(state.range(0));
  const bool implicit = state.range(1) != 0;
  const double max_dt = 1e-4 * double(state.range(2));
  const double tolerance = std::pow(10.0, -double(state.range(3)));
  slurry::parallel::ThreadLimit threads(int(state.range(4)));
  const auto pre = slurry::ImplicitPreconditioner(state.range(5));
  const slurry::Scene scene = stiff_body(dim, implicit, max_dt, tolerance, pre);
  std::int64_t substeps = 0, cg = 0, unconverged = 0;
  double particles = 0;
  for (auto _ : state) {
    auto run = [&](auto sim) {
      substeps += sim.advance_to(1.0);
      cg += sim.cg_stats().iterations;
      unconverged += sim.cg_stats().unconverged;
      particles = double(sim.particle_count());
    };
    if (dim == 2)
      run(slurry::MpmSolver<double, 2>(scene));
    else
      run(slurry::MpmSolver<double, 3>(scene));
  }
  const double runs = double(state.iterations());
  state.counters["particles"] = particles;
  state.counters["substeps"] = double(substeps) / runs;
  state.counters["cg_total"] = double(cg) / runs;
  state.counters["cg_mean"] = substeps > 0 ? double(cg) / double(substeps) : 0.0;
  state.counters["cg_unconverged"] = double(unconverged) / runs;
  state.counters["particle-steps/s"] = benchmark::Counter(particles * double(substeps), benchmark::Counter::kIsRate);
}

void Args(benchmark::internal::Benchmark* b) {
  // {dimension, implicit, max_dt / 1e-4 s, -log10 tolerance, threads, preconditioner}
  for (int dim : {2, 3}) {
    b->Args({dim, 0, 10, 6, 1, 2});
    for (int pre : {0, 1, 2})
      for (int dt : {20, 40, 80, 160}) b->Args({dim, 1, dt, 6, 1, pre});
    b->Args({dim, 1, 40, 4, 1, 2});
  }
  b->Unit(benchmark::kSecond)->UseRealTime()->Iterations(1);
}

BENCHMARK(BM_StiffBodyOneSecond)->Apply(Args);

}  // namespace

BENCHMARK_MAIN();
