// output.up_axis: frames written in Z-up axes are the simulation's frames rotated by +90 degrees
// about x, (x, y, z) -> (x, -z, y), velocities alike; "z" is refused for 2D scenes.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <unistd.h>

#include "slurry/engine/errors.h"
#include "slurry/engine/run/run.h"
#include "slurry/io/ply.h"
#include "slurry/io/scene_file.h"

namespace fs = std::filesystem;

namespace {

slurry::Scene falling_block(const std::string& up) {
  return slurry::parse_scene(R"({
    "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
    "solver": {"dimension": 3},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.3, 0.5, 0.4], "max": [0.5, 0.7, 0.7], "material": "jelly",
                "velocity": [0.1, 0.2, -0.3]}],
    "output": {"fps": 24, "frames": 2, "attributes": ["position", "velocity"], "up_axis": ")" + up + R"("}
  })", "up_" + up + ".json");
}

}  // namespace

TEST(UpAxis, ZUpFramesAreTheSimulationsRotatedAboutX) {
  const fs::path root = fs::temp_directory_path() / ("slurry_up_axis_" + std::to_string(::getpid()));
  fs::remove_all(root);
  for (const char* up : {"y", "z"}) {
    slurry::RunOptions opt;
    opt.directory = root / up;
    slurry::run_scene(falling_block(up), opt);
  }
  for (const char* f : {"frame_0000.ply", "frame_0002.ply"}) {
    const slurry::io::PlyData y = slurry::io::read_ply(root / "y" / f), z = slurry::io::read_ply(root / "z" / f);
    const slurry::Table& a = y.table("vertex");
    const slurry::Table& b = z.table("vertex");
    ASSERT_EQ(a.count, b.count);
    ASSERT_GT(a.count, 100u);
    const auto ax = a.column_as_double("x"), ay = a.column_as_double("y"), az = a.column_as_double("z");
    const auto bx = b.column_as_double("x"), by = b.column_as_double("y"), bz = b.column_as_double("z");
    const auto avy = a.column_as_double("vy"), avz = a.column_as_double("vz");
    const auto bvy = b.column_as_double("vy"), bvz = b.column_as_double("vz");
    for (std::size_t i = 0; i < a.count; ++i) {
      ASSERT_EQ(bx[i], ax[i]) << f << " particle " << i;
      ASSERT_EQ(by[i], -az[i]) << f << " particle " << i;
      ASSERT_EQ(bz[i], ay[i]) << f << " particle " << i;
      ASSERT_EQ(bvy[i], -avz[i]) << f << " particle " << i;
      ASSERT_EQ(bvz[i], avy[i]) << f << " particle " << i;
    }
    // Up is +z: the block falls along -z in the Z-up frames.
    if (std::string(f) == "frame_0002.ply") {
      EXPECT_LT(bvz[0], 0.2);
    }
  }
  fs::remove_all(root);
}

TEST(UpAxis, ZIsRefusedForA2dSceneAndOtherValuesNamed) {
  const auto message = [](const std::string& text) {
    try {
      (void)slurry::parse_scene(text, "s.json");
    } catch (const slurry::SceneError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string two_d = R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.05}, "solver": {"dimension": 2},
    "materials": [{"name": "m", "model": "fluid", "density": 1000}],
    "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "m"}],
    "output": {"up_axis": "z"}})";
  EXPECT_NE(message(two_d).find("output.up_axis"), std::string::npos) << message(two_d);
  std::string x_up = two_d;
  x_up.replace(x_up.find("\"z\""), 3, "\"x\"");
  EXPECT_NE(message(x_up).find("output.up_axis"), std::string::npos) << message(x_up);
}

TEST(OutputDirectory, TooLongIsRefusedBeforeAnyFolderIsCreated) {
  // A path of about 4080 bytes (folders of 200 bytes) leaves no room for the files' names
  // within PATH_MAX; a folder name of 300 bytes exceeds NAME_MAX. Both are refused with an
  // IoError naming output.directory's limit, and no folder of the path is left behind.
  const fs::path root = fs::temp_directory_path() / ("slurry_long_out_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::path deep = root;
  while (deep.native().size() < 4080) deep /= std::string(200, 'd');
  for (const fs::path& dir : {deep, root / std::string(300, 'n') / "frames"}) {
    slurry::RunOptions opt;
    opt.directory = dir;
    try {
      slurry::run_scene(falling_block("y"), opt);
      FAIL() << "expected IoError for a path of " << dir.native().size() << " bytes";
    } catch (const slurry::IoError& e) {
      const std::string m = e.what();
      EXPECT_TRUE(m.find("PATH_MAX") != std::string::npos || m.find("NAME_MAX") != std::string::npos) << m;
      EXPECT_NE(m.find("output directory"), std::string::npos) << m;
    }
    EXPECT_FALSE(fs::exists(root)) << "a folder was left behind";
  }
}
