// Closed triangle meshes (geometry/): reading OBJ and PLY, the closedness check, the signed
// distance field against analytic distances, exact segment entry through walls thinner than the
// field's cells, exact inside tests on rows through shared edges, and keyframed rigid motion
// against finite differences. Mesh bodies and colliders in whole scenes: mesh_scene_test.cpp.
#include <gtest/gtest.h>

#include <unistd.h>
#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>

#include "geometry/mesh_util.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/geometry/mesh_sdf.h"
#include "slurry/engine/geometry/rigid_motion.h"
#include "slurry/engine/geometry/triangle_mesh.h"
#include "slurry/io/ply.h"
#include "slurry/io/triangle_mesh_file.h"

namespace fs = std::filesystem;
using namespace slurry::geometry;
using slurry::io::read_triangle_mesh;
using Eigen::Vector3d;

namespace {

fs::path temp_dir(const std::string& name) {
  const fs::path d =
      fs::temp_directory_path() / ("slurry_mesh_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

/// Exact signed distance to the box [-h, h] (per axis).
double box_distance(const Vector3d& p, const Vector3d& h) {
  const Vector3d q = p.cwiseAbs() - h;
  return q.cwiseMax(Vector3d::Zero()).norm() + std::min(q.maxCoeff(), 0.0);
}

}  // namespace

TEST(TriangleMesh, ObjWithQuadsNegativeIndicesAndSlashForms) {
  const fs::path d = temp_dir("obj");
  // A unit cube written with quads, "i/t/n" items and negative indices.
  std::ofstream(d / "cube.obj")
      << "# cube\no cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
         "vn 0 0 1\nf 1/1/1 4/1/1 3/1/1 2/1/1\nf 5//1 6//1 7//1 8//1\nf 1 2 6 5\nf 2 3 7 6\n"
         "f -5 -1 -2 -6\nf 4 1 5 8\n";
  const TriangleMesh m = read_triangle_mesh(d / "cube.obj");
  EXPECT_EQ(m.vertices.size(), 8u);
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_TRUE(check_topology(m).closed());
  EXPECT_NEAR(m.signed_volume(), 1.0, 1e-12);  // wound outward
  const TriangleMesh placed =
      place_closed_mesh(m, {2, 1, 1}, euler_degrees({0, 0, 90}), {1, 0, 0}, "cube");
  EXPECT_NEAR(placed.signed_volume(), 2.0, 1e-12);
  Vector3d lo, hi;
  placed.bounds(lo, hi);
  EXPECT_NEAR(lo[0], 0.0, 1e-12);  // (x, y) -> (-y, x) after scaling x by 2
  EXPECT_NEAR(hi[1], 2.0, 1e-12);
}

TEST(TriangleMesh, PlyFacesAndErrorsNameTheFileAndLine) {
  const fs::path d = temp_dir("ply");
  const TriangleMesh cube = slurry::test::box_mesh({0, 0, 0}, {1, 2, 3});
  slurry::test::write_obj(d / "box.obj", cube);
  slurry::io::PlyData ply;
  auto& v = ply.tables.emplace_back();
  v.name = "vertex";
  v.count = cube.vertices.size();
  std::vector<float> xs[3];
  for (const auto& p : cube.vertices)
    for (int k = 0; k < 3; ++k) xs[k].push_back(float(p[k]));
  v.columns = {{"x", xs[0]}, {"y", xs[1]}, {"z", xs[2]}};
  auto& f = ply.tables.emplace_back();
  f.name = "face";
  f.count = cube.triangles.size();
  auto& list = f.lists.emplace_back();
  list.name = "vertex_indices";
  for (const auto& t : cube.triangles) list.data.push_back({t[0], t[1], t[2]});
  slurry::io::write_ply(d / "box.ply", ply);
  const TriangleMesh a = read_triangle_mesh(d / "box.ply"), b = read_triangle_mesh(d / "box.obj");
  EXPECT_NEAR(a.signed_volume(), 6.0, 1e-9);
  EXPECT_NEAR(b.signed_volume(), 6.0, 1e-9);

  std::ofstream(d / "bad.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n";
  EXPECT_NE(slurry::test::message_of([&] {
              read_triangle_mesh(d / "bad.obj");
            }).find("bad.obj:4: vertex index 4 out of range"),
            std::string::npos);
  std::ofstream(d / "nan.obj") << "v 0 0 x\n";
  EXPECT_NE(slurry::test::message_of([&] {
              read_triangle_mesh(d / "nan.obj");
            }).find("nan.obj:1: expected a vertex"),
            std::string::npos);
  std::ofstream(d / "mesh.stl") << "solid\n";
  EXPECT_NE(slurry::test::message_of([&] {
              read_triangle_mesh(d / "mesh.stl");
            }).find("expected .obj or .ply"),
            std::string::npos);
  EXPECT_NE(
      slurry::test::message_of([&] { read_triangle_mesh(d / "none.obj"); }).find("no such file"),
      std::string::npos);
  // Text quoted from the file is made safe: a terminal escape is shown as \x1b, not replayed,
  // and a 300-digit index is cut to 80 characters.
  std::ofstream(d / "esc.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv \x1b[31mred\n";
  const std::string esc = slurry::test::message_of([&] { read_triangle_mesh(d / "esc.obj"); });
  EXPECT_NE(esc.find("esc.obj:4: expected a vertex \"v x y z\" of three finite numbers, got \"v \\x1b[31mred\""),
            std::string::npos)
      << esc;
  EXPECT_EQ(esc.find('\x1b'), std::string::npos) << esc;
  std::ofstream(d / "long.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3" << std::string(300, '9') << "x\n";
  const std::string longer = slurry::test::message_of([&] { read_triangle_mesh(d / "long.obj"); });
  EXPECT_NE(longer.find("...(302 bytes in all)"), std::string::npos) << longer;
  EXPECT_LT(longer.size(), 300u) << longer;
  // Named for what they are, not "no such file".
  fs::create_directory(d / "dir.obj");
  EXPECT_NE(slurry::test::message_of([&] { read_triangle_mesh(d / "dir.obj"); })
                .find("dir.obj: a directory, not a file (expected a triangle mesh, .obj or .ply)"),
            std::string::npos);
  fs::create_symlink(d / "loop2.obj", d / "loop1.obj");
  fs::create_symlink(d / "loop1.obj", d / "loop2.obj");
  EXPECT_NE(slurry::test::message_of([&] { read_triangle_mesh(d / "loop1.obj"); }).find("a loop of symbolic links"),
            std::string::npos);
}

TEST(TriangleMesh, OpenOrInconsistentMeshesAreRefusedAndInsideOutIsReversed) {
  TriangleMesh cube = slurry::test::box_mesh({0, 0, 0}, {1, 1, 1});
  TriangleMesh open = cube;
  open.triangles.pop_back();
  const std::string hole = slurry::test::message_of([&] {
    place_closed_mesh(open, {1, 1, 1}, Eigen::Matrix3d::Identity(), {0, 0, 0},
                      "s.json: bodies[0].mesh (c.obj)");
  });
  EXPECT_NE(hole.find("s.json: bodies[0].mesh (c.obj): the mesh does not enclose a volume"),
            std::string::npos)
      << hole;
  EXPECT_NE(hole.find("3 edges on a hole"), std::string::npos) << hole;
  TriangleMesh flipped = cube;
  std::swap(flipped.triangles[0][1], flipped.triangles[0][2]);
  EXPECT_NE(slurry::test::message_of([&] {
              place_closed_mesh(flipped, {1, 1, 1}, Eigen::Matrix3d::Identity(), {0, 0, 0}, "m");
            }).find("wound in opposite senses"),
            std::string::npos);
  TriangleMesh inside_out = cube;
  for (auto& t : inside_out.triangles) std::swap(t[1], t[2]);
  EXPECT_LT(inside_out.signed_volume(), 0);
  EXPECT_NEAR(place_closed_mesh(inside_out, {1, 1, 1}, Eigen::Matrix3d::Identity(), {0, 0, 0}, "m")
                  .signed_volume(),
              1.0, 1e-12);
  // A mirroring scale turns the mesh inside out too; it is reversed the same way.
  EXPECT_NEAR(place_closed_mesh(cube, {-1, 1, 1}, Eigen::Matrix3d::Identity(), {0, 0, 0}, "m")
                  .signed_volume(),
              1.0, 1e-12);
}

// The box mesh is exactly its box, so the field at its nodes is the box's exact signed distance
// (to float rounding): the band, the sweeping and the sign all have to be right everywhere.
TEST(MeshSdf, BoxFieldIsExactAtTheNodes) {
  const Vector3d h{0.3, 0.2, 0.45};
  const MeshSdf sdf(slurry::test::box_mesh(-h, h), 0.05, 0.25);
  const Vector3d lo = sdf.lower(), hi = sdf.upper();
  double worst = 0;
  int inside = 0, nodes = 0;
  for (double z = lo[2]; z <= hi[2] + 1e-9; z += sdf.spacing())
    for (double y = lo[1]; y <= hi[1] + 1e-9; y += sdf.spacing())
      for (double x = lo[0]; x <= hi[0] + 1e-9; x += sdf.spacing()) {
        const Vector3d p(x, y, z);
        worst = std::max(worst, std::abs(sdf.phi(p) - box_distance(p, h)));
        inside += sdf.phi(p) < 0;
        ++nodes;
      }
  EXPECT_LT(worst, 1e-6) << "largest error at the nodes over " << nodes << " nodes";
  EXPECT_GT(inside, 100);
  // Between nodes the trilinear interpolation of a distance errs by at most ~h^2 / (8 r) at a
  // curved level set and not at all where it is planar; the normal points out of the nearest face.
  EXPECT_NEAR(sdf.phi({0.31, 0.013, 0.027}), 0.01, 1e-6);
  EXPECT_TRUE(sdf.normal({0.29, 0.013, 0.027}).isApprox(Vector3d::UnitX(), 1e-6));
  EXPECT_TRUE(sdf.normal({0.01, -0.19, 0.027}).isApprox(-Vector3d::UnitY(), 1e-6));
  // Far outside the grid the distance is still positive and grows.
  EXPECT_GT(sdf.phi({5, 0, 0}), 4);
}

// A subdivided icosahedron of radius 0.5: the field against |x| - r to within the polyhedron's
// own deviation from the sphere (its faces lie up to r (1 - cos a) inside it, a the angle from a
// face's centre to its corners) plus interpolation; the sign exact wherever the two differ.
TEST(MeshSdf, SphereFieldMatchesTheAnalyticDistance) {
  const TriangleMesh ball = slurry::test::icosphere(0.5, 3);
  const MeshSdf sdf(ball, 0.02, 0.1);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-0.6, 0.6);
  double worst = 0;
  int wrong_sign = 0;
  for (int i = 0; i < 20000; ++i) {
    const Vector3d p(u(rng), u(rng), u(rng));
    if (p.norm() < 0.1)
      continue;  // the distance's kink at the centre, where interpolation errs by ~h
    const double exact = p.norm() - 0.5, phi = sdf.phi(p);
    worst = std::max(worst, std::abs(phi - exact));
    if (std::abs(exact) > 0.01 && (phi < 0) != (exact < 0)) ++wrong_sign;
  }
  EXPECT_EQ(wrong_sign, 0);
  EXPECT_LT(worst, 0.01) << "largest |phi - (|x| - r)| (r = 0.5, h = 0.02)";
  // The polyhedron's volume by exact inside tests on a lattice: within 1% of its own volume.
  int in = 0;
  const double step = 0.01;
  for (double x = -0.5 + step / 2; x < 0.5; x += step)
    for (double y = -0.5 + step / 2; y < 0.5; y += step)
      for (double z = -0.5 + step / 2; z < 0.5; z += step) in += sdf.inside({x, y, z});
  EXPECT_NEAR(in * step * step * step / ball.signed_volume(), 1.0, 0.01);
}

// Rows through the cube's centre run along the diagonals that split its faces into triangles,
// and rows along its edges through shared vertices: each crossing must be counted once.
TEST(MeshSdf, RowsThroughSharedEdgesAndVerticesCountOnce) {
  const MeshSdf sdf(slurry::test::box_mesh({-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}), 0.1, 0.1,
                    std::int64_t(1) << 22, false);
  for (const Vector3d& p : {Vector3d(0, 0, 0.3), Vector3d(0.25, 0.25, -0.2),
                            Vector3d(-0.25, 0.25, 0.45), Vector3d(0.3, -0.3, 0)}) {
    EXPECT_TRUE(sdf.inside(p)) << p.transpose();
    EXPECT_FALSE(sdf.inside(Vector3d(p[0], p[1], 0.7))) << p.transpose();
    EXPECT_FALSE(sdf.inside(Vector3d(p[0], p[1], -0.7))) << p.transpose();
  }
  std::vector<char> in;
  sdf.inside_along_row(0, 0.0, 0.0, {-0.7, -0.3, 0.0, 0.3, 0.7}, in);
  EXPECT_EQ(std::vector<char>({0, 1, 1, 1, 0}), in);
}

// A plate 1/40 of the field's spacing thick: the field cannot see it, the exact segment test
// must, from both sides, and a segment that starts inside or passes beside it is no entry.
TEST(MeshSdf, SegmentsEnterAWallThinnerThanTheFieldSpacing) {
  const double t = 0.0005;
  const MeshSdf sdf(slurry::test::box_mesh({-t, -0.5, -0.5}, {t, 0.5, 0.5}), 0.04, 0.1);
  double s;
  Vector3d n;
  ASSERT_TRUE(sdf.first_entry({-0.03, 0.1, 0.2}, {0.05, 0.12, 0.2}, s, n));
  EXPECT_NEAR(s, (0.03 - t) / 0.08, 1e-12);
  EXPECT_TRUE(n.isApprox(-Vector3d::UnitX()));
  ASSERT_TRUE(
      sdf.first_entry({0.05, 0.0, 0.0}, {-0.05, 0.0, 0.0}, s, n));  // through the shared diagonal
  EXPECT_NEAR(s, (0.05 - t) / 0.1, 1e-12);
  EXPECT_TRUE(n.isApprox(Vector3d::UnitX()));
  EXPECT_FALSE(sdf.first_entry({-0.03, 0.6, 0}, {0.03, 0.6, 0}, s, n));   // beside it
  EXPECT_FALSE(sdf.first_entry({0, 0.1, 0}, {0.05, 0.1, 0}, s, n));       // leaving it
  EXPECT_FALSE(sdf.first_entry({-0.03, 0.1, 0}, {-0.01, 0.1, 0}, s, n));  // short of it
}

TEST(RigidMotion, KeysSlerpAndVelocityMatchesFiniteDifferences) {
  const std::vector<RigidMotion::Key> keys{{0.5, {0, 0, 0}, euler_degrees({0, 0, 0})},
                                           {1.5, {1, 2, 0}, euler_degrees({0, 0, 90})},
                                           {2.5, {1, 2, 3}, euler_degrees({30, 0, 90})}};
  const RigidMotion m(Eigen::Matrix3d::Identity(), Vector3d::Zero(), Vector3d(0.1, 0, 0), keys);
  EXPECT_TRUE(m.moves());
  // Held before the first key (plus the drift), at the keys exactly.
  EXPECT_TRUE(m.at(0.0).translation.isApprox(Vector3d(0, 0, 0)));
  EXPECT_TRUE(m.at(1.5).rotation.isApprox(euler_degrees({0, 0, 90}), 1e-12));
  EXPECT_TRUE(m.at(1.5).translation.isApprox(Vector3d(1.15, 2, 0), 1e-12));
  // Halfway between keys 0 and 1: half the turn about z.
  EXPECT_TRUE(m.at(1.0).rotation.isApprox(euler_degrees({0, 0, 45}), 1e-12));
  const Vector3d body(0.3, -0.2, 0.7);
  for (double t : {0.2, 0.9, 1.2, 2.0, 2.4, 3.0}) {
    const double e = 1e-6;
    const Vector3d fd = (m.at(t + e).to_world(body) - m.at(t - e).to_world(body)) / (2 * e);
    const Pose p = m.at(t);
    EXPECT_LT((p.velocity_at(p.to_world(body)) - fd).norm(), 1e-6) << "t = " << t;
    EXPECT_TRUE(p.to_body(p.to_world(body)).isApprox(body, 1e-12));
  }
  EXPECT_FALSE(RigidMotion(euler_degrees({10, 20, 30}), {1, 2, 3}, Vector3d::Zero()).moves());
}

TEST(RigidMotion, EulerAnglesTurnAboutXThenYThenZ) {
  EXPECT_TRUE((euler_degrees({90, 0, 0}) * Vector3d::UnitY()).isApprox(Vector3d::UnitZ(), 1e-12));
  EXPECT_TRUE((euler_degrees({0, 90, 0}) * Vector3d::UnitZ()).isApprox(Vector3d::UnitX(), 1e-12));
  EXPECT_TRUE((euler_degrees({0, 0, 90}) * Vector3d::UnitX()).isApprox(Vector3d::UnitY(), 1e-12));
  // x first, then z: y -> z (about x) stays z about z.
  EXPECT_TRUE((euler_degrees({90, 0, 90}) * Vector3d::UnitY()).isApprox(Vector3d::UnitZ(), 1e-12));
  EXPECT_TRUE((euler_degrees({90, 0, 90}) * Vector3d::UnitX()).isApprox(Vector3d::UnitY(), 1e-12));
}
