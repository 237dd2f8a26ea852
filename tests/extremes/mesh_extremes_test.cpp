// Mesh colliders at the extremes: a triangle-mesh wall a quarter of a cell
// thick, hit at 20 m/s by an elastic block (MPM, separate and sticky) and by a block of water
// (FLIP). The grid cannot resolve such a wall: nodes on both sides of it lie outside the solid.
// The particle-level check (colliders.h, stop_at_collider: the exact first crossing of each
// particle's path with the mesh's triangles, in the collider's moving frame) must keep every
// particle on the near side. The same wall, turned 30 degrees about y and sweeping towards the
// block, checks the moving frame.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "geometry/mesh_util.h"
#include "extremes/extremes.h"

namespace fs = std::filesystem;
using extremes::expect_runs;
using extremes::Outcome;
using slurry::Scene;

namespace {

/// A 3D scene in a temporary folder (so that the wall's mesh file sits beside it): a block
/// [0.1, 0.25] x [0.1, 0.3] x [0.15, 0.35] thrown at `speed` along x at a plate x in [0.5, 0.5 + t]
/// spanning the whole domain. dx = 1/16 m; 4 particles per cell.
Scene wall_scene(bool flip, double speed, double thickness, fs::path& dir) {
  dir = fs::temp_directory_path() / ("slurry_mesh_extremes_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  slurry::test::write_obj(dir / "plate.obj",
                          slurry::test::box_mesh({0, -0.5, -0.5}, {thickness, 1.0, 1.0}));
  Scene s = slurry::parse_scene(flip ? R"({
    "domain": {"min": [0, 0, 0], "max": [1, 0.5, 0.5], "dx": 0.0625},
    "solver": {"type": "flip", "dimension": 3, "transfer": "apic"},
    "materials": [{"name": "water", "model": "fluid"}],
    "bodies": [{"shape": "box", "min": [0.1, 0.1, 0.15], "max": [0.25, 0.3, 0.35], "material": "water"}],
    "colliders": [{"shape": "mesh", "mesh": "plate.obj", "translation": [0.5, 0, 0], "condition": "slip"}],
    "output": {"fps": 500, "frames": 15}
  })"
                                     : R"({
    "domain": {"min": [0, 0, 0], "max": [1, 0.5, 0.5], "dx": 0.0625},
    "solver": {"dimension": 3},
    "materials": [{"name": "jelly", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.1, 0.15], "max": [0.25, 0.3, 0.35], "material": "jelly", "particles_per_cell": 4}],
    "colliders": [{"shape": "mesh", "mesh": "plate.obj", "translation": [0.5, 0, 0]}],
    "output": {"fps": 500, "frames": 15}
  })",
                                (dir / "scene.json").string());
  s.bodies[0].velocity = {speed, 0, 0};
  return s;
}

}  // namespace

TEST(Extremes, ThinMeshWallHitAt20MetresPerSecond) {
  const double dx = 0.0625, t = dx / 4;
  for (int c = 0; c < 3; ++c) {
    const bool flip = c == 2;
    fs::path dir;
    Scene s = wall_scene(flip, 20, t, dir);
    if (c == 1) s.colliders[0].condition = slurry::Condition::Sticky;
    double far = -1;
    const Outcome o = extremes::run(s, 15, [&](const slurry::Table& v) {
      for (double x : v.column_as_double("x")) far = std::max(far, x - 0.5);
    });
    const std::string name = std::string(flip ? "FLIP water" : "MPM jelly") +
                             " at 20 m/s into a mesh wall dx/4 thick" +
                             (c == 1 ? ", sticky"
                              : flip ? ", slip"
                                     : ", separate");
    expect_runs(name, o, 15, flip ? 1.05 : 1.01);
    std::printf(
        "[ extreme ] %s: largest x - 0.5 = %.3g m (frames to t = 0.03 s; the block reaches the "
        "wall at 0.0125 s)\n",
        name.c_str(), far);
    EXPECT_LE(far, 0.0) << name << ": a particle entered or passed the wall";
    EXPECT_GT(far, -dx) << name << ": the block never reached the wall";
    fs::remove_all(dir);
  }
}

// The wall turned 30 degrees about y and moving at 5 m/s towards a block coming at 15 m/s:
// the path check works in the wall's moving, rotated frame (keyframes), for MPM and FLIP.
TEST(Extremes, ThinMeshWallTurnedAndMovingThroughKeyframes) {
  const double dx = 0.0625, t = dx / 4;
  for (const bool flip : {false, true}) {
    fs::path dir;
    Scene s = wall_scene(flip, 15, t, dir);
    auto& wall = s.colliders[0];
    wall.keyframes = {{0.0, {0.6, 0, 0}, {0, 30, 0}}, {0.03, {0.45, 0, 0}, {0, 30, 0}}};
    // The plate's near face is the plane through (x0(t), ., .) with normal R (-1, 0, 0): a
    // particle is on the near side where (x - x0(t)) . n >= 0.
    const Eigen::Matrix3d R = slurry::geometry::euler_degrees({0, 30, 0});
    const Eigen::Vector3d n = R * Eigen::Vector3d(-1, 0, 0);
    int frame = 0;
    double worst = -1;
    const Outcome o = extremes::run(s, 15, [&](const slurry::Table& v) {
      const double time = frame++ / 500.0, x0 = 0.6 - 5 * std::min(time, 0.03);
      const auto x = v.column_as_double("x"), y = v.column_as_double("y"),
                 z = v.column_as_double("z");
      for (std::size_t p = 0; p < x.size(); ++p)
        worst = std::max(worst, -(Eigen::Vector3d(x[p] - x0, y[p], z[p]).dot(n)));
    });
    const std::string name = std::string(flip ? "FLIP water" : "MPM jelly") +
                             " at 15 m/s into a turned mesh wall moving at 5 m/s";
    expect_runs(name, o, 15, flip ? 1.5 : 1.5);  // the moving wall does work on the block
    std::printf("[ extreme ] %s: deepest particle behind the near face %.3g m\n", name.c_str(),
                worst);
    EXPECT_LE(worst, 1e-6) << name << ": a particle got past the wall";
    fs::remove_all(dir);
  }
}
