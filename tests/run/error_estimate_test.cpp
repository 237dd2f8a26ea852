// Tests of the run's own error estimate (output.error_estimate, run/error_estimate.h): the
// columns it adds to stats.csv, a resumed run writing the same estimates, the keys refused where
// the estimate does not apply, and the estimate against the true error of the total energy on
// four problems of the speed-against-accuracy study whose exact solution conserves it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>

#include "problems.h"  // benchmarks/tradeoff: the reference problems' scenes
#include "slurry/engine/run/error_estimate.h"
#include "slurry/engine/run/run.h"
#include "slurry/io/scene_file.h"

namespace fs = std::filesystem;

namespace {

std::string read(const fs::path& f) {
  std::ifstream in(f, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

fs::path fresh_dir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("slurry_error_estimate_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  return d;
}

/// A 2D jelly block dropped on sand (MPM) with the estimate on.
std::string drop_scene(bool estimate) {
  return std::string(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.03125},
    "solver": {"dimension": 2},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "E": 20000, "nu": 0.3},
                  {"name": "sand", "model": "hencky_stvk", "density": 2200, "E": 350000.0, "nu": 0.3,
                   "plasticity": "drucker_prager"}],
    "bodies": [{"shape": "box", "min": [0.3, 0.5], "max": [0.6, 0.7], "material": "jelly"},
               {"shape": "box", "min": [0.0625, 0.0625], "max": [0.9375, 0.2], "material": "sand"}],
    "output": {"fps": 24, "frames": 8, "checkpoint_every": 4)") +
         (estimate ? R"(, "error_estimate": true)" : "") + "}}";
}

}  // namespace

TEST(ErrorEstimate, StatsCsvHasTheEstimateColumnsOnlyWhenAsked) {
  for (bool on : {false, true}) {
    const fs::path dir = fresh_dir(on ? "on" : "off");
    slurry::RunOptions o;
    o.directory = dir;
    slurry::run_scene(slurry::parse_scene(drop_scene(on), "drop.json"), o);
    std::ifstream in(dir / "stats.csv");
    std::string header, line;
    std::getline(in, header);
    EXPECT_EQ(header.find(",error_energy,error_centroid") != std::string::npos, on) << header;
    int rows = 0;
    double largest_centroid = 0;
    while (std::getline(in, line)) {
      ++rows;
      if (!on) {
      continue;
    }
      const auto c2 = line.rfind(','), c1 = line.rfind(',', c2 - 1);
      const double energy = std::stod(line.substr(c1 + 1, c2 - c1 - 1)), centroid = std::stod(line.substr(c2 + 1));
      EXPECT_TRUE(std::isfinite(energy) && energy >= 0) << line;
      EXPECT_TRUE(std::isfinite(centroid) && centroid >= 0 && centroid < 0.1) << line;
      largest_centroid = std::max(largest_centroid, centroid);
    }
    EXPECT_EQ(rows, 9);
    if (on) {
      EXPECT_GT(largest_centroid, 0) << "the two resolutions never differed";
    }
    fs::remove_all(dir);
  }
}

// The shadow is not in the checkpoint: a resumed run simulates it again up to the checkpoint,
// frame by frame, and writes the same estimates as the run that was not stopped.
TEST(ErrorEstimate, ResumedRunWritesTheSameEstimates) {
  const slurry::Scene scene = slurry::parse_scene(drop_scene(true), "drop.json");
  const fs::path whole = fresh_dir("whole"), parts = fresh_dir("parts");
  slurry::RunOptions o;
  o.directory = whole;
  slurry::run_scene(scene, o);
  o.directory = parts;
  o.frames = 4;
  slurry::run_scene(scene, o);
  o.frames = 8;
  o.resume = true;
  slurry::run_scene(scene, o);
  EXPECT_EQ(read(whole / "stats.csv"), read(parts / "stats.csv"));
  fs::remove_all(whole);
  fs::remove_all(parts);
}

TEST(ErrorEstimate, KeysAreValidated) {
  EXPECT_THROW(slurry::parse_scene(R"({"solver": {"dimension": 2}, "materials": [{"name": "m"}],
      "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "m"}],
      "output": {"error_order": 0}})", "s.json"), slurry::SceneError);
  slurry::Scene fem = slurry::load_scene(SLURRY_EXAMPLES_DIR "/fem_cantilever_2d.json");
  EXPECT_NO_THROW(fem.validate());
  fem.output.error_estimate = true;
  try {
    fem.validate();
    ADD_FAILURE() << "FEM with the estimate was accepted";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("output.error_estimate"), std::string::npos) << e.what();
  }
}

namespace {

/// Runs `Solver` on `scene` and on its shadow, each with its initial velocities set by `init`,
/// to time t; returns the estimate of the energy's error and its true error |E(t) - E(0)|
/// (the exact solutions conserve energy).
template <class Solver>
std::pair<double, double> energy_estimate(const slurry::Scene& scene, double t, const std::function<void(Solver&)>& init) {
  Solver fine(scene);
  auto coarse = std::make_unique<Solver>(slurry::shadow_scene(scene));
  init(fine);
  init(*coarse);
  const double e0 = fine.take_stats().energy();
  coarse->take_stats();
  slurry::ErrorEstimator est(std::move(coarse), scene);
  fine.advance_to(t);
  est.advance_to(t);
  slurry::RunStats s = fine.take_stats();
  est.estimate(fine, s);
  return {s.error_energy, std::abs(s.energy() - e0)};
}

void expect_within_factor_2(const char* name, std::pair<double, double> r) {
  const auto [estimate, truth] = r;
  std::printf("%-16s energy error: estimate %.4g J, true %.4g J, ratio %.2f\n", name, estimate, truth, estimate / truth);
  EXPECT_GT(truth, 0) << name;
  EXPECT_GE(estimate, 0.5 * truth) << name;
  EXPECT_LE(estimate, 2.0 * truth) << name;
}

}  // namespace

// The study's problems at their default dx, the estimate's default order p = 1.5.
TEST(ErrorEstimate, EnergyEstimateWithinAFactorOfTwoOfTheTrueError) {
  using Flip = slurry::flip::FlipSolver<float, 2>;
  using Mpm = slurry::MpmSolver<float, 2>;
  {  // Taylor-Green vortex, 1 s
    const auto r = energy_estimate<Flip>(tradeoff::taylor_green_scene(1.0 / 32), 1.0,
                                         [](Flip& sim) { tradeoff::taylor_green_initial_velocity(sim); });
    expect_within_factor_2("taylor_green_2d", r);
  }
  {  // standing wave, 1 s
    const auto r = energy_estimate<Flip>(tradeoff::wave_scene(1.0 / 32), 1.0,
                                         [](Flip& sim) { tradeoff::wave_initial_velocity(sim); });
    expect_within_factor_2("standing_wave_2d", r);
  }
  {  // two elastic disks colliding, 3 s
    const auto r = energy_estimate<Mpm>(tradeoff::disks_scene(1.0 / 40), 3.0, [](Mpm&) {});
    expect_within_factor_2("disks_2d", r);
  }
  {  // elastic bar, first axial mode, 0.05 s (2.5 periods)
    const auto r = energy_estimate<Mpm>(tradeoff::bar_scene(1.0 / 32), 0.05,
                                        [](Mpm& sim) { tradeoff::bar_initial_velocity(sim); });
    expect_within_factor_2("bar_2d", r);
  }
}
