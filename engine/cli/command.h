#pragma once
// What the slurry CLI's subcommands share: option parsing helpers, the process's place in an
// mpirun job, and the mapping of errors to exit codes (0 success, 1 the simulation became
// unstable, 2 invalid scene or usage, 3 file or resource error).
#include <new>
#include <stdexcept>
#include <string>

#include "slurry/engine/errors.h"

namespace slurry::mpi {
class Session;
}

namespace slurry::cli {

/// A command line that parsed but asks for something invalid: exit code 2.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// A command-line integer in [lo, hi], or a UsageError naming the option and the range.
long long parse_integer(const std::string& option, const std::string& text, long long lo, long long hi);
/// A command-line number > 0, or a UsageError naming the option.
double parse_positive(const std::string& option, const std::string& text);
/// "12.3 s", "4m05s", "2h07m".
std::string human_seconds(double s);

/// This process in an mpirun job (rank 0 of 1 otherwise) and how it reports an error.
struct Process {
  int rank = 0, ranks = 1;
  slurry::mpi::Session* mpi = nullptr;  ///< the MPI session when started by mpirun (SLURRY_WITH_MPI)
  /// Prints "slurry: error: <what>" (rank 0 alone for a collective error: every rank met it;
  /// every rank for its own, which then ends the whole job) and returns `code`.
  int report(bool collective, int code, const char* what) const;
};

/// Runs `body` (which returns the exit code) and maps the engine's errors to exit codes:
/// SimulationError 1 and SceneError 2 (collective: every rank meets them), IoError (and
/// ResourceError) 3, out of memory 3 naming `scene_path` as it is when the error is caught.
template <class Body>
int with_exit_codes(const Process& process, const std::string& scene_path, Body&& body) {
  try {
    return body();
  } catch (const SimulationError& e) {
    return process.report(true, 1, e.what());  // the health check is global: every rank stops here
  } catch (const SceneError& e) {
    return process.report(true, 2, e.what());  // every rank reads the same scene
  } catch (const IoError& e) {
    return process.report(false, 3, e.what());
  } catch (const std::bad_alloc&) {
    const std::string what = scene_path + ": out of memory (the estimate before the run was too low; lower the scene's "
                             "resolution or limits.memory_gb)";
    return process.report(false, 3, what.c_str());
  }
}

}  // namespace slurry::cli
