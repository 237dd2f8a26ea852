#pragma once
/// \file surface.h
/// Effects-pipeline outputs from particles: a narrow-band level set of the liquid (an OpenVDB
/// FloatGrid named "surface"), a triangle mesh of its zero level with per-vertex velocities,
/// OpenVDB points (PointDataGrid) with velocity, id and pscale, and PLY/OBJ mesh files.
/// OpenVDB stays behind this header: no OpenVDB type appears here, so a program including it
/// needs no OpenVDB headers (only the slurry::io target links OpenVDB).
///
/// Surfacing (surface_particles) has two methods.
///
/// SurfaceMethod::Anisotropic (the default) follows Yu & Turk 2013, "Reconstructing surfaces of
/// particle-based fluids using anisotropic kernels" (ACM TOG 32(1)), the method splashsurf uses,
/// and keeps the particles' volume:
///  A1. each particle spreads its volume spacing^3 with a kernel shaped by its neighbourhood
///      within 2 spacings: round of radius 2 spacings in the bulk, flattened across a flat
///      surface, a disc in a sheet, at most 4:1; round and small (radius 1 spacing) for a lone
///      particle; centred at its position moved half-way to its neighbours' weighted mean. The sum
///      is the liquid's volume fraction, about 1 inside and 0 outside (src/vdb/anisotropic.h);
///  A2. `smoothing` passes of a Gaussian filter (openvdb::tools::Filter::gaussian, width one
///      voxel) smooth the field;
///  A3. the level is chosen so that the voxels above it hold the particles' volume
///      n spacing^3 (the k-th largest voxel value), within [kMinIso, kMaxIso]: smoothing and
///      the kernels' shapes change where the surface lies, not how much liquid it encloses;
///  A4. openvdb::tools::volumeToMesh meshes that level (adaptivity 0); a droplet of one particle
///      is a small closed piece, none is dropped;
///  A5. the level set is the narrow-band signed distance to that mesh, 3 voxels either side: the
///      distance to its nearest triangle (src/vdb/mesh_band.h; exact within a voxel of the
///      surface), negative where the field exceeds the level or inside a droplet.
///
/// SurfaceMethod::Spheres follows the usual "union of spheres, then closing" recipe:
///  1. every particle is rasterized as a sphere of radius r = max(spacing, 1.5 voxels) into a
///     narrow-band signed distance field (what openvdb::tools::ParticlesToLevelSet computes,
///     1.5 voxels being its smallest radius; see union_of_spheres);
///  2. the field is eroded by r - spacing / 2 (LevelSetFilter::offset), so the zero level lies
///     half a particle spacing beyond the outermost particle centres, where the sampled liquid
///     ends (each particle stands for a cube of side `spacing`); with step 1 this is a
///     morphological closing, which fills the gaps between the spheres;
///  3. `smoothing` iterations of LevelSetFilter::gaussian(1) (OpenVDB: a separable Gaussian of
///     width one voxel, approximated by 4 mean-filter passes, followed by renormalization) smooth
///     away the bumps the spheres leave. Like any smoothing it shrinks convex parts: a pass has
///     the variance 4 x 2h^2/3 of four 3-voxel box means (h the voxel size), and diffusing
///     phi = |x| - R for that variance moves a sphere's surface inward by (8 h^2 / 3) / R per pass
///     (the Laplacian of |x| is 2/|x|), 0.18 voxel for R = 15 voxels; thin sheets and droplets
///     erode away;
///  4. openvdb::tools::volumeToMesh at isovalue 0 with adaptivity 0 meshes the zero level
///     (quads split along the shorter diagonal); triangles are oriented with outward normals.
///
/// Both: each vertex takes the particles' velocity averaged with the poly6 weight
/// (1 - d^2/h^2)^3 within h = 2 spacing (Mueller, Charypar & Gross 2003, "Particle-based
/// fluid simulation for interactive applications", eq. 20), or the nearest particle's if
/// none lies that close, for motion blur.
#include <array>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "slurry/io/ply.h"

namespace slurry::io {

/// Particles in world space (m). `velocity` (m/s) and `id` are empty or hold one entry per
/// position.
struct PointCloud {
  std::vector<std::array<float, 3>> position;
  std::vector<std::array<float, 3>> velocity;
  std::vector<std::uint32_t> id;
  std::vector<std::uint8_t> type;  ///< whitewater frames' `type` (0 spray, 1 foam, 2 bubble), else empty
  std::size_t size() const { return position.size(); }
};

/// Reads a particle frame (a PLY "vertex" element with x, y and optionally z, vx, vy, vz, id;
/// 2D frames get z = 0). If `material` >= 0 and the frame has a "material" column, only that
/// material's particles are taken. Throws IoError naming the file.
PointCloud point_cloud(const Frame& frame, int material = -1);

enum class SurfaceMethod { Anisotropic, Spheres };

/// The range of the anisotropic method's level (A3): a volume fraction the field reaches.
constexpr double kMinIso = 0.1, kMaxIso = 0.9;

struct SurfaceParams {
  double voxel_size = 0;  ///< m, > 0: the level set's voxel size (the CLI uses domain.dx)
  double spacing = 0;     ///< m, > 0: the particle spacing, dx / particles_per_cell^(1/dim)
  int smoothing = 0;      ///< Gaussian filter iterations, >= 0 (A2 or step 3 below)
  SurfaceMethod method = SurfaceMethod::Anisotropic;
  /// Throws std::invalid_argument naming the field, the value and the expected range.
  void validate() const;
  /// The radius the particles are rasterized with, max(spacing, 1.5 voxel_size).
  double radius() const;
};

/// A triangle mesh: vertices (m), per-vertex velocities (m/s; empty if the particles had none)
/// and triangles as vertex index triples, counter-clockwise seen from outside.
struct TriangleMesh {
  std::vector<std::array<float, 3>> vertices;
  std::vector<std::array<float, 3>> velocities;
  std::vector<std::array<std::int32_t, 3>> triangles;
};

/// A narrow-band level set (an openvdb::FloatGrid of class level set, negative inside), named
/// "surface". Cheap to copy (shared, immutable after construction).
class LevelSet {
 public:
  struct Impl;
  explicit LevelSet(std::shared_ptr<const Impl> impl) : impl_(std::move(impl)) {}
  /// Active voxels: those of the narrow band (about 3 voxels either side of the surface).
  std::size_t active_voxels() const;
  double voxel_size() const;
  /// Index-space bounding box of the active voxels: {min i, j, k, max i, j, k}, inclusive.
  std::array<std::int32_t, 6> bounding_box() const;
  /// The signed distance at a world-space point (trilinear; +background outside the band).
  double value(const std::array<double, 3>& p) const;
  /// The volume enclosed by the zero level (m^3).
  double enclosed_volume() const;
  /// Whether it carries a "velocity" grid (surface_particles of points with velocities).
  bool has_velocity() const;
  /// The velocity (m/s) at a world-space point, trilinear in the band's voxels (0 beyond them,
  /// or without a velocity grid).
  std::array<double, 3> velocity(const std::array<double, 3>& p) const;
  const Impl& impl() const { return *impl_; }

 private:
  std::shared_ptr<const Impl> impl_;
};

struct Surface {
  LevelSet level_set{nullptr};
  TriangleMesh mesh;
  double iso = 0;  ///< the anisotropic method's level (A3); 0 for the spheres method
};

/// Step 1 alone: the union of spheres of `radius` (>= 1.5 voxels) as a narrow-band level set of
/// half-width 3 voxels. By default computed on a dense block of voxels over the particles, with
/// the values ParticlesToLevelSet::rasterizeSpheres computes (voxel for voxel, tested) about 5x
/// faster; by ParticlesToLevelSet itself with `openvdb_rasterizer`, or when the block would
/// exceed 2^28 voxels.
LevelSet union_of_spheres(const PointCloud& points, double voxel_size, double radius,
                          bool openvdb_rasterizer = false);
/// The level set of surface_particles (A1-A5 or 1-3 above). Throws std::invalid_argument for
/// invalid parameters, no particles or a non-finite position.
LevelSet particles_to_level_set(const PointCloud& points, const SurfaceParams& params);
/// Meshes the zero level of a level set (step 4 above), with velocities from `points` when it
/// has them.
TriangleMesh level_set_to_mesh(const LevelSet& level_set, const PointCloud& points,
                               const SurfaceParams& params);
/// The level set and its mesh, by params.method.
Surface surface_particles(const PointCloud& points, const SurfaceParams& params);
/// The mesh of surface_particles alone (the same vertices, triangles and vertex velocities), for
/// outputs without a .vdb: the anisotropic method then skips the level set of its mesh (A6) and
/// its velocity grid, a quarter of its time on the 3D dam break (benchmarks/RESULTS.md); the
/// spheres method meshes its level set and drops it without a velocity grid.
/// Surface::level_set is empty (no voxels).
Surface surface_mesh(const PointCloud& points, const SurfaceParams& params);
/// Surfacing keeps the large buffers (4 MiB and more) that a frame frees, up to 2 GiB in all, and
/// reuses them at the next frame instead of touching fresh pages (io/src/vdb/buffer.h). This
/// returns them to the system, for a process that surfaces no more frames (a bake's end, an
/// editor session); it returns the bytes released. Thread-safe.
std::size_t release_surfacing_memory();

/// Per-vertex velocities (step 5) at `vertices` from `points` (which must have velocities).
std::vector<std::array<float, 3>> sample_velocities(
    const std::vector<std::array<float, 3>>& vertices, const PointCloud& points, double spacing);

/// Writes the level set as a .vdb file holding a FloatGrid named "surface" (class level set) and,
/// if it has one, a Vec3s grid named "velocity" over the same voxels (the name Blender's and
/// Houdini's volume motion blur read), atomically (temporary name, then rename). Throws IoError.
void write_vdb(const std::filesystem::path& path, const LevelSet& level_set);
/// Reads the FloatGrid called `name` from a .vdb file, with its "velocity" grid if the file has
/// one. Throws IoError.
LevelSet read_vdb_level_set(const std::filesystem::path& path, const std::string& name = "surface");

/// Writes OpenVDB points (a PointDataGrid named "points", voxel size `voxel_size`) with the
/// attributes P, v (if the cloud has velocities), id (int32, if it has ids), type (int32, if it
/// has types: whitewater) and pscale (float, `radius` for every point), the names Houdini and
/// other VDB point readers expect. Atomic.
void write_vdb_points(const std::filesystem::path& path, const PointCloud& points, double radius,
                      double voxel_size);
/// Reads the PointDataGrid called `name` back (P, v, id, type when it has them), points in
/// ascending id order if they have ids;
/// `pscale` (if not null) receives each point's radius. Throws IoError.
PointCloud read_vdb_points(const std::filesystem::path& path, std::vector<float>* pscale = nullptr,
                           const std::string& name = "points");

/// Writes a mesh as PLY (our writer): element "vertex" with x y z (float) and vx vy vz when it
/// has velocities, element "face" with the list vertex_indices. Atomic; throws IoError.
void write_mesh_ply(const std::filesystem::path& path, const TriangleMesh& mesh,
                    PlyFormat format = PlyFormat::BinaryLittleEndian);
/// Writes a mesh as Wavefront OBJ (`v x y z` lines, then `f a b c` with 1-based indices).
/// OBJ has no per-vertex attribute for velocity: use the PLY or VDB outputs for motion blur.
/// Atomic; throws IoError.
void write_mesh_obj(const std::filesystem::path& path, const TriangleMesh& mesh);

}  // namespace slurry::io
