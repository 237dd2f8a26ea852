#include "slurry/engine/fem/fem_simulation.h"
#include "slurry/engine/flip/flip_simulation.h"
#include "slurry/engine/simulation.h"

namespace slurry {

std::unique_ptr<SimulationBase> make_simulation(const Scene& scene) {
  scene.validate();
  check_resources(scene);  // before any allocation
  const bool dbl = scene.solver.precision == Precision::Double;
  if (scene.solver.type == SolverType::FLIP) {
    if (scene.solver.dimension == 2) {
      if (dbl) return std::make_unique<flip::FlipSimulation<double, 2>>(scene);
      return std::make_unique<flip::FlipSimulation<float, 2>>(scene);
    }
    if (dbl) return std::make_unique<flip::FlipSimulation<double, 3>>(scene);
    return std::make_unique<flip::FlipSimulation<float, 3>>(scene);
  }
  if (scene.solver.type == SolverType::FEM) {
    if (scene.solver.dimension == 2) {
      if (dbl) return std::make_unique<FemSimulation<double, 2>>(scene);
      return std::make_unique<FemSimulation<float, 2>>(scene);
    }
    if (dbl) return std::make_unique<FemSimulation<double, 3>>(scene);
    return std::make_unique<FemSimulation<float, 3>>(scene);
  }
  if (scene.solver.dimension == 2) {
    if (dbl) return std::make_unique<Simulation<double, 2>>(scene);
    return std::make_unique<Simulation<float, 2>>(scene);
  }
  if (dbl) return std::make_unique<Simulation<double, 3>>(scene);
  return std::make_unique<Simulation<float, 3>>(scene);
}

}  // namespace slurry
