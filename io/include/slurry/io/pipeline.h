#pragma once
/// \file pipeline.h
/// The effects-pipeline files of a particle frame sequence (docs/pipeline-outputs.md):
/// beside `frame_NNNN.ply`, `surface_NNNN.vdb` (a level set grid named "surface"),
/// `surface_NNNN.ply` and `.obj` (its triangle mesh, the PLY with per-vertex velocity), and
/// `points_NNNN.vdb` (OpenVDB points with v, id and pscale). A scene asks for them with
/// output.surface and output.vdb_points; `slurry surface DIR` makes them from frames already
/// written.
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "slurry/engine/scene/scene.h"
#include "slurry/io/surface.h"

namespace slurry::io {

/// One surface per group of materials: `label` "" names the files surface_NNNN.*, another label
/// surface_<label>_NNNN.*; `materials` empty means every particle of the frame.
struct SurfaceGroup {
  std::string label;
  std::vector<int> materials;
};

/// What to write for each frame.
struct FrameOutputs {
  bool vdb = false, ply = false,
       obj = false;         ///< the surface as a level set, a PLY mesh, an OBJ mesh
  bool vdb_points = false;  ///< points_NNNN.vdb
  SurfaceParams params;     ///< voxel size, particle spacing, smoothing
  std::vector<SurfaceGroup> groups{SurfaceGroup{}};
  PlyFormat format = PlyFormat::BinaryLittleEndian;  ///< of the PLY mesh
  bool any_surface() const { return vdb || ply || obj; }
  bool any() const { return any_surface() || vdb_points; }
};

/// The outputs a scene asks for (output.surface, output.vdb_points, output.surface_voxel_size,
/// output.surface_method, output.surface_smoothing, output.surface_per_material): voxel size domain.dx unless set,
/// particle spacing dx / ppc^(1/dim) for the largest particles_per_cell of its bodies and
/// emitters; groups: the scene's liquid (FLIP: every particle; MPM: the "fluid" materials, or
/// every particle if it has none), or one group per such material with surface_per_material.
FrameOutputs frame_outputs(const Scene& scene);

/// Counts of what write_frame_outputs wrote (summed over the groups).
struct FrameOutputReport {
  std::vector<std::filesystem::path> files;
  std::size_t points = 0, vertices = 0, triangles = 0, voxels = 0;
  double surface_seconds = 0;  ///< wall time of surfacing (level set, filtering, mesh, velocities)
  double write_seconds = 0;    ///< wall time of writing the files
};

/// Writes the outputs of particle frame `frame` (index `index`) into `dir`. A group with no
/// particles in this frame writes no surface files. With vdb_points and a `whitewater` frame
/// (FLIP whitewater, Solver::whitewater_frame_view), also whitewater_NNNN.vdb: OpenVDB points
/// with P, v, id, type and pscale. Throws IoError.
FrameOutputReport write_frame_outputs(const Frame& frame, int index,
                                      const std::filesystem::path& dir,
                                      const FrameOutputs& outputs, const Frame* whitewater = nullptr);

/// The frames `frame_NNNN.ply` of `dir`, sorted by index. Throws IoError if `dir` is no directory.
std::vector<std::pair<int, std::filesystem::path>> find_frames(const std::filesystem::path& dir);

/// Runs `work` with the worker threads of OpenVDB (oneTBB) and of Slurry's loops limited to
/// `threads` (0 = all cores): in a task arena of that concurrency, with a parallel::ThreadLimit
/// on the calling thread. Nothing process-wide is changed.
void with_threads(int threads, const std::function<void()>& work);

}  // namespace slurry::io
