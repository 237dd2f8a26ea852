// Tests of the per-run statistics (engine/include/slurry/engine/stats.h): stats.csv beside the
// frames, the figures against analytic values, and drift warnings that name the frame.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/io/scene_file.h"

namespace {

using slurry::RunStats;

std::vector<std::vector<double>> read_csv(const std::filesystem::path& file, std::string* header) {
  std::ifstream in(file);
  std::getline(in, *header);
  std::vector<std::vector<double>> rows;
  std::string line;
  while (std::getline(in, line)) {
    std::vector<double> row;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) row.push_back(std::stod(cell));
    rows.push_back(row);
  }
  return rows;
}

int column(const std::string& header, const std::string& name) {
  std::stringstream ss(header);
  std::string cell;
  for (int i = 0; std::getline(ss, cell, ','); ++i)
    if (cell == name) return i;
  ADD_FAILURE() << "no column " << name << " in " << header;
  return 0;
}

TEST(DriftWarnings, NameTheFrameAndOnlyReportWhatIsBeyondTheTolerance) {
  RunStats first, now;
  first.mass = 2.0;
  first.volume = 1.0;
  first.kinetic = 1.0;
  now = first;
  now.frame = 7;
  now.time = 0.25;
  slurry::DriftTolerances tol;
  EXPECT_TRUE(slurry::drift_warnings(first, now, tol, 10.0).empty());
  now.mass = 2.0 * (1 + 2e-4);  // beyond the 1e-4 default
  now.volume = 0.95;            // within 10%
  now.kinetic = 0.2;            // energy lost: dissipation is never reported
  auto w = slurry::drift_warnings(first, now, tol, 10.0);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("frame 7 (t = 0.25 s): total mass changed by 0.02%"), std::string::npos) << w[0];
  EXPECT_NE(w[0].find("output.mass_drift"), std::string::npos) << w[0];
  now.mass = first.mass;
  now.volume = 0.8;
  now.kinetic = 1.6;  // energy grew by 0.6 J of 10 J available: 6% > 5%
  w = slurry::drift_warnings(first, now, tol, 10.0);
  ASSERT_EQ(w.size(), 2u);
  EXPECT_NE(w[0].find("volume changed by -20%"), std::string::npos) << w[0];
  EXPECT_NE(w[1].find("energy grew by 6%"), std::string::npos) << w[1];
  tol.check_energy = false;  // emitters or moving colliders
  EXPECT_EQ(slurry::drift_warnings(first, now, tol, 10.0).size(), 1u);
  tol.check_energy = true;
  now.surface = first.surface - 0.6;  // surface energy turned into motion (drops merging)
  EXPECT_EQ(slurry::drift_warnings(first, now, tol, 10.0).size(), 1u);
  now.surface = first.surface;
}

// A 2D elastic block in free fall (no contact within the run): stats.csv has a row per frame,
// the mass is constant, the momentum follows M g t and the total energy is conserved to the
// scheme's accuracy, with no warning.
TEST(RunStats, FreeFallFollowsGravityInStatsCsv) {
  const auto dir = std::filesystem::temp_directory_path() / "slurry_stats_free_fall";
  std::filesystem::remove_all(dir);
  const slurry::Scene scene = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 1], "dx": 0.02},
    "solver": {"dimension": 2, "transfer": "apic", "kernel": "quadratic"},
    "materials": [{"name": "jelly", "model": "fixed_corotated", "density": 1000, "E": 1e4, "nu": 0.3}],
    "bodies": [{"shape": "box", "min": [0.4, 0.6], "max": [0.6, 0.8], "material": "jelly"}],
    "output": {"fps": 24, "frames": 6, "attributes": ["position", "velocity"]}
  })", "free_fall.json");
  slurry::RunOptions opt;
  opt.directory = dir;
  int warnings = 0;
  const auto summary = slurry::run_scene(scene, opt, [&](const slurry::FrameReport& r) { warnings += int(r.warnings.size()); });
  EXPECT_EQ(warnings, 0);
  std::string header;
  const auto rows = read_csv(dir / "stats.csv", &header);
  ASSERT_EQ(rows.size(), 7u);
  const int t = column(header, "time"), m = column(header, "mass"), py = column(header, "momentum_y"),
            e = column(header, "energy"), k = column(header, "kinetic"), cfl = column(header, "cfl");
  const double M = rows[0][std::size_t(m)];
  EXPECT_NEAR(M, 1000 * 0.2 * 0.2, 1e-3 * M);  // density x area, to the seeding's round-off
  for (const auto& r : rows) {
    EXPECT_EQ(r[std::size_t(m)], M);  // particles carry fixed masses
    const double expected = -M * 9.81 * r[std::size_t(t)];
    EXPECT_NEAR(r[std::size_t(py)], expected, 1e-4 * M * 9.81 * 0.25 + 1e-9);
  }
  // Free fall turns potential into kinetic energy. Symplectic Euler (v += g dt, then x += dt v)
  // loses M g^2 dt^2 / 2 per substep: at the default max_dt 1e-3 s (the CFL and elastic limits
  // are longer here) E(t) - E(0) = -M g^2 dt t / 2, which the figures must show to 5%.
  const double gained = rows.back()[std::size_t(k)];
  EXPECT_NEAR(gained, 0.5 * M * std::pow(9.81 * 0.25, 2), 1e-3 * gained);
  const double loss = rows[0][std::size_t(e)] - rows.back()[std::size_t(e)];
  const double predicted = 0.5 * M * 9.81 * 9.81 * 1e-3 * 0.25;
  EXPECT_NEAR(loss, predicted, 0.05 * predicted);
  EXPECT_GT(rows.back()[std::size_t(cfl)], 0);
  EXPECT_LE(summary.largest_cfl, 0.5 + 1e-6);  // solver.cfl
  EXPECT_EQ(summary.drift_warnings, 0);
}

// An injected drift is reported: the FLIP dam break at one substep per 1/60 s frame without the
// volume correction loses a quarter of its volume (tests/flip/physics_test.cpp); with
// output.volume_drift 0.1 the run warns and names the frame.
TEST(RunStats, FlipVolumeLossIsReportedWithItsFrame) {
  const auto dir = std::filesystem::temp_directory_path() / "slurry_stats_flip_drift";
  std::filesystem::remove_all(dir);
  const slurry::Scene scene = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [3, 2], "dx": 0.02},
    "solver": {"type": "flip", "dimension": 2, "transfer": "apic", "kernel": "linear", "cfl": 5,
               "max_dt": 0.016666666666666666, "volume_correction": 0},
    "materials": [{"name": "water", "model": "fluid", "density": 1000}],
    "bodies": [{"shape": "box", "min": [0, 0], "max": [0.54, 1.08], "material": "water"}],
    "output": {"fps": 60, "frames": 180, "attributes": ["position"], "volume_drift": 0.1}
  })", "dam_break.json");
  slurry::RunOptions opt;
  opt.directory = dir;
  std::vector<std::string> warnings;
  const auto summary = slurry::run_scene(scene, opt, [&](const slurry::FrameReport& r) {
    for (const auto& w : r.warnings) warnings.push_back(w);
  });
  ASSERT_FALSE(warnings.empty());
  EXPECT_NE(warnings[0].find("volume changed by -"), std::string::npos) << warnings[0];
  EXPECT_EQ(warnings[0].rfind("frame ", 0), 0u) << warnings[0];
  EXPECT_GT(summary.drift_warnings, 0);
  std::printf("[ figure ] first drift warning: %s; %d of 180 frames warned\n", warnings[0].c_str(),
              summary.drift_warnings);
}

TEST(RunStats, DriftTolerancesAreSceneKeys) {
  const auto base = [](const std::string& output) {
    return R"({"domain": {"min": [0, 0], "max": [1, 1], "dx": 0.1}, "solver": {"dimension": 2, "transfer": "apic"},
      "materials": [{"name": "m"}], "bodies": [{"shape": "box", "min": [0.2, 0.2], "max": [0.4, 0.4], "material": "m"}],
      "output": )" + output + "}";
  };
  const auto s = slurry::parse_scene(base(R"({"mass_drift": 0.01, "volume_drift": 0.2, "energy_growth": 0.5})"), "a.json");
  EXPECT_EQ(s.output.mass_drift, 0.01);
  EXPECT_EQ(s.output.volume_drift, 0.2);
  EXPECT_EQ(s.output.energy_growth, 0.5);
  try {
    slurry::parse_scene(base(R"({"energy_growth": -1})"), "b.json");
    ADD_FAILURE() << "a negative tolerance was accepted";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("b.json: output.energy_growth: expected a number >= 0, got -1"), std::string::npos)
        << e.what();
  }
}

}  // namespace
