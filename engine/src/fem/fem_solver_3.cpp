// FemSolver<float, 3> and FemSolver<double, 3> (see fem_solver_impl.h).
#include "fem/fem_solver_impl.h"

namespace slurry {
template class FemSolver<float, 3>;
template class FemSolver<double, 3>;
}  // namespace slurry
