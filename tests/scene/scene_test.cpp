// Scene files: a table of bad scenes, each with the message it must produce (file, JSON path,
// what was expected); a good scene round-trips its values; the CLI exits non-zero on a bad scene
// and writes nothing.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace {

using nlohmann::json;

json good_scene() {
  return json::parse(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05},
    "solver": {"dimension": 2, "transfer": "apic", "kernel": "quadratic"},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e5, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"}],
    "output": {"directory": "unused", "fps": 24, "frames": 2}
  })");
}

struct BadCase {
  const char* name;
  const char* patch;     // JSON merge patch applied to the good scene
  const char* expected;  // substring of the message after "bad.json: "
};

const BadCase kBad[] = {
    {"nu_at_half", R"({"materials": [{"name": "jelly", "model": "fixed_corotated", "nu": 0.5}]})",
     "materials[0].nu: expected a number in (-1, 0.5), got 0.5"},
    {"E_zero", R"({"materials": [{"name": "jelly", "E": 0}]})", "materials[0].E: expected a number > 0, got 0"},
    {"E_negative", R"({"materials": [{"name": "jelly", "E": -3}]})", "materials[0].E: expected a number > 0, got -3"},
    {"dx_zero", R"({"domain": {"dx": 0}})", "domain.dx: expected a number > 0, got 0"},
    {"dx_negative", R"({"domain": {"dx": -0.1}})", "domain.dx: expected a number > 0, got -0.1"},
    {"empty_box", R"({"bodies": [{"shape": "box", "min": [0.3, 0.2], "max": [0.3, 0.4], "material": "jelly"}]})",
     "bodies[0].max: expected every component greater than min [0.3, 0.2] (an empty box), got [0.3, 0.4]"},
    {"body_outside", R"({"bodies": [{"shape": "sphere", "center": [0.95, 0.5], "radius": 0.1, "material": "jelly"}]})",
     "bodies[0]: the body spans [0.85, 0.4] to [1.05, 0.6], expected it inside the domain [0, 0] to [1, 1]"},
    {"unknown_key", R"({"solver": {"trnasfer": "apic"}})", "solver.trnasfer: unknown key (expected one of:"},
    {"unknown_top_key", R"({"outptu": {}})", "outptu: unknown key"},
    {"wrong_type", R"({"materials": [{"name": "jelly", "density": "heavy"}]})",
     "materials[0].density: expected a number, got \"heavy\""},
    {"vector_length", R"({"bodies": [{"shape": "box", "min": [0.2, 0.2, 0.2], "max": [0.4, 0.4], "material": "jelly"}]})",
     "bodies[0].min: expected an array of 2 numbers (the scene's dimension), got [0.2,0.2,0.2]"},
    {"unknown_material", R"({"bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "jello"}]})",
     "bodies[0].material: expected the name of a material (\"jelly\"), got \"jello\""},
    {"bad_enum", R"({"solver": {"kernel": "quintic"}})",
     "solver.kernel: expected one of \"linear\", \"quadratic\", \"cubic\", got \"quintic\""},
    {"mls_linear", R"({"solver": {"transfer": "mls", "kernel": "linear"}})",
     "solver.kernel: transfer \"mls\" needs kernel \"quadratic\" or \"cubic\""},
    {"key_of_other_model", R"({"materials": [{"name": "jelly", "friction_angle": 35}]})",
     "materials[0].friction_angle: unknown key"},
    {"fluid_with_E", R"({"materials": [{"name": "jelly", "model": "fluid", "E": 1e5}]})",
     "materials[0].E: unknown key"},
    {"plastic_attribute_without_plasticity", R"({"output": {"attributes": ["position", "plastic"]}})",
     "output.attributes[1]: \"plastic\" needs a material with plasticity"},
    {"unknown_attribute", R"({"output": {"attributes": ["position", "colour"]}})",
     "output.attributes[1]: expected one of \"position\", \"velocity\", \"material\", \"J\", \"plastic\", \"id\", got \"colour\""},
    {"cfl_too_large", R"({"solver": {"cfl": 2}})", "solver.cfl: expected a number in (0, 1], got 2"},
    {"flip_ratio", R"({"solver": {"transfer": "flip", "flip_ratio": 1.5}})",
     "solver.flip_ratio: expected a number in [0, 1], got 1.5"},
    {"dimension", R"({"solver": {"dimension": 4}})", "solver.dimension: expected 2 or 3, got 4"},
    {"no_materials", R"({"materials": []})", "materials: expected at least one material"},
    {"no_bodies", R"({"bodies": []})", "bodies: expected at least one body"},
    {"snow_theta", R"({"materials": [{"name": "jelly", "plasticity": "snow", "critical_compression": 1.5}]})",
     "materials[0].critical_compression: expected a number in (0, 1), got 1.5"},
    {"friction_on_slip", R"({"boundaries": {"walls": "slip", "friction": 0.3}})",
     "boundaries.friction: friction applies to walls \"separate\" only"},
    {"zero_normal", R"({"colliders": [{"shape": "half_space", "point": [0, 0.1], "normal": [0, 0]}]})",
     "colliders[0].normal: expected a non-zero vector"},
    {"negative_fps", R"({"output": {"fps": -24}})", "output.fps: expected a number > 0, got -24"},
    // Integers range-checked instead of wrapped, the limits block, what a frame must hold.
    {"dimension_wraps", R"({"solver": {"dimension": 4294967298}})", "solver.dimension: expected 2 or 3, got 4294967298"},
    {"frames_wrap", R"({"output": {"frames": 4294967297}})", "output.frames: expected an integer in [0, 2147483647], got 4294967297"},
    {"thickness_wraps", R"({"boundaries": {"thickness": 4294967298}})",
     "boundaries.thickness: expected an integer in [-2147483648, 2147483647], got 4294967298"},
    {"no_position", R"({"output": {"attributes": ["velocity"]}})", "output.attributes: expected a list that includes \"position\""},
    {"description_not_a_string", R"({"description": 42})", "description: expected a string, got 42"},
    {"tiny_fps", R"({"output": {"fps": 1e-300}})", "output.fps: expected a number in [1e-06, 1000000], got 1e-300"},
    {"substeps_limit", R"({"limits": {"substeps_per_frame": 0}})", "limits.substeps_per_frame: expected an integer >= 1, got 0"},
    {"negative_memory", R"({"limits": {"memory_gb": -1}})", "limits.memory_gb: expected a number >= 0, got -1"},
};

class BadScenes : public testing::TestWithParam<BadCase> {};

TEST_P(BadScenes, MessageNamesFilePathAndExpectation) {
  json j = good_scene();
  j.merge_patch(json::parse(GetParam().patch));
  try {
    slurry::parse_scene(j.dump(), "bad.json");
    FAIL() << "accepted a bad scene: " << j.dump();
  } catch (const slurry::SceneError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.rfind("bad.json: ", 0), 0u) << msg;
    EXPECT_NE(msg.find(GetParam().expected), std::string::npos) << "message: " << msg << "\nexpected: "
                                                                  << GetParam().expected;
  }
}

INSTANTIATE_TEST_SUITE_P(Table, BadScenes, testing::ValuesIn(kBad),
                         [](const testing::TestParamInfo<BadCase>& i) { return std::string(i.param.name); });

TEST(Scene, InvalidJsonNamesTheFile) {
  try {
    slurry::parse_scene("{\"domain\": ", "broken.json");
    FAIL();
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("broken.json: not valid JSON"), std::string::npos) << e.what();
  }
}

// Inputs nlohmann::json cannot build as a value: each error names the JSON path.
TEST(Scene, JsonLimitsNameThePath) {
  const std::pair<std::string, std::string> cases[] = {
      {std::string(100000, '[') + std::string(100000, ']'), "deep.json: [0][0][0]"},
      {R"({"domain": {"dx": 0.05, "dx": 0.1}})", "deep.json: domain.dx: duplicate key"},
      {R"({"bodies": [{}, {"velocity": [0, 1e400]}]})", "deep.json: bodies[1].velocity[1]: number '1e400' is out of the range of double"},
  };
  for (const auto& [text, expected] : cases) {
    try {
      slurry::parse_scene(text, "deep.json");
      FAIL() << "accepted " << text.substr(0, 80);
    } catch (const slurry::SceneError& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  }
}

TEST(Scene, MissingFileIsAnIoError) {
  EXPECT_THROW(slurry::load_scene("/nonexistent/scene.json"), slurry::IoError);
}

TEST(Scene, GoodSceneKeepsItsValues) {
  json j = good_scene();
  j["solver"]["gravity"] = {0.5, -3};
  j["bodies"][0]["velocity"] = {1, 2};
  const auto s = slurry::parse_scene(j.dump(), "good.json");
  EXPECT_EQ(s.solver.dimension, 2);
  EXPECT_EQ(s.solver.transfer, slurry::TransferKind::APIC);
  EXPECT_DOUBLE_EQ(s.solver.gravity[0], 0.5);
  EXPECT_DOUBLE_EQ(s.solver.gravity[1], -3);
  EXPECT_DOUBLE_EQ(s.materials[0].E, 1e5);
  EXPECT_DOUBLE_EQ(s.bodies[0].velocity[1], 2);
  EXPECT_EQ(s.output.frames, 2);
}

TEST(Scene, ExampleScenesAreValid) {
  const std::filesystem::path dir = SLURRY_EXAMPLES_DIR;
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().extension() != ".json") continue;
    EXPECT_NO_THROW(slurry::load_scene(e.path())) << e.path();
    ++n;
  }
  EXPECT_GE(n, 8);
}

#ifdef SLURRY_CLI
// The CLI on a bad scene: exit code 2, the message on stderr, and no output directory created.
TEST(Cli, BadSceneExitsNonZeroAndWritesNothing) {
  const auto dir = std::filesystem::temp_directory_path() / "slurry_cli_bad_scene";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  json j = good_scene();
  j["materials"][0]["nu"] = 0.5;
  j["output"]["directory"] = (dir / "frames").string();
  std::ofstream(dir / "bad.json") << j.dump();
  const std::string cmd = std::string(SLURRY_CLI) + " run " + (dir / "bad.json").string() + " 2> " +
                          (dir / "err.txt").string();
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 2);
  EXPECT_FALSE(std::filesystem::exists(dir / "frames"));
  std::ifstream err(dir / "err.txt");
  const std::string text((std::istreambuf_iterator<char>(err)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("bad.json: materials[0].nu: expected a number in (-1, 0.5), got 0.5"), std::string::npos) << text;
}

// The CLI on a good 2D scene writes frames 0..N that read back with the right particle count.
TEST(Cli, RunsASceneAndWritesFrames) {
  const auto dir = std::filesystem::temp_directory_path() / "slurry_cli_good_scene";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  json j = good_scene();
  j["output"]["directory"] = (dir / "frames").string();
  std::ofstream(dir / "good.json") << j.dump();
  const std::string cmd = std::string(SLURRY_CLI) + " run -q " + (dir / "good.json").string() + " --frames 3";
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
  for (int f = 0; f <= 3; ++f) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04d.ply", f);
    EXPECT_TRUE(std::filesystem::exists(dir / "frames" / name)) << name;
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "frames" / "frame_0004.ply"));
}
#endif

}  // namespace
