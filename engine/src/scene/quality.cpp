// solver.quality presets (quality.h). The values come from the Pareto fronts of the study in
// benchmarks/tradeoff/ (docs/accuracy.md, "Quality presets", says which point each one is).
#include "slurry/engine/scene/quality.h"

#include <string>

namespace slurry {

namespace {

/// The knobs a preset sets. MPM and FLIP presets share the struct; each solver reads its own.
struct Preset {
  Precision precision;
  TransferKind transfer;
  KernelKind kernel;
  double cfl, elastic_cfl, max_dt;
  double particles_per_cell;
  double pressure_tolerance;  // FLIP
  PressurePreconditioner preconditioner;
  double volume_correction;
};

// MPM solids, sand and weakly compressible fluids. At a fixed dx the study found no knob that
// lowers the error much on every MPM problem, but particles per cell order them: preview halves
// the particles (about 0.6x the CPU, errors a few percent above production); production is the
// library defaults; reference doubles them and runs in double precision (about 2-3x the CPU; the
// sand's runout and the bar's period move towards the reference by a few percent, the disks do
// not change). Smaller substeps are not more accurate: each transfer dissipates a little, and the
// sand stops short. Refining dx is what buys accuracy.
constexpr Preset kMpm[] = {
    /* preview    */ {Precision::Float, TransferKind::MLS, KernelKind::Quadratic, 0.5, 0.5, 1e-3, 4, 0,
                      PressurePreconditioner::MIC0, 0},
    /* production */ {Precision::Float, TransferKind::MLS, KernelKind::Quadratic, 0.5, 0.5, 1e-3, 8, 0,
                      PressurePreconditioner::MIC0, 0},
    /* reference  */ {Precision::Double, TransferKind::MLS, KernelKind::Quadratic, 0.5, 0.5, 1e-3, 16, 0,
                      PressurePreconditioner::MIC0, 0},
};
// FLIP liquids. The error grows with the number of transfers (APIC dissipates a little each
// step): a substep of 1/240 s with cfl 1 beat the defaults (1e-3 s) on every problem at a
// fifth of the cost, the linear kernel beat the quadratic one at that step, and the multigrid
// preconditioner was the cheapest at equal error. Preview: one substep per 1/60 s frame where
// cfl 2 allows, 4 particles per cell, tolerance 1e-4 (5x cheaper than production). Reference:
// production in double precision with tolerance 1e-8, so that neither round-off nor the solve
// is an error source; at a fixed dx it is no more accurate.
constexpr Preset kFlip[] = {
    /* preview    */ {Precision::Float, TransferKind::APIC, KernelKind::Quadratic, 2, 0.5, 1.0 / 60, 4, 1e-4,
                      PressurePreconditioner::Multigrid, 0.5},
    /* production */ {Precision::Float, TransferKind::APIC, KernelKind::Linear, 1, 0.5, 1.0 / 240, 8, 1e-6,
                      PressurePreconditioner::Multigrid, 0.5},
    /* reference  */ {Precision::Double, TransferKind::APIC, KernelKind::Linear, 1, 0.5, 1.0 / 240, 8, 1e-8,
                      PressurePreconditioner::Multigrid, 0.5},
};

}  // namespace

double apply_quality(Scene& scene, std::string_view quality) {
  int index = -1;
  std::string names;
  for (int i = 0; i < int(std::size(kQualityPresets)); ++i) {
    if (quality == kQualityPresets[i]) index = i;
    names += std::string(i ? ", " : "") + "\"" + std::string(kQualityPresets[i]) + "\"";
  }
  if (index < 0)
    throw SceneError(scene.source + ": solver.quality: expected one of " + names + ", got \"" + std::string(quality) + "\"");
  SolverParams& s = scene.solver;
  if (s.type == SolverType::FEM)
    throw SceneError(scene.source + ": solver.quality: presets exist for solver.type \"mpm\" and \"flip\" (the study has no FEM "
                     "problem), got solver.type \"fem\"");
  const Preset& p = (s.type == SolverType::FLIP ? kFlip : kMpm)[index];
  s.precision = p.precision;
  s.transfer = p.transfer;
  s.kernel = p.kernel;
  s.cfl = p.cfl;
  s.max_dt = p.max_dt;
  if (s.type == SolverType::FLIP) {
    s.pressure.tolerance = p.pressure_tolerance;
    s.pressure.preconditioner = p.preconditioner;
    s.volume_correction = p.volume_correction;
  } else {
    s.elastic_cfl = p.elastic_cfl;
  }
  for (auto& b : scene.bodies) b.particles_per_cell = p.particles_per_cell;
  return p.particles_per_cell;
}

double apply_default_quality(Scene& scene) {
  return scene.solver.type == SolverType::FLIP ? apply_quality(scene, "production") : 0;
}

}  // namespace slurry
