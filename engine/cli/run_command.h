#pragma once
// `slurry run SCENE.json [--out DIR] [--frames N] [--threads N] [--memory-limit GB] [--overwrite]
// [--ascii] [--quiet] [--resume [--force]]`: runs a scene and writes its frames (and the
// pipeline outputs it asks for); `slurry resume DIR` (resume_command.cpp) continues one.
#include <CLI/CLI.hpp>
#include <string>

#include "command.h"

namespace slurry::cli {

/// What `run` and `resume` are asked to do, parsed.
struct RunRequest {
  std::string scene_path;  ///< empty for resume: the scene the newest checkpoint names
  std::string resume_dir;  ///< resume: the output directory holding the checkpoints
  std::string out_dir;
  int frames = -1, threads = 0;
  double memory_gb = 0;
  bool ascii = false, quiet = false, overwrite = false, resume = false, force = false;
};

/// Runs the request to its last frame (or until SIGINT / SIGTERM); returns the exit code.
int run_request(const Process& process, RunRequest request);

/// The options --frames, --threads and --memory-limit as typed, checked after parsing.
struct NumberOptions {
  std::string frames, threads, memory;
  /// Parses those given on `app` into `r` (UsageError naming the option).
  void parse(const CLI::App& app, RunRequest& r) const;
};

struct RunCommand {
  CLI::App* app = nullptr;
  CLI::Option* out_option = nullptr;
  RunRequest request;
  NumberOptions numbers;

  void add(CLI::App& parent);
  /// After a successful parse: the checks between options (UsageError).
  void check();
};

}  // namespace slurry::cli
