// FEM from the scene format: validation of fem scenes, TetGen meshes found relative to the
// scene file, frames with a "face" element, free fall, and a clamped beam's static deflection
// under gravity against Euler-Bernoulli.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "slurry/engine/fem/fem_solver.h"
#include "slurry/io/tetgen.h"
#include "slurry/io/ply.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace {

namespace fs = std::filesystem;

fs::path temp_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_fem_scene_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

const char* kScene2D = R"({
  "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
  "solver": {"type": "fem", "dimension": 2, "precision": "double", "integrator": "explicit"},
  "materials": [{"name": "jelly", "model": "corotated_linear", "density": 1000, "E": 1e5, "nu": 0.3}],
  "bodies": [{"shape": "box", "min": [0.3, 0.5], "max": [0.6, 0.7], "material": "jelly"}],
  "output": {"directory": "unused", "fps": 24, "frames": 2, "attributes": ["position", "velocity", "material", "J"]}
})";

// The checked-in TetGen example is exactly what ball_mesh generates, and close to a ball.
TEST(FemScene, ExampleBallMeshMatchesItsGenerator) {
  const auto m = slurry::io::read_tetgen<3>(fs::path(SLURRY_EXAMPLES_DIR) / "meshes" / "ball");
  const auto g = slurry::fem::ball_mesh<3>(Eigen::Vector3d(0.25, 0.55, 0.25), 0.12, 6);
  ASSERT_EQ(m.vertex_count(), g.vertex_count());
  ASSERT_EQ(m.element_count(), g.element_count());
  double dx = 0, volume = 0;
  for (std::size_t i = 0; i < m.vertex_count(); ++i) dx = std::max(dx, (m.x[i] - g.x[i]).norm());
  for (std::size_t e = 0; e < m.element_count(); ++e) {
    EXPECT_EQ(m.elements[e], g.elements[e]);
    volume += m.signed_volume(e);
  }
  const double ball = 4.0 / 3.0 * M_PI * 0.12 * 0.12 * 0.12;
  std::printf("[ figure ] ball.node/.ele: %zu vertices, %zu tetrahedra, volume %.3f of the ball's\n", m.vertex_count(),
              m.element_count(), volume / ball);
  EXPECT_LT(dx, 1e-15);
  EXPECT_NEAR(volume / ball, 1.0, 0.15);  // inscribed, and the caps at the cube edges are cut off
}

// Scene -> frames: a 3D body read from a TetGen file next to the scene (relative path), and a
// 2D meshed box; every frame has the vertices and the faces (outward triangles in 3D).
TEST(FemScene, RunsEndToEndWritingPlyWithFaces) {
  const auto dir = temp_dir("e2e");
  fs::create_directories(dir / "meshes");
  const auto cube = slurry::fem::box_mesh<3>(Eigen::Vector3d(0.4, 0.5, 0.4), Eigen::Vector3d(0.6, 0.7, 0.6), Eigen::Vector3i(2, 2, 2));
  slurry::io::write_tetgen<3>(dir / "meshes" / "cube", cube);
  std::ofstream(dir / "scene3d.json") << R"({
    "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
    "solver": {"type": "fem", "dimension": 3, "integrator": "implicit", "max_dt": 0.005},
    "materials": [{"name": "jelly", "model": "corotated_linear", "E": 1e5, "nu": 0.3, "damping": 0.01}],
    "bodies": [{"mesh": "meshes/cube.node", "material": "jelly", "velocity": [1, 0, 0]}],
    "output": {"directory": "frames", "frames": 3, "attributes": ["position", "velocity"]}
  })";
  std::ofstream(dir / "scene2d.json") << kScene2D;
  for (const char* name : {"scene3d.json", "scene2d.json"}) {
    const auto scene = slurry::load_scene(dir / name);
    slurry::RunOptions opt;
    opt.directory = dir / (std::string(name) + ".frames");
    const auto summary = slurry::run_scene(scene, opt);
    EXPECT_EQ(summary.frames_written, scene.output.frames + 1);
    const int dim = scene.solver.dimension;
    const std::size_t vertices = dim == 3 ? cube.vertex_count() : 7 * 5;
    const std::size_t faces = dim == 3 ? 6 * 4 * 2 : 6 * 4 * 2;  // 3D: 2x2 quads per cube face; 2D: 6x4 cells
    double y0 = 0;
    for (int f = 0; f <= scene.output.frames; ++f) {
      const auto ply = slurry::io::read_ply(slurry::frame_file(*opt.directory, f));
      const auto& v = ply.table("vertex");
      const auto& fc = ply.table("face");
      ASSERT_EQ(v.count, vertices) << name;
      ASSERT_EQ(fc.count, faces) << name;
      for (const auto& t : fc.list("vertex_indices").data) {
        ASSERT_EQ(t.size(), 3u);
        for (int k : t) ASSERT_TRUE(k >= 0 && std::size_t(k) < vertices);
      }
      EXPECT_NE(v.find("vx"), nullptr);
      const auto y = v.column_as_double("y");
      double mean = 0;
      for (double yi : y) mean += yi / double(y.size());
      if (f == 0) y0 = mean;
      if (f == scene.output.frames) {
        const double t = scene.output.frames / scene.output.fps;
        std::printf("[ figure ] %s: %zu vertices, %zu faces, mean y dropped %.4f m in %.3f s (free fall %.4f m)\n", name,
                    vertices, faces, y0 - mean, t, 0.5 * 9.81 * t * t);
        EXPECT_NEAR(y0 - mean, 0.5 * 9.81 * t * t, 0.1 * 0.5 * 9.81 * t * t);
      }
    }
    if (dim == 3) {  // outward faces: the divergence theorem gives the body's volume
      const auto ply = slurry::io::read_ply(slurry::frame_file(*opt.directory, 0));
      const auto x = ply.table("vertex").column_as_double("x"), y = ply.table("vertex").column_as_double("y"),
                 z = ply.table("vertex").column_as_double("z");
      double vol = 0;
      for (const auto& t : ply.table("face").list("vertex_indices").data) {
        const Eigen::Vector3d a(x[t[0]], y[t[0]], z[t[0]]), b(x[t[1]], y[t[1]], z[t[1]]), c(x[t[2]], y[t[2]], z[t[2]]);
        vol += a.dot(b.cross(c)) / 6;
      }
      EXPECT_NEAR(vol, 0.2 * 0.2 * 0.2, 1e-6) << "faces not outward oriented";
    }
  }
}

// Away from walls a body translates rigidly: every vertex follows symplectic Euler's free fall
// y_n = y_0 + g dt^2 n (n + 1) / 2 exactly (the co-rotated forces of a translation vanish).
TEST(FemScene, FreeFallFollowsSymplecticEuler) {
  const auto scene = slurry::parse_scene(kScene2D, "free_fall.json");
  slurry::FemSolver<double, 2> sim(scene);
  const auto x0 = sim.fem().x;
  const double dt = sim.stable_dt();
  const int n = int(0.1 / dt);
  for (int i = 0; i < n; ++i) sim.step(dt);
  double worst = 0;
  for (std::size_t i = 0; i < x0.size(); ++i) {
    worst = std::max(worst, std::abs(sim.fem().x[i][1] - (x0[i][1] - 9.81 * dt * dt * n * (n + 1) / 2.0)));
    worst = std::max(worst, std::abs(sim.fem().x[i][0] - x0[i][0]));
  }
  EXPECT_LT(worst, 1e-12);
}

// A beam clamped by a sticky collider sags under its own weight; with Rayleigh damping and the
// implicit step it settles to the static deflection, which Euler-Bernoulli gives as
// q L^4 / (8 E I) with q = rho g h, I = h^3 / 12 (per unit thickness; nu = 0). The clamped
// vertices do not move at all.
TEST(FemScene, ClampedBeamSettlesToEulerBernoulliDeflection) {
  const double L = 0.8, h = 0.08, E = 1e8, rho = 1000, g = 9.81;
  auto scene = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 0.6], "dx": 0.01},
    "solver": {"type": "fem", "dimension": 2, "precision": "double", "integrator": "implicit", "max_dt": 0.01},
    "materials": [{"name": "beam", "model": "corotated_linear", "density": 1000, "E": 1e8, "nu": 0, "damping": 0.01}],
    "bodies": [{"shape": "box", "min": [0.1, 0.4], "max": [0.9, 0.48], "material": "beam"}],
    "colliders": [{"shape": "box", "min": [0, 0.3], "max": [0.105, 0.6], "condition": "sticky"}]
  })", "beam.json");
  slurry::FemSolver<double, 2> sim(scene);
  const auto x0 = sim.fem().x;
  sim.advance_to(1.0);
  double tip = 0, clamped = 0;
  int ntip = 0;
  for (std::size_t i = 0; i < x0.size(); ++i) {
    if (x0[i][0] > 0.9 - 1e-9) tip += sim.fem().x[i][1] - x0[i][1], ++ntip;
    if (x0[i][0] < 0.105) clamped = std::max(clamped, (sim.fem().x[i] - x0[i]).norm());
  }
  tip /= ntip;
  const double expected = rho * g * h * L * L * L * L / (8 * E * h * h * h / 12);
  std::printf("[ figure ] clamped beam (80 x 8 cells, implicit): tip deflection %.5f m, Euler-Bernoulli %.5f m, error %+.2f%%\n",
              -tip, expected, 100 * (-tip / expected - 1));
  EXPECT_EQ(clamped, 0.0);
  EXPECT_NEAR(-tip / expected, 1.0, 0.05);
}

struct BadCase {
  const char* name;
  const char* json;
  const char* expected;
};

const BadCase kBad[] = {
    {"model", R"({"solver": {"type": "fem", "dimension": 2}, "materials": [{"name": "a", "model": "neo_hookean"}],
       "bodies": [{"min": [0.1, 0.1], "max": [0.2, 0.2], "material": "a"}]})",
     "materials[0].model: solver.type \"fem\" simulates \"corotated_linear\" only, got \"neo_hookean\""},
    {"cylinder", R"({"solver": {"type": "fem", "dimension": 3}, "materials": [{"name": "a", "model": "corotated_linear"}],
       "bodies": [{"shape": "cylinder", "center": [0.5, 0.5, 0.5], "radius": 0.1, "height": 0.2, "material": "a"}]})",
     "bodies[0].shape: solver.type \"fem\" meshes \"box\" and \"sphere\" bodies"},
    {"damping", R"({"solver": {"type": "fem", "dimension": 2}, "materials": [{"name": "a", "model": "corotated_linear", "damping": -1}],
       "bodies": [{"min": [0.1, 0.1], "max": [0.2, 0.2], "material": "a"}]})",
     "materials[0].damping: expected a number >= 0, got -1"},
    {"damping_on_mpm", R"({"solver": {"dimension": 2}, "materials": [{"name": "a", "damping": 0.1}],
       "bodies": [{"min": [0.1, 0.1], "max": [0.2, 0.2], "material": "a"}]})",
     "materials[0].damping: unknown key"},
    {"mesh_on_mpm", R"({"solver": {"dimension": 2}, "materials": [{"name": "a"}],
       "bodies": [{"mesh": "a.node", "material": "a"}]})",
     "bodies[0].mesh: a triangle mesh is filled with particles by \"shape\": \"mesh\" (TetGen meshes are for solver.type \"fem\")"},
    {"mesh_shape_on_fem", R"({"solver": {"type": "fem", "dimension": 3}, "materials": [{"name": "a", "model": "corotated_linear"}],
       "bodies": [{"shape": "mesh", "mesh": "a.obj", "material": "a"}]})",
     "bodies[0].shape: solver.type \"fem\" reads a TetGen \"mesh\""},
};

class BadFemScenes : public testing::TestWithParam<BadCase> {};

TEST_P(BadFemScenes, MessageNamesThePathAndExpectation) {
  try {
    slurry::parse_scene(GetParam().json, "bad.json");
    FAIL() << "accepted a bad scene";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find(GetParam().expected), std::string::npos) << e.what();
  }
}

INSTANTIATE_TEST_SUITE_P(Table, BadFemScenes, testing::ValuesIn(kBad),
                         [](const testing::TestParamInfo<BadCase>& i) { return std::string(i.param.name); });

// A missing mesh is an IoError naming the file, resolved next to the scene file.
TEST(FemScene, MissingMeshNamesTheResolvedFile) {
  const auto dir = temp_dir("missing");
  std::ofstream(dir / "s.json") << R"({"solver": {"type": "fem", "dimension": 2}, "materials": [{"name": "a", "model": "corotated_linear"}],
    "bodies": [{"mesh": "nothere", "material": "a"}]})";
  auto scene = slurry::load_scene(dir / "s.json");
  try {
    slurry::io::read_scene_files(scene);  // the solvers take their meshes read (Scene::files)
    FAIL();
  } catch (const slurry::IoError& e) {
    EXPECT_NE(std::string(e.what()).find((dir / "nothere.node").string() + ": no such file (expected a TetGen mesh file)"), std::string::npos) << e.what();
  }
}

}  // namespace
