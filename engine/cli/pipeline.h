#pragma once
// The effects-pipeline part of the slurry CLI, built when slurry::io is (SLURRY_WITH_OPENVDB=ON): the
// per-frame outputs a scene asks for (output.surface, output.vdb_points) and the
// `slurry surface DIR` command.
//
// It is a module of its own (pipeline.cpp, built as slurry_pipeline.so), which the CLI opens
// (dlopen) only when a scene asks for those outputs or the surface command runs
// (pipeline_loader.cpp): OpenVDB and the rest of slurry::io are then mapped only by the runs
// that use them. Debian links libopenvdb with BIND_NOW, so merely linking it cost every run its
// 64 000 relocations at start-up and about 26 MB of resident symbol tables.
#include <CLI/CLI.hpp>
#include <functional>
#include <memory>
#include <string>

#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"

namespace slurry::cli {

/// `slurry surface DIR [--scene S] [--voxel-size H] [--spacing S] [--method M] [--smoothing N] [--formats LIST]
/// [--points] [--threads N] [--quiet]`: surfaces a PLY frame sequence already written.
struct SurfaceCommand {
  CLI::App* app = nullptr;
  std::string dir, scene, voxel_size, spacing, method, smoothing, formats = "vdb,ply,obj", threads;
  bool points = false, quiet = false;
};
void add_surface_command(CLI::App& app, SurfaceCommand& c);
/// Runs it (after a successful parse); returns the exit code: 0, 2 (usage), 3 (files).
int run_surface_command(const SurfaceCommand& c);

/// Writes the scene's pipeline outputs beside a frame just written; returns a log line.
using FrameOutputFn = std::function<std::string(const FrameReport&)>;

/// What the module exports, through `extern "C" const PipelineModule* slurry_pipeline_module()`.
/// The CLI and the module come from one build (the same compiler and types); `abi` guards
/// against a stale module left in place by an older build.
struct PipelineModule {
  int abi;
  int (*run_surface_command)(const SurfaceCommand&);
  FrameOutputFn (*frame_output_writer)(const Scene&);
};
constexpr int kPipelineAbi = 2;

/// The module, opened at the first call: SLURRY_PIPELINE_MODULE if set, else the path the
/// build placed it at relative to the executable (SLURRY_PIPELINE_MODULE_RELPATH). Throws
/// IoError naming the path and the loader's reason when it cannot be opened.
const PipelineModule& pipeline_module();

/// Writes the scene's pipeline outputs beside each frame the run writes (inside the module).
class FrameOutputWriter {
 public:
  explicit FrameOutputWriter(const Scene& scene);
  bool active() const;
  /// Writes the outputs of the frame just written (FrameReport::frame_data, from memory) beside
  /// it; returns a log line.
  std::string operator()(const FrameReport& r) const;

 private:
  struct State;
  std::shared_ptr<const State> state_;
};

}  // namespace slurry::cli
