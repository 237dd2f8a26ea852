// `slurry merge` (merge_command.h).
#include "merge_command.h"

#include <cstdio>

#include "slurry/engine/run/run.h"

namespace slurry::cli {

void MergeCommand::add(CLI::App& parent) {
  app = parent.add_subcommand(
      "merge", "Join the per-rank frames of a run split over MPI processes (output.per_rank: frame_NNNN.rankR.ply) "
               "into frame_NNNN.ply, the frames one process writes");
  app->add_option("directory", directory, "Output directory holding frame_NNNN.rankR.ply files")->required();
  app->add_flag("--keep-parts", keep_parts, "Keep the per-rank files (default: removed once merged)");
}

int MergeCommand::run(const Process& process) const {
  if (process.rank != 0) return 0;
  try {
    const auto m = merge_rank_frames(directory, keep_parts);
    if (m.frames == 0) throw IoError(directory + ": no per-rank frames (frame_NNNN.rankR.ply) to merge");
    std::printf("slurry: merged %d frames from %d per-rank files in %s (%zu particles in the last)\n", m.frames, m.parts,
                directory.c_str(), m.particles);
    return 0;
  } catch (const IoError& e) {
    return process.report(true, 3, e.what());
  }
}

}  // namespace slurry::cli
