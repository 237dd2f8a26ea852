// The effects-pipeline outputs of a run: scene keys, what a scene asks for, MPM ids, and the
// CLI's per-frame outputs and `slurry surface`.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <variant>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"
#include "slurry/io/pipeline.h"

namespace fs = std::filesystem;

namespace {

/// A small 3D MPM scene: a water cube (fluid) and a jelly cube (solid), dx 0.05.
std::string scene_text(const std::string& output, const std::string& dir = "frames") {
  return R"({"domain": {"min": [0, 0, 0], "max": [1, 1, 1], "dx": 0.05},
    "solver": {"dimension": 3, "max_dt": 0.002},
    "materials": [{"name": "water", "model": "fluid", "bulk_modulus": 20000},
                  {"name": "jelly", "E": 20000, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.1, 0.1, 0.1], "max": [0.4, 0.4, 0.4], "material": "water"},
               {"shape": "box", "min": [0.6, 0.1, 0.6], "max": [0.8, 0.3, 0.8], "material": "jelly", "particles_per_cell": 27}],
    "output": {"directory": ")" +
         dir + R"(", "fps": 50, "frames": 1, )" + output + "}}";
}

std::string error_of(const std::string& output) {
  try {
    (void)slurry::parse_scene(scene_text(output), "s.json");
  } catch (const slurry::SceneError& e) {
    return e.what();
  }
  return "";
}

int run(const std::string& cmd) {
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

TEST(Pipeline, SceneKeysAreValidated) {
  EXPECT_NE(error_of(R"("attributes": ["position", "material"], "surface": ["vdb", "stl"])")
                .find("output.surface[1]: expected one of \"vdb\", \"ply\", \"obj\", got \"stl\""),
            std::string::npos);
  EXPECT_NE(error_of(R"("attributes": ["position", "material"], "surface": ["ply", "ply"])")
                .find("duplicate format"),
            std::string::npos);
  EXPECT_NE(error_of(R"("vdb_points": true)")
                .find("output.vdb_points: the points carry velocity and a persistent id"),
            std::string::npos);
  EXPECT_NE(error_of(R"("vdb_points": 1)").find("output.vdb_points: expected true or false"),
            std::string::npos);
  // Per-rank frames hold part of the particles: no surface or points can be made from one.
  EXPECT_NE(error_of(R"("attributes": ["position", "material"], "surface": ["vdb"], "per_rank": true)")
                .find("output.per_rank: per-rank frames hold part of the particles"),
            std::string::npos);
  EXPECT_EQ(error_of(R"("attributes": ["position", "material"], "per_rank": true)"), "");
  EXPECT_NE(
      error_of(
          R"("attributes": ["position", "material"], "surface": ["vdb"], "surface_smoothing": 101)")
          .find("output.surface_smoothing"),
      std::string::npos);
  EXPECT_NE(
      error_of(
          R"("attributes": ["position", "material"], "surface": ["vdb"], "surface_voxel_size": 10)")
          .find("output.surface_voxel_size"),
      std::string::npos);
  // OpenVDB cannot represent a voxel below kMinVoxelSize: refused by validation, not an uncaught
  // openvdb::ArithmeticError in the middle of the run.
  const auto tiny = [](double dx) {
    const std::string d = std::to_string(dx);
    try {
      (void)slurry::parse_scene(R"({"domain": {"min": [0, 0, 0], "max": [)" + std::to_string(40 * dx) + ", " +
                                    std::to_string(40 * dx) + ", " + std::to_string(40 * dx) + R"(], "dx": )" + d + R"(},
        "solver": {"type": "flip", "dimension": 3, "transfer": "apic", "kernel": "linear"},
        "materials": [{"name": "water", "model": "fluid"}],
        "bodies": [{"shape": "box", "min": [0, 0, 0], "max": [)" + std::to_string(10 * dx) + ", " +
                                    std::to_string(10 * dx) + ", " + std::to_string(10 * dx) + R"(], "material": "water"}],
        "output": {"frames": 1, "surface": ["ply"]}})",
                                "tiny.json");
    } catch (const slurry::SceneError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(tiny(1e-5).find("domain.dx: the voxel of the OpenVDB outputs is 1e-05 m, below the 1.45e-05 m OpenVDB "
                            "can represent"),
            std::string::npos)
      << tiny(1e-5);
  EXPECT_EQ(tiny(2e-5), "");
  // A fluid and a solid: the liquid is some of the materials, chosen by the material column.
  EXPECT_NE(error_of(R"("surface": ["vdb"])").find("expected \"material\" in output.attributes"),
            std::string::npos);
  // MPM writes ids now.
  EXPECT_EQ(
      error_of(
          R"("attributes": ["position", "velocity", "id", "material"], "surface": ["vdb"], "vdb_points": true)"),
      "");
}

TEST(Pipeline, FrameOutputsOfAScene) {
  const auto s = slurry::parse_scene(
      scene_text(R"("attributes": ["position", "material"], "surface": ["ply", "vdb"])"), "s.json");
  const auto o = slurry::io::frame_outputs(s);
  EXPECT_TRUE(o.ply && o.vdb && !o.obj && !o.vdb_points);
  EXPECT_DOUBLE_EQ(o.params.voxel_size, 0.05);
  // The largest particles_per_cell (27, the jelly) sets the spacing dx / 3.
  EXPECT_NEAR(o.params.spacing, 0.05 / 3, 1e-12);
  ASSERT_EQ(o.groups.size(), 1u);
  EXPECT_EQ(o.groups[0].materials, std::vector<int>{0});  // the water only
}

#ifdef SLURRY_CLI
TEST(Pipeline, CliWritesSurfacesPointsAndIdsAndResurfaces) {
  const fs::path dir =
      fs::temp_directory_path() / ("slurry_pipeline_cli_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "s.json") << scene_text(
      R"("attributes": ["position", "velocity", "id", "material"], "surface": ["vdb", "ply", "obj"], "vdb_points": true)",
      (dir / "frames").string());
  ASSERT_EQ(run(std::string(SLURRY_CLI) + " run -q " + (dir / "s.json").string()), 0);
  const fs::path f = dir / "frames";
  for (const char* name : {"surface_0001.vdb", "surface_0001.ply", "surface_0001.obj",
                           "points_0001.vdb", "surface_0000.vdb"})
    EXPECT_TRUE(fs::exists(f / name)) << name;
  // MPM frames list particles by id: the id column is the row.
  const auto frame = slurry::io::read_ply(f / "frame_0001.ply");
  const auto& id = frame.table("vertex").values<std::uint32_t>("id");
  for (std::size_t i = 0; i < id.size(); ++i) ASSERT_EQ(id[i], i);
  // The VDB points: every particle, its id and velocity.
  const auto cloud = slurry::io::point_cloud(frame);
  std::vector<float> pscale;
  const auto points = slurry::io::read_vdb_points(f / "points_0001.vdb", &pscale);
  ASSERT_EQ(points.size(), cloud.size());
  EXPECT_EQ(points.id, cloud.id);
  EXPECT_EQ(points.velocity, cloud.velocity);
  EXPECT_FLOAT_EQ(pscale[0], float(0.5 * 0.05 / 3));
  // The surface of the water alone: its mesh lies within the water cube grown by a voxel or so
  // (the jelly at x >= 0.6 is not surfaced).
  const auto mesh =
      slurry::io::read_ply(f / "surface_0001.ply").table("vertex").column_as_double("x");
  ASSERT_FALSE(mesh.empty());
  for (double x : mesh) ASSERT_LT(x, 0.5);
  const std::size_t vertices = mesh.size();

  // Re-meshing the frames already written: the scene named in them gives the same parameters.
  fs::remove(f / "surface_0001.ply");
  ASSERT_EQ(run(std::string(SLURRY_CLI) + " surface -q " + f.string() + " --formats ply"), 0);
  EXPECT_EQ(slurry::io::read_ply(f / "surface_0001.ply").table("vertex").count, vertices);
  // Usage and file errors.
  EXPECT_EQ(
      run(std::string(SLURRY_CLI) + " surface -q " + f.string() + " --formats stl 2>/dev/null"), 2);
  EXPECT_EQ(
      run(std::string(SLURRY_CLI) + " surface -q " + f.string() + " --voxel-size -1 2>/dev/null"),
      2);
  EXPECT_EQ(
      run(std::string(SLURRY_CLI) + " surface -q " + (dir / "missing").string() + " 2>/dev/null"),
      3);
  // A voxel OpenVDB cannot represent: a usage error, not an abort.
  EXPECT_EQ(run(std::string(SLURRY_CLI) + " surface -q " + f.string() + " --voxel-size 1e-5 --spacing 1e-5 2>/dev/null"), 2);
  // A frame with a non-finite position (one particle at NaN, one at infinity, or all at NaN):
  // an error naming the file and the vertex (it crashed with SIGSEGV, dropped the particle at
  // infinity, or wrote an empty surface).
  auto data = slurry::io::read_ply(f / "frame_0001.ply");
  std::vector<float>* column = nullptr;
  for (auto& p : data.find("vertex")->columns)
    if (p.name == "x") column = &std::get<std::vector<float>>(p.data);
  ASSERT_NE(column, nullptr);
  auto& x = *column;
  for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    const float kept = x[3];
    x[3] = bad;
    slurry::io::write_ply(f / "frame_0001.ply", data);
    x[3] = kept;
    const std::string cmd = std::string(SLURRY_CLI) + " surface -q " + f.string() + " 2> " + (dir / "err.txt").string();
    EXPECT_EQ(run(cmd), 3) << bad;
    std::ifstream in(dir / "err.txt");
    const std::string err((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NE(err.find("frame_0001.ply: vertex 3 has a non-finite position"), std::string::npos) << err;
  }
  // The library's entry point refuses them too (std::invalid_argument, not a crash).
  auto nan_cloud = slurry::io::point_cloud(slurry::io::read_ply(f / "frame_0000.ply"));
  nan_cloud.position[0][1] = std::numeric_limits<float>::quiet_NaN();
  slurry::io::SurfaceParams params;
  params.voxel_size = 0.05;
  params.spacing = 0.05 / 2;
  EXPECT_THROW(slurry::io::particles_to_level_set(nan_cloud, params), std::invalid_argument);
  fs::remove_all(dir);
}

// FLIP whitewater with vdb_points: whitewater_NNNN.vdb holds the same particles as
// whitewater_NNNN.ply, with their ids, velocities and types.
TEST(Pipeline, CliWritesWhitewaterPoints) {
  const fs::path dir = fs::temp_directory_path() / ("slurry_pipeline_ww_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream(dir / "s.json") << R"({"domain": {"min": [0, 0, 0], "max": [1, 0.6, 0.25], "dx": 0.04},
    "solver": {"type": "flip", "dimension": 3, "max_dt": 0.005, "whitewater": {"enabled": true}},
    "materials": [{"name": "water", "model": "fluid"}],
    "bodies": [{"shape": "box", "min": [0, 0, 0], "max": [0.3, 0.5, 0.25], "material": "water"}],
    "output": {"directory": ")" + (dir / "frames").string() + R"(", "fps": 24, "frames": 12,
               "attributes": ["position", "velocity", "id"], "vdb_points": true}})";
  ASSERT_EQ(run(std::string(SLURRY_CLI) + " run -q " + (dir / "s.json").string()), 0);
  const auto ply = slurry::io::read_ply(dir / "frames" / "whitewater_0012.ply");
  const auto cloud = slurry::io::point_cloud(ply);
  ASSERT_GT(cloud.size(), 0u);
  std::vector<float> pscale;
  const auto points = slurry::io::read_vdb_points(dir / "frames" / "whitewater_0012.vdb", &pscale);
  ASSERT_EQ(points.size(), cloud.size());
  EXPECT_EQ(points.id, cloud.id);
  EXPECT_EQ(points.velocity, cloud.velocity);
  EXPECT_EQ(points.type, cloud.type);
  EXPECT_FLOAT_EQ(pscale[0], float(0.25 * 0.04 / 2));
  fs::remove_all(dir);
}
#endif

TEST(PipelineOutputs, DocumentedDefaultsAreTheCode) {
  // docs/pipeline-outputs.md's table of output keys, the scene's defaults and SurfaceParams agree.
  std::ifstream in(std::string(SLURRY_SOURCE_DIR) + "/docs/pipeline-outputs.md");
  ASSERT_TRUE(in) << "docs/pipeline-outputs.md";
  const std::string doc((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const slurry::OutputParams defaults;
  EXPECT_NE(doc.find("| `surface_smoothing` | " + std::to_string(defaults.surface_smoothing) + " |"),
            std::string::npos);
  EXPECT_NE(doc.find("| `surface_method` | `\"" + defaults.surface_method + "\"` |"), std::string::npos);
  EXPECT_NE(doc.find("| `surface_voxel_size` | 0 |"), std::string::npos);
  EXPECT_EQ(defaults.surface_voxel_size, 0.0);
  const slurry::io::SurfaceParams params;
  EXPECT_EQ(params.smoothing, defaults.surface_smoothing);
  EXPECT_EQ(params.method == slurry::io::SurfaceMethod::Anisotropic, defaults.surface_method == "anisotropic");
}
