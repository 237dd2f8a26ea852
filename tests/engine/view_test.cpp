// The embedding API (simulation_base.h): the typed particle view lists every solver's particles
// in ascending persistent id, reads them in place, agrees value for value with the PLY frame, and
// refuses the wrong scalar type or dimension; run_scene without files hands each frame to the
// callback and writes nothing.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <stdexcept>
#include <string>

#include "slurry/slurry.h"

namespace {

namespace fs = std::filesystem;

const char* kMpm3D = R"({
  "domain": {"min": [0, 0, 0], "max": [0.4, 0.4, 0.4], "dx": 0.04},
  "solver": {"type": "mpm", "dimension": 3, "precision": "float"},
  "materials": [{"name": "jelly", "model": "fixed_corotated", "E": 2e4, "nu": 0.3},
                {"name": "snow", "model": "fixed_corotated", "E": 2e4, "nu": 0.2, "plasticity": "snow"}],
  "bodies": [{"shape": "sphere", "center": [0.2, 0.25, 0.2], "radius": 0.08, "material": "jelly", "velocity": [1, 0, 0]},
             {"shape": "box", "min": [0.08, 0.08, 0.08], "max": [0.32, 0.14, 0.32], "material": "snow"}],
  "output": {"fps": 24, "frames": 2}
})";

// FLIP with an emitter and reseeding: ids grow and have gaps, the storage is sorted by cell.
const char* kFlip2D = R"({
  "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
  "solver": {"type": "flip", "dimension": 2, "precision": "double", "transfer": "apic", "kernel": "linear",
             "reseed": {"min_per_cell": 2, "max_per_cell": 5}},
  "materials": [{"name": "water", "model": "fluid", "density": 998}],
  "bodies": [{"shape": "box", "min": [0, 0], "max": [1, 0.4], "material": "water", "particles_per_cell": 6}],
  "emitters": [{"shape": "sphere", "center": [0.5, 0.8], "radius": 0.1, "rate": 0.05, "velocity": [0, -1],
                "material": "water", "particles_per_cell": 4}],
  "output": {"fps": 24, "frames": 2}
})";

const char* kFem2D = R"({
  "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
  "solver": {"type": "fem", "dimension": 2, "precision": "double"},
  "materials": [{"name": "jelly", "model": "corotated_linear", "density": 1000, "E": 1e5, "nu": 0.3}],
  "bodies": [{"shape": "box", "min": [0.3, 0.5], "max": [0.6, 0.7], "material": "jelly"}],
  "output": {"fps": 24, "frames": 2}
})";

// Rows of the frame keyed by particle id (MPM and FEM frames list particles by id already;
// FLIP frames are in storage order with an "id" column).
template <class T, int Dim>
void expect_view_matches_frame(const slurry::Solver& sim, bool frame_has_ids) {
  const auto view = sim.particles_view<T, Dim>();
  ASSERT_EQ(view.size(), sim.particle_count());
  const auto frame = sim.frame(frame_has_ids ? std::vector<std::string>{"position", "velocity", "id"}
                                             : std::vector<std::string>{"position", "velocity"});
  const auto& vertex = frame.table("vertex");
  std::map<std::uint32_t, std::size_t> row_of;
  for (std::size_t r = 0; r < vertex.count; ++r)
    row_of[frame_has_ids ? vertex.values<std::uint32_t>("id")[r] : std::uint32_t(r)] = r;
  static const char* xs[3] = {"x", "y", "z"};
  static const char* vs[3] = {"vx", "vy", "vz"};
  for (std::size_t i = 0; i < view.size(); ++i) {
    if (i > 0) {
      ASSERT_LT(view.id(i - 1), view.id(i)) << "ids must ascend";
    }
    ASSERT_EQ(row_of.count(view.id(i)), 1u) << "id " << view.id(i) << " is not in the frame";
    const std::size_t r = row_of[view.id(i)];
    for (int d = 0; d < Dim; ++d) {
      ASSERT_EQ(view.position(i)[d], vertex.values<T>(xs[d])[r]) << "particle id " << view.id(i);
      ASSERT_EQ(view.velocity(i)[d], vertex.values<T>(vs[d])[r]) << "particle id " << view.id(i);
    }
    // In place: the view's element is the solver's own storage, not a copy.
    ASSERT_EQ(&view.position(i), view.positions() + view.slot(i));
  }
}

TEST(ParticleView, MpmViewFollowsIdsThroughTheBinReorder) {
  auto sim = slurry::make_simulation(slurry::parse_scene(kMpm3D, "view_mpm.json"));
  sim->advance_to(2.0 / 24);  // dozens of substeps: the storage has been re-sorted by grid block
  ASSERT_GT(sim->steps(), 16);
  const auto view = sim->particles_view<float, 3>();
  bool permuted = false;
  for (std::size_t p = 0; p < view.size() && !permuted; ++p) permuted = view.ids()[p] != p;
  EXPECT_TRUE(permuted) << "the test needs a storage order other than the id order";
  for (std::size_t i = 0; i < view.size(); ++i) ASSERT_EQ(view.id(i), i);
  expect_view_matches_frame<float, 3>(*sim, false);
  // Channels the scene's materials need, and nothing else: F for solids, a plastic state for
  // snow, a material index for two materials; no J (no fluid).
  EXPECT_NE(view.F(), nullptr);
  EXPECT_NE(view.plastic(), nullptr);
  EXPECT_NE(view.materials(), nullptr);
  EXPECT_EQ(view.J(), nullptr);
  std::size_t snow = 0;
  for (std::size_t i = 0; i < view.size(); ++i) snow += view.material(i) == 1;
  EXPECT_GT(snow, 0u);
  EXPECT_LT(snow, view.size());
}

TEST(ParticleView, FlipViewSortsIdsWithGaps) {
  auto sim = slurry::make_simulation(slurry::parse_scene(kFlip2D, "view_flip.json"));
  sim->advance_to(2.0 / 24);
  expect_view_matches_frame<double, 2>(*sim, true);
  const auto view = sim->particles_view<double, 2>();
  EXPECT_GT(view.id(view.size() - 1), view.size() - 1) << "expected emission and reseeding to leave gaps in the ids";
}

TEST(ParticleView, FemViewIsTheVertices) {
  auto sim = slurry::make_simulation(slurry::parse_scene(kFem2D, "view_fem.json"));
  sim->advance_to(1.0 / 24);
  expect_view_matches_frame<double, 2>(*sim, false);
}

TEST(ParticleView, WrongTypeOrDimensionIsRefusedNamingTheScene) {
  auto sim = slurry::make_simulation(slurry::parse_scene(kFem2D, "view_fem.json"));
  try {
    sim->particles_view<float, 2>();
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("the simulation is double in 2D"), std::string::npos) << e.what();
  }
  EXPECT_THROW((sim->particles_view<double, 3>()), std::invalid_argument);
}

TEST(RunScene, WithoutFilesHandsEveryFrameToTheCallbackAndWritesNothing) {
  auto scene = slurry::parse_scene(kMpm3D, "view_mpm.json");
  const fs::path dir = fs::temp_directory_path() / "slurry_view_test_no_files";
  fs::remove_all(dir);
  scene.output.directory = dir.string();
  slurry::RunOptions options;
  options.write_files = false;
  int frames = 0;
  double last_time = -1;
  const auto summary = slurry::run_scene(scene, options, [&](const slurry::FrameReport& r) {
    ASSERT_NE(r.simulation, nullptr);
    EXPECT_TRUE(r.file.empty());
    EXPECT_EQ(r.frame, frames);
    EXPECT_DOUBLE_EQ(r.simulation->time(), r.frame / 24.0);
    EXPECT_EQ((r.simulation->particles_view<float, 3>().size()), r.particles);
    last_time = r.simulation->time();
    ++frames;
  });
  EXPECT_EQ(frames, 3);
  EXPECT_EQ(summary.frames_written, 3);
  EXPECT_DOUBLE_EQ(last_time, 2.0 / 24);
  EXPECT_FALSE(fs::exists(dir)) << "write_files = false created " << dir;
}

}  // namespace
