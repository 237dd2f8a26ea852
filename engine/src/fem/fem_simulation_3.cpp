// FemSimulation<float, 3> and FemSimulation<double, 3> (see fem_simulation_impl.h).
#include "fem_simulation_impl.h"

namespace slurry {
template class FemSimulation<float, 3>;
template class FemSimulation<double, 3>;
}  // namespace slurry
