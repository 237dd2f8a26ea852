// FLIP scene keys: a table of bad FLIP scenes, each with the message it must produce (JSON path,
// value, what was expected), and a good one that keeps its values and runs from make_simulation.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <variant>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"
#include "slurry/engine/run/run.h"

namespace {

using nlohmann::json;

json good_flip_scene() {
  return json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"type": "flip", "dimension": 2, "transfer": "apic", "kernel": "linear", "cfl": 4,
               "advection": "rk3", "free_surface": "subcell", "pressure": {"preconditioner": "jacobi", "tolerance": 1e-5, "max_iterations": 300},
               "reseed": {"min_per_cell": 2, "max_per_cell": 9}},
    "materials": [{"name": "water", "model": "fluid", "density": 998}],
    "bodies": [{"shape": "box", "min": [0, 0], "max": [1, 0.4], "material": "water", "particles_per_cell": 4}],
    "emitters": [{"shape": "sphere", "center": [0.5, 0.8], "radius": 0.1, "rate": 0.02, "velocity": [0, -1],
                  "start": 0.1, "end": 0.5, "material": "water", "particles_per_cell": 4, "seed": 3}],
    "output": {"directory": "unused", "fps": 24, "frames": 2, "attributes": ["position", "velocity"]}
  })");
}

struct BadCase {
  const char* name;
  const char* patch;
  const char* expected;
};

const BadCase kBad[] = {
    {"mls", R"({"solver": {"transfer": "mls", "kernel": "quadratic"}})", "solver.transfer: solver.type \"flip\" takes \"pic\", \"flip\" or \"apic\", got \"mls\""},
    {"cubic", R"({"solver": {"kernel": "cubic"}})", "solver.kernel: solver.type \"flip\" takes \"linear\" or \"quadratic\", got \"cubic\""},
    {"cfl", R"({"solver": {"cfl": 6}})", "solver.cfl: expected a number in (0, 5], got 6"},
    {"advection", R"({"solver": {"advection": "rk4"}})",
     "solver.advection: expected one of \"euler\", \"midpoint\", \"heun\", \"rk3\", got \"rk4\""},
    {"free_surface", R"({"solver": {"free_surface": "exact"}})",
     "solver.free_surface: expected one of \"auto\", \"cell\", \"subcell\", got \"exact\""},
    {"free_surface_cell_with_surface_tension",
     R"({"solver": {"free_surface": "cell"}, "materials": [{"name": "water", "model": "fluid", "surface_tension": 0.07}]})",
     "solver.free_surface: surface tension's pressure jump is imposed at the subcell surface: expected \"auto\" or "
     "\"subcell\" with materials[].surface_tension 0.07, got \"cell\""},
    {"tolerance", R"({"solver": {"pressure": {"tolerance": 0}}})", "solver.pressure.tolerance: expected a number in (0, 1), got 0"},
    {"iterations", R"({"solver": {"pressure": {"max_iterations": 0}}})",
     "solver.pressure.max_iterations: expected an integer in [1, 1000000], got 0"},
    {"preconditioner", R"({"solver": {"pressure": {"preconditioner": "ilu"}}})",
     "solver.pressure.preconditioner: expected one of \"multigrid\", \"mic0\", \"jacobi\", \"none\", got \"ilu\""},
    {"reseed_bounds", R"({"solver": {"reseed": {"min_per_cell": 5, "max_per_cell": 5}}})",
     "solver.reseed.max_per_cell: expected 0 (off) or an integer in (min_per_cell = 5, 512], got 5"},
    {"solid", R"({"materials": [{"name": "water", "model": "neo_hookean"}]})",
     "materials[0].model: solver.type \"flip\" simulates liquids: expected \"fluid\", got \"neo_hookean\""},
    {"bulk_modulus", R"({"materials": [{"name": "water", "model": "fluid", "bulk_modulus": 1e6}]})",
     "materials[0].bulk_modulus: unknown key"},
    {"sticky_walls", R"({"boundaries": {"walls": "sticky"}})", "boundaries.walls: solver.type \"flip\" walls are free-slip"},
    {"J_attribute", R"({"output": {"attributes": ["position", "J"]}})",
     "output.attributes[1]: solver.type \"flip\" writes \"position\", \"velocity\", \"material\" and \"id\""},
    {"emitter_rate", R"({"emitters": [{"shape": "box", "min": [0.1, 0.8], "max": [0.2, 0.9], "rate": 0, "material": "water"}]})",
     "emitters[0].rate: expected a number > 0, got 0"},
    {"emitter_end", R"({"emitters": [{"shape": "box", "min": [0.1, 0.8], "max": [0.2, 0.9], "rate": 1, "start": 2, "end": 1, "material": "water"}]})",
     "emitters[0].end: expected a time greater than start (2), got 1"},
    {"emitter_outside", R"({"emitters": [{"shape": "sphere", "center": [0.95, 0.5], "radius": 0.1, "rate": 1, "material": "water"}]})",
     "emitters[0]: the emitter spans [0.85, 0.4] to [1.05, 0.6], expected it inside the domain"},
    {"emitter_material", R"({"emitters": [{"shape": "box", "min": [0.1, 0.8], "max": [0.2, 0.9], "rate": 1, "material": "oil"}]})",
     "emitters[0].material: expected the name of a material (\"water\"), got \"oil\""},
    {"emitter_cylinder", R"({"emitters": [{"shape": "cylinder", "center": [0.5, 0.5], "radius": 0.1, "rate": 1, "material": "water"}]})",
     "emitters[0].shape: expected \"box\" or \"sphere\", got \"cylinder\""},
};

class BadFlipScenes : public testing::TestWithParam<BadCase> {};

TEST_P(BadFlipScenes, MessageNamesPathAndExpectation) {
  json j = good_flip_scene();
  j.merge_patch(json::parse(GetParam().patch));
  try {
    slurry::parse_scene(j.dump(), "bad.json");
    FAIL() << "accepted a bad scene: " << j.dump();
  } catch (const slurry::SceneError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(GetParam().expected), std::string::npos) << "message: " << msg << "\nexpected: " << GetParam().expected;
  }
}

INSTANTIATE_TEST_SUITE_P(Table, BadFlipScenes, testing::ValuesIn(kBad),
                         [](const testing::TestParamInfo<BadCase>& i) { return std::string(i.param.name); });

TEST(FlipScene, KeysOfTheMpmSolverAreRejected) {
  json j = good_flip_scene();
  j["solver"]["type"] = "mpm";
  j["materials"][0]["model"] = "fluid";
  EXPECT_THROW(slurry::parse_scene(j.dump(), "mpm.json"), slurry::SceneError) << "advection is a FLIP key";
}

TEST(FlipScene, IdAttributeIsFlipAndMpm) {
  json j = good_flip_scene();
  j["output"]["attributes"] = {"position", "id"};
  EXPECT_NO_THROW(slurry::parse_scene(j.dump(), "flip.json"));
  // MPM writes the seeding index (tests/io/vdb/pipeline_test.cpp checks the column).
  json m = json::parse(R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"type": "mpm", "dimension": 2},
    "materials": [{"name": "jelly", "model": "neo_hookean"}],
    "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"}],
    "output": {"attributes": ["position", "id"]}})");
  EXPECT_NO_THROW(slurry::parse_scene(m.dump(), "mpm.json"));
}

TEST(FlipScene, GoodSceneKeepsItsValuesAndRuns) {
  const auto s = slurry::parse_scene(good_flip_scene().dump(), "good.json");
  EXPECT_EQ(s.solver.type, slurry::SolverType::FLIP);
  EXPECT_EQ(s.solver.advection, slurry::AdvectionScheme::RK3);
  EXPECT_EQ(s.solver.free_surface, slurry::FreeSurface::Subcell);
  EXPECT_EQ(s.solver.pressure.preconditioner, slurry::PressurePreconditioner::Jacobi);
  EXPECT_DOUBLE_EQ(s.solver.pressure.tolerance, 1e-5);
  EXPECT_EQ(s.solver.pressure.max_iterations, 300);
  EXPECT_EQ(s.solver.reseed.min_per_cell, 2);
  EXPECT_EQ(s.solver.reseed.max_per_cell, 9);
  ASSERT_EQ(s.emitters.size(), 1u);
  EXPECT_DOUBLE_EQ(s.emitters[0].rate, 0.02);
  EXPECT_DOUBLE_EQ(s.emitters[0].end, 0.5);
  auto sim = slurry::make_simulation(s);
  const bool is_flip = dynamic_cast<slurry::flip::FlipSolver<float, 2>*>(sim.get()) != nullptr;
  ASSERT_TRUE(is_flip);
  const auto n0 = sim->particle_count();
  sim->advance_to(0.5);
  EXPECT_GT(sim->particle_count(), n0) << "the emitter added liquid";
  const auto frame = sim->frame({"position", "velocity", "id"});
  ASSERT_EQ(frame.tables[0].columns.size(), 5u);
  // Emitted particles take new ids: all distinct.
  const auto* ids = std::get_if<std::vector<std::uint32_t>>(&frame.tables[0].columns[4].data);
  ASSERT_NE(ids, nullptr) << "id is a uint32 property";
  EXPECT_EQ(frame.tables[0].columns[4].name, "id");
  std::vector<std::uint32_t> sorted = *ids;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(std::adjacent_find(sorted.begin(), sorted.end()), sorted.end()) << "duplicate ids";
  std::printf("[ figure ] emitter scene: %zu particles (%zu at start), ids %u..%u, all distinct\n", ids->size(), n0,
              sorted.front(), sorted.back());
}

}  // namespace

// The per-frame log line names the last pressure solve: its iteration count and a relative
// residual that met solver.pressure.tolerance (parsed back from the text the CLI prints).
TEST(FlipScene, SolverStatusReportsThePressureSolve) {
  auto j = good_flip_scene();
  j["bodies"][0]["max"] = {0.4, 0.8};  // a collapsing column: every substep has work to do
  const auto s = slurry::parse_scene(j.dump(), "column.json");
  auto sim = slurry::make_simulation(s);
  EXPECT_EQ(sim->solver_status(), "") << "no solve before the first substep";
  sim->advance_to(0.1);
  const std::string status = sim->solver_status();
  int iterations = -1;
  double residual = -1, divergence = -1;
  ASSERT_EQ(std::sscanf(status.c_str(), "pressure PCG %d iterations, residual %lf, max |div u| %lf", &iterations,
                        &residual, &divergence),
            3)
      << status;
  EXPECT_GT(iterations, 0);
  EXPECT_LE(residual, s.solver.pressure.tolerance);
  EXPECT_GE(divergence, 0.0);
  std::printf("[ figure ] %s\n", status.c_str());
}
