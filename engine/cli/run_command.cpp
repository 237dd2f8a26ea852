// `slurry run` (run_command.h): options, the progress log, the pipeline outputs beside each
// frame, SIGINT / SIGTERM, the summary.
#include "run_command.h"

#include <unistd.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <thread>

#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"
#include "slurry/transfer/parallel.h"
#ifdef SLURRY_WITH_OPENVDB
#include "pipeline.h"
#endif
#ifdef SLURRY_WITH_MPI
#include "slurry/mpi/mpi.h"
#endif

namespace slurry::cli {
namespace {

/// Whether the scene asks for effects-pipeline outputs (output.surface or output.vdb_points).
bool wants_pipeline_outputs(const Scene& scene) {
  return !scene.output.surface.empty() || scene.output.vdb_points;
}

/// A one-line progress bar on a terminal; plain log lines otherwise (CI logs, pipes).
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(fileno(stderr)) != 0) {}
  void operator()(const FrameReport& r) {
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

volatile std::sig_atomic_t g_stop = 0;

/// The first SIGINT or SIGTERM asks the run to stop after the frame it is on; the handler is
/// reset, so a second one ends the process at once (its temporary file is removed by the next run).
void on_signal(int sig) { g_stop = sig; }

void install_signal_handlers() {
  struct sigaction sa {};
  sa.sa_handler = on_signal;
  sa.sa_flags = SA_RESETHAND;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

void print_summary(const RunSummary& s) {
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
}

}  // namespace

void NumberOptions::parse(const CLI::App& app, RunRequest& r) const {
  if (app.count("--frames")) r.frames = int(parse_integer("--frames", frames, 0, INT_MAX));
  if (app.count("--threads"))
    r.threads = int(parse_integer("--threads", threads, 0, parallel::max_thread_count()));
  if (app.count("--memory-limit")) r.memory_gb = parse_positive("--memory-limit", memory);
}

void RunCommand::add(CLI::App& parent) {
  app = parent.add_subcommand("run", "Run a scene and write its PLY frames");
  app->add_option("scene", request.scene_path, "Scene file (JSON)")->required();
  out_option = app->add_option("--out,-o", request.out_dir, "Output directory (replaces output.directory)");
  app->add_option("--frames,-f", numbers.frames, "Frames to simulate after frame 0 (replaces output.frames)");
  app->add_option("--threads,-t", numbers.threads, "Worker threads (0 = all cores; at most 4 x the hardware threads)");
  app->add_option("--memory-limit", numbers.memory, "Memory limit in GiB (replaces limits.memory_gb; default: the machine's memory)");
  app->add_flag("--overwrite", request.overwrite, "Remove another scene's frames from the output directory");
  app->add_flag("--ascii", request.ascii, "Write ASCII PLY instead of binary");
  app->add_flag("--quiet,-q", request.quiet, "No progress output");
  app->add_flag("--resume", request.resume, "Continue from the newest valid checkpoint in the output directory");
  app->add_flag("--force", request.force, "With --resume: accept checkpoints written for another version of the scene file");
}

void RunCommand::check() {
  numbers.parse(*app, request);
  if (out_option->count() && request.out_dir.empty()) throw UsageError("--out: expected a non-empty directory path, got \"\"");
  if (request.force && !request.resume) throw UsageError("--force: only with --resume");
  if (request.resume && request.overwrite)
    throw UsageError("--resume and --overwrite: expected one of them (--overwrite starts afresh)");
}

int run_request(const Process& process, RunRequest q) {
  const int rank = process.rank, ranks = process.ranks;
  // The log, the summary and the pipeline outputs are rank 0's.
  if (rank != 0) q.quiet = true;
  // What an out-of-memory error names: the scene, or the directory resumed until its scene is known.
  if (q.scene_path.empty()) q.scene_path = q.resume_dir;
  return with_exit_codes(process, q.scene_path, [&]() -> int {
    if (!q.resume_dir.empty()) {
      q.scene_path = checkpoint_scene(q.resume_dir).string();
      q.out_dir = q.resume_dir;
      q.resume = true;
    }
    const Scene scene = load_scene(q.scene_path);
    RunOptions opt;
    if (!q.out_dir.empty()) opt.directory = q.out_dir;
    if (q.frames >= 0) opt.frames = q.frames;
    if (q.ascii) opt.format = PlyEncoding::Ascii;
    int threads = q.threads;
#ifdef SLURRY_WITH_MPI
    // The machine's cores shared among the ranks on it (one thread each for mpirun -np 2 here).
    if (process.mpi && threads == 0)
      threads = std::max(1, int(std::max(1u, std::thread::hardware_concurrency())) / process.mpi->local_size());
    opt.communicator = process.mpi;
#endif
    opt.threads = threads;
    opt.memory_gb = q.memory_gb;
    opt.overwrite = q.overwrite;
    opt.resume = q.resume;
    opt.force = q.force;
    opt.stop = &g_stop;
    if (rank == 0) opt.notice = [](const std::string& line) { std::fprintf(stderr, "slurry: %s\n", line.c_str()); };
    const std::string& scene_path = q.scene_path;
    if (!q.quiet && scene.solver.type == SolverType::FEM)
      std::fprintf(stderr, "slurry: %s (%dD %s, fem, %s), %s backend, %d threads\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == Precision::Float ? "float" : "double",
                   std::string(to_string(scene.solver.integrator)).c_str(), parallel::backend(),
                   threads > 0 ? threads : parallel::max_threads());
    else if (!q.quiet)
      std::fprintf(stderr, "slurry: %s (%dD %s, %s, %s kernel), %s backend, %d threads%s\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == Precision::Float ? "float" : "double",
                   std::string(to_string(scene.solver.transfer)).c_str(),
                   std::string(to_string(scene.solver.kernel)).c_str(), parallel::backend(),
                   threads > 0 ? threads : parallel::max_threads(),
                   ranks > 1 ? (" per process, " + std::to_string(ranks) + " MPI processes").c_str() : "");
#ifdef SLURRY_WITH_OPENVDB
    // The module (and OpenVDB) is loaded only for a scene that asks for its outputs, and only by
    // rank 0, which writes them.
    const FrameOutputFn pipeline =
        rank == 0 && wants_pipeline_outputs(scene) ? pipeline_module().frame_output_writer(scene) : FrameOutputFn();
#else
    if (wants_pipeline_outputs(scene))
      throw SceneError(scene_path + ": " + (scene.output.vdb_points ? "output.vdb_points" : "output.surface") +
                       ": this slurry was built without OpenVDB (SLURRY_WITH_OPENVDB=OFF); expected no pipeline outputs");
#endif
    install_signal_handlers();
    Progress progress(q.quiet);
    const auto on_frame = [&](const FrameReport& r) {
#ifdef SLURRY_WITH_OPENVDB
      if (pipeline) {  // rank 0's: a split run's rank 0 holds every particle of the frame (mpm_solver.h)
        const std::string line = pipeline(r);
        if (!q.quiet && !line.empty() && !isatty(fileno(stderr))) std::fprintf(stderr, "frame %d: %s\n", r.frame, line.c_str());
      }
#endif
      progress(r);
    };
    const auto s = run_scene(scene, opt, on_frame);
    if (s.interrupted) {
      if (rank != 0) return 128 + s.interrupted;
      std::fprintf(stderr, "\nslurry: stopped by %s after frame %d (frames 0-%d are complete%s)\n",
                   s.interrupted == SIGINT ? "SIGINT" : "SIGTERM", s.frames_written - 1, s.frames_written - 1,
                   s.checkpoints_written > 0 ? "; continue with slurry run SCENE --resume" : "");
      print_summary(s);
      return 128 + s.interrupted;
    }
    if (rank == 0) print_summary(s);
    return 0;
  });
}

}  // namespace slurry::cli
