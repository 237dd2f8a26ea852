// MpmSolver<double, 2>: one instantiation per translation unit (see mpm_solver_impl.h).
#include "mpm/mpm_solver_impl.h"

namespace slurry {
template class MpmSolver<double, 2>;
}  // namespace slurry
