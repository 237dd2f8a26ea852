// Sleeping material (solver.sleep): a sand layer settles on the floor and goes
// to sleep block by block; a ball dropped into it wakes what it hits. Frames equal the run
// without sleeping bit for bit until the first block sleeps, and stay within a fraction of a
// cell of it after; the ball comes to rest on the layer at the same height; a checkpoint taken
// while blocks sleep resumes to the same frames; the keys are validated.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "slurry/engine/errors.h"
#include "slurry/engine/mpm/mpm_solver.h"
#include "slurry/io/scene_file.h"

using slurry::Scene;

namespace {

constexpr double kDx = 0.015625;

/// A 2D sand layer (Drucker-Prager, the sand_column example's material) 0.12 m deep on the floor
/// of a 1 x 1.5 m box, and a jelly ball of radius 0.03 m released at `ball_height` with downward
/// speed `ball_speed`. Blocks sleep after 50 calm substeps (of 1 ms) below 1 cm/s.
Scene pile(double sleep_speed, double ball_speed, double ball_height) {
  Scene s = slurry::parse_scene(R"({
    "domain": {"min": [0, 0], "max": [1, 1.5], "dx": 0.015625},
    "solver": {"dimension": 2, "transfer": "apic", "kernel": "quadratic", "max_dt": 0.001},
    "materials": [
      {"name": "sand", "model": "hencky_stvk", "density": 2200, "E": 350000.0, "nu": 0.3, "plasticity": "drucker_prager", "friction_angle": 30},
      {"name": "ball", "model": "fixed_corotated", "density": 1000, "E": 100000.0, "nu": 0.3}
    ],
    "bodies": [
      {"shape": "box", "min": [0.05, 0.0], "max": [0.95, 0.12], "material": "sand", "particles_per_cell": 4, "sampling": "jittered", "seed": 3},
      {"shape": "sphere", "center": [0.5, 0.45], "radius": 0.03, "material": "ball"}
    ],
    "boundaries": {"walls": "separate", "friction": 0.5},
    "output": {"fps": 30, "frames": 24}
  })",
                                "pile_2d");
  s.solver.sleep.speed = sleep_speed;
  s.solver.sleep.substeps = 50;
  s.bodies[1].center = {0.5, ball_height, 0};
  s.bodies[1].velocity = {0, -ball_speed, 0};
  return s;
}

struct Columns {
  std::vector<double> x, y, vx, vy, material;
};

Columns columns(const slurry::MpmSolver<float, 2>& sim) {
  const auto data = sim.frame({"position", "velocity", "material"});
  const auto& v = data.table("vertex");
  return {v.column_as_double("x"), v.column_as_double("y"), v.column_as_double("vx"),
          v.column_as_double("vy"), v.column_as_double("material")};
}

double largest_difference(const Columns& a, const Columns& b) {
  double d = 0;
  for (std::size_t p = 0; p < a.x.size(); ++p)
    d = std::max(d, std::hypot(a.x[p] - b.x[p], a.y[p] - b.y[p]));
  return d;
}

}  // namespace

TEST(Sleep, FramesEqualUntilTheFirstBlockSleepsAndStayCloseAfter) {
  // The ball falls from 1.4 m and lands at about t = 0.5 s (5 m/s), when much of the layer sleeps.
  slurry::MpmSolver<float, 2> awake(pile(0, 0.0, 1.4)), sleepy(pile(0.01, 0.0, 1.4));
  bool slept = false;
  int first_sleep_frame = -1;
  double worst_after = 0;
  // The ball's deepest point over the run and the sand's surface under it at the end: the sand
  // the ball hits must wake and give way as it does awake.
  double ball_low[2] = {1, 1}, surface[2] = {0, 0};
  for (int f = 1; f <= 24; ++f) {
    awake.advance_to(f / 30.0);
    sleepy.advance_to(f / 30.0);
    const Columns a = columns(awake), b = columns(sleepy);
    if (!slept && sleepy.blocks_fallen_asleep() > 0) slept = true, first_sleep_frame = f;
    if (!slept) {
      ASSERT_EQ(a.x, b.x) << "frame " << f << ": positions differ before any block slept";
      ASSERT_EQ(a.vy, b.vy) << "frame " << f;
    } else {
      worst_after = std::max(worst_after, largest_difference(a, b));
    }
    int k = 0;
    for (const Columns* c : {&a, &b}) {
      surface[k] = 0;
      for (std::size_t p = 0; p < c->x.size(); ++p) {
        if (c->material[p] == 1) ball_low[k] = std::min(ball_low[k], c->y[p]);
        if (c->material[p] == 0 && std::abs(c->x[p] - 0.5) < 0.02)
          surface[k] = std::max(surface[k], c->y[p]);
      }
      ++k;
    }
  }
  std::printf(
      "first block asleep in frame %d; at the end %s; largest position difference after: %.3g m "
      "(%.3f dx); ball's "
      "deepest point %.4f / %.4f m, sand surface under it %.4f / %.4f m (awake / sleeping)\n",
      first_sleep_frame, sleepy.solver_status().c_str(), worst_after, worst_after / kDx,
      ball_low[0], ball_low[1], surface[0], surface[1]);
  ASSERT_TRUE(slept) << "no block ever fell asleep";
  // The layer (x 0.05 .. 0.95 m, 0.12 m deep) spans 8 blocks of 8 x 8 nodes.
  EXPECT_GE(sleepy.sleeping_blocks(), 6u) << "most of the settled layer should sleep";
  EXPECT_LT(worst_after, 0.5 * kDx);
  EXPECT_LT(ball_low[0], 0.16) << "the ball did not come down onto the layer";
  EXPECT_GT(sleepy.blocks_fallen_asleep(), std::int64_t(sleepy.sleeping_blocks()))
      << "no sleeping block ever woke";
  EXPECT_NEAR(ball_low[0], ball_low[1], 0.25 * kDx);
  EXPECT_NEAR(surface[0], surface[1], 0.25 * kDx);
}

// A checkpoint taken while blocks sleep: the resumed simulation writes the frames of the
// uninterrupted one bit for bit (the sleeping blocks' contributions are scattered again from the
// unchanged particles, in the same order).
TEST(Sleep, ResumeWhileBlocksSleepIsExact) {
  const Scene s = pile(0.01, 0.0, 1.4);
  slurry::MpmSolver<float, 2> a(s);
  a.advance_to(20 / 30.0);
  ASSERT_GT(a.sleeping_blocks(), 0u);
  std::string state;
  a.save_state(state);
  slurry::MpmSolver<float, 2> b(s);
  b.load_state(state, "test state");
  EXPECT_EQ(b.sleeping_blocks(), a.sleeping_blocks());
  for (int f = 21; f <= 28; ++f) {
    a.advance_to(f / 30.0);
    b.advance_to(f / 30.0);
    const Columns ca = columns(a), cb = columns(b);
    ASSERT_EQ(ca.x, cb.x) << "frame " << f;
    ASSERT_EQ(ca.vy, cb.vy) << "frame " << f;
  }
}

TEST(Sleep, KeysAreValidated) {
  Scene s = pile(0.01, 0, 1.4);
  s.solver.sleep.strain_rate = 0;
  EXPECT_THROW(s.validate(), slurry::SceneError);
  s = pile(0.01, 0, 1.4);
  s.solver.integrator = slurry::Integrator::Implicit;
  try {
    s.validate();
    FAIL() << "implicit with sleeping accepted";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "solver.sleep.speed: sleeping material is for the \"explicit\" integrator"),
              std::string::npos)
        << e.what();
  }
  try {
    slurry::parse_scene(
        R"({"solver": {"dimension": 2, "sleep": {"speed": -1}}, "materials": [{"name": "a"}],
      "bodies": [{"min": [0.1, 0.1], "max": [0.2, 0.2], "material": "a"}]})",
        "s.json");
    FAIL() << "a negative sleep speed accepted";
  } catch (const slurry::SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("solver.sleep.speed"), std::string::npos) << e.what();
  }
}
