#pragma once
// `slurry validate SCENE.json [--memory-limit GB]`: checks a scene file, its meshes and its
// resources (check_scene), and exits: 0 valid, 2 invalid scene, 3 file or resource error.
#include <CLI/CLI.hpp>
#include <string>

#include "command.h"

namespace slurry::cli {

struct ValidateCommand {
  CLI::App* app = nullptr;
  std::string scene_path, memory;
  double memory_gb = 0;

  void add(CLI::App& parent);
  void check();
  int run(const Process& process) const;
};

}  // namespace slurry::cli
