// Simulation<double, 3>: one instantiation per translation unit (see simulation_impl.h).
#include "simulation_impl.h"

namespace slurry {
template class Simulation<double, 3>;
}  // namespace slurry
