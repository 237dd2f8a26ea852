// FemSimulation<float, 2> and FemSimulation<double, 2> (see fem_simulation_impl.h).
#include "fem_simulation_impl.h"

namespace slurry {
template class FemSimulation<float, 2>;
template class FemSimulation<double, 2>;
}  // namespace slurry
