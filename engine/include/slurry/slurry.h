#pragma once
/// \file slurry.h
/// Everything a program that embeds Slurry needs (README, "Using Slurry from C++"): scenes
/// (built in code or read from JSON), make_simulation and the typed particle view, run_scene with
/// its frame callback, run statistics, PLY frames and the error types. It does not include the
/// solver classes (slurry/engine/simulation.h, flip/, fem/), the grid or the threading backend.
#include "slurry/engine/errors.h"
#include "slurry/engine/ply.h"
#include "slurry/engine/run.h"
#include "slurry/engine/scene.h"
#include "slurry/engine/simulation_base.h"
#include "slurry/engine/stats.h"
