// Mesh bodies and mesh colliders in whole scenes: a mesh body seeds the
// same lattice as the box it describes (MPM and FLIP), a sphere mesh fills its volume, bad
// meshes and keys are refused with messages naming the scene, the key and the mesh file, a
// static mesh collider holds a block where the analytic box collider does, and a keyframed
// sticky collider carries what rests on it at its own speed.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>

#include "geometry/mesh_util.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/solver.h"
#include "slurry/io/scene_file.h"
#include "slurry/engine/run/run.h"

namespace fs = std::filesystem;
using slurry::Scene;
using geometry_mesh = slurry::geometry::TriangleMesh;

namespace {

fs::path temp_dir() {
  const fs::path d =
      fs::temp_directory_path() / ("slurry_mesh_scene_" + std::to_string(::getpid()));
  fs::create_directories(d);
  return d;
}

std::vector<double> column(const slurry::Solver& sim, const char* name) {
  return sim.frame({"position", "velocity"}).table("vertex").column_as_double(name);
}

/// The lowest particle height over 0.6 s (30 frames of 0.02 s) of a block dropped in `s`.
double deepest_particle(const Scene& s) {
  const auto sim = slurry::make_simulation(s);
  double deepest = 1;
  for (int f = 1; f <= 30; ++f) {
    sim->advance_to(0.02 * f);
    const auto y = column(*sim, "y");
    deepest = std::min(deepest, *std::min_element(y.begin(), y.end()));
  }
  return deepest;
}

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return s / double(v.size());
}

/// An MPM (or FLIP) 3D scene with one body, a box or that box as a mesh.
Scene body_scene(bool flip, bool mesh, const fs::path& dir) {
  slurry::test::write_obj(dir / "box.obj",
                          slurry::test::box_mesh({-0.2, -0.1, -0.1}, {0.2, 0.1, 0.1}));
  const std::string body =
      mesh
          ? R"({"shape": "mesh", "mesh": "box.obj", "translation": [0.5, 0.3, 0.5], "material": "m"})"
          : R"({"shape": "box", "min": [0.3, 0.2, 0.4], "max": [0.7, 0.4, 0.6], "material": "m"})";
  const std::string text =
      std::string(R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},)") +
      (flip
           ? R"("solver": {"type": "flip", "dimension": 3, "transfer": "apic"}, "materials": [{"name": "m", "model": "fluid"}],)"
           : R"("solver": {"dimension": 3}, "materials": [{"name": "m"}],)") +
      R"("bodies": [)" + body + "]}";
  return slurry::parse_scene(text, (dir / "scene.json").string());
}

}  // namespace

TEST(MeshScene, MeshBodySeedsTheLatticeOfTheBoxItDescribes) {
  const fs::path dir = temp_dir();
  for (const bool flip : {false, true}) {
    const auto box = slurry::make_simulation(body_scene(flip, false, dir));
    const auto mesh = slurry::make_simulation(body_scene(flip, true, dir));
    ASSERT_EQ(box->particle_count(), mesh->particle_count()) << (flip ? "FLIP" : "MPM");
    for (const char* axis : {"x", "y", "z"}) {
      const auto a = column(*box, axis), b = column(*mesh, axis);
      for (std::size_t p = 0; p < a.size(); ++p)
        ASSERT_NEAR(a[p], b[p], 1e-6) << axis << " of particle " << p;
    }
    // Same mass: the stats see the same total.
    EXPECT_NEAR(box->take_stats().mass, mesh->take_stats().mass, 1e-9 * box->take_stats().mass);
  }
}

// A cube mesh seeds exactly the lattice of its box at any placement and scale, mirrored ones
// included: rows of lattice points that pass exactly through a face's diagonal (x = y for a cube
// centred on the lattice) are counted once, not dropped (4000 of 4096 particles were seeded for
// [0.3, 0.7]^3 when the two triangles' edge functions were rounded apart).
TEST(MeshScene, CubeMeshSeedsItsBoxAtEveryPlacementAndScale) {
  const fs::path dir = temp_dir();
  slurry::test::write_obj(dir / "cube.obj", slurry::test::box_mesh({-0.2, -0.2, -0.2}, {0.2, 0.2, 0.2}));
  const auto v = [](const Eigen::Vector3d& x) {
    return "[" + std::to_string(x[0]) + ", " + std::to_string(x[1]) + ", " + std::to_string(x[2]) + "]";
  };
  const auto scene = [&](const std::string& body) {
    return slurry::parse_scene(R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
      "solver": {"dimension": 3}, "materials": [{"name": "m"}], "bodies": [)" + body + "]}",
                               (dir / "scene.json").string());
  };
  int cases = 0;
  for (const Eigen::Vector3d& t : {Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::Vector3d(0.37, 0.41, 0.53),
                                  Eigen::Vector3d(0.3125, 0.5, 0.6875), Eigen::Vector3d(0.45, 0.45, 0.45)}) {
    for (const Eigen::Vector3d& sc : {Eigen::Vector3d(1, 1, 1), Eigen::Vector3d(0.75, 0.75, 0.75),
                                     Eigen::Vector3d(1.3, 0.6, 1), Eigen::Vector3d(-1, 1, 1),
                                     Eigen::Vector3d(-0.5, -0.5, -0.5)}) {
      const Eigen::Vector3d half = 0.2 * sc.cwiseAbs();
      const auto box = slurry::make_simulation(
          scene(R"({"shape": "box", "min": )" + v(t - half) + R"(, "max": )" + v(t + half) + R"(, "material": "m"})"));
      const auto mesh = slurry::make_simulation(scene(R"({"shape": "mesh", "mesh": "cube.obj", "scale": )" + v(sc) +
                                                      R"(, "translation": )" + v(t) + R"(, "material": "m"})"));
      EXPECT_EQ(mesh->particle_count(), box->particle_count()) << "translation " << v(t) << ", scale " << v(sc);
      ++cases;
    }
  }
  EXPECT_EQ(cases, 20);
}

// Two closed parts that overlap (a common artist mesh) are filled as their union, the overlap
// once (not left hollow, as the parity of the crossings left it), and a closed shell whose inner
// surface faces inward stays hollow. Counted against the lattice points inside the boxes.
TEST(MeshScene, OverlappingPartsFillTheirUnionAndAShellStaysHollow) {
  const fs::path dir = temp_dir();
  const auto joined = [](geometry_mesh a, const geometry_mesh& b, bool flip_b) {
    const int base = int(a.vertices.size());
    a.vertices.insert(a.vertices.end(), b.vertices.begin(), b.vertices.end());
    for (auto t : b.triangles) {
      if (flip_b) std::swap(t[1], t[2]);
      a.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
    }
    return a;
  };
  const Eigen::Vector3d a_lo(-0.2, -0.2, -0.2), a_hi(0.1, 0.1, 0.1), b_lo(-0.1, -0.1, -0.1), b_hi(0.2, 0.2, 0.2);
  const Eigen::Vector3d s_lo(-0.1, -0.1, -0.1), s_hi(0.1, 0.1, 0.1);  // the shell's cavity
  slurry::test::write_obj(dir / "union.obj", joined(slurry::test::box_mesh(a_lo, a_hi), slurry::test::box_mesh(b_lo, b_hi), false));
  slurry::test::write_obj(dir / "shell.obj", joined(slurry::test::box_mesh(a_lo, b_hi), slurry::test::box_mesh(s_lo, s_hi), true));
  const auto count = [&](const char* mesh) {
    return slurry::make_simulation(
               slurry::parse_scene(std::string(R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
      "solver": {"dimension": 3}, "materials": [{"name": "m"}],
      "bodies": [{"shape": "mesh", "mesh": ")") + mesh + R"(", "translation": [0.5, 0.5, 0.5], "material": "m"}]})",
                                   (dir / "scene.json").string()))
        ->particle_count();
  };
  // The seeding lattice over the bounding box [-0.2, 0.2]^3: 8 per cell of 0.05, spacing 0.025.
  const auto in = [](const Eigen::Vector3d& x, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    return (x.array() > lo.array()).all() && (x.array() < hi.array()).all();
  };
  std::size_t in_union = 0, in_shell = 0;
  for (int i = 0; i < 16; ++i)
    for (int j = 0; j < 16; ++j)
      for (int k = 0; k < 16; ++k) {
        const Eigen::Vector3d x = Eigen::Vector3d(-0.2, -0.2, -0.2) + 0.025 * Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5);
        in_union += in(x, a_lo, a_hi) || in(x, b_lo, b_hi);
        in_shell += !in(x, s_lo, s_hi);
      }
  EXPECT_EQ(count("union.obj"), in_union);  // 12^3 + 12^3 - 8^3 = 2944
  EXPECT_EQ(in_union, 2944u);
  EXPECT_EQ(count("shell.obj"), in_shell);  // 16^3 - 8^3 = 3584
  EXPECT_EQ(in_shell, 3584u);
}

TEST(MeshScene, SphereMeshFillsItsVolume) {
  const fs::path dir = temp_dir();
  const auto ball = slurry::test::icosphere(1.0, 3);
  slurry::test::write_obj(dir / "ball.obj", ball);
  Scene s = slurry::parse_scene(R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.02},
    "solver": {"dimension": 3}, "materials": [{"name": "snow", "density": 400}],
    "bodies": [{"shape": "mesh", "mesh": "ball.obj", "scale": [0.2, 0.2, 0.2], "translation": [0.5, 0.5, 0.5],
                "material": "snow", "sampling": "jittered"}]})",
                                (dir / "scene.json").string());
  const auto sim = slurry::make_simulation(s);
  const double volume = 0.2 * 0.2 * 0.2 * ball.signed_volume();
  const double mass = sim->take_stats().mass;
  EXPECT_NEAR(mass / (400 * volume), 1.0, 0.01) << "particles: " << sim->particle_count();
}

TEST(MeshScene, BadMeshesAndKeysAreRefusedNamingSceneKeyAndFile) {
  const fs::path dir = temp_dir();
  auto open = slurry::test::box_mesh({0, 0, 0}, {0.2, 0.2, 0.2});
  open.triangles.pop_back();
  slurry::test::write_obj(dir / "open.obj", open);
  slurry::test::write_obj(dir / "big.obj", slurry::test::box_mesh({0, 0, 0}, {2, 2, 2}));
  const auto scene = [&](const std::string& body, const std::string& extra = "") {
    return slurry::parse_scene(
        R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05}, "solver": {"dimension": 3},
      "materials": [{"name": "m"}], "bodies": [)" +
            body + "]" + extra + "}",
        (dir / "scene.json").string());
  };
  const std::string s = (dir / "scene.json").string();
  std::string m = slurry::test::message_of([&] {
    slurry::make_simulation(scene(R"({"shape": "mesh", "mesh": "open.obj", "material": "m"})"));
  });
  EXPECT_NE(m.find(s + ": bodies[0].mesh (open.obj): the mesh does not enclose a volume"),
            std::string::npos)
      << m;
  m = slurry::test::message_of([&] {
    slurry::make_simulation(scene(R"({"shape": "mesh", "mesh": "missing.obj", "material": "m"})"));
  });
  EXPECT_NE(m.find(s + ": bodies[0].mesh: "), std::string::npos) << m;
  EXPECT_NE(m.find("missing.obj: no such file"), std::string::npos) << m;
  m = slurry::test::message_of([&] {
    slurry::make_simulation(scene(R"({"shape": "mesh", "mesh": "big.obj", "material": "m"})"));
  });
  EXPECT_NE(m.find("bodies[0]: the placed mesh spans"), std::string::npos) << m;
  m = slurry::test::message_of([&] { scene(R"({"shape": "mesh", "material": "m"})"); });
  EXPECT_NE(m.find("bodies[0].mesh: missing"), std::string::npos) << m;
  m = slurry::test::message_of([&] {
    scene(R"({"shape": "mesh", "mesh": "big.obj", "scale": [1, 0, 1], "material": "m"})");
  });
  EXPECT_NE(m.find("bodies[0].scale[1]: expected a non-zero factor"), std::string::npos) << m;
  m = slurry::test::message_of([&] {
    scene(
        R"({"shape": "box", "min": [0.1, 0.1, 0.1], "max": [0.3, 0.3, 0.3], "material": "m"})",
        R"(, "colliders": [{"shape": "mesh", "mesh": "big.obj", "keyframes": [{"time": 1}, {"time": 0.5}]}])");
  });
  EXPECT_NE(m.find("colliders[0].keyframes[1].time: expected times in increasing order"),
            std::string::npos)
      << m;
  m = slurry::test::message_of([&] {
    scene(
        R"({"shape": "box", "min": [0.1, 0.1, 0.1], "max": [0.3, 0.3, 0.3], "material": "m"})",
        R"(, "colliders": [{"shape": "box", "min": [0, 0, 0], "max": [1, 0.1, 1], "keyframes": []}])");
  });
  EXPECT_NE(m.find("colliders[0].keyframes: unknown key"), std::string::npos) << m;
  // The same scene built in code is refused by validate().
  Scene coded =
      scene(R"({"shape": "box", "min": [0.1, 0.1, 0.1], "max": [0.3, 0.3, 0.3], "material": "m"})");
  slurry::ColliderParams box;
  box.shape = slurry::ColliderShape::Box;
  box.max = {1, 0.1, 1};
  box.keyframes.push_back({});
  coded.colliders = {box};
  m = slurry::test::message_of([&] { coded.validate(); });
  EXPECT_NE(
      m.find("colliders[0].keyframes: \"mesh\" and \"keyframes\" belong to \"shape\": \"mesh\""),
      std::string::npos)
      << m;
  m = slurry::test::message_of([&] {
    slurry::parse_scene(
        R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05}, "solver": {"dimension": 2},
      "materials": [{"name": "m"}], "bodies": [{"shape": "mesh", "mesh": "big.obj", "material": "m"}]})",
        s);
  });
  EXPECT_NE(m.find("bodies[0].shape: \"mesh\" bodies are 3D"), std::string::npos) << m;
}

// A block dropped on a static table: the table as an analytic box collider and as that box's
// mesh. Both hold it on top (the deepest particle over the bounces). The grid alone lets particles
// sink up to about half a cell into a thick analytic box; a mesh collider also checks every
// particle's path against its triangles, so its block rests on the surface itself.
TEST(MeshScene, MeshBodyThinnerThanTheParticleSpacingIsRefusedAsABoxIs) {
  // A 1 mm plate, a cube scaled to 1e-12 and a flat closed mesh (zero thickness) seeded a single
  // row, one particle or zero-mass particles; a box body as thin is refused, and so are they.
  const fs::path dir = temp_dir();
  slurry::test::write_obj(dir / "unit.obj", slurry::test::box_mesh({-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}));
  geometry_mesh flat;  // a closed, manifold, flat quad: two triangles up, two down
  flat.vertices = {{0.3, 0.5, 0.3}, {0.7, 0.5, 0.3}, {0.7, 0.5, 0.7}, {0.3, 0.5, 0.7}};
  flat.triangles = {{0, 2, 1}, {0, 3, 2}, {0, 1, 3}, {1, 2, 3}};
  slurry::test::write_obj(dir / "flat.obj", flat);
  const std::string s = (dir / "scene.json").string();
  const auto run = [&](const std::string& body) {
    return slurry::test::message_of([&] {
      slurry::make_simulation(slurry::parse_scene(
          R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.02}, "solver": {"dimension": 3},
            "materials": [{"name": "m"}], "bodies": [)" + body + "]}",
          s));
    });
  };
  std::string m = run(R"({"shape": "mesh", "mesh": "unit.obj", "scale": [0.4, 0.001, 0.4], "translation": [0.5, 0.5, 0.5], "material": "m"})");
  EXPECT_NE(m.find(s + ": bodies[0]: the placed mesh is 0.001 m across along axis 1, expected at least one particle spacing"),
            std::string::npos) << m;
  m = run(R"({"shape": "mesh", "mesh": "unit.obj", "scale": [1e-12, 1e-12, 1e-12], "translation": [0.5, 0.5, 0.5], "material": "m"})");
  EXPECT_NE(m.find("bodies[0]: the placed mesh is "), std::string::npos) << m;
  EXPECT_NE(m.find(" m across along axis 0, expected at least one particle spacing"), std::string::npos) << m;
  m = run(R"({"shape": "mesh", "mesh": "flat.obj", "material": "m"})");
  EXPECT_NE(m.find("bodies[0]"), std::string::npos) << m;
  EXPECT_TRUE(m.find("m across along axis 1") != std::string::npos || m.find("the mesh encloses no volume") != std::string::npos) << m;
  m = run(R"({"shape": "mesh", "mesh": "unit.obj", "scale": [0.4, 1e-9, 0.4], "translation": [0.5, 0.5, 0.5], "material": "m"})");
  EXPECT_NE(m.find("m across along axis 1, expected at least one particle spacing"), std::string::npos) << m;
  // The box body of the plate: refused with the same words.
  m = run(R"({"shape": "box", "min": [0.3, 0.5, 0.3], "max": [0.7, 0.501, 0.7], "material": "m"})");
  EXPECT_NE(m.find("across along axis 1, expected at least one particle spacing"), std::string::npos) << m;
}

// A mesh body whose lattice would not fit in memory is refused before any particle is seeded,
// naming the body's mesh and the count (it failed after 30 s of seeding with an out-of-memory
// that named no field). The count is the enclosed volume over the lattice cell.
TEST(MeshScene, MeshBodyTooLargeForMemoryIsRefusedNamingTheMesh) {
  const fs::path dir = temp_dir();
  slurry::test::write_obj(dir / "unit.obj", slurry::test::box_mesh({-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}));
  const auto scene = [&](double memory_gb) {
    return slurry::parse_scene(
        R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.001}, "solver": {"dimension": 3},
          "materials": [{"name": "m"}], "limits": {"memory_gb": )" + std::to_string(memory_gb) + R"(},
          "bodies": [{"shape": "mesh", "mesh": "unit.obj", "scale": [0.4, 0.4, 0.4], "translation": [0.5, 0.5, 0.5], "material": "m"}]})",
        (dir / "scene.json").string());
  };
  // 0.4^3 m^3 at 8 particles per (1 mm)^3 cell: 5.12e8 particles, about 130 GiB.
  for (const bool check : {true, false}) {
    const std::string m = slurry::test::message_of([&] {
      if (check) slurry::check_scene(scene(16));
      else slurry::make_simulation(scene(16));
    });
    EXPECT_NE(m.find("scene.json: bodies[0].mesh: the run would need about "), std::string::npos) << m;
    EXPECT_NE(m.find(" particles seeded by the bodies"), std::string::npos) << m;
    EXPECT_TRUE(m.find("for 512000000 ") != std::string::npos || m.find("for 511999999.") != std::string::npos) << m;
  }
  // The estimate follows the volume, not the bounding box: a limit above the need passes the check.
  EXPECT_EQ(slurry::test::message_of([&] { slurry::check_scene(scene(1e4)); }), "");
}

TEST(MeshScene, StaticMeshColliderHoldsABlockOnItsSurface) {
  const fs::path dir = temp_dir();
  const double dx = 0.05;
  slurry::test::write_obj(dir / "table.obj",
                          slurry::test::box_mesh({0.1, 0.1, 0.1}, {0.9, 0.3, 0.9}));
  double rest[2];
  for (int mesh = 0; mesh < 2; ++mesh) {
    const std::string collider =
        mesh
            ? R"({"shape": "mesh", "mesh": "table.obj", "condition": "separate", "friction": 0.5})"
            : R"({"shape": "box", "min": [0.1, 0.1, 0.1], "max": [0.9, 0.3, 0.9], "condition": "separate", "friction": 0.5})";
    const Scene s = slurry::parse_scene(
        R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05}, "solver": {"dimension": 3},
      "materials": [{"name": "jelly", "E": 2e4}], "bodies": [{"shape": "box", "min": [0.35, 0.45, 0.35], "max": [0.65, 0.6, 0.65], "material": "jelly"}],
      "colliders": [)" +
            collider + "]}",
        (dir / "scene.json").string());
    rest[mesh] = deepest_particle(s);
  }
  std::printf(
      "deepest particle over 0.6 s: analytic box %.4f m, mesh %.4f m (table top 0.3 m, dx %.2f "
      "m)\n",
      rest[0], rest[1], dx);
  EXPECT_GT(rest[0], 0.3 - 0.6 * dx);
  EXPECT_LT(rest[0], 0.3 + 0.5 * dx);
  EXPECT_GE(rest[1], 0.3 - 1e-5) << "a particle entered the mesh";
  EXPECT_LT(rest[1], 0.3 + 0.5 * dx);
}

// A sticky platform raised through keyframes at 0.5 m/s from t = 0.1 s carries the block lying
// on it at that speed (the collider's velocity at the contact point, not zero).
TEST(MeshScene, StaticMeshColliderFarLargerThanTheDomainHoldsABlock) {
  // A ground mesh of 1e8 m or 1e12 m: its distance field is sampled over the domain only (at
  // 0.5 dx), where over its own extent the grid's spacing grew past the domain and the block
  // fell through it.
  const fs::path dir = temp_dir();
  const double dx = 0.05;
  slurry::test::write_obj(dir / "unit.obj", slurry::test::box_mesh({-0.5, -0.5, -0.5}, {0.5, 0.5, 0.5}));
  for (const double scale : {1e8, 1e12}) {
    char collider[512];
    std::snprintf(collider, sizeof collider,
                  R"({"shape": "mesh", "mesh": "unit.obj", "scale": [%.17g, %.17g, %.17g], "translation": [0.5, %.17g, 0.5], "condition": "separate", "friction": 0.5})",
                  scale, scale, scale, 0.3 - 0.5 * scale);
    const Scene s = slurry::parse_scene(
        R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05}, "solver": {"dimension": 3},
      "materials": [{"name": "jelly", "E": 2e4}], "bodies": [{"shape": "box", "min": [0.35, 0.45, 0.35], "max": [0.65, 0.6, 0.65], "material": "jelly"}],
      "colliders": [)" + std::string(collider) + "]}",
        (dir / "scene.json").string());
    const double rest = deepest_particle(s);
    std::printf("ground mesh scaled %g: deepest particle over 0.6 s %.4f m (top 0.3 m)\n", scale, rest);
    EXPECT_GE(rest, 0.3 - 1e-3) << "scale " << scale << ": the block fell into the ground";
    EXPECT_LT(rest, 0.3 + 0.5 * dx) << "scale " << scale;
  }
}

TEST(MeshScene, KeyframedStickyPlatformCarriesItsLoad) {
  const fs::path dir = temp_dir();
  slurry::test::write_obj(dir / "platform.obj",
                          slurry::test::box_mesh({-0.4, -0.1, -0.4}, {0.4, 0.1, 0.4}));
  const Scene s = slurry::parse_scene(
      R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05}, "solver": {"dimension": 3},
    "materials": [{"name": "block", "E": 1e6}],
    "bodies": [{"shape": "box", "min": [0.4, 0.3, 0.4], "max": [0.6, 0.4, 0.6], "material": "block"}],
    "colliders": [{"shape": "mesh", "mesh": "platform.obj", "condition": "sticky",
                   "keyframes": [{"time": 0.1, "translation": [0.5, 0.2, 0.5]}, {"time": 0.5, "translation": [0.5, 0.4, 0.5]}]}]})",
      (dir / "scene.json").string());
  const auto sim = slurry::make_simulation(s);
  sim->advance_to(0.09);
  EXPECT_LT(std::abs(mean(column(*sim, "vy"))), 0.05) << "at rest before the platform moves";
  sim->advance_to(0.4);
  EXPECT_NEAR(mean(column(*sim, "vy")), 0.5, 0.05) << "the block rides the platform at its speed";
  const auto y = column(*sim, "y");
  EXPECT_NEAR(*std::min_element(y.begin(), y.end()), 0.3 + 0.5 * 0.3, 0.05);
}
