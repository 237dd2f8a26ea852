// The stable substep of each solver class: the one place the Python module names them.
#include "substep.h"

#include <stdexcept>

#include "slurry/engine/fem/fem_solver.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace slurry::python {
namespace {

template <template <class, int> class S, class T, int Dim>
bool try_stable_dt(const Solver& solver, double& dt) {
  const auto* s = dynamic_cast<const S<T, Dim>*>(&solver);
  if (s) dt = double(s->stable_dt());
  return s != nullptr;
}

template <template <class, int> class S>
bool any_stable_dt(const Solver& solver, double& dt) {
  return try_stable_dt<S, float, 2>(solver, dt) || try_stable_dt<S, float, 3>(solver, dt) ||
         try_stable_dt<S, double, 2>(solver, dt) || try_stable_dt<S, double, 3>(solver, dt);
}

}  // namespace

double stable_dt(const Solver& solver) {
  double dt = 0;
  if (any_stable_dt<MpmSolver>(solver, dt) || any_stable_dt<flip::FlipSolver>(solver, dt) ||
      any_stable_dt<FemSolver>(solver, dt))
    return dt;
  throw std::logic_error("stable_dt: not an MPM, FLIP or FEM solver");
}

}  // namespace slurry::python
