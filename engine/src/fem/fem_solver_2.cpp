// FemSolver<float, 2> and FemSolver<double, 2> (see fem_solver_impl.h).
#include "fem/fem_solver_impl.h"

namespace slurry {
template class FemSolver<float, 2>;
template class FemSolver<double, 2>;
}  // namespace slurry
