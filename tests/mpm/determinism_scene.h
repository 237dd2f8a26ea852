// The scene of the determinism tests, shared by parallel_test.cpp and the determinism program
// that is built with the other parallel backend.
#pragma once
#include <filesystem>
#include <string>

#include "slurry/engine/flip/flip_solver.h"
#include "slurry/io/ply.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/mpm/mpm_solver.h"

namespace slurry::test {

/// Jelly, snow, sand and water in one box, thrown into each other so that blocks hold several
/// materials and particles cross block boundaries every few steps.
inline Scene determinism_scene(int dim, GridKind grid) {
  Scene s;
  s.source = "determinism";
  s.solver.dimension = dim;
  s.solver.transfer = TransferKind::MLS;
  s.domain.dx = dim == 3 ? 1.0 / 32 : 1.0 / 64;
  s.domain.grid = grid;
  MaterialParams jelly, snow, sand, water;
  jelly.name = "jelly";
  jelly.E = 2e5;
  snow.name = "snow";
  snow.E = 1.4e5;
  snow.nu = 0.2;
  snow.density = 400;
  snow.plasticity = PlasticModel::Snow;
  sand.name = "sand";
  sand.model = ElasticModel::HenckyStVK;
  sand.E = 3.5e5;
  sand.density = 1600;
  sand.plasticity = PlasticModel::DruckerPrager;
  water.name = "water";
  water.model = ElasticModel::Fluid;
  water.bulk_modulus = 5e4;
  s.materials = {jelly, snow, sand, water};
  auto box = [&](const char* m, Eigen::Vector3d lo, Eigen::Vector3d hi, Eigen::Vector3d v) {
    BodyParams b;
    b.material = m;
    b.min = lo;
    b.max = hi;
    b.velocity = v;
    b.particles_per_cell = dim == 3 ? 8 : 4;
    b.sampling = Sampling::Jittered;
    return b;
  };
  s.bodies = {box("jelly", {0.2, 0.3, 0.35}, {0.45, 0.55, 0.6}, {2, 0, 0}),
              box("snow", {0.55, 0.3, 0.35}, {0.8, 0.5, 0.6}, {-2, 0, 0}),
              box("sand", {0.35, 0.6, 0.3}, {0.6, 0.75, 0.55}, {0, -1, 0}),
              box("water", {0.1, 0.05, 0.1}, {0.9, 0.15, 0.9}, {0, 0, 0})};
  return s;
}

/// Runs `steps` substeps and writes the frame (all attributes) to `file`; returns its bytes.
template <class Read>
std::string determinism_frame(const Scene& s, int steps, const std::filesystem::path& file, Read&& read) {
  MpmSolver<float, 3> sim(s);
  for (int i = 0; i < steps; ++i) sim.step(sim.stable_dt());
  io::write_ply(file, sim.frame({"position", "velocity", "material", "J", "plastic"}));
  return read(file);
}

/// A 3D FLIP dam break with a moving sphere collider and an emitter (APIC, quadratic kernel,
/// MIC(0)-PCG with its level-scheduled triangular solves, volume correction on): `steps`
/// substeps of 1/120 s, then the frame (position, velocity, id) written to `file`.
template <class Read>
std::string flip_determinism_frame(int steps, const std::filesystem::path& file, Read&& read) {
  Scene s;
  s.source = "flip determinism";
  s.solver.type = SolverType::FLIP;
  s.solver.dimension = 3;
  s.solver.transfer = TransferKind::APIC;
  s.solver.kernel = KernelKind::Quadratic;
  s.solver.cfl = 3;
  s.solver.max_dt = 1.0 / 120;
  s.solver.pressure.preconditioner = PressurePreconditioner::MIC0;
  s.domain.max = {1, 0.75, 0.5};
  s.domain.dx = 1.0 / 32;
  MaterialParams water;
  water.name = "water";
  water.model = ElasticModel::Fluid;
  s.materials = {water};
  BodyParams column;
  column.material = "water";
  column.min = {0, 0, 0};
  column.max = {0.3, 0.5, 0.5};
  column.particles_per_cell = 8;
  s.bodies = {column};
  ColliderParams ball;
  ball.shape = ColliderShape::Sphere;
  ball.center = {0.6, 0.15, 0.25};
  ball.radius = 0.1;
  ball.velocity = {-0.5, 0, 0};
  s.colliders = {ball};
  EmitterParams e;
  e.shape = Shape::Sphere;
  e.center = {0.8, 0.6, 0.25};
  e.radius = 0.06;
  e.rate = 0.05;
  e.velocity = {0, -1, 0};
  e.material = "water";
  e.particles_per_cell = 8;
  s.emitters = {e};
  s.validate();
  flip::FlipSolver<float, 3> sim(s);
  for (int i = 0; i < steps; ++i) sim.step(float(s.solver.max_dt));
  io::write_ply(file, sim.frame({"position", "velocity", "id"}));
  return read(file);
}

}  // namespace slurry::test
