// Simulation<double, 2>: one instantiation per translation unit (see simulation_impl.h).
#include "simulation_impl.h"

namespace slurry {
template class Simulation<double, 2>;
}  // namespace slurry
