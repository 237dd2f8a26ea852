// slurry: run or check a scene file.
//
//   slurry run SCENE.json [--out DIR] [--frames N] [--threads N] [--memory-limit GB] [--overwrite] [--ascii] [--quiet]
//                         [--resume [--force]]
//   slurry resume DIR [--frames N] [--threads N] [--memory-limit GB] [--ascii] [--quiet] [--force]
//   slurry validate SCENE.json [--memory-limit GB]
//   slurry surface DIR [--scene S] [--voxel-size H] [--spacing S] [--smoothing N] [--formats vdb,ply,obj] [--points]
//                      (built with slurry::io, SLURRY_WITH_OPENVDB=ON)
//   mpirun -np N slurry run SCENE.json ...   (built with slurry::mpi, SLURRY_BUILD_MPI=ON): the MPM
//                      domain split over N processes; rank 0 writes the frames and prints the log
//                      (with output.per_rank each process writes frame_NNNN.rankR.ply instead)
//   slurry merge DIR [--keep-parts]   joins per-rank frames into frame_NNNN.ply
//
// Exit codes: 0 success, 1 the simulation became unstable, 2 invalid scene or usage, 3 file or
// resource error, 130 / 143 stopped by SIGINT / SIGTERM after the last complete frame.
#include <CLI/CLI.hpp>
#include <charconv>
#include <chrono>
#include <climits>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <unistd.h>

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

namespace {

/// Whether the scene asks for effects-pipeline outputs (output.surface or output.vdb_points).
bool wants_pipeline_outputs(const slurry::Scene& scene) {
  return !scene.output.surface.empty() || scene.output.vdb_points;
}

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

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// A command-line integer in [lo, hi], or a UsageError naming the option and the range.
long long parse_integer(const std::string& option, const std::string& text, long long lo, long long hi) {
  long long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < lo || v > hi)
    throw UsageError(option + ": expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got \"" +
                     text + "\"");
  return v;
}

double parse_positive(const std::string& option, const std::string& text) {
  std::size_t end = 0;
  double v = 0;
  try {
    v = std::stod(text, &end);
  } catch (const std::exception&) {
    end = 0;
  }
  if (end == 0 || end != text.size() || !(v > 0) || !std::isfinite(v))
    throw UsageError(option + ": expected a number > 0, got \"" + text + "\"");
  return v;
}

void print_summary(const slurry::RunSummary& s) {
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

int main(int argc, char** argv) {
  // Started by mpirun (or another MPI launcher): MPI first, since it may take its own arguments.
  int rank = 0, ranks = 1;
#ifdef SLURRY_WITH_MPI
  std::unique_ptr<slurry::mpi::Session> mpi;
  if (slurry::mpi::launched()) {
    try {
      mpi = std::make_unique<slurry::mpi::Session>(argc, argv);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "slurry: error: %s\n", e.what());
      return 3;
    }
    rank = mpi->rank();
    ranks = mpi->size();
  }
#else
  if (const char* n = std::getenv("OMPI_COMM_WORLD_SIZE"); n && std::atoi(n) > 1) {
    std::fprintf(stderr, "slurry: error: started by mpirun with %s processes, but this slurry was built without MPI "
                 "(SLURRY_BUILD_MPI=OFF); expected one process, or a build with slurry::mpi\n", n);
    return 2;
  }
#endif
  CLI::App app{"slurry: hybrid particle-grid simulation (MPM solids and liquids)"};
  app.require_subcommand(1);

  std::string scene_path, out_dir, frames_text, threads_text, memory_text;
  bool ascii = false, quiet = false, overwrite = false, resume = false, force = false;
  auto* run = app.add_subcommand("run", "Run a scene and write its PLY frames");
  run->add_option("scene", scene_path, "Scene file (JSON)")->required();
  auto* out_option = run->add_option("--out,-o", out_dir, "Output directory (replaces output.directory)");
  run->add_option("--frames,-f", frames_text, "Frames to simulate after frame 0 (replaces output.frames)");
  run->add_option("--threads,-t", threads_text, "Worker threads (0 = all cores; at most 4 x the hardware threads)");
  run->add_option("--memory-limit", memory_text, "Memory limit in GiB (replaces limits.memory_gb; default: the machine's memory)");
  run->add_flag("--overwrite", overwrite, "Remove another scene's frames from the output directory");
  run->add_flag("--ascii", ascii, "Write ASCII PLY instead of binary");
  run->add_flag("--quiet,-q", quiet, "No progress output");
  run->add_flag("--resume", resume, "Continue from the newest valid checkpoint in the output directory");
  run->add_flag("--force", force, "With --resume: accept checkpoints written for another version of the scene file");

  std::string resume_dir;
  auto* resume_cmd = app.add_subcommand("resume", "Continue the run whose checkpoints are in DIR (its scene file is read again)");
  resume_cmd->add_option("directory", resume_dir, "Output directory holding checkpoint_NNNN.slc files")->required();
  resume_cmd->add_option("--frames,-f", frames_text, "Last frame of the run (replaces output.frames)");
  resume_cmd->add_option("--threads,-t", threads_text, "Worker threads (0 = all cores)");
  resume_cmd->add_option("--memory-limit", memory_text, "Memory limit in GiB (replaces limits.memory_gb)");
  resume_cmd->add_flag("--ascii", ascii, "Write ASCII PLY instead of binary");
  resume_cmd->add_flag("--quiet,-q", quiet, "No progress output");
  resume_cmd->add_flag("--force", force, "Accept checkpoints written for another version of the scene file");

  std::string merge_dir;
  bool keep_parts = false;
  auto* merge = app.add_subcommand(
      "merge", "Join the per-rank frames of a run split over MPI processes (output.per_rank: frame_NNNN.rankR.ply) "
               "into frame_NNNN.ply, the frames one process writes");
  merge->add_option("directory", merge_dir, "Output directory holding frame_NNNN.rankR.ply files")->required();
  merge->add_flag("--keep-parts", keep_parts, "Keep the per-rank files (default: removed once merged)");

  auto* validate = app.add_subcommand("validate", "Check a scene file, its meshes and its resources, and exit");
  validate->add_option("scene", scene_path, "Scene file (JSON)")->required();
  validate->add_option("--memory-limit", memory_text, "Memory limit in GiB (replaces limits.memory_gb)");

#ifdef SLURRY_WITH_OPENVDB
  slurry::cli::SurfaceCommand surface;
  slurry::cli::add_surface_command(app, surface);
#endif

  int frames = -1, threads = 0;
  double memory_gb = 0;
  try {
    app.parse(argc, argv);
    const int hardware = int(std::max(1u, std::thread::hardware_concurrency()));
    if (!frames_text.empty() || run->count("--frames") || resume_cmd->count("--frames"))
      frames = int(parse_integer("--frames", frames_text, 0, INT_MAX));
    if (run->count("--threads") || resume_cmd->count("--threads"))
      threads = int(parse_integer("--threads", threads_text, 0, 4 * hardware));
    if (run->count("--memory-limit") || validate->count("--memory-limit") || resume_cmd->count("--memory-limit"))
      memory_gb = parse_positive("--memory-limit", memory_text);
    if (out_option->count() && out_dir.empty()) throw UsageError("--out: expected a non-empty directory path, got \"\"");
    if (force && run->parsed() && !resume) throw UsageError("--force: only with --resume");
    if (resume && overwrite) throw UsageError("--resume and --overwrite: expected one of them (--overwrite starts afresh)");
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return rank == 0 ? app.exit(e) : 0;  // --help
    if (rank == 0) std::fprintf(stderr, "slurry: error: %s (usage: slurry --help)\n", e.what());
    return 2;
  } catch (const UsageError& e) {
    if (rank == 0) std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 2;
  }
  // The log, the summary and the pipeline outputs are rank 0's; every rank reports an error
  // that only it met (a file it could not read), and such an error ends the whole job.
  if (rank != 0) quiet = true;
  const auto report = [&](bool collective, int code, const char* what) {
    if (rank == 0 || !collective)
      std::fprintf(stderr, "%sslurry: error: %s%s\n", code == 1 ? "\n" : "",
                   ranks > 1 ? ("[rank " + std::to_string(rank) + "] ").c_str() : "", what);
#ifdef SLURRY_WITH_MPI
    if (!collective && ranks > 1) mpi->abort(code);
#else
    (void)collective;
#endif
    return code;
  };

#ifdef SLURRY_WITH_OPENVDB
  if (surface.app->parsed()) {
    try {
      return slurry::cli::pipeline_module().run_surface_command(surface);
    } catch (const slurry::IoError& e) {
      return report(false, 3, e.what());
    }
  }
#endif

  if (merge->parsed()) {
    if (rank != 0) return 0;
    try {
      const auto m = slurry::merge_rank_frames(merge_dir, keep_parts);
      if (m.frames == 0) throw slurry::IoError(merge_dir + ": no per-rank frames (frame_NNNN.rankR.ply) to merge");
      std::printf("slurry: merged %d frames from %d per-rank files in %s (%zu particles in the last)\n", m.frames, m.parts,
                  merge_dir.c_str(), m.particles);
      return 0;
    } catch (const slurry::IoError& e) {
      return report(true, 3, e.what());
    }
  }

  try {
    if (resume_cmd->parsed()) {
      scene_path = slurry::checkpoint_scene(resume_dir).string();
      out_dir = resume_dir;
      resume = true;
    }
    const slurry::Scene scene = slurry::load_scene(scene_path);
    if (validate->parsed()) {
      slurry::check_scene(scene, memory_gb);
      if (rank == 0)
        std::printf("%s: valid (%dD, %zu materials, %zu bodies)\n", scene_path.c_str(), scene.solver.dimension,
                  scene.materials.size(), scene.bodies.size());
      return 0;
    }
    slurry::RunOptions opt;
    if (!out_dir.empty()) opt.directory = out_dir;
    if (frames >= 0) opt.frames = frames;
    if (ascii) opt.format = slurry::PlyEncoding::Ascii;
#ifdef SLURRY_WITH_MPI
    // The machine's cores shared among the ranks on it (one thread each for mpirun -np 2 here).
    if (mpi && threads == 0)
      threads = std::max(1, int(std::max(1u, std::thread::hardware_concurrency())) / mpi->local_size());
    opt.communicator = mpi.get();
#endif
    opt.threads = threads;
    opt.memory_gb = memory_gb;
    opt.overwrite = overwrite;
    opt.resume = resume;
    opt.force = force;
    opt.stop = &g_stop;
    if (rank == 0) opt.notice = [](const std::string& line) { std::fprintf(stderr, "slurry: %s\n", line.c_str()); };
    if (!quiet && scene.solver.type == slurry::SolverType::FEM)
      std::fprintf(stderr, "slurry: %s (%dD %s, fem, %s), %s backend, %d threads\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == slurry::Precision::Float ? "float" : "double",
                   std::string(slurry::to_string(scene.solver.integrator)).c_str(), slurry::parallel::backend(),
                   threads > 0 ? threads : slurry::parallel::max_threads());
    else if (!quiet)
      std::fprintf(stderr, "slurry: %s (%dD %s, %s, %s kernel), %s backend, %d threads%s\n", scene_path.c_str(),
                   scene.solver.dimension, scene.solver.precision == slurry::Precision::Float ? "float" : "double",
                   std::string(slurry::to_string(scene.solver.transfer)).c_str(),
                   std::string(slurry::to_string(scene.solver.kernel)).c_str(), slurry::parallel::backend(),
                   threads > 0 ? threads : slurry::parallel::max_threads(),
                   ranks > 1 ? (" per process, " + std::to_string(ranks) + " MPI processes").c_str() : "");
#ifdef SLURRY_WITH_OPENVDB
    // The module (and OpenVDB) is loaded only for a scene that asks for its outputs, and only by
    // rank 0, which writes them.
    const slurry::cli::FrameOutputFn pipeline = rank == 0 && wants_pipeline_outputs(scene)
                                                    ? slurry::cli::pipeline_module().frame_output_writer(scene)
                                                    : slurry::cli::FrameOutputFn();
#else
    if (wants_pipeline_outputs(scene))
      throw slurry::SceneError(scene_path + ": " + (scene.output.vdb_points ? "output.vdb_points" : "output.surface") +
                               ": this slurry was built without OpenVDB (SLURRY_WITH_OPENVDB=OFF); expected no pipeline outputs");
#endif
    install_signal_handlers();
    Progress progress(quiet);
    const auto on_frame = [&](const slurry::FrameReport& r) {
#ifdef SLURRY_WITH_OPENVDB
      if (pipeline) {  // rank 0's: a split run's rank 0 holds every particle of the frame (simulation.h)
        const std::string line = pipeline(r);
        if (!quiet && !line.empty() && !isatty(fileno(stderr))) std::fprintf(stderr, "frame %d: %s\n", r.frame, line.c_str());
      }
#endif
      progress(r);
    };
    const auto s = slurry::run_scene(scene, opt, on_frame);
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
  } catch (const slurry::SimulationError& e) {
    return report(true, 1, e.what());  // the health check is global: every rank stops here
  } catch (const slurry::SceneError& e) {
    return report(true, 2, e.what());  // every rank reads the same scene
  } catch (const slurry::IoError& e) {
    return report(false, 3, e.what());
  } catch (const std::bad_alloc&) {
    const std::string what = scene_path + ": out of memory (the estimate before the run was too low; lower the scene's "
                             "resolution or limits.memory_gb)";
    return report(false, 3, what.c_str());
  }
}
