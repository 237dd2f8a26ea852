// The liquid's surface keeps the liquid: on every frame of the shipped liquid scenes with
// surfaces, at their default surface settings, the mesh encloses 92 % to 108 % of the particles'
// volume (count x spacing^3) and fewer than 2 % of the particles lie outside the level set by
// more than half a voxel. Built twice: with SLURRY_FULL_SCENES (label validation) on the shipped
// scenes, else (CI) flip_drop_3d on a copy with dx doubled, every frame.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "mesh_volume.h"
#include "slurry/io/pipeline.h"
#include "slurry/slurry.h"

namespace fs = std::filesystem;

namespace {

struct Worst {
  double low = 1e9, high = 0, outside = 0;
  int frames = 0;
};

Worst surface_volumes(const std::string& name, bool coarse) {
  slurry::Scene scene = slurry::load_scene(fs::path(SLURRY_SOURCE_DIR) / "examples/scenes" / (name + ".json"));
  if (coarse) scene.domain.dx *= 2;
  const slurry::io::FrameOutputs outputs = slurry::io::frame_outputs(scene);
  const double s = outputs.params.spacing, h = outputs.params.voxel_size;
  slurry::RunOptions options;
  options.directory = fs::temp_directory_path() / ("slurry_surface_volume_" + name + "_" + std::to_string(::getpid()));
  options.overwrite = true;
  Worst w;
  slurry::run_scene(scene, options, [&](const slurry::FrameReport& r) {
    const slurry::io::PointCloud cloud = slurry::io::point_cloud(*r.frame_data);
    const slurry::io::Surface sf = slurry::io::surface_particles(cloud, outputs.params);
    const double volume = slurry_test::signed_volume(sf.mesh);
    const double share = volume / (double(cloud.size()) * s * s * s);
    std::size_t outside = 0;
    for (const auto& p : cloud.position)
      if (sf.level_set.value({p[0], p[1], p[2]}) > 0.5 * h) ++outside;
    const double out_share = double(outside) / double(cloud.size());
    std::printf("%s frame %d: %zu particles, iso %.3f, mesh / particles' volume %.4f, outside by > h/2 %.4f\n",
                name.c_str(), r.frame, cloud.size(), sf.iso, share, out_share);
    w.low = std::min(w.low, share);
    w.high = std::max(w.high, share);
    w.outside = std::max(w.outside, out_share);
    ++w.frames;
  });
  fs::remove_all(*options.directory);
  std::printf("%s: %d frames, mesh / particles' volume %.4f .. %.4f, largest share outside %.4f\n",
              name.c_str(), w.frames, w.low, w.high, w.outside);
  return w;
}

void check(const std::string& name, bool coarse, double outside) {
  const Worst w = surface_volumes(name, coarse);
  EXPECT_GT(w.frames, 1);
  EXPECT_GE(w.low, 0.92) << name;
  EXPECT_LE(w.high, 1.08) << name;
  EXPECT_LT(w.outside, outside) << name;
}

#ifdef SLURRY_FULL_SCENES
constexpr bool kCoarse = false;
#else
constexpr bool kCoarse = true;
#endif

}  // namespace

// The shipped scene (28 k particles) in CI too.
TEST(SurfaceVolume, MeshDamBreak3d) { check("mesh_dam_break_3d", false, 0.02); }
TEST(SurfaceVolume, FlipDrop3d) { check("flip_drop_3d", kCoarse, 0.02); }
