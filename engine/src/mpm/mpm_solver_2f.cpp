// MpmSolver<float, 2>: one instantiation per translation unit (see mpm_solver_impl.h).
#include "mpm/mpm_solver_impl.h"

namespace slurry {
template class MpmSolver<float, 2>;
}  // namespace slurry
