#pragma once
// `slurry resume DIR [--frames N] [--threads N] [--memory-limit GB] [--ascii] [--quiet] [--force]`:
// continues the run whose checkpoints are in DIR, reading its scene file again.
#include <CLI/CLI.hpp>

#include "run_command.h"

namespace slurry::cli {

struct ResumeCommand {
  CLI::App* app = nullptr;
  RunRequest request;
  NumberOptions numbers;

  void add(CLI::App& parent);
  void check() { numbers.parse(*app, request); }
};

}  // namespace slurry::cli
