// The OpenVDB level-set half of slurry::io (surface.h): particles to a narrow-band level set,
// filtering, meshing, and .vdb grid files. Kept in one translation unit because OpenVDB's
// headers are slow to compile.
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/ParticlesToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <system_error>
#include <unistd.h>

#include "slurry/engine/errors.h"
#include "slurry/io/surface.h"
#include "vdb_common.h"

namespace slurry::io {

struct LevelSet::Impl {
  openvdb::FloatGrid::ConstPtr grid;
};

namespace {

constexpr float kHalfWidth = 3.0f;  // narrow band half width (voxels), OpenVDB's LEVEL_SET_HALF_WIDTH

/// The particle list ParticlesToLevelSet reads (its documented duck-typed interface).
struct ParticleList {
  using PosType = openvdb::Vec3R;
  const PointCloud& cloud;
  std::size_t size() const { return cloud.size(); }
  void getPos(std::size_t n, openvdb::Vec3R& xyz) const {
    const auto& p = cloud.position[n];
    xyz = openvdb::Vec3R(p[0], p[1], p[2]);
  }
};

std::string fmt(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", x);
  return buf;
}

}  // namespace

void SurfaceParams::validate() const {
  if (!(voxel_size > 0) || !std::isfinite(voxel_size))
    throw std::invalid_argument("voxel_size: expected a length > 0, got " + fmt(voxel_size));
  if (!(spacing > 0) || !std::isfinite(spacing))
    throw std::invalid_argument("spacing: expected a length > 0, got " + fmt(spacing));
  if (spacing > 1000 * voxel_size || voxel_size > 1000 * spacing)
    throw std::invalid_argument("spacing / voxel_size: expected a ratio within [1e-3, 1e3], got " +
                                fmt(spacing / voxel_size));
  if (smoothing < 0 || smoothing > 100)
    throw std::invalid_argument("smoothing: expected an integer in [0, 100], got " + std::to_string(smoothing));
}

double SurfaceParams::radius() const { return std::max(spacing, 1.5 * voxel_size); }

std::size_t LevelSet::active_voxels() const { return std::size_t(impl_->grid->activeVoxelCount()); }
double LevelSet::voxel_size() const { return impl_->grid->voxelSize()[0]; }

std::array<std::int32_t, 6> LevelSet::bounding_box() const {
  const openvdb::CoordBBox b = impl_->grid->evalActiveVoxelBoundingBox();
  return {b.min().x(), b.min().y(), b.min().z(), b.max().x(), b.max().y(), b.max().z()};
}

double LevelSet::value(const std::array<double, 3>& p) const {
  openvdb::tools::GridSampler<openvdb::FloatGrid, openvdb::tools::BoxSampler> s(*impl_->grid);
  return s.wsSample(openvdb::Vec3R(p[0], p[1], p[2]));
}

double LevelSet::enclosed_volume() const {
  return openvdb::tools::levelSetVolume(*impl_->grid, /*useWorldSpace=*/true);
}

LevelSet particles_to_level_set(const PointCloud& points, const SurfaceParams& params) {
  params.validate();
  if (points.size() == 0) throw std::invalid_argument("particles_to_level_set: no particles to surface");
  detail::initialize_openvdb();
  const double h = params.voxel_size, r = params.radius();
  openvdb::FloatGrid::Ptr grid = openvdb::createLevelSet<openvdb::FloatGrid>(h, kHalfWidth);
  {
    openvdb::tools::ParticlesToLevelSet<openvdb::FloatGrid> raster(*grid);
    raster.setRmin(1.5);  // OpenVDB's default, stated: r >= 1.5 voxels by construction
    raster.rasterizeSpheres(ParticleList{points}, r);
    raster.finalize(/*prune=*/true);
  }
  openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(*grid);
  // Closing: erode the union of spheres back to half a spacing beyond the outermost centres.
  filter.offset(float(r - 0.5 * params.spacing));
  for (int i = 0; i < params.smoothing; ++i) filter.gaussian(1);
  grid->setName("surface");
  grid->setGridClass(openvdb::GRID_LEVEL_SET);
  return LevelSet(std::make_shared<const LevelSet::Impl>(LevelSet::Impl{grid}));
}

TriangleMesh level_set_to_mesh(const LevelSet& level_set, const PointCloud& points, const SurfaceParams& params) {
  std::vector<openvdb::Vec3s> vertices;
  std::vector<openvdb::Vec3I> tris;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*level_set.impl().grid, vertices, tris, quads, /*isovalue=*/0.0, /*adaptivity=*/0.0);
  TriangleMesh mesh;
  mesh.vertices.resize(vertices.size());
  for (std::size_t i = 0; i < vertices.size(); ++i) mesh.vertices[i] = {vertices[i][0], vertices[i][1], vertices[i][2]};
  // volumeToMesh orients polygons clockwise seen from the outside of a level set (negative
  // inside); reversed here, so that normals (b - a) x (c - a) point out.
  const auto tri = [&](openvdb::Index a, openvdb::Index b, openvdb::Index c) {
    mesh.triangles.push_back({std::int32_t(a), std::int32_t(c), std::int32_t(b)});
  };
  mesh.triangles.reserve(tris.size() + 2 * quads.size());
  for (const auto& t : tris) tri(t[0], t[1], t[2]);
  const auto dist2 = [&](openvdb::Index a, openvdb::Index b) { return (vertices[a] - vertices[b]).lengthSqr(); };
  for (const auto& q : quads) {
    if (dist2(q[0], q[2]) <= dist2(q[1], q[3])) {
      tri(q[0], q[1], q[2]);
      tri(q[0], q[2], q[3]);
    } else {
      tri(q[0], q[1], q[3]);
      tri(q[1], q[2], q[3]);
    }
  }
  if (!points.velocity.empty()) mesh.velocities = sample_velocities(mesh.vertices, points, params.spacing);
  return mesh;
}

Surface surface_particles(const PointCloud& points, const SurfaceParams& params) {
  LevelSet ls = particles_to_level_set(points, params);
  TriangleMesh mesh = level_set_to_mesh(ls, points, params);
  return {std::move(ls), std::move(mesh)};
}

void write_vdb(const std::filesystem::path& path, const LevelSet& level_set) {
  detail::initialize_openvdb();
  openvdb::GridPtrVec grids{level_set.impl().grid->deepCopyGrid()};
  detail::write_grids_atomically(path, grids);
}

LevelSet read_vdb_level_set(const std::filesystem::path& path, const std::string& name) {
  openvdb::GridBase::Ptr base = detail::read_grid(path, name);
  openvdb::FloatGrid::Ptr grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
  if (!grid)
    throw IoError(path.string() + ": grid \"" + name + "\" is a " + base->type() + ", expected a FloatGrid (a level set)");
  return LevelSet(std::make_shared<const LevelSet::Impl>(LevelSet::Impl{grid}));
}

namespace detail {

void initialize_openvdb() {
  static const bool done = [] {
    openvdb::initialize();
    return true;
  }();
  (void)done;
}

void write_grids_atomically(const std::filesystem::path& path, const openvdb::GridPtrVec& grids) {
  static int counter = 0;
  std::filesystem::path tmp = path;
  tmp += ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  try {
    openvdb::io::File file(tmp.string());
    file.write(grids);
    file.close();
  } catch (const openvdb::Exception& e) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw IoError(path.string() + ": cannot write the OpenVDB file: " + e.what());
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw IoError(path.string() + ": cannot rename the temporary file onto it: " + ec.message());
  }
}

openvdb::GridBase::Ptr read_grid(const std::filesystem::path& path, const std::string& name) {
  initialize_openvdb();
  try {
    openvdb::io::File file(path.string());
    file.open();
    if (!file.hasGrid(name)) {
      std::string names;
      for (auto it = file.beginName(); it != file.endName(); ++it) names += (names.empty() ? "" : ", ") + it.gridName();
      throw IoError(path.string() + ": no grid named \"" + name + "\" (it has: " + (names.empty() ? "none" : names) + ")");
    }
    openvdb::GridBase::Ptr grid = file.readGrid(name);
    file.close();
    return grid;
  } catch (const openvdb::Exception& e) {
    throw IoError(path.string() + ": cannot read it as an OpenVDB file: " + e.what());
  }
}

}  // namespace detail
}  // namespace slurry::io
