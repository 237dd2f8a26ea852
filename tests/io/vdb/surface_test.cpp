// slurry::io: particles to level set and mesh, VDB grids and points, PLY and OBJ meshes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <numeric>
#include <random>
#include <sstream>

#include "slurry/engine/errors.h"
#include "slurry/io/surface.h"
#include "mesh_volume.h"

namespace fs = std::filesystem;
using slurry::io::PointCloud;
using slurry::io::SurfaceParams;
using slurry::io::TriangleMesh;
using slurry_test::signed_volume;

namespace {

constexpr double kPi = 3.14159265358979323846;

/// Particles on a lattice of spacing s (cell centres) inside a sphere of radius R around c, the
/// way the engine seeds a body with particles_per_cell = (dx / s)^3. The sampled liquid is the
/// union of the lattice cells, whose volume tends to 4/3 pi R^3.
PointCloud lattice_sphere(double R, double s, std::array<double, 3> c) {
  PointCloud cloud;
  const int n = int(std::ceil(R / s)) + 1;
  for (int i = -n; i < n; ++i)
    for (int j = -n; j < n; ++j)
      for (int k = -n; k < n; ++k) {
        const double x = (i + 0.5) * s, y = (j + 0.5) * s, z = (k + 0.5) * s;
        if (x * x + y * y + z * z > R * R) continue;
        cloud.position.push_back({float(c[0] + x), float(c[1] + y), float(c[2] + z)});
      }
  return cloud;
}


fs::path temp_dir(const std::string& name) {
  const fs::path d =
      fs::temp_directory_path() / ("slurry_io_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A sphere of radius 0.3 m sampled at spacing 0.01 m (dx = 0.02, 8 particles per cell), surfaced
// on voxels of dx: the shared fixture of the sphere tests (one surfacing, ~113 k particles).
struct SphereCase {
  static constexpr double R = 0.3, dx = 0.02, s = 0.01;
  static constexpr std::array<double, 3> c{0.5, 0.45, 0.55};
  PointCloud cloud = lattice_sphere(R, s, c);
  SurfaceParams params{dx, s, 1, slurry::io::SurfaceMethod::Spheres};  // one Gaussian pass
  slurry::io::Surface surface = [this] {
    // A rigid rotation about the z axis through c (omega = 2 rad/s) plus a translation.
    for (const auto& p : cloud.position)
      cloud.velocity.push_back({float(1.0 - 2 * (p[1] - c[1])), float(2 * (p[0] - c[0])), -0.5f});
    return slurry::io::surface_particles(cloud, params);
  }();
};

const SphereCase& sphere() {
  static const SphereCase s;
  return s;
}

/// Mean distance of the vertices from the centre.
double mean_radius(const TriangleMesh& m, const std::array<double, 3>& c) {
  double sum = 0;
  for (const auto& v : m.vertices) sum += std::hypot(v[0] - c[0], v[1] - c[1], v[2] - c[2]);
  return sum / double(m.vertices.size());
}

}  // namespace

TEST(Surface, UnsmoothedSphereEnclosesTheSampledVolumeAndRadius) {
  // Without smoothing the closing puts the surface half a spacing beyond the outermost
  // particle centres, where the lattice cells of the particles end: at R, up to the cells the
  // sphere cuts and the dimples between spheres. Tolerances: 0.05 voxel for the mean vertex
  // radius, 1 % for the volume (0.05 voxel of radius), 0.3 voxel for any vertex.
  const auto& sc = sphere();
  SurfaceParams p = sc.params;
  p.smoothing = 0;
  const auto surface = slurry::io::surface_particles(sc.cloud, p);
  const double exact = 4.0 / 3.0 * kPi * std::pow(sc.R, 3);
  EXPECT_NEAR(signed_volume(surface.mesh) / exact, 1.0, 0.01);
  EXPECT_NEAR(surface.level_set.enclosed_volume() / exact, 1.0, 0.01);
  EXPECT_NEAR(mean_radius(surface.mesh, sc.c), sc.R, 0.05 * sc.dx);
  double worst = 0;
  for (const auto& v : surface.mesh.vertices)
    worst = std::max(worst,
                     std::abs(std::hypot(v[0] - sc.c[0], v[1] - sc.c[1], v[2] - sc.c[2]) - sc.R));
  std::printf(
      "unsmoothed: volume / exact %.4f, mean radius - R %.3f voxel, worst vertex %.3f voxel\n",
      signed_volume(surface.mesh) / exact, (mean_radius(surface.mesh, sc.c) - sc.R) / sc.dx,
      worst / sc.dx);
  EXPECT_LT(worst, 0.3 * sc.dx) << "largest |r - R| of a vertex";
}

TEST(Surface, SmoothedSphereShrinksAsTheGaussianPredicts) {
  // One Gaussian pass moves the sphere inward by delta = (8 h^2 / 3) / R (surface.h), 1.07 mm
  // or 0.18 voxel here; the mean radius must match R - delta within 0.05 voxel and the volume
  // 4/3 pi (R - delta)^3 within 1 %, and the smoothed surface stay within 0.2 voxel of it.
  const auto& sc = sphere();
  const TriangleMesh& m = sc.surface.mesh;
  ASSERT_GT(m.triangles.size(), 1000u);
  const double delta = sc.params.smoothing * (8 * sc.dx * sc.dx / 3) / sc.R;
  const double R = sc.R - delta, exact = 4.0 / 3.0 * kPi * std::pow(R, 3);
  EXPECT_NEAR(signed_volume(m) / exact, 1.0, 0.01);
  EXPECT_NEAR(sc.surface.level_set.enclosed_volume() / exact, 1.0, 0.01);
  EXPECT_NEAR(mean_radius(m, sc.c), R, 0.05 * sc.dx);
  double worst = 0;
  for (const auto& v : m.vertices)
    worst =
        std::max(worst, std::abs(std::hypot(v[0] - sc.c[0], v[1] - sc.c[1], v[2] - sc.c[2]) - R));
  std::printf(
      "smoothed: volume / predicted %.4f, mean radius - (R - delta) %.3f voxel, worst vertex %.3f "
      "voxel\n",
      signed_volume(m) / exact, (mean_radius(m, sc.c) - R) / sc.dx, worst / sc.dx);
  EXPECT_LT(worst, 0.2 * sc.dx) << "largest |r - (R - delta)| of a vertex";
}

TEST(Surface, SphereMeshIsClosedOrientedAndOfGenusZero) {
  const TriangleMesh& m = sphere().surface.mesh;
  // Every directed edge once, and its reverse once: a closed, consistently oriented 2-manifold.
  std::map<std::pair<int, int>, int> directed;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) ++directed[{t[std::size_t(e)], t[std::size_t((e + 1) % 3)]}];
  std::size_t bad = 0;
  for (const auto& [edge, count] : directed) {
    const auto reverse = directed.find({edge.second, edge.first});
    if (count != 1 || reverse == directed.end() || reverse->second != 1) ++bad;
  }
  EXPECT_EQ(bad, 0u) << "edges not shared by exactly two opposite triangles";
  // Euler characteristic V - E + F = 2 of a sphere.
  const long long V = (long long)m.vertices.size(), E = (long long)directed.size() / 2,
                  F = (long long)m.triangles.size();
  EXPECT_EQ(V - E + F, 2);
  // Outward normals: positive enclosed volume.
  EXPECT_GT(signed_volume(m), 0);
  // No unused vertex.
  std::vector<char> used(m.vertices.size(), 0);
  for (const auto& t : m.triangles)
    for (int k : t) used[std::size_t(k)] = 1;
  EXPECT_EQ(std::count(used.begin(), used.end(), 0), 0);
}

TEST(Surface, VertexVelocitiesFollowARigidMotion) {
  const auto& sc = sphere();
  const TriangleMesh& m = sc.surface.mesh;
  ASSERT_EQ(m.velocities.size(), m.vertices.size());
  // u(x) = (1 - 2 (y - cy), 2 (x - cx), -0.5) is linear: the poly6 average of the particles
  // within h = 2 spacings of a vertex (a one-sided neighbourhood at the surface) differs from
  // u at the vertex by at most omega h = 2 * 0.02 m/s; the constant part is exact.
  double worst = 0, worst_z = 0;
  for (std::size_t i = 0; i < m.vertices.size(); ++i) {
    const auto& x = m.vertices[i];
    const auto& u = m.velocities[i];
    const double ex = 1.0 - 2 * (x[1] - sc.c[1]), ey = 2 * (x[0] - sc.c[0]);
    worst = std::max(worst, std::hypot(u[0] - ex, u[1] - ey));
    worst_z = std::max(worst_z, std::abs(u[2] + 0.5));
  }
  EXPECT_LT(worst, 2 * 2 * sc.s);
  EXPECT_LT(worst_z, 1e-6);
}

TEST(Surface, VdbGridNamedSurfaceReadsBack) {
  const auto& sc = sphere();
  const fs::path dir = temp_dir("vdb");
  slurry::io::write_vdb(dir / "surface.vdb", sc.surface.level_set);
  const auto back = slurry::io::read_vdb_level_set(dir / "surface.vdb", "surface");
  EXPECT_EQ(back.active_voxels(), sc.surface.level_set.active_voxels());
  EXPECT_EQ(back.bounding_box(), sc.surface.level_set.bounding_box());
  EXPECT_DOUBLE_EQ(back.voxel_size(), sc.dx);
  // The narrow band: voxels within 3 voxels either side of the sphere, about 4 pi R^2 * 6 dx / dx^3
  // (17 000); within 15 % (the band's edges are voxel-ragged).
  const double band = 4 * kPi * sc.R * sc.R * 6 * sc.dx / std::pow(sc.dx, 3);
  EXPECT_NEAR(double(back.active_voxels()) / band, 1.0, 0.15)
      << back.active_voxels() << " active voxels";
  // Signed distances: the surface lies at R - delta (the smoothing's shrink, see above).
  const double delta = sc.params.smoothing * (8 * sc.dx * sc.dx / 3) / sc.R;
  EXPECT_NEAR(back.value({sc.c[0] + sc.R - delta, sc.c[1], sc.c[2]}), 0.0, 0.1 * sc.dx);
  EXPECT_NEAR(back.value({sc.c[0], sc.c[1] + sc.R + sc.dx, sc.c[2]}), sc.dx + delta, 0.1 * sc.dx);
  EXPECT_NEAR(back.value({sc.c[0], sc.c[1], sc.c[2] - sc.R + sc.dx}), -sc.dx + delta, 0.1 * sc.dx);
  EXPECT_LT(back.value({sc.c[0], sc.c[1], sc.c[2]}), 0.0);  // the centre: inside, beyond the band
  // A missing grid name is an IoError naming the grids the file has.
  try {
    (void)slurry::io::read_vdb_level_set(dir / "surface.vdb", "density");
    FAIL() << "expected IoError";
  } catch (const slurry::IoError& e) {
    EXPECT_NE(std::string(e.what()).find("surface"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)slurry::io::read_vdb_level_set(dir / "missing.vdb"), slurry::IoError);
  fs::remove_all(dir);
}

TEST(Surface, VdbVelocityGridFollowsTheParticles) {
  // The surface .vdb carries a Vec3s grid "velocity" (volume motion blur) on the band's voxels:
  // at points of the surface, the rigid motion u(x) = (1 - 2 (y - cy), 2 (x - cx), -0.5) within
  // omega x 2 spacings (the one-sided average at the surface), read back from the file.
  const auto& sc = sphere();
  ASSERT_TRUE(sc.surface.level_set.has_velocity());
  const fs::path dir = temp_dir("vdb_velocity");
  slurry::io::write_vdb(dir / "surface.vdb", sc.surface.level_set);
  const auto back = slurry::io::read_vdb_level_set(dir / "surface.vdb");
  ASSERT_TRUE(back.has_velocity());
  double worst = 0;
  for (double a = 0; a < 2 * kPi; a += 0.3) {
    const std::array<double, 3> x{sc.c[0] + sc.R * std::cos(a), sc.c[1] + sc.R * std::sin(a), sc.c[2]};
    const auto u = back.velocity(x);
    worst = std::max({worst, std::hypot(u[0] - (1.0 - 2 * (x[1] - sc.c[1])), u[1] - 2 * (x[0] - sc.c[0])),
                      std::abs(u[2] + 0.5)});
  }
  EXPECT_LT(worst, 2 * 2 * sc.s);
  // A level set of points without velocities has none.
  PointCloud still = sc.cloud;
  still.velocity.clear();
  EXPECT_FALSE(slurry::io::surface_particles(still, sc.params).level_set.has_velocity());
  fs::remove_all(dir);
}

TEST(Surface, DenseRasterizerMatchesParticlesToLevelSet) {
  // Random particles (no lattice: every offset from the voxel centres occurs): a sparse cluster
  // with empty voxels inside, a small one, and a dense block (8 per voxel) whose interior takes
  // the rasterizer's short cut for deep particles.
  PointCloud cloud;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 20000; ++i)
    cloud.position.push_back({0.2f + 0.3f * u(rng), 0.1f + 0.5f * u(rng), 0.3f * u(rng)});
  for (int i = 0; i < 3000; ++i)
    cloud.position.push_back({0.8f + 0.1f * u(rng), 0.7f + 0.1f * u(rng), 0.5f + 0.1f * u(rng)});
  for (int i = 0; i < 64000; ++i)
    cloud.position.push_back({1.0f + 0.4f * u(rng), 0.2f + 0.4f * u(rng), 0.6f + 0.4f * u(rng)});
  const double h = 0.02, r = 0.037;
  const auto dense = slurry::io::union_of_spheres(cloud, h, r);
  const auto vdb = slurry::io::union_of_spheres(cloud, h, r, /*openvdb_rasterizer=*/true);
  ASSERT_EQ(dense.active_voxels(), vdb.active_voxels());
  EXPECT_EQ(dense.bounding_box(), vdb.bounding_box());
  // Values at voxel centres (trilinear sampling at a voxel centre is the voxel's value) across
  // the whole band, equal to float round-off.
  const auto b = vdb.bounding_box();
  double worst = 0;
  std::size_t compared = 0;
  for (int i = b[0]; i <= b[3]; ++i)
    for (int j = b[1]; j <= b[4]; j += 2)
      for (int k = b[2]; k <= b[5]; ++k) {
        const std::array<double, 3> x{i * h, j * h, k * h};
        worst = std::max(worst, std::abs(dense.value(x) - vdb.value(x)));
        ++compared;
      }
  EXPECT_LT(worst, 1e-6 * h) << "over " << compared << " voxels";
}

TEST(Surface, VdbPointsReadBackWithIdsVelocitiesAndRadius) {
  PointCloud cloud;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 2.0f);
  const std::size_t n = 5000;
  for (std::size_t i = 0; i < n; ++i) {
    cloud.position.push_back({u(rng), u(rng), u(rng)});
    cloud.velocity.push_back({u(rng), u(rng), u(rng)});
    cloud.id.push_back(std::uint32_t(3 * i + 11));  // persistent ids need not be 0..n-1
  }
  const fs::path dir = temp_dir("points");
  slurry::io::write_vdb_points(dir / "points.vdb", cloud, 0.0125, 0.05);
  std::vector<float> pscale;
  const PointCloud back = slurry::io::read_vdb_points(dir / "points.vdb", &pscale);
  ASSERT_EQ(back.size(), n);
  ASSERT_EQ(back.velocity.size(), n);
  ASSERT_EQ(back.id.size(), n);
  ASSERT_EQ(pscale.size(), n);
  double worst = 0;
  for (std::size_t i = 0; i < n; ++i) {
    ASSERT_EQ(back.id[i], cloud.id[i]);              // read back in id order, as written
    EXPECT_EQ(back.velocity[i], cloud.velocity[i]);  // stored uncompressed
    EXPECT_FLOAT_EQ(pscale[i], 0.0125f);
    for (int d = 0; d < 3; ++d)
      worst = std::max(worst, double(std::abs(back.position[i][d] - cloud.position[i][d])));
  }
  // Positions are stored as float offsets within a voxel of 0.05 m: round-off ~ 1e-7 m.
  EXPECT_LT(worst, 1e-6);
  fs::remove_all(dir);
}

TEST(Surface, MeshFilesReadBack) {
  const auto& m = sphere().surface.mesh;
  const fs::path dir = temp_dir("mesh");
  slurry::io::write_mesh_ply(dir / "m.ply", m);
  const auto ply = slurry::io::read_ply(dir / "m.ply");
  const auto& v = ply.table("vertex");
  EXPECT_EQ(v.count, m.vertices.size());
  EXPECT_EQ(v.values<float>("vx")[7], m.velocities[7][0]);
  EXPECT_EQ(v.values<float>("z")[9], m.vertices[9][2]);
  const auto& f = ply.table("face");
  ASSERT_EQ(f.count, m.triangles.size());
  EXPECT_EQ(f.list("vertex_indices").data[5],
            (std::vector<std::int32_t>{m.triangles[5][0], m.triangles[5][1], m.triangles[5][2]}));

  slurry::io::write_mesh_obj(dir / "m.obj", m);
  std::ifstream obj(dir / "m.obj");
  std::string line;
  std::size_t nv = 0, nf = 0;
  std::array<float, 3> v3{};
  std::array<int, 3> f3{};
  while (std::getline(obj, line)) {
    std::istringstream in(line);
    std::string tag;
    in >> tag;
    if (tag == "v") {
      in >> v3[0] >> v3[1] >> v3[2];
      if (nv == 3) {
        EXPECT_EQ(v3, m.vertices[3]);  // %.9g reads back to the same float
      }
      ++nv;
    } else if (tag == "f") {
      in >> f3[0] >> f3[1] >> f3[2];
      if (nf == 4) {
        EXPECT_EQ(f3, (std::array<int, 3>{m.triangles[4][0] + 1, m.triangles[4][1] + 1,
                                          m.triangles[4][2] + 1}));
      }
      ++nf;
    }
  }
  EXPECT_EQ(nv, m.vertices.size());
  EXPECT_EQ(nf, m.triangles.size());
  // No temporary files left beside them.
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);
  fs::remove_all(dir);
}

TEST(Surface, PointCloudFromAFrameSelectsAMaterial) {
  slurry::io::PlyData frame;
  auto& v = frame.tables.emplace_back();
  v.name = "vertex";
  v.count = 4;
  v.columns.push_back({"x", std::vector<double>{0, 1, 2, 3}});
  v.columns.push_back({"y", std::vector<double>{4, 5, 6, 7}});
  v.columns.push_back({"vx", std::vector<double>{1, 1, 2, 2}});
  v.columns.push_back({"vy", std::vector<double>{0, 0, 0, 0}});
  v.columns.push_back({"material", std::vector<std::uint16_t>{0, 1, 0, 1}});
  v.columns.push_back({"id", std::vector<std::uint32_t>{10, 11, 12, 13}});
  const PointCloud all = slurry::io::point_cloud(frame);
  ASSERT_EQ(all.size(), 4u);
  EXPECT_EQ(all.position[2], (std::array<float, 3>{2, 6, 0}));  // 2D: z = 0
  const PointCloud one = slurry::io::point_cloud(frame, 1);
  ASSERT_EQ(one.size(), 2u);
  EXPECT_EQ(one.id, (std::vector<std::uint32_t>{11, 13}));
  EXPECT_EQ(one.velocity[1], (std::array<float, 3>{2, 0, 0}));
}

TEST(Surface, InvalidParametersAreRejected) {
  const PointCloud cloud = lattice_sphere(0.05, 0.01, {0, 0, 0});
  EXPECT_THROW((void)slurry::io::particles_to_level_set(cloud, SurfaceParams{0, 0.01, 1}),
               std::invalid_argument);
  EXPECT_THROW((void)slurry::io::particles_to_level_set(cloud, SurfaceParams{0.01, -1, 1}),
               std::invalid_argument);
  EXPECT_THROW((void)slurry::io::particles_to_level_set(cloud, SurfaceParams{0.01, 0.01, -1}),
               std::invalid_argument);
  EXPECT_THROW((void)slurry::io::particles_to_level_set(PointCloud{}, SurfaceParams{0.01, 0.01, 1}),
               std::invalid_argument);
}
