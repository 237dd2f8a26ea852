#pragma once
// `slurry merge DIR [--keep-parts]`: joins the per-rank frames of a run split over MPI processes
// (output.per_rank: frame_NNNN.rankR.ply) into frame_NNNN.ply, the frames one process writes.
#include <CLI/CLI.hpp>
#include <string>

#include "command.h"

namespace slurry::cli {

struct MergeCommand {
  CLI::App* app = nullptr;
  std::string directory;
  bool keep_parts = false;

  void add(CLI::App& parent);
  int run(const Process& process) const;
};

}  // namespace slurry::cli
