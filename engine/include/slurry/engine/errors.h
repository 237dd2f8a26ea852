#pragma once
/// \file errors.h
/// Typed exceptions thrown at Slurry's boundaries (scene files, file I/O, API entry points and
/// the run-time health checks). Each message says what was wrong, where, and what was expected.
#include <stdexcept>
#include <string>

namespace slurry {

/// Base of every exception Slurry throws on purpose.
struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// A scene file (or a parameter struct built in code) is invalid: names the file, the JSON path
/// and what was expected.
struct SceneError : Error {
  using Error::Error;
};

/// Reading or writing a file failed: names the file and the reason.
struct IoError : Error {
  using Error::Error;
};

/// A scene asks for more than the machine or the configured limits give (memory, particles, grid
/// cells, mesh elements, threads); checked before anything is allocated. An IoError, so that it
/// exits like a file error (CLI exit code 3).
struct ResourceError : IoError {
  using IoError::IoError;
};

/// The simulation became unhealthy (non-finite state, CFL violation, particle left the domain):
/// names the step, the time, the particle index and its material.
struct SimulationError : Error {
  using Error::Error;
};

}  // namespace slurry
