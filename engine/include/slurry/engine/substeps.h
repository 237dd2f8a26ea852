#pragma once
/// \file substeps.h
/// What every solver's advance_to shares: the substep loop from one frame time to the next, with
/// its time-step floor and the diagnosis of a substep that collapsed.
#include <cstdint>

#include "slurry/engine/scene/scene.h"

namespace slurry {

/// The substep loop every solver's advance_to shares: takes substeps of stable_dt() from `time`
/// until it reaches t_end exactly. A substep that would overshoot ends on t_end (and `time` is
/// set to t_end, so frame times do not drift by summing substeps); one longer than half the
/// remainder is halved, giving two even substeps rather than a long and a tiny one. `step(dt)`
/// advances `time` itself. Returns the number of substeps.
///
/// Time-step floor: a stable substep below kMinSubstepRatio of the interval, or more than
/// scene.limits.substeps_per_frame substeps, throws SceneError naming the limit that caused it.
inline constexpr double kMinSubstepRatio = 1e-9;
/// Throws for a substep below the floor or one substep too many: SimulationError when the CFL
/// step collapsed because the velocities blew up (a speed far beyond what the scene's energy
/// allows), else SceneError naming the limit that set the substep (solver.cfl, solver.max_dt,
/// solver.elastic_cfl or limits.substeps_per_frame) and the value to change.
[[noreturn]] void substep_limit_error(const Scene& scene, double dt, double interval, std::int64_t substeps, double time);
template <class StableDt, class Step>
std::int64_t substep_to(double& time, double t_end, StableDt&& stable_dt, Step&& step, const Scene& scene) {
  std::int64_t n = 0;
  const double interval = t_end - time;
  while (time < t_end) {
    const double remaining = t_end - time;
    double dt = double(stable_dt());
    if (!(dt >= kMinSubstepRatio * interval) || n >= scene.limits.substeps_per_frame)
      substep_limit_error(scene, dt, interval, n, time);
    bool last = false;
    if (dt >= remaining * (1 - 1e-9)) {
      dt = remaining;
      last = true;
    } else if (dt > 0.5 * remaining) {
      dt = 0.5 * remaining;
    }
    step(dt);
    if (last) time = t_end;
    ++n;
  }
  return n;
}

}  // namespace slurry
