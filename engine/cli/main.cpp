// slurry: run or check a scene file.
//
//   slurry run SCENE.json [--out DIR] [--frames N] [--threads N] [--ascii] [--quiet]
//   slurry validate SCENE.json
//
// Exit codes: 0 success, 1 the simulation became unstable, 2 invalid scene or usage, 3 I/O error.
#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <string>
#include <unistd.h>

#include "slurry/engine/run.h"
#include "slurry/engine/scene.h"
#include "slurry/transfer/parallel.h"

namespace {

std::string human_seconds(double s) {
  char buf[32];
  if (s < 60)
    std::snprintf(buf, sizeof buf, "%.1f s", s);
  else if (s < 3600)
    std::snprintf(buf, sizeof buf, "%dm%02ds", int(s) / 60, int(s) % 60);
  else
    std::snprintf(buf, sizeof buf, "%dh%02dm", int(s) / 3600, (int(s) % 3600) / 60);
  return buf;
}

/// A one-line progress bar on a terminal; plain log lines otherwise (CI logs, pipes).
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(fileno(stderr)) != 0) {}
  void operator()(const slurry::FrameReport& r) {
    // Drift warnings are printed even with --quiet: they say the result is not to be trusted.
    for (const auto& w : r.warnings) std::fprintf(stderr, "%sslurry: warning: %s\n", tty_ ? "\n" : "", w.c_str());
    if (quiet_) return;
    const int done = r.frame, total = r.frames;
    const double per_frame = done > 0 ? (r.elapsed - first_) / done : 0;
    if (done == 0) first_ = r.elapsed;
    const double eta = per_frame * (total - done);
    if (tty_) {
      const int width = 30;
      const int filled = total > 0 ? width * done / total : width;
      std::string bar(std::size_t(filled), '#');
      bar.resize(width, '.');
      std::fprintf(stderr, "\r[%s] frame %d/%d  substeps %lld  particles %zu  %.2f s/frame  ETA %s   ",
                   bar.c_str(), done, total, static_cast<long long>(r.substeps), r.particles, per_frame,
                   human_seconds(eta).c_str());
      if (done == total) std::fputc('\n', stderr);
    } else {
      std::fprintf(stderr, "frame %d/%d: %lld substeps, %zu particles, %.3f s, wrote %s%s%s\n", done, total,
                   static_cast<long long>(r.substeps), r.particles, r.seconds, r.file.string().c_str(),
                   r.solver.empty() ? "" : "; ", r.solver.c_str());
    }
    std::fflush(stderr);
  }

 private:
  bool quiet_, tty_;
  double first_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"slurry: hybrid particle-grid simulation (MPM solids and liquids)"};
  app.require_subcommand(1);

  std::string scene_path, out_dir;
  int frames = -1, threads = 0;
  bool ascii = false, quiet = false;
  auto* run = app.add_subcommand("run", "Run a scene and write its PLY frames");
  run->add_option("scene", scene_path, "Scene file (JSON)")->required();
  run->add_option("--out,-o", out_dir, "Output directory (replaces output.directory)");
  run->add_option("--frames,-f", frames, "Frames to simulate after frame 0 (replaces output.frames)")
      ->check(CLI::NonNegativeNumber);
  run->add_option("--threads,-t", threads, "Worker threads (0 = all cores)")->check(CLI::NonNegativeNumber);
  run->add_flag("--ascii", ascii, "Write ASCII PLY instead of binary");
  run->add_flag("--quiet,-q", quiet, "No progress output");

  auto* validate = app.add_subcommand("validate", "Check a scene file and exit");
  validate->add_option("scene", scene_path, "Scene file (JSON)")->required();

  CLI11_PARSE(app, argc, argv);

  try {
    const slurry::Scene scene = slurry::load_scene(scene_path);
    if (validate->parsed()) {
      std::printf("%s: valid (%dD, %zu materials, %zu bodies)\n", scene_path.c_str(), scene.solver.dimension,
                  scene.materials.size(), scene.bodies.size());
      return 0;
    }
    slurry::RunOptions opt;
    if (!out_dir.empty()) opt.directory = out_dir;
    if (frames >= 0) opt.frames = frames;
    if (ascii) opt.format = slurry::PlyEncoding::Ascii;
    opt.threads = threads;
    if (!quiet && scene.solver.type == slurry::SolverType::FEM)
      std::fprintf(stderr, "slurry: %s (%dD %s, fem, %s), %s backend, %d threads\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == slurry::Precision::Float ? "float" : "double",
                   std::string(slurry::to_string(scene.solver.integrator)).c_str(), slurry::parallel::backend(),
                   threads > 0 ? threads : slurry::parallel::max_threads());
    else if (!quiet)
      std::fprintf(stderr, "slurry: %s (%dD %s, %s, %s kernel), %s backend, %d threads\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == slurry::Precision::Float ? "float" : "double",
                   std::string(slurry::to_string(scene.solver.transfer)).c_str(),
                   std::string(slurry::to_string(scene.solver.kernel)).c_str(), slurry::parallel::backend(),
                   threads > 0 ? threads : slurry::parallel::max_threads());
    Progress progress(quiet);
    const auto s = slurry::run_scene(scene, opt, std::ref(progress));
    std::printf(
        "done: %d frames in %s (%s), %lld substeps, %zu particles, %.3g particle-steps/s, "
        "%.0f bytes/particle\n",
        s.frames_written, s.directory.string().c_str(), human_seconds(s.wall_seconds).c_str(),
        static_cast<long long>(s.substeps), s.particles, s.particle_steps_per_second,
        s.particles ? double(s.bytes) / double(s.particles) : 0.0);
    const auto rel = [](double now, double first) { return first != 0 ? 100 * (now - first) / std::abs(first) : 0.0; };
    std::printf(
        "stats: mass %+.3g%%, volume %+.3g%%, energy %.4g -> %.4g J, |momentum| %.4g kg m/s, largest CFL %.3g, "
        "%d frames with drift warnings (per frame: %s)\n",
        rel(s.last.mass, s.first.mass), rel(s.last.volume, s.first.volume), s.first.energy(), s.last.energy(),
        s.last.momentum.norm(), s.largest_cfl, s.drift_warnings, (s.directory / "stats.csv").string().c_str());
    return 0;
  } catch (const slurry::SimulationError& e) {
    std::fprintf(stderr, "\nslurry: error: %s\n", e.what());
    return 1;
  } catch (const slurry::SceneError& e) {
    std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 2;
  } catch (const slurry::IoError& e) {
    std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 3;
  }
}
