#include "slurry/engine/run/run.h"

#include <cerrno>
#include <chrono>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <new>
#include <map>
#include <random>
#include <regex>
#include <signal.h>
#include <string_view>
#include <thread>
#include <type_traits>
#include <variant>

#include "geometry/collider_surfaces.h"
#include "geometry/scene_meshes.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/engine/run/error_estimate.h"
#include "slurry/io/checkpoint.h"
#include "slurry/io/obj.h"
#include "slurry/io/ply.h"
#include "slurry/io/scene_file.h"
#include "slurry/io/stats_csv.h"
#include "slurry/transfer/parallel.h"
#include "state_io.h"

namespace slurry {
namespace fs = std::filesystem;
namespace {

/// Refuses an output directory whose files could not be created: a folder name longer than the
/// file system's NAME_MAX (255 bytes), or a path that leaves fewer than 64 bytes of the
/// system's PATH_MAX (4096) for the longest file name the run writes
/// (frame_NNNN.rankR.ply.tmp-PID-N, checkpoint_NNNN.slc.tmp-PID-N). Checked before anything is
/// created, so a refused run leaves no folder behind.
void check_output_path(const fs::path& dir, const std::string& source) {
  constexpr std::size_t kNameMax = 255, kPathMax = 4096, kLongestFile = 64;
  std::error_code ec;
  const fs::path full = fs::absolute(dir, ec);
  for (const auto& part : full)
    if (part.native().size() > kNameMax)
      throw IoError(source + ": output directory: one of its folder names is " + std::to_string(part.native().size()) +
                    " bytes; expected at most " + std::to_string(kNameMax) + " (NAME_MAX)");
  if (full.native().size() + 1 + kLongestFile > kPathMax)
    throw IoError(source + ": output directory: its path is " + std::to_string(full.native().size()) +
                  " bytes; expected at most " + std::to_string(kPathMax - 1 - kLongestFile) + " so that its files (" +
                  std::to_string(kLongestFile) + " bytes of name) stay within the system's " + std::to_string(kPathMax) +
                  " (PATH_MAX)");
}

/// output.up_axis "z": the particle table in Z-up axes, (x, y, z) -> (x, -z, y) and
/// (vx, vy, vz) -> (vx, -vz, vy), the rotation by +90 degrees about x that takes the
/// simulation's up (+y) to +z. Borrowed columns are copied first.
void to_z_up(Frame& frame) {
  Table* v = frame.find("vertex");
  if (!v) return;
  v->own();
  const auto rotate = [&](std::string_view a, std::string_view b) {  // (a, b) -> (-b, a)
    Column* ca = nullptr;
    Column* cb = nullptr;
    for (Column& c : v->columns) {
      if (c.name == a) ca = &c;
      if (c.name == b) cb = &c;
    }
    if (!ca || !cb) return;
    std::visit(
        [&](auto& first) {
          using V = std::decay_t<decltype(first)>;
          auto* second = std::get_if<V>(&cb->data);
          if (!second) return;
          for (std::size_t i = 0; i < first.size(); ++i) {
            const auto t = first[i];
            first[i] = static_cast<typename V::value_type>(-(*second)[i]);
            (*second)[i] = t;
          }
        },
        ca->data);
  };
  rotate("y", "z");
  rotate("vy", "vz");
}

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

/// What the output directory holds before a run: frames and checkpoints of an earlier run,
/// and temporary files of a killed one (frame_NNNN.ply.tmp-PID-N or checkpoint_NNNN.slc.tmp-PID-N
/// whose process is gone).
struct DirectoryState {
  std::vector<fs::path> frames, stale;
  std::vector<std::pair<int, fs::path>> checkpoints;  // oldest first
  std::string source;  // the scene the frames came from
};

DirectoryState scan_directory(const fs::path& dir) {
  DirectoryState s;
  std::error_code ec;
  if (!fs::exists(dir, ec)) return s;
  if (!fs::is_directory(dir, ec))
    throw IoError(dir.string() + ": exists and is not a directory (expected an output directory)");
  // Frames are frame_NNNN.ply, or frame_NNNN.rankR.ply for each process of a run split with
  // output.per_rank.
  static const std::regex frame(R"(frame_\d{4,}(?:\.rank\d+)?\.ply)"),
      temp(R"((?:frame_\d{4,}(?:\.rank\d+)?\.ply|checkpoint_\d{4,}(?:\.rank\d+)?\.slc)\.tmp-(\d+)-\d+)");
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
  s.checkpoints = detail::list_checkpoints(dir);
  return s;
}

/// The frame index of frame_NNNN.ply (or frame_NNNN.rankR.ply).
int frame_index(const fs::path& file) { return std::atoi(file.filename().string().c_str() + 6); }

/// The run's own part of a checkpoint (the solver's state follows it in the payload).
struct RunSection {
  std::string source;  // the scene file as the run named it (Scene::source; frames carry it)
  std::string scene;   // its absolute path
  int frame = 0;
  RunStats first;     // frame 0's figures, the reference of the drift warnings
  std::int64_t substeps = 0;
  int drift_warnings = 0;
  double largest_cfl = 0;
  int last_frame = -1;  // the run's last frame when the checkpoint was written (-1: not recorded)
};

void put_stats(detail::StateWriter& w, const RunStats& s) {
  w.pod(std::int32_t(s.frame));
  w.pod(s.time);
  w.pod(s.substeps);
  w.pod(std::uint64_t(s.particles));
  w.pod(s.mass);
  w.pod(s.momentum);
  w.pod(s.angular_momentum);
  w.pod(s.kinetic);
  w.pod(s.potential);
  w.pod(s.elastic);
  w.pod(s.volume);
  w.pod(s.max_fluid_J_error);
  w.pod(s.projected);
  w.pod(s.cfl);
}

RunStats get_stats(detail::StateReader& r) {
  RunStats s;
  s.frame = r.get<std::int32_t>();
  r.pod(s.time);
  r.pod(s.substeps);
  s.particles = std::size_t(r.get<std::uint64_t>());
  r.pod(s.mass);
  r.pod(s.momentum);
  r.pod(s.angular_momentum);
  r.pod(s.kinetic);
  r.pod(s.potential);
  r.pod(s.elastic);
  r.pod(s.volume);
  r.pod(s.max_fluid_J_error);
  r.pod(s.projected);
  r.pod(s.cfl);
  return s;
}

/// Payload: the run section (length-prefixed), then the solver state, handed to `sink`
/// (collective in a split run: every rank takes part in the solver state's gather), or with
/// `own` this process's part of it (not collective).
void checkpoint_payload(const RunSection& run, const Solver& sim, const Solver::StateSink& sink, bool own = false) {
  std::string section;
  detail::StateWriter w(section);
  w.text(run.source);
  w.text(run.scene);
  w.pod(std::int32_t(run.frame));
  put_stats(w, run.first);
  w.pod(run.substeps);
  w.pod(std::int32_t(run.drift_warnings));
  w.pod(run.largest_cfl);
  w.pod(std::int32_t(run.last_frame));
  w.pod(run.first.surface);
  detail::StateWriter(sink).text(section);
  if (own)
    sim.save_own_state(sink);
  else
    sim.save_state(sink);
}

/// Splits a checkpoint's payload into its run section and the solver state.
RunSection parse_payload(const detail::Checkpoint& c, std::string_view& state) {
  detail::StateReader outer(c.payload, c.file.string());
  const std::string section = outer.text();
  state = std::string_view(c.payload).substr(section.size() + sizeof(std::uint64_t));
  detail::StateReader r(section, c.file.string());
  RunSection run;
  run.source = r.text();
  run.scene = r.text();
  run.frame = r.get<std::int32_t>();
  run.first = get_stats(r);
  r.pod(run.substeps);
  run.drift_warnings = r.get<std::int32_t>();
  r.pod(run.largest_cfl);
  if (!r.done()) run.last_frame = r.get<std::int32_t>();  // absent from checkpoints of older versions
  if (!r.done()) r.pod(run.first.surface);                 // likewise
  r.finish();
  if (run.frame != c.frame) r.fail("the run section names frame " + std::to_string(run.frame));
  return run;
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

namespace {

/// whitewater_NNNN.ply: the secondary particles of FLIP whitewater (Solver::whitewater_frame_view).
std::filesystem::path whitewater_file(const std::filesystem::path& directory, int frame) {
  char name[40];
  std::snprintf(name, sizeof name, "whitewater_%04d.ply", frame);
  return directory / name;
}

/// colliders_NNNN.<extension>.
std::filesystem::path collider_file(const std::filesystem::path& directory, int frame, const char* extension) {
  char name[40];
  std::snprintf(name, sizeof name, "colliders_%04d.%s", frame, extension);
  return directory / name;
}

/// check_scene's checks; returns the scene with its mesh files read.
Scene checked_scene(const Scene& scene, double memory_gb) {
  scene.validate();
  check_resources(scene, memory_gb);
  Scene read = scene;
  if (!read.files) io::read_scene_files(read);
  detail::check_scene_meshes(read);
  check_resources(read, memory_gb);  // with the mesh bodies' volumes
  return read;
}

}  // namespace

void check_scene(const Scene& scene, double memory_gb) { checked_scene(scene, memory_gb); }

std::unique_ptr<Solver> make_simulation(const Scene& scene, Communicator* communicator) {
  if (scene.files || !io::names_files(scene)) return make_solver(scene, communicator);
  scene.validate();
  check_resources(scene);  // before the mesh files are read
  Scene read = scene;
  io::read_scene_files(read);
  return make_solver(read, communicator);
}

namespace {

/// The drift tolerances of a run (stats.h): volume for liquids only, energy only without
/// emitters or moving colliders.
DriftTolerances drift_tolerances(const Scene& scene) {
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
  for (const auto& c : scene.colliders) tol.check_energy = tol.check_energy && c.velocity.isZero() && c.keyframes.empty();
  return tol;
}

/// The energy the scene can release: its kinetic and surface energy plus its mass falling the
/// domain's extent along gravity (the denominator of the energy-growth warning).
double energy_scale_of(const Scene& scene, const RunStats& first) {
  const Eigen::Vector3d g = scene.solver.gravity;
  const int dim = scene.solver.dimension;
  double H = 0;
  if (g.head(dim).norm() > 0)
    for (int d = 0; d < dim; ++d)
      H += std::abs(scene.domain.max[d] - scene.domain.min[d]) * std::abs(g[d]) / g.head(dim).norm();
  return first.kinetic + first.surface + first.mass * g.head(dim).norm() * H;
}

/// Continues from the newest checkpoint in `dir` that reads, fits this solver and was written for
/// this scene file (or any, with options.force), naming the ones refused; loads its state into
/// `sim` (rebuilt by `rebuild` after a failed load), sets the run's figures in `summary` and its
/// last frame, and drops the frames up to the checkpoint from `removed_frames`. Returns the
/// first frame to simulate. Refuses frames or checkpoints beyond the run's last frame.
int resume_from_checkpoint(const Scene& scene, const RunOptions& options, const fs::path& dir,
                           const DirectoryState& before, const std::function<std::unique_ptr<Solver>()>& rebuild,
                           std::unique_ptr<Solver>& sim, RunSummary& summary, int& frames,
                           std::vector<fs::path>& removed_frames, const std::function<void(const std::string&)>& notice) {
  if (before.checkpoints.empty())
    throw IoError(dir.string() + ": no checkpoint to resume from (expected checkpoint_NNNN.slc files, written every "
                  "output.checkpoint_every frames); run without --resume to start from frame 0");
  std::vector<std::string> refused;
  bool other_scene = false;
  fs::path resumed_file;  // the checkpoint resumed from (part 0 of one in parts)
  std::size_t resumed_parts = 1;
  for (auto it = before.checkpoints.rbegin(); it != before.checkpoints.rend() && summary.resumed_from < 0; ++it) {
    const fs::path& file = it->second;
    try {
      const detail::Checkpoint c = detail::read_checkpoint(file);
      if (c.scene_hash != scene.source_hash && !options.force) {
        other_scene = true;
        refused.push_back(file.string() + ": written for another version of the scene file " + scene.source +
                          " (its hash differs; pass --force to resume anyway)");
        continue;
      }
      std::string_view state;
      const RunSection run = parse_payload(c, state);
      const int last = options.frames.value_or(run.last_frame >= 0 ? run.last_frame : scene.output.frames);
      if (c.frame > last)  // resuming from an earlier checkpoint would remove frames it never writes again
        throw SceneError(file.string() + ": frame " + std::to_string(c.frame) + " lies beyond the run's last frame " +
                         std::to_string(last) + (options.frames ? " (--frames)" : "") +
                         "; nothing was removed; expected --frames " + std::to_string(c.frame) + " or more");
      std::vector<bool> present(std::size_t(c.frame) + 1, false);  // whole, or in parts (output.per_rank)
      for (const auto& g : before.frames)
        if (const int i = frame_index(g); i >= 0 && i <= c.frame) {
          present[std::size_t(i)] = true;
          // Frames up to the checkpoint are kept as they are, so each must be whole (a copy cut
          // off, a disk that filled up under another program): a damaged one refuses the checkpoint.
          try {
            io::check_ply(g);
          } catch (const IoError& e) {
            throw IoError(file.string() + ": frame " + g.filename().string() + " before it is damaged (" + e.what() +
                          "); expected it whole, or a run from the start with --overwrite");
          }
        }
      for (int f = 0; f <= c.frame; ++f)
        if (!present[std::size_t(f)])
          throw IoError(file.string() + ": frame " + frame_file(dir, f).filename().string() + " before it is missing");
      const auto parts = detail::checkpoint_parts(file);
      if (file.filename() == detail::checkpoint_file(dir, c.frame).filename()) {
        sim->load_state(state, file.string());
      } else {
        // A checkpoint in parts (output.per_rank), read part by part as the solver asks.
        sim->load_state_parts(int(parts.size()), [&](int i) {
          const detail::Checkpoint p = detail::read_checkpoint(parts[std::size_t(i)]);
          if (p.scene_hash != c.scene_hash || p.frame != c.frame)
            throw IoError(p.file.string() + ": a part of " + file.string() + " of another run or frame");
          std::string_view s;
          parse_payload(p, s);
          return std::string(s);
        }, file.string());
      }
      // The frame's time at the scene's frame rate must be the state's (a changed output.fps
      // with --force would write every later frame at once, with no substep between them).
      const double t_frame = c.frame * scene.frame_dt();
      if (!(std::abs(sim->time() - t_frame) <= 1e-9 * std::max(1.0, t_frame)))
        throw SceneError(file.string() + ": its state is at t = " + fmt(sim->time()) + " s but frame " +
                         std::to_string(c.frame) + " lies at t = " + fmt(t_frame) + " s at output.fps " +
                         fmt(scene.output.fps) + "; expected the output.fps the run was started with");
      frames = last;
      resumed_file = file;
      resumed_parts = parts.size();
      summary.resumed_from = c.frame;
      summary.first = run.first;
      summary.substeps = run.substeps;
      summary.drift_warnings = run.drift_warnings;
      summary.largest_cfl = run.largest_cfl;
    } catch (const IoError& e) {
      refused.push_back(e.what());
      sim = rebuild();  // a failed load_state may have left part of the state
    } catch (const std::bad_alloc&) {
      refused.push_back(file.string() + ": out of memory loading its state");
      sim.reset();
      sim = rebuild();
    }
  }
  for (const auto& r : refused)
    notice("refused checkpoint " + r + (summary.resumed_from >= 0 ? "; using an earlier one" : ""));
  if (summary.resumed_from < 0) {
    std::string why;
    for (const auto& r : refused) why += "\n  " + r;
    if (other_scene)
      throw SceneError(scene.source + ": the scene file changed since its checkpoints in " + dir.string() +
                       " were written; expected the same scene file, or pass --force to resume anyway:" + why);
    throw IoError(dir.string() + ": no valid checkpoint to resume from:" + why);
  }
  notice("resuming from " + resumed_file.string() +
         (resumed_parts > 1 ? " and its " + std::to_string(resumed_parts - 1) + " other parts" : "") + " (frame " +
         std::to_string(summary.resumed_from) + ", t = " + fmt(sim->time()) + " s, step " +
         std::to_string(sim->steps()) + ")");
  summary.particles = sim->particle_count();
  // Frames after the checkpoint are written again; none may lie beyond the run's last frame.
  int beyond = -1;
  for (const auto& f : before.frames) beyond = std::max(beyond, frame_index(f));
  if (beyond > frames)
    throw SceneError(dir.string() + ": holds frame " + std::to_string(beyond) + ", beyond the run's last frame " +
                     std::to_string(frames) + (options.frames ? " (--frames)" : "") +
                     "; nothing was removed; expected --frames " + std::to_string(beyond) + " or more");
  removed_frames.erase(std::remove_if(removed_frames.begin(), removed_frames.end(),
                                      [&](const fs::path& f) { return frame_index(f) <= summary.resumed_from; }),
                       removed_frames.end());
  return summary.resumed_from + 1;
}

/// Advances `sim` to frame f; on a SimulationError redoes the frame from the state at its start
/// with the substep halved, up to solver.max_retries times (on_instability "retry"), telling each
/// retry to `notice`. Returns the substeps of the attempt that succeeded.
std::int64_t advance_with_retries(Solver* sim, const Scene& scene, int f, std::string& snapshot, RunSummary& summary,
                                  const std::function<void(const std::string&)>& notice) {
  const double t_end = f * scene.frame_dt();
  std::int64_t substeps = 0;
  snapshot.clear();
  sim->save_state(snapshot);
  for (int attempt = 0;; ++attempt) {
    try {
      substeps = sim->advance_to(t_end);
      break;
    } catch (const SimulationError& e) {
      if (attempt == scene.solver.max_retries)
        throw SimulationError(scene.source + ": frame " + std::to_string(f) + " is still unstable after " +
                              std::to_string(attempt) + " retries with the substep halved (solver.max_retries): " +
                              e.what());
      sim->load_state(snapshot, "the retry snapshot");
      sim->set_dt_scale(0.5 * sim->dt_scale());
      ++summary.retries;
      notice("retry " + std::to_string(attempt + 1) + " of " + std::to_string(scene.solver.max_retries) +
             ": frame " + std::to_string(f) + " redone from t = " + fmt(sim->time()) + " s with the substep x " +
             fmt(sim->dt_scale()) + " after: " + e.what());
    }
  }
  sim->set_dt_scale(1);
  return substeps;
}

}  // namespace

RunSummary run_scene(const Scene& scene, const RunOptions& options,
                     const std::function<void(const FrameReport&)>& on_frame) {
  using Clock = std::chrono::steady_clock;
  const auto seconds_since = [](Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
  };
  const auto notice = [&](const std::string& line) {
    if (options.notice) options.notice(line);
  };
  Scene limited = scene;
  if (options.memory_gb > 0) limited.limits.memory_gb = options.memory_gb;
  limited = checked_scene(limited, 0);
  const std::filesystem::path dir = options.directory.value_or(scene.output.directory);
  const bool files = options.write_files;
  // A split run: every rank simulates and takes part in the gathers; rank 0 writes.
  Communicator* const comm = options.communicator;
  const bool writer = files && (!comm || comm->rank() == 0);
  // output.per_rank: every process writes its own particles (frame_NNNN.rankR.ply), nothing is gathered.
  const bool per_rank = files && comm && comm->size() > 1 && scene.output.per_rank;
  if (files && dir.empty()) throw SceneError(scene.source + ": output directory: expected a non-empty path");
  if (files) check_output_path(dir, scene.source);
  // The run's last frame: --frames, else (resuming) the one the run was started with, which the
  // checkpoint records, else the scene's.
  int frames = options.frames.value_or(scene.output.frames);
  if (frames < 0) throw SceneError(scene.source + ": frames: expected an integer >= 0, got " + std::to_string(frames));
  if (options.threads < 0 || options.threads > parallel::max_thread_count())
    throw SceneError(scene.source + ": threads: expected an integer in [0, " + std::to_string(parallel::max_thread_count()) +
                     "] (4 x the " + std::to_string(parallel::max_thread_count() / 4) + " hardware threads), got " +
                     std::to_string(options.threads));
  const io::PlyFormat format = options.format.value_or(scene.output.format) == PlyEncoding::Ascii
                                   ? io::PlyFormat::Ascii
                                   : io::PlyFormat::BinaryLittleEndian;
  // Another scene's frames are refused before anything is built or removed.
  const DirectoryState before = files ? scan_directory(dir) : DirectoryState{};
  if (!before.frames.empty() && !options.overwrite && !same_file(before.source, scene.source))
    throw IoError(dir.string() + ": holds " + std::to_string(before.frames.size()) + " frames of another scene (" +
                  (before.source.empty() ? std::string("not written by slurry") : before.source) +
                  "); expected an empty directory or this scene's own frames (pass --overwrite to remove them)");

  // The threads of this call's loops only (parallel.h, ThreadLimit): no process-wide setting.
  parallel::ThreadLimit limit(options.threads);
  const auto start = Clock::now();
  auto sim = make_simulation(limited, comm);
  // output.error_estimate: the shadow at twice dx (error_estimate.h), in one process.
  const bool estimating = scene.output.error_estimate;
  if (estimating && comm && comm->size() > 1)
    throw SceneError(scene.source + ": output.error_estimate: the shadow simulation runs in one process; expected false "
                     "for a run split over " + std::to_string(comm->size()) + " processes");
  std::unique_ptr<ErrorEstimator> estimator = estimating ? std::make_unique<ErrorEstimator>(limited) : nullptr;
  std::ofstream csv;  // stats.csv, opened once frame 0 is written (the directory exists then)
  const DriftTolerances tol = drift_tolerances(scene);
  double energy_scale = 0;
  RunSummary summary;
  summary.directory = dir;
  summary.particles = sim->particle_count();
  const fs::path scene_file = fs::absolute(scene.source);

  // Resume: the newest checkpoint that reads, fits this solver and was written for this scene
  // file (or any, with force); the ones refused are named.
  int first_frame = 0;
  std::vector<fs::path> removed_frames = before.frames;
  if (options.resume && !files)
    throw SceneError(scene.source + ": resume: a run that writes no files (RunOptions::write_files = false) has no "
                     "checkpoints to resume from");
  if (options.resume) {
    first_frame = resume_from_checkpoint(scene, options, dir, before, [&] { return make_simulation(limited, comm); }, sim,
                                         summary, frames, removed_frames, notice);
    energy_scale = energy_scale_of(scene, summary.first);
  }
  if (comm) comm->barrier();  // every rank has read the directory before rank 0 changes it
  if (writer) {
    summary.removed_temporaries = remove_all(before.stale);
    summary.removed_frames = remove_all(removed_frames);  // a sequence is never mixed with an earlier run's
    std::vector<fs::path> old;  // checkpoints the run will not continue from
    for (const auto& [f, file] : before.checkpoints)
      if (f > summary.resumed_from)
        for (const auto& part : detail::checkpoint_parts(file)) old.push_back(part);
    remove_all(old);
  }
  if (summary.removed_temporaries > 0)
    notice("removed " + std::to_string(summary.removed_temporaries) + " temporary frame files of a killed run from " +
           dir.string());
  if (summary.removed_frames > 0 && summary.resumed_from >= 0)
    notice("removed " + std::to_string(summary.removed_frames) + " frames after the checkpoint from " + dir.string() +
           " (they are written again)");
  else if (summary.removed_frames > 0)
    notice("removed " + std::to_string(summary.removed_frames) + " frames of an earlier run" +
           (same_file(before.source, scene.source) ? " of this scene" : " (--overwrite)") + " from " + dir.string() +
           " before writing");
  double sim_seconds = 0, particle_steps = 0;

  std::error_code ec;
  const bool created = writer && !fs::exists(dir, ec);
  // The outermost folder this call creates: removed again if creating the rest fails.
  fs::path first_new;
  if (writer)
    for (fs::path p = fs::absolute(dir, ec); !p.empty() && !fs::exists(p, ec); p = p.parent_path()) {
      first_new = p;
      if (p == p.parent_path()) break;
    }
  if (writer) fs::create_directories(dir, ec);
  if (ec) {
    const std::string why = ec.message();
    if (!first_new.empty()) fs::remove_all(first_new, ec);
    throw IoError(dir.string() + ": cannot create the output directory: " + why);
  }
  if (per_rank) comm->barrier();  // every process writes into it
  // The run's token in every part's comments ("slurry run T"): merge joins only parts of one run,
  // not a part left by another run of the same scene. Every rank draws a number; all take the largest.
  std::string run_token;
  if (per_rank) {
    double draw = double(std::random_device{}());
    comm->max(&draw, 1);
    char buf[32];
    std::snprintf(buf, sizeof buf, "%08llx", static_cast<unsigned long long>(draw));
    run_token = buf;
  }
  if (first_frame > 0) summary.frames_written = first_frame;
  if (first_frame > 0 && writer) {
    io::truncate_stats_csv(dir / "stats.csv", first_frame - 1);
    const bool had = fs::exists(dir / "stats.csv");
    csv.open(dir / "stats.csv", std::ios::app);
    if (!csv) throw IoError((dir / "stats.csv").string() + ": cannot write the run statistics");
    if (!had) csv << io::stats_csv_header(estimating) << '\n';
  }
  // A resumed run's shadow is simulated again up to the checkpoint, frame by frame as the
  // uninterrupted run did (its state is not in the checkpoint; it costs 1/8 of the main run in 3D).
  if (estimator)
    for (int f = 1; f < first_frame; ++f) estimator->advance_to(f * scene.frame_dt());
  // The colliders beside the surface meshes, in their formats (3D): colliders_NNNN.ply, .obj.
  const auto asks = [&](const char* format) {
    return std::find(scene.output.surface.begin(), scene.output.surface.end(), format) != scene.output.surface.end();
  };
  const bool collider_ply = asks("ply"), collider_obj = asks("obj");
  std::unique_ptr<detail::ColliderSurfaces> colliders;
  if (writer && (collider_ply || collider_obj)) {
    colliders = std::make_unique<detail::ColliderSurfaces>(limited);
    if (colliders->empty()) colliders.reset();
  }
  const bool z_up = scene.output.up_axis == "z";
  const int every = scene.output.checkpoint_every;
  const bool retry = scene.solver.on_instability == OnInstability::Retry;
  std::string snapshot;  // on_instability "retry": the state at the start of the frame
  const auto write_checkpoint = [&](int f) {
    RunSection run;
    run.source = scene.source;
    run.scene = scene_file.string();
    run.frame = f;
    run.first = summary.first;
    run.substeps = summary.substeps;
    run.drift_warnings = summary.drift_warnings;
    run.largest_cfl = summary.largest_cfl;
    run.last_frame = frames;
    ++summary.checkpoints_written;
    // Streamed to the file: the state is never copied whole into memory (it was the run's
    // memory peak: the 3D FLIP dam break's 80 MB state on top of the solver's 300 MB).
    if (per_rank) {
      // Every process writes its own part, checkpoint_NNNN.rankR.slc; nothing is gathered. The
      // older ones are removed once every part of this one is in place.
      detail::write_checkpoint(detail::checkpoint_part_file(dir, f, comm->rank()), scene.source_hash, f,
                               [&](const detail::PayloadSink& sink) { checkpoint_payload(run, *sim, sink, true); });
      comm->barrier();
      if (!writer) return;
    } else if (!writer) {
      checkpoint_payload(run, *sim, [](const char*, std::size_t) {});  // the other ranks of a split run
      return;
    } else {
      detail::write_checkpoint(detail::checkpoint_file(dir, f), scene.source_hash, f,
                               [&](const detail::PayloadSink& sink) { checkpoint_payload(run, *sim, sink); });
    }
    // Keep the last two (whole files or sets of parts).
    auto list = detail::list_checkpoints(dir);
    std::vector<fs::path> old;
    for (std::size_t i = 0; i + 2 < list.size(); ++i)
      for (const auto& file : detail::checkpoint_parts(list[i].second)) old.push_back(file);
    remove_all(old);
  };
  for (int f = first_frame; f <= frames; ++f) {
    const auto t0 = Clock::now();
    std::int64_t substeps = 0;
    if (f > 0) {
      const double t_end = f * scene.frame_dt();
      substeps = retry ? advance_with_retries(sim.get(), scene, f, snapshot, summary, notice) : sim->advance_to(t_end);
      sim_seconds += seconds_since(t0);
      particle_steps += double(sim->particle_count()) * double(substeps);  // emitters add particles
      if (estimator) estimator->advance_to(t_end);
    }
    const auto file = files ? frame_file(dir, f) : fs::path();
    // Gathered to rank 0 in a split run; columns may point into the particle arrays (no copy), so
    // the frame lives until the frame callback has run and the simulation has not moved on.
    Frame frame, whitewater;
    try {
      if (per_rank) {
        Frame part = sim->own_frame(scene.output.attributes);
        if (z_up) to_z_up(part);
        part.comments.push_back("slurry run " + run_token);
        io::write_ply(rank_frame_file(dir, f, comm->rank()), part, format);
      } else if (files) {
        frame = sim->frame_view(scene.output.attributes);
        if (z_up) to_z_up(frame);
        if (writer) io::write_ply(file, frame, format);
        whitewater = sim->whitewater_frame_view();
        if (!whitewater.tables.empty()) {
          if (z_up) to_z_up(whitewater);
          if (writer) io::write_ply(whitewater_file(dir, f), whitewater, format);
        }
      }
      if (colliders) {
        const double t = f * scene.frame_dt();
        Frame surfaces = colliders->at(t);
        if (z_up) to_z_up(surfaces);
        if (collider_ply) io::write_ply(collider_file(dir, f, "ply"), surfaces, format);
        if (collider_obj)
          io::write_obj(collider_file(dir, f, "obj"), surfaces, "slurry colliders at t = " + fmt(t) + " s: one object per collider",
                        "collider", "collider_");
      }
    } catch (...) {
      if (f == 0 && created) fs::remove(dir, ec);  // nothing is left of a run without a frame
      throw;
    }
    RunStats stats = sim->take_stats();
    stats.frame = f;
    stats.substeps = substeps;
    if (estimator) estimator->estimate(*sim, stats);
    std::vector<std::string> warnings;
    if (f == 0) {
      summary.first = stats;
      energy_scale = energy_scale_of(scene, stats);
      if (writer) csv.open(dir / "stats.csv");
      if (writer && !csv) throw IoError((dir / "stats.csv").string() + ": cannot write the run statistics");
      if (writer) csv << io::stats_csv_header(estimating) << '\n';
    } else {
      warnings = drift_warnings(summary.first, stats, tol, energy_scale);
      summary.drift_warnings += !warnings.empty();
    }
    summary.last = stats;
    summary.largest_cfl = std::max(summary.largest_cfl, stats.cfl);
    if (writer) {
      csv << io::stats_csv_row(stats, estimating) << '\n';
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
      r.frame_data = writer && !per_rank && files ? &frame : nullptr;
      r.whitewater_data = r.frame_data && !whitewater.tables.empty() ? &whitewater : nullptr;
      r.simulation = sim.get();
      r.solver = sim->solver_status();
      r.stats = stats;
      r.warnings = std::move(warnings);
      on_frame(r);
    }
    double signal = options.stop ? double(*options.stop) : 0.0;
    if (comm) comm->max(&signal, 1);  // the ranks of a split run stop together, after the same frame
    const bool stopping = signal != 0;
    // A stopped run also leaves a checkpoint of the frame it stopped after.
    if (files && every > 0 && f > 0 && (f % every == 0 || (stopping && f < frames))) write_checkpoint(f);
    if (stopping) {  // the frame just written is complete; stop here
      summary.interrupted = int(signal);
      break;
    }
  }
  if (summary.resumed_from >= 0 && summary.resumed_from == frames) {  // nothing was left to do
    notice("the run is already complete: its checkpoint is of its last frame, " + std::to_string(frames) +
           "; nothing to simulate (pass --frames to run it further)");
    summary.last = sim->take_stats();
    summary.last.frame = frames;
  }
  summary.wall_seconds = seconds_since(start);
  summary.bytes = sim->bytes();
  summary.particles = sim->particle_count();
  if (sim_seconds > 0) summary.particle_steps_per_second = particle_steps / sim_seconds;
  return summary;
}

std::filesystem::path rank_frame_file(const std::filesystem::path& directory, int frame, int rank) {
  char name[48];
  std::snprintf(name, sizeof name, "frame_%04d.rank%d.ply", frame, rank);
  return directory / name;
}

namespace {

/// "slurry part R of N id=requested|added" of a per-rank frame, or false.
/// The run token of a part ("slurry run T"), or "" for a part written without one.
std::string part_run(const io::PlyData& d) {
  for (const auto& c : d.comments)
    if (c.rfind("slurry run ", 0) == 0) return c.substr(11);
  return {};
}

bool parse_part(const io::PlyData& d, int& rank, int& ranks, bool& id_added) {
  for (const auto& c : d.comments) {
    char id[16] = {};
    if (std::sscanf(c.c_str(), "slurry part %d of %d id=%15s", &rank, &ranks, id) == 3) {
      id_added = std::string(id) == "added";
      return ranks > 0 && rank >= 0 && rank < ranks && (id_added || std::string(id) == "requested");
    }
  }
  return false;
}

/// The body format a PLY file was written in (its header's second line).
io::PlyFormat file_format(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::string magic, line;
  std::getline(in, magic);
  std::getline(in, line);
  return line.rfind("format ascii", 0) == 0 ? io::PlyFormat::Ascii : io::PlyFormat::BinaryLittleEndian;
}

}  // namespace

MergeSummary merge_rank_frames(const std::filesystem::path& directory, bool keep_parts) {
  static const std::regex part(R"(frame_\d{4,}\.rank\d+\.ply)");
  std::map<int, std::vector<fs::path>> frames;  // frame -> its parts
  std::error_code ec;
  if (!fs::is_directory(directory, ec))
    throw IoError(directory.string() + ": expected a directory of per-rank frames (frame_NNNN.rankR.ply)");
  for (const auto& e : fs::directory_iterator(directory, ec)) {
    const std::string name = e.path().filename().string();
    if (std::regex_match(name, part)) frames[frame_index(e.path())].push_back(e.path());
  }
  if (ec) throw IoError(directory.string() + ": cannot list it: " + ec.message());
  MergeSummary summary;
  for (auto& [f, files] : frames) {
    std::sort(files.begin(), files.end());
    std::vector<io::PlyData> parts;
    std::vector<bool> seen;
    int ranks = -1;
    bool id_added = false;
    std::size_t n = 0;
    for (const auto& file : files) {
      io::PlyData d = io::read_ply(file);
      int r = 0, nr = 0;
      bool added = false;
      if (!parse_part(d, r, nr, added))
        throw IoError(file.string() + ": expected a per-rank frame (the comment \"slurry part R of N id=...\"), found none");
      if (ranks < 0) {
        ranks = nr;
        id_added = added;
        seen.assign(std::size_t(nr), false);
      }
      if (nr != ranks || added != id_added ||
          (!parts.empty() && (d.comments.front() != parts.front().comments.front() || part_run(d) != part_run(parts.front()))))
        throw IoError(file.string() + ": part of another run than " + files.front().string() +
                      " (expected the same process count, time, id column and run token)");
      if (seen[std::size_t(r)]) throw IoError(file.string() + ": a second part " + std::to_string(r) + " of frame " + std::to_string(f));
      seen[std::size_t(r)] = true;
      n += d.table("vertex").count;
      parts.push_back(std::move(d));
    }
    for (int r = 0; r < ranks; ++r)
      if (!seen[std::size_t(r)])
        throw IoError(rank_frame_file(directory, f, r).string() + ": missing (frame " + std::to_string(f) + " was written by " +
                      std::to_string(ranks) + " processes; expected every part)");
    // Row = id: an MPM run keeps every particle, and its ids are 0 .. n - 1.
    io::PlyData merged;
    merged.comments.push_back(parts.front().comments.front());
    Table& out = merged.tables.emplace_back();
    out.name = "vertex";
    out.count = n;
    std::vector<bool> filled(n, false);
    for (std::size_t k = 0; k < parts.size(); ++k) {
      const Table& v = parts[k].table("vertex");
      const auto& ids = v.values<std::uint32_t>("id");
      if (k == 0) {
        for (const auto& p : v.columns) {
          if (id_added && p.name == "id") continue;
          auto& col = out.columns.emplace_back();
          col.name = p.name;
          std::visit([&](const auto& c) { col.data = std::decay_t<decltype(c)>(n); }, p.data);
        }
      }
      for (std::size_t i = 0; i < v.count; ++i) {
        if (ids[i] >= n || filled[ids[i]])
          throw IoError(v.source.string() + ": particle id " + std::to_string(ids[i]) + (ids[i] >= n ? " beyond the " + std::to_string(n) + " particles of the frame" : " appears twice") +
                        " (expected the ids 0 .. n - 1 once each over the parts)");
        filled[ids[i]] = true;
      }
      for (auto& col : out.columns) {
        const Column* src = v.find(col.name);
        if (!src || src->data.index() != col.data.index())
          throw IoError(v.source.string() + ": column " + col.name + " missing or of another type than in the frame's first part");
        std::visit([&](auto& dst) {
          const auto& c = std::get<std::decay_t<decltype(dst)>>(src->data);
          for (std::size_t i = 0; i < v.count; ++i) dst[ids[i]] = c[i];
        }, col.data);
      }
    }
    io::write_ply(frame_file(directory, f), merged, file_format(files.front()));
    ++summary.frames;
    summary.parts += int(files.size());
    summary.particles = n;
    if (!keep_parts) remove_all(files);
  }
  return summary;
}

std::filesystem::path checkpoint_scene(const std::filesystem::path& directory) {
  const auto list = detail::list_checkpoints(directory);
  std::string why;
  for (auto it = list.rbegin(); it != list.rend(); ++it) {
    try {
      const detail::Checkpoint c = detail::read_checkpoint(it->second);
      std::string_view state;
      const RunSection run = parse_payload(c, state);
      // The name the run used, if it still names the same file from here (frames record it).
      return same_file(run.source, run.scene) ? run.source : run.scene;
    } catch (const IoError& e) {
      why += std::string("\n  ") + e.what();
    }
  }
  throw IoError(directory.string() + ": no readable checkpoint (checkpoint_NNNN.slc) to resume from" +
                (why.empty() ? std::string(" (the directory holds none)") : ":" + why));
}

}  // namespace slurry
