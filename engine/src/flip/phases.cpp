#include "slurry/engine/flip/flip_solver.h"

namespace slurry::flip {

const char* phase_name(int phase) {
  static const char* names[kPhaseCount] = {"emit",    "sort",       "transfer_to_grid", "save_velocities",
                                           "gravity", "boundaries", "viscosity", "project",          "extrapolate",
                                           "enforce_solids", "transfer_to_particles", "advect", "reseed",
                                           "whitewater"};
  return phase >= 0 && phase < kPhaseCount ? names[phase] : "?";
}

}  // namespace slurry::flip
