// Surfacing against simulating, on the 3D FLIP dam break (examples/scenes/flip_dam_break_3d.json,
// ~875 k particles, dx 0.02 m, 8 particles per cell):
//
//   OMP_WAIT_POLICY=passive build/release/bin/bench_surface --benchmark_counters_tabular=true
//       --benchmark_repetitions=3 --benchmark_enable_random_interleaving=true
//
//   BM_Surface/<method>/<threads>: surface_particles (slurry/io/surface.h) of the frame at
//     t = SLURRY_SURFACE_FRAME / 60 s (default frame 30, the column collapsing against the wall)
//     at the simulation's dx: level set, mesh, vertex velocities and the velocity grid. method 0:
//     anisotropic (the default), 1: spheres. Counters: seconds, particles per second, vertices.
//   BM_SurfaceMesh/<threads>: surface_mesh with the anisotropic method, what a scene whose
//     output.surface has no "vdb" asks for: the mesh and its vertex velocities, no level set.
//   BM_SimulateFrame/<threads>: advancing the same simulation by one frame (1/60 s) from there.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <memory>

#include "slurry/io/pipeline.h"
#include "slurry/slurry.h"
#include "slurry/transfer/parallel.h"

namespace {

int start_frame() {
  const char* e = std::getenv("SLURRY_SURFACE_FRAME");
  return e ? std::atoi(e) : 30;
}

struct DamBreak {
  slurry::Scene scene = slurry::load_scene(SLURRY_EXAMPLES_DIR "/flip_dam_break_3d.json");
  std::unique_ptr<slurry::Solver> sim = slurry::make_simulation(scene);
  slurry::io::FrameOutputs outputs = slurry::io::frame_outputs(scene);
  slurry::io::PointCloud cloud;
  DamBreak() {
    const slurry::parallel::ThreadLimit limit(2);
    sim->advance_to(start_frame() / scene.output.fps);
    cloud = slurry::io::point_cloud(sim->frame({"position", "velocity"}));
  }
};

DamBreak& dam_break() {
  static DamBreak d;
  return d;
}

/// Times `surface` (a function of the cloud) on `threads` threads, with the counters.
template <class Surface>
void time_surfacing(benchmark::State& state, int threads, Surface&& surface) {
  DamBreak& d = dam_break();
  std::size_t vertices = 0;
  slurry::io::with_threads(threads, [&] {
    for (auto _ : state) {
      vertices = surface(d.cloud).mesh.vertices.size();
      benchmark::DoNotOptimize(vertices);
    }
  });
  state.counters["particles/s"] =
      benchmark::Counter(double(d.cloud.size()) * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["particles"] = double(d.cloud.size());
  state.counters["vertices"] = double(vertices);
}

void BM_Surface(benchmark::State& state) {
  slurry::io::SurfaceParams params = dam_break().outputs.params;
  params.method = state.range(0) == 0 ? slurry::io::SurfaceMethod::Anisotropic : slurry::io::SurfaceMethod::Spheres;
  time_surfacing(state, int(state.range(1)),
                 [&](const slurry::io::PointCloud& c) { return slurry::io::surface_particles(c, params); });
}
BENCHMARK(BM_Surface)->ArgsProduct({{0, 1}, {2}})->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SurfaceMesh(benchmark::State& state) {
  const slurry::io::SurfaceParams params = dam_break().outputs.params;
  time_surfacing(state, int(state.range(0)),
                 [&](const slurry::io::PointCloud& c) { return slurry::io::surface_mesh(c, params); });
}
BENCHMARK(BM_SurfaceMesh)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_SimulateFrame(benchmark::State& state) {
  DamBreak& d = dam_break();
  const slurry::parallel::ThreadLimit limit(int(state.range(0)));
  for (auto _ : state) d.sim->advance_to(d.sim->time() + 1.0 / d.scene.output.fps);
  state.counters["particles"] = double(d.sim->particle_count());
}
BENCHMARK(BM_SimulateFrame)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(1);

}  // namespace

BENCHMARK_MAIN();
