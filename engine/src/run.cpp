#include "slurry/engine/run.h"

#include <cerrno>
#include <chrono>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <regex>
#include <signal.h>
#include <thread>

#include "slurry/engine/fem/tetgen.h"
#include "slurry/engine/ply.h"
#include "slurry/engine/simulation.h"
#include "slurry/transfer/parallel.h"

namespace slurry {
namespace fs = std::filesystem;
namespace {

std::string fmt(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", x);
  return buf;
}

/// The source a frame's comment names ("slurry ... source=<source>"), or "" if it has none.
std::string frame_source(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::string line;
  for (int i = 0; i < 64 && std::getline(in, line) && line != "end_header"; ++i)
    if (line.rfind("comment slurry ", 0) == 0)
      if (const auto at = line.find(" source="); at != std::string::npos) return line.substr(at + 8);
  return {};
}

bool same_file(const std::string& a, const std::string& b) {
  if (a == b) return true;
  std::error_code ec1, ec2;
  const fs::path ca = fs::weakly_canonical(a, ec1), cb = fs::weakly_canonical(b, ec2);
  return !ec1 && !ec2 && ca == cb;
}

/// What the output directory holds before a run: frames of an earlier run, and temporary
/// frame files of a killed one (frame_NNNN.ply.tmp-PID-N whose process is gone).
struct DirectoryState {
  std::vector<fs::path> frames, stale;
  std::string source;  // the scene the frames came from
};

DirectoryState scan_directory(const fs::path& dir) {
  DirectoryState s;
  std::error_code ec;
  if (!fs::exists(dir, ec)) return s;
  if (!fs::is_directory(dir, ec))
    throw IoError(dir.string() + ": exists and is not a directory (expected an output directory)");
  static const std::regex frame(R"(frame_\d{4,}\.ply)"), temp(R"(frame_\d{4,}\.ply\.tmp-(\d+)-\d+)");
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    std::smatch m;
    if (std::regex_match(name, frame)) {
      s.frames.push_back(e.path());
    } else if (std::regex_match(name, m, temp)) {
      const long pid = std::strtol(m[1].str().c_str(), nullptr, 10);
      if (pid > 0 && ::kill(pid_t(pid), 0) != 0 && errno == ESRCH) s.stale.push_back(e.path());
    }
  }
  if (ec) throw IoError(dir.string() + ": cannot list the output directory: " + ec.message());
  std::sort(s.frames.begin(), s.frames.end());
  if (!s.frames.empty()) s.source = frame_source(s.frames.front());
  return s;
}

int remove_all(const std::vector<fs::path>& files) {
  int n = 0;
  for (const auto& f : files) {
    std::error_code ec;
    if (fs::remove(f, ec)) ++n;
    if (ec) throw IoError(f.string() + ": cannot remove it: " + ec.message());
  }
  return n;
}

}  // namespace

std::filesystem::path frame_file(const std::filesystem::path& directory, int frame) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%04d.ply", frame);
  return directory / name;
}

void substep_limit_error(const Scene& scene, double dt, double interval, std::int64_t substeps, double time) {
  const bool too_many = substeps >= scene.limits.substeps_per_frame;
  std::string limit = "solver.cfl", cause = "the CFL limit cfl dx / max |v|";
  if (dt >= scene.solver.max_dt * (1 - 1e-6)) {
    limit = "solver.max_dt";
    cause = "solver.max_dt";
  } else if (dt > 0 && std::abs(dt - scene.elastic_dt()) <= 1e-5 * dt) {
    limit = "solver.elastic_cfl";
    cause = "the elastic limit elastic_cfl dx / c";
  }
  const std::string what =
      too_many ? "the frame ending at t = " + fmt(time + interval) + " s needs more than limits.substeps_per_frame = " +
                     std::to_string(scene.limits.substeps_per_frame) + " substeps"
               : "the substep fell to " + fmt(dt) + " s at t = " + fmt(time) + " s, below " + fmt(kMinSubstepRatio) +
                     " of the frame (" + fmt(interval) + " s)";
  throw SceneError(scene.source + ": " + limit + ": " + what + "; the substep is set by " + cause + " = " + fmt(dt) +
                   " s (expected a larger " + limit + ")");
}

void check_scene(const Scene& scene, double memory_gb) {
  scene.validate();
  check_resources(scene, memory_gb);
  if (scene.solver.type != SolverType::FEM) return;
  for (const auto& b : scene.bodies) {
    if (b.mesh.empty()) continue;
    fs::path p(b.mesh);
    if (!p.is_absolute()) p = fs::path(scene.source).parent_path() / p;
    if (scene.solver.dimension == 2)
      fem::read_tetgen<2>(p);
    else
      fem::read_tetgen<3>(p);
  }
}

RunSummary run_scene(const Scene& scene, const RunOptions& options,
                     const std::function<void(const FrameReport&)>& on_frame) {
  using Clock = std::chrono::steady_clock;
  const auto seconds_since = [](Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
  };
  Scene limited = scene;
  if (options.memory_gb > 0) limited.limits.memory_gb = options.memory_gb;
  check_scene(limited);
  const std::filesystem::path dir = options.directory.value_or(scene.output.directory);
  const bool files = options.write_files;
  if (files && dir.empty()) throw SceneError(scene.source + ": output directory: expected a non-empty path");
  const int frames = options.frames.value_or(scene.output.frames);
  if (frames < 0) throw SceneError(scene.source + ": frames: expected an integer >= 0, got " + std::to_string(frames));
  const int hardware = int(std::max(1u, std::thread::hardware_concurrency()));
  if (options.threads < 0 || options.threads > 4 * hardware)
    throw SceneError(scene.source + ": threads: expected an integer in [0, " + std::to_string(4 * hardware) +
                     "] (4 x the " + std::to_string(hardware) + " hardware threads), got " + std::to_string(options.threads));
  const io::PlyFormat format = options.format.value_or(scene.output.format) == PlyEncoding::Ascii
                                   ? io::PlyFormat::Ascii
                                   : io::PlyFormat::BinaryLittleEndian;
  // Another scene's frames are refused before anything is built or removed.
  const DirectoryState before = files ? scan_directory(dir) : DirectoryState{};
  if (!before.frames.empty() && !options.overwrite && !same_file(before.source, scene.source))
    throw IoError(dir.string() + ": holds " + std::to_string(before.frames.size()) + " frames of another scene (" +
                  (before.source.empty() ? std::string("not written by slurry") : before.source) +
                  "); expected an empty directory or this scene's own frames (pass --overwrite to remove them)");

  parallel::ThreadLimit limit(options.threads);
  const auto start = Clock::now();
  auto sim = make_simulation(limited);
  std::ofstream csv;  // stats.csv, opened once frame 0 is written (the directory exists then)
  DriftTolerances tol;
  tol.mass = scene.output.mass_drift;
  tol.volume = scene.output.volume_drift;
  // Volume is conserved by liquids only; a solid's volume changes with its deformation (two
  // jelly cubes colliding: -17% for a moment) and is reported in stats.csv without a warning.
  bool liquid = scene.solver.type == SolverType::FLIP;
  if (scene.solver.type == SolverType::MPM) {
    liquid = !scene.materials.empty();
    for (const auto& m : scene.materials) liquid = liquid && m.model == ElasticModel::Fluid;
  }
  if (!liquid) tol.volume = std::numeric_limits<double>::infinity();
  tol.energy = scene.output.energy_growth;
  tol.check_energy = scene.emitters.empty();
  for (const auto& c : scene.colliders) tol.check_energy = tol.check_energy && c.velocity.isZero();
  double energy_scale = 0;
  RunSummary summary;
  summary.directory = dir;
  summary.particles = sim->particle_count();
  summary.removed_temporaries = remove_all(before.stale);
  summary.removed_frames = remove_all(before.frames);  // a sequence is never mixed with an earlier run's
  if (options.notice && summary.removed_temporaries > 0)
    options.notice("removed " + std::to_string(summary.removed_temporaries) + " temporary frame files of a killed run from " +
                   dir.string());
  if (options.notice && summary.removed_frames > 0)
    options.notice("removed " + std::to_string(summary.removed_frames) + " frames of an earlier run" +
                   (same_file(before.source, scene.source) ? " of this scene" : " (--overwrite)") + " from " + dir.string() +
                   " before writing");
  double sim_seconds = 0, particle_steps = 0;

  std::error_code ec;
  const bool created = files && !fs::exists(dir, ec);
  if (files) fs::create_directories(dir, ec);
  if (ec) throw IoError(dir.string() + ": cannot create the output directory: " + ec.message());
  for (int f = 0; f <= frames; ++f) {
    const auto t0 = Clock::now();
    std::int64_t substeps = 0;
    if (f > 0) {
      substeps = sim->advance_to(f * scene.frame_dt());
      sim_seconds += seconds_since(t0);
      particle_steps += double(sim->particle_count()) * double(substeps);  // emitters add particles
    }
    const auto file = files ? frame_file(dir, f) : fs::path();
    try {
      if (files) io::write_ply(file, sim->frame(scene.output.attributes), format);
    } catch (...) {
      if (f == 0 && created) fs::remove(dir, ec);  // nothing is left of a run without a frame
      throw;
    }
    RunStats stats = sim->take_stats();
    stats.frame = f;
    stats.substeps = substeps;
    std::vector<std::string> warnings;
    if (f == 0) {
      summary.first = stats;
      // The energy the scene can release: its kinetic energy plus its mass falling the
      // domain's extent along gravity.
      const Eigen::Vector3d g = scene.solver.gravity;
      const int dim = scene.solver.dimension;
      double H = 0;
      if (g.head(dim).norm() > 0)
        for (int d = 0; d < dim; ++d)
          H += std::abs(scene.domain.max[d] - scene.domain.min[d]) * std::abs(g[d]) / g.head(dim).norm();
      energy_scale = stats.kinetic + stats.mass * g.head(dim).norm() * H;
      if (files) csv.open(dir / "stats.csv");
      if (files && !csv) throw IoError((dir / "stats.csv").string() + ": cannot write the run statistics");
      csv << stats_csv_header() << '\n';
    } else {
      warnings = drift_warnings(summary.first, stats, tol, energy_scale);
      summary.drift_warnings += !warnings.empty();
    }
    summary.last = stats;
    summary.largest_cfl = std::max(summary.largest_cfl, stats.cfl);
    if (files) {
      csv << stats_csv_row(stats) << '\n';
      csv.flush();
    }
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
      r.simulation = sim.get();
      r.solver = sim->solver_status();
      r.stats = stats;
      r.warnings = std::move(warnings);
      on_frame(r);
    }
    if (options.stop && *options.stop) {  // the frame just written is complete; stop here
      summary.interrupted = int(*options.stop);
      break;
    }
  }
  summary.wall_seconds = seconds_since(start);
  summary.bytes = sim->bytes();
  summary.particles = sim->particle_count();
  if (sim_seconds > 0) summary.particle_steps_per_second = particle_steps / sim_seconds;
  return summary;
}

}  // namespace slurry
