// `slurry validate` (validate_command.h).
#include "validate_command.h"

#include <cstdio>

#include "slurry/engine/run/run.h"
#include "slurry/io/scene_file.h"

namespace slurry::cli {

void ValidateCommand::add(CLI::App& parent) {
  app = parent.add_subcommand("validate", "Check a scene file, its meshes and its resources, and exit");
  app->add_option("scene", scene_path, "Scene file (JSON)")->required();
  app->add_option("--memory-limit", memory, "Memory limit in GiB (replaces limits.memory_gb)");
}

void ValidateCommand::check() {
  if (app->count("--memory-limit")) memory_gb = parse_positive("--memory-limit", memory);
}

int ValidateCommand::run(const Process& process) const {
  return with_exit_codes(process, scene_path, [&] {
    const Scene scene = load_scene(scene_path);
    check_scene(scene, memory_gb);
    if (process.rank == 0)
      std::printf("%s: valid (%dD, %zu materials, %zu bodies)\n", scene_path.c_str(), scene.solver.dimension,
                  scene.materials.size(), scene.bodies.size());
    return 0;
  });
}

}  // namespace slurry::cli
