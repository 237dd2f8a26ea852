// The substep floor's diagnosis (substeps.h).
#include "slurry/engine/substeps.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "slurry/engine/errors.h"

namespace slurry {
namespace {

std::string fmt(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g", x);
  return buf;
}

}  // namespace

void substep_limit_error(const Scene& scene, double dt, double interval, std::int64_t substeps, double time) {
  const bool too_many = substeps >= scene.limits.substeps_per_frame;
  std::string limit = "solver.cfl", cause = "the CFL limit cfl dx / max |v|";
  if (dt >= scene.solver.max_dt * (1 - 1e-6)) {
    limit = "solver.max_dt";
    cause = "solver.max_dt";
  } else if (dt > 0 && std::abs(dt - scene.elastic_dt()) <= 1e-5 * dt) {
    limit = "solver.elastic_cfl";
    cause = "the elastic limit elastic_cfl dx / c";
  }
  // A CFL step that collapsed because velocities blew up is an instability, not a setting that
  // asks too much: the speed it implies (cfl dx / dt) is far beyond anything the scene's energy
  // allows (the bodies' and emitters' speeds, a fall through the domain, the colliders' speeds).
  // Then the run stops (or retries) as for any instability, with that diagnosis.
  if (limit == "solver.cfl" && dt > 0 && scene.solver.cfl > 0) {
    const int dim = scene.solver.dimension;
    const double g = scene.solver.gravity.head(dim).norm();
    const double H = (scene.domain.max - scene.domain.min).head(dim).norm();
    double v0 = 0;
    for (const auto& b : scene.bodies) v0 = std::max(v0, b.velocity.head(dim).norm());
    for (const auto& e : scene.emitters) v0 = std::max(v0, e.velocity.head(dim).norm());
    for (const auto& c : scene.colliders) v0 = std::max(v0, c.velocity.head(dim).norm() + (c.keyframes.empty() ? 0.0 : 10.0));
    const double plausible = 100 * (std::sqrt(v0 * v0 + 2 * g * H) + 1);
    const double speed = scene.solver.cfl * scene.domain.dx / dt;
    if (speed > plausible)
      throw SimulationError(scene.source + ": simulation unstable at t = " + fmt(time) + " s: particles reached " + fmt(speed) +
                            " m/s (the CFL limit cut the substep to " + fmt(dt) + " s), far beyond the " + fmt(plausible / 100) +
                            " m/s the scene's energy allows: the state blew up. No further frames are written. Try a smaller "
                            "solver.max_dt or solver.cfl, or keep moving colliders from squeezing material against walls.");
  }
  const std::string what =
      too_many ? "the frame ending at t = " + fmt(time + interval) + " s needs more than limits.substeps_per_frame = " +
                     std::to_string(scene.limits.substeps_per_frame) + " substeps"
               : "the substep fell to " + fmt(dt) + " s at t = " + fmt(time) + " s, below " + fmt(kMinSubstepRatio) +
                     " of the frame (" + fmt(interval) + " s)";
  throw SceneError(scene.source + ": " + limit + ": " + what + "; the substep is set by " + cause + " = " + fmt(dt) +
                   " s (expected a larger " + limit + ")");
}

}  // namespace slurry
