// The CLI's side of the effects-pipeline module (pipeline.h): the surface command's options,
// and opening the module when a run needs it.
#include <dlfcn.h>
#include <unistd.h>

#include <cerrno>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <string>

#include "pipeline.h"
#include "slurry/engine/errors.h"

namespace slurry::cli {

void add_surface_command(CLI::App& app, SurfaceCommand& c) {
  c.app = app.add_subcommand(
      "surface",
      "Surface a PLY frame sequence already written: level sets (.vdb) and meshes (.ply, .obj)");
  c.app->add_option("dir", c.dir, "Directory of frame_NNNN.ply files (the outputs go beside them)")
      ->required();
  c.app->add_option(
      "--scene", c.scene,
      "Scene of the frames: its domain.dx, particles_per_cell and output.surface_* settings "
      "(default: the scene named in the frames)");
  c.app->add_option("--voxel-size", c.voxel_size,
                    "Level-set voxel size in m (default: the scene's domain.dx)");
  c.app->add_option("--spacing", c.spacing,
                    "Particle spacing in m (default: dx / particles_per_cell^(1/3))");
  c.app->add_option("--method", c.method,
                    "Surfacing method: anisotropic or spheres (default: output.surface_method, anisotropic)");
  c.app->add_option("--smoothing", c.smoothing,
                    "Gaussian smoothing passes (default: output.surface_smoothing, 0)");
  c.app->add_option("--formats", c.formats,
                    "Comma-separated surface formats: vdb, ply, obj (default: all three)");
  c.app->add_flag("--points", c.points, "Also write OpenVDB points (points_NNNN.vdb)");
  c.app->add_option("--threads,-t", c.threads, "Worker threads (0 = all cores)");
  c.app->add_flag("--quiet,-q", c.quiet, "No progress output");
}

namespace {

/// SLURRY_PIPELINE_MODULE, or the module's place relative to this executable.
std::string module_path() {
  if (const char* env = std::getenv("SLURRY_PIPELINE_MODULE"); env && *env) return env;
  char exe[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
  if (n <= 0) throw IoError(std::string("/proc/self/exe: cannot find this executable to load its pipeline module: ") +
                            std::strerror(errno) + " (set SLURRY_PIPELINE_MODULE to the module's path)");
  exe[n] = '\0';
  return (std::filesystem::path(exe).parent_path() / SLURRY_PIPELINE_MODULE_RELPATH).lexically_normal().string();
}

}  // namespace

const PipelineModule& pipeline_module() {
  // Opened once per process and never closed: the writers it returns live in it.
  static std::mutex mutex;
  static const PipelineModule* module = nullptr;
  const std::lock_guard<std::mutex> lock(mutex);
  if (module) return *module;
  const std::string path = module_path();
  void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (!handle)
    throw IoError(path + ": cannot load slurry's effects-pipeline module (OpenVDB surfaces and points): " + dlerror() +
                  " (it is installed beside the CLI; SLURRY_PIPELINE_MODULE overrides its path)");
  using Entry = const PipelineModule* (*)();
  const auto entry = reinterpret_cast<Entry>(dlsym(handle, "slurry_pipeline_module"));
  const PipelineModule* m = entry ? entry() : nullptr;
  if (!m || m->abi != kPipelineAbi)
    throw IoError(path + ": not the effects-pipeline module of this slurry build (expected the entry point "
                         "slurry_pipeline_module with ABI " + std::to_string(kPipelineAbi) + ")");
  module = m;
  return *module;
}

}  // namespace slurry::cli
