// An effects pipeline's use of Slurry (docs/cpp-api.md): a scene built in code,
// stepped frame by frame, its particles read from memory (positions, velocities, persistent ids)
// without files; then the same scene through run_scene with a frame callback and no output.
//
// It checks what it reads and exits 1 on a mismatch, so that ctest can run it: ids ascend; until
// the ball nears the floor its centre of mass follows free fall, y(t) = y0 - g t^2 / 2 (to the
// symplectic Euler step's O(g t dt) error); no particle ever passes the floor.
#include <slurry/slurry.h>

#include <cmath>
#include <cstdio>

namespace {

slurry::Scene jelly_ball() {
  slurry::Scene scene;
  scene.source = "pipeline.cpp";
  scene.domain.min = {0, 0, 0};
  scene.domain.max = {0.5, 0.8, 0.5};
  scene.domain.dx = 0.02;
  scene.solver.type = slurry::SolverType::MPM;
  scene.solver.dimension = 3;
  scene.solver.precision = slurry::Precision::Float;
  slurry::MaterialParams jelly;
  jelly.name = "jelly";
  jelly.model = slurry::ElasticModel::FixedCorotated;
  jelly.density = 1000;
  jelly.E = 5e4;
  jelly.nu = 0.3;
  scene.materials.push_back(jelly);
  slurry::BodyParams ball;
  ball.shape = slurry::Shape::Sphere;
  ball.center = {0.25, 0.55, 0.25};
  ball.radius = 0.1;
  ball.material = "jelly";
  scene.bodies.push_back(ball);
  scene.boundaries.walls = slurry::Condition::Separate;
  scene.output.fps = 24;
  scene.output.frames = 12;
  return scene;
}

int failures = 0;
void check(bool ok, const char* what, int frame) {
  if (!ok) {
    std::fprintf(stderr, "frame %d: %s\n", frame, what);
    ++failures;
  }
}

}  // namespace

int main() {
  try {
    const slurry::Scene scene = jelly_ball();
    auto sim = slurry::make_simulation(scene);
    const double g = 9.81, floor_y = scene.domain.dx * scene.boundaries.thickness;
    double y0 = 0;
    bool touched = false;  // the ball has come within reach of the floor's wall nodes
    for (int f = 0; f <= scene.output.frames; ++f) {
      if (f > 0) sim->advance_to(f * scene.frame_dt());
      const auto view = sim->particles_view<float, 3>();
      double cy = 0, lowest = 1e30, top_speed = 0;
      bool ascending = true;
      for (std::size_t i = 0; i < view.size(); ++i) {
        cy += view.position(i).y();
        lowest = std::min(lowest, double(view.position(i).y()));
        top_speed = std::max(top_speed, double(view.velocity(i).norm()));
        ascending = ascending && (i == 0 || view.id(i) > view.id(i - 1));
      }
      cy /= double(view.size());
      if (f == 0) y0 = cy;
      const double t = sim->time(), free_fall = y0 - 0.5 * g * t * t;
      std::printf("frame %2d  t %.4f s  particles %zu  centre y %.4f m (free fall %.4f)  lowest %.4f m  top speed %.3f m/s\n",
                  f, t, view.size(), cy, free_fall, lowest, top_speed);
      check(ascending, "particle ids do not ascend", f);
      check(lowest >= floor_y - scene.domain.dx, "a particle passed the floor", f);
      touched = touched || lowest <= floor_y + 3 * scene.domain.dx;
      if (!touched)
        check(std::abs(cy - free_fall) < 2e-3 + g * t * 1e-3, "centre of mass is not in free fall", f);
    }

    // The same scene through run_scene: no files, the particles handed to a callback.
    slurry::RunOptions options;
    options.write_files = false;
    std::size_t frames_seen = 0, last_count = 0;
    slurry::run_scene(scene, options, [&](const slurry::FrameReport& r) {
      const auto view = r.simulation->particles_view<float, 3>();
      last_count = view.size();
      ++frames_seen;
      check(r.file.empty(), "run_scene wrote a file with write_files = false", r.frame);
    });
    std::printf("run_scene: %zu frames handed to the callback, %zu particles\n", frames_seen, last_count);
    check(frames_seen == std::size_t(scene.output.frames + 1), "run_scene did not report every frame", -1);
    check(last_count == sim->particle_count(), "run_scene and make_simulation seeded different particles", -1);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  }
  if (failures) std::fprintf(stderr, "%d checks failed\n", failures);
  return failures ? 1 : 0;
}
