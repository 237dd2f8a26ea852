#pragma once
/// \file run.h
/// The one-call API: run a scene and write its PLY frame sequence (and make_simulation, which
/// builds a scene's solver after reading the files it names).
///
/// Frame 0 is the initial state; frame f is the state at t = f / output.fps. Each frame is
/// written atomically (temporary name, then rename) as `<directory>/frame_NNNN.ply`, so a killed
/// or failed run leaves every frame it finished intact and no partial one. If the simulation
/// becomes unstable, SimulationError is thrown after the last good frame: a frame with
/// non-finite values is never written.
///
/// Checkpoints: every output.checkpoint_every frames (and never for frame 0) the run writes
/// `<directory>/checkpoint_NNNN.slc` after frame NNNN, atomically (temporary name, fsync,
/// rename), and keeps the last two (a run split with output.per_rank: one part per process,
/// checkpoint_NNNN.rankR.slc, together one checkpoint). It holds the solver's whole state (particles with every
/// channel in storage order, time, step counter, emitter generators, carried-over grid fields
/// or FEM vertex state), the run's figures (frame 0's statistics, substep count), the format
/// version, the hash of the scene file and a checksum. RunOptions::resume continues from the
/// newest valid one: frames after it are written again, byte-identical to an uninterrupted run
/// on any thread count; stats.csv keeps its rows up to the checkpoint. A checkpoint that is
/// corrupt, truncated, of another format version or another solver layout is refused with a
/// notice and the previous one is used; one written for another version of the scene file is
/// refused (SceneError if no other fits) unless RunOptions::force.
///
/// solver.on_instability "retry": the state at the start of each frame is kept in memory (one
/// copy); when the health check fires, the frame is redone from there with the substep halved,
/// up to solver.max_retries halvings, and the next frame returns to the automatic substep. Each
/// retry is told to RunOptions::notice. Frames before the first retry are byte-identical to
/// those of "stop".
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "slurry/engine/scene/scene.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/stats.h"

namespace slurry {

/// Overrides of the scene's output block and the run's resources.
struct RunOptions {
  std::optional<std::filesystem::path> directory;  ///< replaces output.directory
  std::optional<int> frames;                       ///< replaces output.frames
  std::optional<PlyEncoding> format;               ///< replaces output.format
  /// Worker threads of this call's parallel loops; 0 = all cores. In [0, 4 x the hardware
  /// threads] (parallel::max_thread_count). It sets nothing process-wide (parallel::ThreadLimit).
  int threads = 0;
  /// Replaces limits.memory_gb (GiB; 0 keeps the scene's limit).
  double memory_gb = 0;
  /// The output directory holds another scene's frames: remove them (else IoError).
  bool overwrite = false;
  /// false: write nothing (no directory, frames or stats.csv); the frame callback still runs
  /// after every frame, for programs that read the particles from memory (FrameReport::simulation).
  bool write_files = true;
  /// Polled between substep loops and frames: when non-zero, the run stops after the frame it
  /// is writing (no partial frame) and returns with `interrupted` set to its value (a signal number).
  const volatile std::sig_atomic_t* stop = nullptr;
  /// Continue from the newest valid checkpoint in the output directory instead of frame 0.
  bool resume = false;
  /// With resume: accept a checkpoint written for another version of the scene file.
  bool force = false;
  /// Told what the run removed from the output directory, which checkpoint it resumes from
  /// (and which it refused), and each retry of an unstable frame (one line each).
  std::function<void(const std::string&)> notice;
  /// Splits an MPM run over the communicator's ranks (mpm/mpm_solver.h; slurry::mpi gives one for
  /// `mpirun`): every rank calls run_scene with the same scene and options, and rank 0 alone
  /// writes files (frames, stats.csv, checkpoints), the same files as one process would. Every
  /// rank reads the checkpoints on resume: the output directory must be one they all see.
  Communicator* communicator = nullptr;
};

/// Progress after each written frame.
struct FrameReport {
  int frame = 0;               ///< index of the frame just written
  int frames = 0;              ///< last frame index of the run
  std::int64_t substeps = 0;   ///< substeps taken for this frame
  double seconds = 0;          ///< wall time for this frame (simulation and writing)
  double elapsed = 0;          ///< wall time since the run started
  std::size_t particles = 0;
  std::filesystem::path file;  ///< the frame written (empty when RunOptions::write_files is false)
  /// The frame as written to `file`, in memory (frame.h; its columns may point into the
  /// particle arrays), for writers that take the same frame in another format; null when no
  /// frame file was written (write_files false, a per-rank part, a rank other than 0). Valid
  /// during the callback.
  const Frame* frame_data = nullptr;
  /// The secondary particles written beside it as whitewater_NNNN.ply (FLIP whitewater), in
  /// memory; null when the scene has none or frame_data is null. Valid during the callback.
  const Frame* whitewater_data = nullptr;
  /// The simulation at this frame, for reading its particles in memory
  /// (simulation->particles_view<float, 3>() for a 3D float scene); valid during the callback.
  const Solver* simulation = nullptr;
  std::string solver;          ///< Solver::solver_status() after the frame's last substep
  RunStats stats;              ///< conservation figures after the frame (also a row of stats.csv)
  /// Drift beyond the scene's tolerances at this frame (stats.h), one line each; empty if none.
  std::vector<std::string> warnings;
};

struct RunSummary {
  int frames_written = 0;  ///< including frame 0
  std::int64_t substeps = 0;
  double wall_seconds = 0;
  double particle_steps_per_second = 0;  ///< particles x substeps / simulation wall time
  std::size_t particles = 0;
  std::size_t bytes = 0;  ///< particles and grid
  std::filesystem::path directory;
  RunStats first, last;   ///< figures of frame 0 and of the last frame written
  int drift_warnings = 0;  ///< frames with at least one drift warning
  double largest_cfl = 0;  ///< largest RunStats::cfl over the run
  int interrupted = 0;          ///< RunOptions::stop's value if the run was stopped early, else 0
  int removed_frames = 0;       ///< frames of an earlier run removed from the directory before the run
  int removed_temporaries = 0;  ///< temporary frame files of a killed run removed before the run
  int resumed_from = -1;        ///< frame of the checkpoint the run continued from, or -1
  int checkpoints_written = 0;
  int retries = 0;              ///< frames redone with a halved substep (on_instability "retry")
};

/// Runs `scene` to its last frame. Throws SceneError, IoError (ResourceError) or SimulationError.
/// Checks the scene and its resources (check_scene) before creating anything; the output
/// directory is created just before frame 0 is written. Frames and checkpoints of an earlier run
/// of the same scene (their comment names the same source) are removed first, so a sequence is
/// never mixed (with options.resume: only the frames after the checkpoint it continues from);
/// another scene's frames are an IoError unless options.overwrite. Temporary files of a killed
/// run (frame_NNNN.ply.tmp-PID-N whose process is gone) are removed. Besides the frames it
/// writes `<directory>/stats.csv`, one row of RunStats per frame (stats.h), and reports drift
/// beyond output.mass_drift, volume_drift and energy_growth in FrameReport::warnings.
RunSummary run_scene(const Scene& scene, const RunOptions& options = {},
                     const std::function<void(const FrameReport&)>& on_frame = {});

/// Everything `run_scene` checks before it allocates: validate(), resource estimates against the
/// memory limit (memory_gb as in check_resources), the mesh files read, placed and inside the
/// domain. Throws like run_scene.
void check_scene(const Scene& scene, double memory_gb = 0);

/// Builds the solver a scene asks for, as make_solver (solver.h) does, after reading the mesh
/// files the scene names if scene.files does not hold them yet (io::read_scene_files). Validates
/// the scene and checks its resources before reading anything.
std::unique_ptr<Solver> make_simulation(const Scene& scene, Communicator* communicator = nullptr);

/// The file name of frame f: frame_NNNN.ply.
std::filesystem::path frame_file(const std::filesystem::path& directory, int frame);

/// The file name of process `rank`'s part of frame f in a run with output.per_rank:
/// frame_NNNN.rankR.ply.
std::filesystem::path rank_frame_file(const std::filesystem::path& directory, int frame, int rank);

struct MergeSummary {
  int frames = 0;  ///< frame_NNNN.ply files written
  int parts = 0;   ///< frame_NNNN.rankR.ply files read
  std::size_t particles = 0;  ///< of the last frame
};

/// Joins the per-rank frames in `directory` (output.per_rank: frame_NNNN.rankR.ply, each with the
/// comment "slurry part R of N") into frame_NNNN.ply, byte for byte the frame one process writes:
/// rows in persistent id order, the scene's columns (the id column only if the scene asked for
/// it), the same format. Removes the parts unless keep_parts. Throws IoError naming the file if a
/// part is missing, duplicated, from another run, or the ids are not 0 .. n - 1 once each.
MergeSummary merge_rank_frames(const std::filesystem::path& directory, bool keep_parts = false);

/// The scene file a checkpoint in `directory` was written for, from the newest checkpoint that
/// reads: its path as the run named it if that names the same file from the working directory
/// (frames record it), else its absolute path; for `slurry resume DIR`. Throws IoError if none.
std::filesystem::path checkpoint_scene(const std::filesystem::path& directory);

}  // namespace slurry
