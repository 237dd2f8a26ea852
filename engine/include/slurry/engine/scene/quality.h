#pragma once
/// \file quality.h
/// `solver.quality` presets: "preview", "production", "reference". A preset sets the solver knobs
/// (and the default particles_per_cell of bodies) that the speed-against-accuracy study
/// (benchmarks/tradeoff/) found on the Pareto front of error against CPU time for its budget;
/// keys written in the scene still win (the scene parser applies the preset first). The values
/// and the error each gives on the study's problems are listed in docs/accuracy.md ("Quality
/// presets"). Grid spacing is not part of a preset: it is the scene's resolution.
#include <string_view>

#include "slurry/engine/scene/scene.h"

namespace slurry {

/// The names solver.quality accepts.
inline constexpr std::string_view kQualityPresets[] = {"preview", "production", "reference"};

/// Sets the knobs of preset `quality` for scene.solver.type in scene.solver and the
/// particles_per_cell of every body already in the scene, and returns that particles_per_cell
/// (parse_scene makes it the default of the bodies and emitters it reads afterwards). Throws
/// SceneError naming `scene.source`, `solver.quality`, the value and the allowed names for an
/// unknown name, and for solver.type "fem" (no preset was measured for it).
double apply_quality(Scene& scene, std::string_view quality);

/// The knobs of a scene that names no solver.quality: for solver.type "flip" those of
/// "production" (apply_quality(scene, "production")), since the SolverParams initializers, which
/// are MPM's, cost 3.8-9.5x as much CPU on the study's liquids for the same or a larger error
/// (docs/accuracy.md); for "mpm" nothing ("production" is the initializers) and for "fem"
/// nothing. parse_scene calls it after reading solver.type, before the other solver keys; a
/// FLIP scene built in C++ calls it after setting solver.type to get the library's defaults.
/// Returns the particles_per_cell it set (0 if none).
double apply_default_quality(Scene& scene);

}  // namespace slurry
