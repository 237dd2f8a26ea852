// The colliders' surfaces written beside the surface meshes (colliders_NNNN.ply / .obj): every
// analytic shape tessellated where the solver puts it, closed shapes wound outward with their
// volume, moving colliders at their pose of the frame's time with their material's velocity at
// each vertex, and the files a run writes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>

#include "geometry/collider_surfaces.h"
#include "geometry/mesh_util.h"
#include "slurry/engine/run/run.h"
#include "slurry/io/ply.h"
#include "slurry/io/scene_file.h"
#include "slurry/io/triangle_mesh_file.h"

namespace fs = std::filesystem;

namespace {

constexpr double kPi = 3.14159265358979323846;

fs::path temp_dir() {
  const fs::path d = fs::temp_directory_path() / ("slurry_collider_surfaces_" + std::to_string(::getpid()));
  fs::create_directories(d);
  return d;
}

/// Collider `which` of a colliders frame as a mesh with its vertex velocities.
struct Piece {
  slurry::geometry::TriangleMesh mesh;
  std::vector<Eigen::Vector3d> velocity;
};

Piece piece(const slurry::Frame& f, int which) {
  const auto& v = f.table("vertex");
  const auto& faces = f.table("face");
  const auto x = v.column_as_double("x"), y = v.column_as_double("y"), z = v.column_as_double("z");
  const auto vx = v.column_as_double("vx"), vy = v.column_as_double("vy"), vz = v.column_as_double("vz");
  const auto id = faces.column_as_double("collider");
  const auto& tris = faces.list("vertex_indices").data;
  Piece p;
  std::map<int, int> local;
  for (std::size_t t = 0; t < tris.size(); ++t) {
    if (int(id[t]) != which) continue;
    std::array<int, 3> tri{};
    for (int k = 0; k < 3; ++k) {
      const int g = tris[t][std::size_t(k)];
      auto it = local.find(g);
      if (it == local.end()) {
        it = local.emplace(g, int(p.mesh.vertices.size())).first;
        p.mesh.vertices.emplace_back(x[std::size_t(g)], y[std::size_t(g)], z[std::size_t(g)]);
        p.velocity.emplace_back(vx[std::size_t(g)], vy[std::size_t(g)], vz[std::size_t(g)]);
      }
      tri[std::size_t(k)] = it->second;
    }
    p.mesh.triangles.push_back(tri);
  }
  return p;
}

const char* const kScene = R"({
  "domain": {"min": [0, 0, 0], "max": [1, 2, 1], "dx": 0.1},
  "solver": {"dimension": 3},
  "materials": [{"name": "m"}],
  "bodies": [{"shape": "box", "min": [0.6, 1.2, 0.6], "max": [0.8, 1.4, 0.8], "material": "m"}],
  "colliders": [
    {"shape": "half_space", "point": [0, 0.1, 0], "normal": [0, 1, 0]},
    {"shape": "box", "min": [0.1, 0.2, 0.1], "max": [0.3, 0.5, 0.4], "velocity": [0.5, 0, 0]},
    {"shape": "sphere", "center": [0.7, 0.5, 0.5], "radius": 0.2},
    {"shape": "mesh", "mesh": "paddle.obj", "scale": [2, 1, 1],
     "keyframes": [{"time": 0, "translation": [0.5, 1.5, 0.5], "rotation": [0, 0, 0]},
                   {"time": 1, "translation": [0.5, 1.7, 0.5], "rotation": [0, 90, 0]}]},
    {"shape": "half_space", "point": [0.5, 1, 0.5], "normal": [1, 0.5, 1]}],
  "output": {"directory": "frames", "fps": 4, "frames": 4, "surface": ["obj", "ply"]}
})";

slurry::Scene scene_in(const fs::path& dir) {
  slurry::test::write_obj(dir / "paddle.obj", slurry::test::box_mesh({-0.1, -0.05, -0.02}, {0.1, 0.05, 0.02}));
  std::ofstream(dir / "scene.json") << kScene;
  slurry::Scene s = slurry::load_scene(dir / "scene.json");
  slurry::io::read_scene_files(s);
  return s;
}

}  // namespace

TEST(ColliderSurfaces, ShapesWhereTheSolverPutsThem) {
  const fs::path dir = temp_dir();
  const slurry::detail::ColliderSurfaces colliders(scene_in(dir));
  ASSERT_FALSE(colliders.empty());
  const double t = 0.5;
  const slurry::Frame f = colliders.at(t);

  // The ground: the domain's cross-section at y = 0.1, facing up.
  const Piece ground = piece(f, 0);
  ASSERT_EQ(ground.mesh.triangles.size(), 2u);
  double area = 0;
  for (const auto& tri : ground.mesh.triangles) {
    const Eigen::Vector3d a = ground.mesh.vertices[std::size_t(tri[0])], b = ground.mesh.vertices[std::size_t(tri[1])],
                          c = ground.mesh.vertices[std::size_t(tri[2])];
    const Eigen::Vector3d n = (b - a).cross(c - a);
    EXPECT_GT(n.y(), 0);  // out of the solid below
    area += 0.5 * n.norm();
  }
  EXPECT_NEAR(area, 1.0, 1e-6);
  for (const auto& v : ground.mesh.vertices) EXPECT_NEAR(v.y(), 0.1, 1e-6);

  // The box, moved by velocity x t, closed, outward, its volume; every vertex at its velocity.
  const Piece box = piece(f, 1);
  EXPECT_EQ(box.mesh.triangles.size(), 12u);
  EXPECT_TRUE(slurry::geometry::check_topology(box.mesh).closed());
  EXPECT_NEAR(box.mesh.signed_volume(), 0.2 * 0.3 * 0.3, 1e-6);
  Eigen::Vector3d lo, hi;
  box.mesh.bounds(lo, hi);
  EXPECT_NEAR(lo.x(), 0.1 + 0.5 * t, 1e-6);
  EXPECT_NEAR(hi.x(), 0.3 + 0.5 * t, 1e-6);
  for (const auto& u : box.velocity) EXPECT_NEAR((u - Eigen::Vector3d(0.5, 0, 0)).norm(), 0, 1e-6);

  // The sphere: 1280 triangles on the sphere, inscribed, volume within 1.5% below the ball's.
  const Piece ball = piece(f, 2);
  EXPECT_EQ(ball.mesh.triangles.size(), 1280u);
  EXPECT_TRUE(slurry::geometry::check_topology(ball.mesh).closed());
  for (const auto& v : ball.mesh.vertices) EXPECT_NEAR((v - Eigen::Vector3d(0.7, 0.5, 0.5)).norm(), 0.2, 1e-6);
  const double ball_volume = 4.0 / 3.0 * kPi * 0.008;
  EXPECT_LT(ball.mesh.signed_volume(), ball_volume);
  EXPECT_GT(ball.mesh.signed_volume(), 0.985 * ball_volume);

  // The mesh at its keyframed pose: half-way, translated by 0.1 up and turned 45 degrees about y,
  // scale 2 along its own x; vertex velocities are the rigid motion's.
  const Piece paddle = piece(f, 3);
  EXPECT_EQ(paddle.mesh.triangles.size(), 12u);
  EXPECT_NEAR(paddle.mesh.signed_volume(), 0.4 * 0.1 * 0.04, 1e-6);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(kPi / 4, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d c(0.5, 1.6, 0.5), corner = c + R * Eigen::Vector3d(0.2, 0.05, 0.02);
  double nearest = 1;
  std::size_t at = 0;
  for (std::size_t i = 0; i < paddle.mesh.vertices.size(); ++i)
    if ((paddle.mesh.vertices[i] - corner).norm() < nearest) nearest = (paddle.mesh.vertices[i] - corner).norm(), at = i;
  EXPECT_LT(nearest, 1e-6);
  const Eigen::Vector3d omega(0, kPi / 2, 0), expected = Eigen::Vector3d(0, 0.2, 0) + omega.cross(corner - c);
  EXPECT_NEAR((paddle.velocity[at] - expected).norm(), 0, 1e-5);

  // A slanted plane through the domain's centre cuts it in a hexagon (4 triangles), all on the
  // plane, facing along n.
  const Piece slant = piece(f, 4);
  EXPECT_EQ(slant.mesh.triangles.size(), 4u);
  const Eigen::Vector3d n = Eigen::Vector3d(1, 0.5, 1).normalized();
  for (const auto& v : slant.mesh.vertices) EXPECT_NEAR((v - Eigen::Vector3d(0.5, 1, 0.5)).dot(n), 0, 1e-6);
  for (const auto& tri : slant.mesh.triangles)
    EXPECT_GT((slant.mesh.vertices[std::size_t(tri[1])] - slant.mesh.vertices[std::size_t(tri[0])])
                  .cross(slant.mesh.vertices[std::size_t(tri[2])] - slant.mesh.vertices[std::size_t(tri[0])])
                  .dot(n),
              0);
  fs::remove_all(dir);
}

// A run whose scene asks for surface meshes writes colliders_NNNN.ply and .obj for every frame;
// the OBJ holds one object per collider (Blender and Houdini import them as separate objects) and
// reads back as the same triangles.
TEST(ColliderSurfaces, RunWritesThemBesideTheFrames) {
  const fs::path dir = temp_dir();
  slurry::Scene s = scene_in(dir);
  slurry::RunOptions o;
  o.directory = dir / "frames";
  o.threads = 1;
  slurry::run_scene(s, o);
  const slurry::detail::ColliderSurfaces colliders(s);
  for (int f = 0; f <= 4; ++f) {
    char name[32];
    std::snprintf(name, sizeof name, "colliders_%04d", f);
    const slurry::io::PlyData ply = slurry::io::read_ply(dir / "frames" / (std::string(name) + ".ply"));
    const slurry::Frame expected = colliders.at(f * 0.25);
    ASSERT_EQ(ply.table("vertex").count, expected.table("vertex").count);
    EXPECT_EQ(ply.table("vertex").column_as_double("x"), expected.table("vertex").column_as_double("x")) << f;
    EXPECT_EQ(ply.table("face").count, 2u + 12 + 1280 + 12 + 4);
    const fs::path obj = dir / "frames" / (std::string(name) + ".obj");
    std::ifstream in(obj);
    std::string line;
    int objects = 0;
    while (std::getline(in, line)) objects += line.rfind("o collider_", 0) == 0;
    EXPECT_EQ(objects, 5);
    EXPECT_EQ(slurry::io::read_triangle_mesh(obj).triangles.size(), 2u + 12 + 1280 + 12 + 4);
  }
  fs::remove_all(dir);
}
