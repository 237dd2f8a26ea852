#pragma once
/// \file slurry.h
/// Everything a program that embeds Slurry needs (docs/cpp-api.md): scenes (built in code or
/// read from JSON with load_scene), make_simulation and the typed particle view, frames as
/// format-free tables, run_scene with its frame callback, run statistics and the error types. It
/// includes no file-format, checkpoint or MPI header, nor the solver classes (mpm/, flip/, fem/),
/// the grid or the threading backend; PLY files are slurry/io/ply.h.
#include "slurry/engine/errors.h"
#include "slurry/engine/frame.h"
#include "slurry/engine/run/run.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/stats.h"
#include "slurry/io/scene_file.h"
