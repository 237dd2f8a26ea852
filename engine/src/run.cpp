#include "slurry/engine/run.h"

#include <chrono>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>

#include "slurry/engine/ply.h"
#include "slurry/engine/simulation.h"
#include "slurry/transfer/parallel.h"

namespace slurry {

std::filesystem::path frame_file(const std::filesystem::path& directory, int frame) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%04d.ply", frame);
  return directory / name;
}

RunSummary run_scene(const Scene& scene, const RunOptions& options,
                     const std::function<void(const FrameReport&)>& on_frame) {
  using Clock = std::chrono::steady_clock;
  const auto seconds_since = [](Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
  };
  scene.validate();
  const std::filesystem::path dir = options.directory.value_or(scene.output.directory);
  const int frames = options.frames.value_or(scene.output.frames);
  if (frames < 0) throw SceneError(scene.source + ": frames: expected an integer >= 0, got " + std::to_string(frames));
  const io::PlyFormat format = options.format.value_or(scene.output.format) == PlyEncoding::Ascii
                                   ? io::PlyFormat::Ascii
                                   : io::PlyFormat::BinaryLittleEndian;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw IoError(dir.string() + ": cannot create the output directory: " + ec.message());

  parallel::ThreadLimit limit(options.threads);
  const auto start = Clock::now();
  auto sim = make_simulation(scene);
  std::ofstream csv(dir / "stats.csv");
  if (!csv) throw IoError((dir / "stats.csv").string() + ": cannot write the run statistics");
  csv << stats_csv_header() << '\n';
  DriftTolerances tol;
  tol.mass = scene.output.mass_drift;
  tol.volume = scene.output.volume_drift;
  tol.energy = scene.output.energy_growth;
  tol.check_energy = scene.emitters.empty();
  for (const auto& c : scene.colliders) tol.check_energy = tol.check_energy && c.velocity.isZero();
  double energy_scale = 0;
  RunSummary summary;
  summary.directory = dir;
  summary.particles = sim->particle_count();
  double sim_seconds = 0, particle_steps = 0;

  for (int f = 0; f <= frames; ++f) {
    const auto t0 = Clock::now();
    std::int64_t substeps = 0;
    if (f > 0) {
      substeps = sim->advance_to(f * scene.frame_dt());
      sim_seconds += seconds_since(t0);
      particle_steps += double(sim->particle_count()) * double(substeps);  // emitters add particles
    }
    const auto file = frame_file(dir, f);
    io::write_ply(file, sim->frame(scene.output.attributes), format);
    RunStats stats = sim->take_stats();
    stats.frame = f;
    stats.substeps = substeps;
    std::vector<std::string> warnings;
    if (f == 0) {
      summary.first = stats;
      // The energy the scene can release: its kinetic energy plus its mass falling the
      // domain's extent along gravity.
      const Eigen::Vector3d g = scene.solver.gravity;
      double H = 0;
      const int dim = scene.solver.dimension;
      if (g.head(dim).norm() > 0)
        for (int d = 0; d < dim; ++d) H += std::abs(scene.domain.max[d] - scene.domain.min[d]) * std::abs(g[d]) / g.head(dim).norm();
      energy_scale = stats.kinetic + stats.mass * g.head(dim).norm() * H;
    } else {
      warnings = drift_warnings(summary.first, stats, tol, energy_scale);
      summary.drift_warnings += !warnings.empty();
    }
    summary.last = stats;
    summary.largest_cfl = std::max(summary.largest_cfl, stats.cfl);
    csv << stats_csv_row(stats) << '\n';
    csv.flush();
    summary.frames_written = f + 1;
    summary.substeps += substeps;
    if (on_frame) {
      FrameReport r;
      r.frame = f;
      r.frames = frames;
      r.substeps = substeps;
      r.seconds = seconds_since(t0);
      r.elapsed = seconds_since(start);
      r.particles = sim->particle_count();
      r.file = file;
      r.solver = sim->solver_status();
      r.stats = stats;
      r.warnings = std::move(warnings);
      on_frame(r);
    }
  }
  summary.wall_seconds = seconds_since(start);
  summary.bytes = sim->bytes();
  summary.particles = sim->particle_count();
  if (sim_seconds > 0) summary.particle_steps_per_second = particle_steps / sim_seconds;
  return summary;
}

}  // namespace slurry
