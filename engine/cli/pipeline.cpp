// The effects-pipeline part of the slurry CLI (pipeline.h): the slurry_pipeline module.
#include "pipeline.h"

#include <unistd.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <thread>

#include "slurry/engine/errors.h"
#include "slurry/io/pipeline.h"
#include "slurry/io/scene_file.h"
#include "slurry/transfer/parallel.h"

namespace fs = std::filesystem;

namespace slurry::cli {
namespace {

struct Usage : std::runtime_error {
  using std::runtime_error::runtime_error;
};

double positive(const std::string& option, const std::string& text) {
  std::size_t end = 0;
  double v = 0;
  try {
    v = std::stod(text, &end);
  } catch (const std::exception&) {
    end = 0;
  }
  if (end == 0 || end != text.size() || !(v > 0) || !std::isfinite(v))
    throw Usage(option + ": expected a number > 0, got \"" + text + "\"");
  return v;
}

int integer(const std::string& option, const std::string& text, int lo, int hi) {
  std::size_t end = 0;
  long v = 0;
  try {
    v = std::stol(text, &end);
  } catch (const std::exception&) {
    end = 0;
  }
  if (end == 0 || end != text.size() || v < lo || v > hi)
    throw Usage(option + ": expected an integer in [" + std::to_string(lo) + ", " +
                std::to_string(hi) + "], got \"" + text + "\"");
  return int(v);
}

/// The scene a frame names in its comment ("slurry ... frame t=... source=PATH"), or "".
std::string frame_source(const io::PlyData& frame) {
  for (const auto& c : frame.comments) {
    const auto at = c.find(" source=");
    if (c.rfind("slurry ", 0) == 0 && at != std::string::npos) return c.substr(at + 8);
  }
  return "";
}

std::string seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, s < 60 ? "%.1f s" : "%.0f s", s);
  return buf;
}

}  // namespace

int run_surface_command(const SurfaceCommand& c) {
  try {
    io::FrameOutputs out;
    std::istringstream formats(c.formats);
    for (std::string f; std::getline(formats, f, ',');) {
      if (f == "vdb")
        out.vdb = true;
      else if (f == "ply")
        out.ply = true;
      else if (f == "obj")
        out.obj = true;
      else
        throw Usage("--formats: expected a comma-separated list of vdb, ply, obj, got \"" +
                    c.formats + "\"");
    }
    out.vdb_points = c.points;
    if (!out.any()) throw Usage("--formats: expected at least one of vdb, ply, obj (or --points)");
    const int threads = c.threads.empty() ? 0 : integer("--threads", c.threads, 0, parallel::max_thread_count());
    double voxel = c.voxel_size.empty() ? 0 : positive("--voxel-size", c.voxel_size);
    double spacing = c.spacing.empty() ? 0 : positive("--spacing", c.spacing);
    const int smoothing = c.smoothing.empty() ? -1 : integer("--smoothing", c.smoothing, 0, 100);

    const auto frames = io::find_frames(c.dir);
    if (frames.empty()) throw IoError(c.dir + ": no frame_NNNN.ply files in it");
    // The scene: given, or named by the first frame (relative to the working directory, as run
    // wrote it).
    std::string scene_path = c.scene;
    if (scene_path.empty() && (voxel == 0 || spacing == 0)) {
      scene_path = frame_source(io::read_ply(frames.front().second));
      std::error_code ec;
      if (scene_path.empty() || !fs::is_regular_file(scene_path, ec))
        throw Usage(
            frames.front().second.string() + " names the scene \"" + scene_path +
            "\", which is not a file here: pass --scene SCENE.json, or --voxel-size and --spacing");
    }
    if (!scene_path.empty()) {
      const Scene scene = load_scene(scene_path);
      const io::FrameOutputs from_scene = io::frame_outputs(scene);
      out.params = from_scene.params;
      out.groups = from_scene.groups;
      out.format = from_scene.format;
    }
    if (voxel > 0) out.params.voxel_size = voxel;
    if (spacing > 0) out.params.spacing = spacing;
    if (smoothing >= 0) out.params.smoothing = smoothing;
    if (c.method == "anisotropic") out.params.method = io::SurfaceMethod::Anisotropic;
    else if (c.method == "spheres") out.params.method = io::SurfaceMethod::Spheres;
    else if (!c.method.empty())
      throw Usage("--method: expected anisotropic or spheres, got \"" + c.method + "\"");
    try {
      out.params.validate();
    } catch (const std::invalid_argument& e) {
      throw Usage(std::string("surface parameters: ") + e.what());
    }

    const bool tty = isatty(fileno(stderr)) != 0;
    if (!c.quiet)
      std::fprintf(stderr,
                   "slurry: surfacing %zu frames in %s (%s): voxel %.4g m, particle spacing %.4g m, "
                   "%d smoothing passes\n",
                   frames.size(), c.dir.c_str(),
                   out.params.method == io::SurfaceMethod::Anisotropic ? "anisotropic kernels" : "spheres",
                   out.params.voxel_size, out.params.spacing, out.params.smoothing);
    const auto start = std::chrono::steady_clock::now();
    std::size_t files = 0;
    // OpenVDB (oneTBB) and Slurry loops in an arena of `threads` workers.
    io::with_threads(threads, [&] {
      for (std::size_t i = 0; i < frames.size(); ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        const io::PlyData frame = io::read_ply(frames[i].second);
        const io::FrameOutputReport r = io::write_frame_outputs(frame, frames[i].first, c.dir, out);
        files += r.files.size();
        if (c.quiet) continue;
        const auto now = std::chrono::steady_clock::now();
        const double took = std::chrono::duration<double>(now - t0).count();
        const double elapsed = std::chrono::duration<double>(now - start).count();
        const double eta = elapsed / double(i + 1) * double(frames.size() - i - 1);
        if (tty) {
          const int width = 30, filled = int(width * (i + 1) / frames.size());
          std::string bar(std::size_t(filled), '#');
          bar.resize(width, '.');
          std::fprintf(stderr, "\r[%s] frame %zu/%zu  %.2f s/frame  ETA %s   ", bar.c_str(), i + 1,
                       frames.size(), took, seconds(eta).c_str());
          if (i + 1 == frames.size()) std::fputc('\n', stderr);
        } else {
          std::fprintf(stderr,
                       "frame %d: %zu particles -> %zu vertices, %zu triangles, %zu voxels; "
                       "surfacing %.3f s, writing %.3f s, "
                       "frame %.3f s\n",
                       frames[i].first, frame.table("vertex").count, r.vertices, r.triangles,
                       r.voxels, r.surface_seconds, r.write_seconds, took);
        }
        std::fflush(stderr);
      }
    });
    const double total =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("done: %zu frames surfaced in %s, %zu files written to %s\n", frames.size(),
                seconds(total).c_str(), files, c.dir.c_str());
    return 0;
  } catch (const Usage& e) {
    std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 2;
  } catch (const SceneError& e) {
    std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 2;
  } catch (const IoError& e) {
    std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 3;
  }
}

struct FrameOutputWriter::State {
  io::FrameOutputs outputs;
};

FrameOutputWriter::FrameOutputWriter(const Scene& scene) {
  auto s = std::make_shared<State>();
  s->outputs = io::frame_outputs(scene);
  state_ = std::move(s);
}

bool FrameOutputWriter::active() const {
  return state_->outputs.any();
}

std::string FrameOutputWriter::operator()(const FrameReport& r) const {
  if (!active() || !r.frame_data) return "";
  const auto t0 = std::chrono::steady_clock::now();
  const io::FrameOutputReport out =
      io::write_frame_outputs(*r.frame_data, r.frame, r.file.parent_path(), state_->outputs, r.whitewater_data);
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  char line[160];
  std::snprintf(line, sizeof line,
                "%zu pipeline files (%zu vertices, %zu voxels), surfacing %.2f s, in all %.2f s",
                out.files.size(), out.vertices, out.voxels, out.surface_seconds, took);
  return line;
}

}  // namespace slurry::cli

extern "C" __attribute__((visibility("default"))) const slurry::cli::PipelineModule* slurry_pipeline_module() {
  static const slurry::cli::PipelineModule module{
      slurry::cli::kPipelineAbi, &slurry::cli::run_surface_command, [](const slurry::Scene& scene) {
        const slurry::cli::FrameOutputWriter writer(scene);
        return slurry::cli::FrameOutputFn(writer);
      }};
  return &module;
}
