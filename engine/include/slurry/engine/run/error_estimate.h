#pragma once
/// \file error_estimate.h
/// A run's estimate of its own discretization error (output.error_estimate): a shadow
/// simulation of the same scene at twice domain.dx runs beside the main one, and at every frame
/// the difference of a quantity Q between the two gives Richardson's estimate of the main run's
/// error in Q (Richardson 1911; Roache 1998, "Verification and validation in computational
/// science and engineering", as the grid-convergence error estimate):
///   |Q(dx) - Q_exact| ~ |Q(dx) - Q(2 dx)| / (2^p - 1)
/// for a quantity converging at order p in dx (output.error_order). The quantities:
///   error_energy    of the total energy kinetic + potential + elastic (J), from the energies
///                   per unit mass of the two runs times the main run's mass (the two seed
///                   slightly different masses);
///   error_centroid  the largest over materials of the distance between the centroids of the
///                   material's particles (m).
/// The estimate is of the discretization error only: a model that differs from the experiment
/// (docs/accuracy.md) is not seen. It assumes both resolutions are in the asymptotic range,
/// which the coarse one of a scene resolved by a few cells is not.
#include <memory>

#include "slurry/engine/scene/scene.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/stats.h"

namespace slurry {

/// The shadow's scene: domain.dx doubled; MPM walls keep their thickness in metres
/// (boundaries.thickness halved, rounded, at least 1 cell); no outputs, checkpoints or estimate.
/// domain.max is rounded up to whole cells of the doubled dx, so a far wall may lie up to one
/// cell of the main run further out.
Scene shadow_scene(const Scene& scene);

class ErrorEstimator {
 public:
  /// Builds the shadow simulation of `scene` (make_simulation of shadow_scene()).
  explicit ErrorEstimator(const Scene& scene);
  /// With a shadow built by the caller from shadow_scene(scene) (e.g. given the same initial
  /// velocity field as the main solver).
  ErrorEstimator(std::unique_ptr<Solver> shadow, const Scene& scene);
  ~ErrorEstimator();
  /// Advances the shadow to time t (s); call it with the main run's frame times in order.
  void advance_to(double t);
  /// Sets stats.error_energy and stats.error_centroid for the main solver `main` at the
  /// shadow's time, `stats` being the main run's figures of this frame.
  void estimate(const Solver& main, RunStats& stats);

 private:
  std::unique_ptr<Solver> shadow_;
  int dimension_;
  double factor_;  ///< 1 / (2^p - 1)
};

}  // namespace slurry
