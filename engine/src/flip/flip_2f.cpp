// FlipSimulation<float, 2>: one instantiation per translation unit (see flip_simulation_impl.h).
#include "flip_simulation_impl.h"

namespace slurry::flip {
template class FlipSimulation<float, 2>;
}  // namespace slurry::flip
