// FlipSolver<double, 3>: one instantiation per translation unit (see flip_solver_impl.h).
#include "flip/flip_solver_impl.h"

namespace slurry::flip {
template class FlipSolver<double, 3>;
}  // namespace slurry::flip
