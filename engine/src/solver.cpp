// The solver-neutral parts of solver.h: the id order of a particle view and the factory.
#include "slurry/engine/solver.h"

#include <algorithm>

#include "slurry/engine/errors.h"
#include "slurry/engine/fem/fem_solver.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace slurry {

std::vector<std::uint32_t> Solver::id_order(const std::uint32_t* ids, std::size_t n) {
  if (!ids || std::is_sorted(ids, ids + n)) return {};
  std::vector<std::uint32_t> order(n);
  // The MPM solver's ids are 0 .. n-1 (a permutation): invert it in O(n). Otherwise (FLIP:
  // ids grow with emission and reseeding and have gaps) sort the storage indices by id.
  bool dense = true;
  std::vector<std::uint8_t> seen(n, 0);
  for (std::size_t p = 0; p < n && dense; ++p) {
    dense = ids[p] < n && !seen[ids[p]];
    if (dense) seen[ids[p]] = 1, order[ids[p]] = std::uint32_t(p);
  }
  if (!dense) {
    for (std::size_t p = 0; p < n; ++p) order[p] = std::uint32_t(p);
    std::sort(order.begin(), order.end(), [ids](std::uint32_t a, std::uint32_t b) { return ids[a] < ids[b]; });
  }
  return order;
}

void Solver::load_state_parts(int parts, const std::function<std::string(int)>& part, const std::string& what) {
  if (parts != 1)
    throw IoError(what + ": a checkpoint in " + std::to_string(parts) +
                  " parts (one per process of a split MPM run); expected one whole state for this solver");
  load_state(part(0), what);
}

std::unique_ptr<Solver> make_solver(const Scene& scene, Communicator* communicator) {
  scene.validate();
  check_resources(scene);  // before any allocation
  const bool dbl = scene.solver.precision == Precision::Double;
  if (communicator && communicator->size() > 1 && scene.solver.type == SolverType::FEM) {
    // FEM's implicit solve is not distributed.
    const std::string n = std::to_string(communicator->size());
    throw SceneError(scene.source + ": solver.type \"" + std::string(to_string(scene.solver.type)) +
                     "\": runs in one process only (its implicit solve is not distributed); expected an MPM or FLIP "
                     "scene for a run split over " + n + " processes (mpirun -np " + n + "), or mpirun -np 1");
  }
  if (scene.solver.type == SolverType::FLIP) {
    if (scene.solver.dimension == 2) {
      if (dbl) return std::make_unique<flip::FlipSolver<double, 2>>(scene, communicator);
      return std::make_unique<flip::FlipSolver<float, 2>>(scene, communicator);
    }
    if (dbl) return std::make_unique<flip::FlipSolver<double, 3>>(scene, communicator);
    return std::make_unique<flip::FlipSolver<float, 3>>(scene, communicator);
  }
  if (scene.solver.type == SolverType::FEM) {
    if (scene.solver.dimension == 2) {
      if (dbl) return std::make_unique<FemSolver<double, 2>>(scene);
      return std::make_unique<FemSolver<float, 2>>(scene);
    }
    if (dbl) return std::make_unique<FemSolver<double, 3>>(scene);
    return std::make_unique<FemSolver<float, 3>>(scene);
  }
  if (scene.solver.dimension == 2) {
    if (dbl) return std::make_unique<MpmSolver<double, 2>>(scene, communicator);
    return std::make_unique<MpmSolver<float, 2>>(scene, communicator);
  }
  if (dbl) return std::make_unique<MpmSolver<double, 3>>(scene, communicator);
  return std::make_unique<MpmSolver<float, 3>>(scene, communicator);
}

}  // namespace slurry
