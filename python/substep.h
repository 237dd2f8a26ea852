#pragma once
// The stable substep of a simulation, for the Python module's Simulation.step(). The solver
// classes (and their grid headers) stay in substep.cpp.
#include "slurry/engine/solver.h"

namespace slurry::python {

/// The length (s) of the substep the solver would take now: MpmSolver, FlipSolver or
/// FemSolver's stable_dt(). Throws std::logic_error for another Solver.
double stable_dt(const Solver& solver);

}  // namespace slurry::python
