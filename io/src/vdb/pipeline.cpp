// Frame outputs of the effects pipeline (pipeline.h): what a scene asks for, writing them for
// one frame, finding a directory's frames.
#include "slurry/io/pipeline.h"

#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <regex>

#include "slurry/engine/errors.h"
#include "slurry/transfer/parallel.h"

namespace fs = std::filesystem;

namespace slurry::io {

FrameOutputs frame_outputs(const Scene& scene) {
  FrameOutputs out;
  const auto& o = scene.output;
  for (const auto& f : o.surface) {
    out.vdb = out.vdb || f == "vdb";
    out.ply = out.ply || f == "ply";
    out.obj = out.obj || f == "obj";
  }
  out.vdb_points = o.vdb_points;
  out.format = o.format == PlyEncoding::Ascii ? PlyFormat::Ascii : PlyFormat::BinaryLittleEndian;
  const double dx = scene.domain.dx;
  double ppc = 0;
  for (const auto& b : scene.bodies) ppc = std::max(ppc, b.particles_per_cell);
  for (const auto& e : scene.emitters) ppc = std::max(ppc, e.particles_per_cell);
  if (!(ppc > 0)) ppc = 8;
  out.params.voxel_size = o.surface_voxel_size > 0 ? o.surface_voxel_size : dx;
  out.params.spacing = dx / std::pow(ppc, 1.0 / scene.solver.dimension);
  out.params.smoothing = o.surface_smoothing;
  out.params.method = o.surface_method == "spheres" ? SurfaceMethod::Spheres : SurfaceMethod::Anisotropic;

  // The liquid: every particle of a FLIP scene; the "fluid" materials of an MPM scene (all of
  // them if it has none: a surface of snow or sand is asked for as well).
  std::vector<int> liquid;
  for (std::size_t m = 0; m < scene.materials.size(); ++m)
    if (scene.solver.type == SolverType::FLIP || scene.materials[m].model == ElasticModel::Fluid)
      liquid.push_back(int(m));
  if (liquid.empty())
    for (std::size_t m = 0; m < scene.materials.size(); ++m) liquid.push_back(int(m));
  out.groups.clear();
  if (o.surface_per_material && scene.materials.size() > 1) {
    for (int m : liquid) out.groups.push_back({scene.materials[std::size_t(m)].name, {m}});
  } else if (liquid.size() == scene.materials.size()) {
    out.groups.push_back({"", {}});
  } else {
    out.groups.push_back({"", liquid});
  }
  return out;
}

namespace {

fs::path numbered(const fs::path& dir, const std::string& stem, int index, const char* ext) {
  char num[16];
  std::snprintf(num, sizeof num, "%04d", index);
  return dir / (stem + "_" + num + ext);
}

}  // namespace

FrameOutputReport write_frame_outputs(const Frame& frame, int index, const fs::path& dir,
                                      const FrameOutputs& outputs, const Frame* whitewater) {
  FrameOutputReport report;
  if (outputs.vdb_points) {
    const PointCloud all = point_cloud(frame);
    const fs::path f = numbered(dir, "points", index, ".vdb");
    write_vdb_points(f, all, 0.5 * outputs.params.spacing, outputs.params.voxel_size);
    report.files.push_back(f);
    report.points += all.size();
  }
  if (outputs.vdb_points && whitewater && !whitewater->tables.empty()) {
    // Secondary particles are smaller than the liquid's: pscale a quarter of its spacing.
    const PointCloud secondary = point_cloud(*whitewater);
    const fs::path f = numbered(dir, "whitewater", index, ".vdb");
    write_vdb_points(f, secondary, 0.25 * outputs.params.spacing, outputs.params.voxel_size);
    report.files.push_back(f);
    report.points += secondary.size();
  }
  if (!outputs.any_surface()) return report;
  for (const auto& g : outputs.groups) {
    PointCloud cloud;
    if (g.materials.size() == 1) {
      cloud = point_cloud(frame, g.materials.front());
    } else if (!g.materials.empty()) {
      for (int m : g.materials) {
        PointCloud c = point_cloud(frame, m);
        cloud.position.insert(cloud.position.end(), c.position.begin(), c.position.end());
        cloud.velocity.insert(cloud.velocity.end(), c.velocity.begin(), c.velocity.end());
        cloud.id.insert(cloud.id.end(), c.id.begin(), c.id.end());
      }
    } else {
      cloud = point_cloud(frame);
    }
    if (cloud.size() == 0) continue;
    const std::string stem = g.label.empty() ? "surface" : "surface_" + g.label;
    const auto t0 = std::chrono::steady_clock::now();
    const Surface s = outputs.vdb ? surface_particles(cloud, outputs.params) : surface_mesh(cloud, outputs.params);
    const auto t1 = std::chrono::steady_clock::now();
    if (outputs.vdb) {
      report.files.push_back(numbered(dir, stem, index, ".vdb"));
      write_vdb(report.files.back(), s.level_set);
    }
    if (outputs.ply) {
      report.files.push_back(numbered(dir, stem, index, ".ply"));
      write_mesh_ply(report.files.back(), s.mesh, outputs.format);
    }
    if (outputs.obj) {
      report.files.push_back(numbered(dir, stem, index, ".obj"));
      write_mesh_obj(report.files.back(), s.mesh);
    }
    report.surface_seconds += std::chrono::duration<double>(t1 - t0).count();
    report.write_seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
    report.vertices += s.mesh.vertices.size();
    report.triangles += s.mesh.triangles.size();
    report.voxels += s.level_set.active_voxels();
  }
  return report;
}

std::vector<std::pair<int, fs::path>> find_frames(const fs::path& dir) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw IoError(dir.string() + ": expected a directory of frame_NNNN.ply files, it is none");
  static const std::regex frame(R"(frame_(\d{4,})\.ply)");
  std::vector<std::pair<int, fs::path>> frames;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    std::smatch m;
    const std::string name = e.path().filename().string();
    if (std::regex_match(name, m, frame)) frames.emplace_back(std::stoi(m[1].str()), e.path());
  }
  if (ec) throw IoError(dir.string() + ": cannot list it: " + ec.message());
  std::sort(frames.begin(), frames.end());
  return frames;
}

void with_threads(int threads, const std::function<void()>& work) {
  const parallel::ThreadLimit slurry_loops(threads);
  if (threads <= 0) {
    work();
    return;
  }
  tbb::task_arena arena(threads);
  arena.execute(work);
}

}  // namespace slurry::io
