#pragma once
// The effects-pipeline part of the slurry CLI (pipeline.cpp, built when slurry::io is, i.e.
// SLURRY_BUILD_IO=ON): the per-frame outputs a scene asks for (output.surface,
// output.vdb_points) and the `slurry surface DIR` command.
#include <CLI/CLI.hpp>
#include <string>

#include "slurry/engine/run.h"
#include "slurry/engine/scene.h"

namespace slurry::cli {

/// `slurry surface DIR [--scene S] [--voxel-size H] [--spacing S] [--smoothing N] [--formats LIST]
/// [--points] [--threads N] [--quiet]`: surfaces a PLY frame sequence already written.
struct SurfaceCommand {
  CLI::App* app = nullptr;
  std::string dir, scene, voxel_size, spacing, smoothing, formats = "vdb,ply,obj", threads;
  bool points = false, quiet = false;
};
void add_surface_command(CLI::App& app, SurfaceCommand& c);
/// Runs it (after a successful parse); returns the exit code: 0, 2 (usage), 3 (files).
int run_surface_command(const SurfaceCommand& c);

/// Writes the scene's pipeline outputs beside each frame the run writes.
class FrameOutputWriter {
 public:
  explicit FrameOutputWriter(const Scene& scene);
  bool active() const;
  /// Reads the frame just written and writes the outputs beside it; returns a log line.
  std::string operator()(const FrameReport& r) const;

 private:
  struct State;
  std::shared_ptr<const State> state_;
};

}  // namespace slurry::cli
