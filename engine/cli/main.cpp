// slurry: run or check a scene file. One file per subcommand:
//
//   slurry run SCENE.json [--out DIR] [--frames N] [--threads N] [--memory-limit GB] [--overwrite] [--ascii] [--quiet]
//                         [--resume [--force]]                                        run_command.cpp
//   slurry resume DIR [--frames N] [--threads N] [--memory-limit GB] [--ascii] [--quiet] [--force]
//                                                                                     resume_command.cpp
//   slurry validate SCENE.json [--memory-limit GB]                                    validate_command.cpp
//   slurry surface DIR [--scene S] [--voxel-size H] [--spacing S] [--method M] [--smoothing N] [--formats vdb,ply,obj] [--points]
//                      (built with OpenVDB, SLURRY_WITH_OPENVDB=ON)                    pipeline.cpp
//   slurry merge DIR [--keep-parts]   joins per-rank frames into frame_NNNN.ply       merge_command.cpp
//   mpirun -np N slurry run SCENE.json ...   (built with slurry::mpi, SLURRY_BUILD_MPI=ON): the MPM
//                      domain split over N processes; rank 0 writes the frames and prints the log
//                      (with output.per_rank each process writes frame_NNNN.rankR.ply instead)
//
// Exit codes: 0 success, 1 the simulation became unstable, 2 invalid scene or usage, 3 file or
// resource error, 130 / 143 stopped by SIGINT / SIGTERM after the last complete frame.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "command.h"
#include "merge_command.h"
#include "resume_command.h"
#include "run_command.h"
#include "validate_command.h"
#ifdef SLURRY_WITH_OPENVDB
#include "pipeline.h"
#endif
#ifdef SLURRY_WITH_MPI
#include "slurry/mpi/mpi.h"
#endif

int main(int argc, char** argv) {
  using namespace slurry::cli;
  // Started by mpirun (or another MPI launcher): MPI first, since it may take its own arguments.
  Process process;
#ifdef SLURRY_WITH_MPI
  std::unique_ptr<slurry::mpi::Session> mpi;
  if (slurry::mpi::launched()) {
    try {
      mpi = std::make_unique<slurry::mpi::Session>(argc, argv);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "slurry: error: %s\n", e.what());
      return 3;
    }
    process.rank = mpi->rank();
    process.ranks = mpi->size();
    process.mpi = mpi.get();
  }
#else
  if (const char* n = std::getenv("OMPI_COMM_WORLD_SIZE"); n && std::atoi(n) > 1) {
    std::fprintf(stderr, "slurry: error: started by mpirun with %s processes, but this slurry was built without MPI "
                 "(SLURRY_BUILD_MPI=OFF); expected one process, or a build with slurry::mpi\n", n);
    return 2;
  }
#endif
  CLI::App app{"slurry: hybrid particle-grid simulation (MPM solids and liquids)"};
  app.require_subcommand(1);
  RunCommand run;
  run.add(app);
  ResumeCommand resume;
  resume.add(app);
  MergeCommand merge;
  merge.add(app);
  ValidateCommand validate;
  validate.add(app);
#ifdef SLURRY_WITH_OPENVDB
  SurfaceCommand surface;
  add_surface_command(app, surface);
#endif

  try {
    app.parse(argc, argv);
    if (run.app->parsed()) run.check();
    if (resume.app->parsed()) resume.check();
    if (validate.app->parsed()) validate.check();
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return process.rank == 0 ? app.exit(e) : 0;  // --help
    if (process.rank == 0) std::fprintf(stderr, "slurry: error: %s (usage: slurry --help)\n", e.what());
    return 2;
  } catch (const UsageError& e) {
    if (process.rank == 0) std::fprintf(stderr, "slurry: error: %s\n", e.what());
    return 2;
  }

#ifdef SLURRY_WITH_OPENVDB
  if (surface.app->parsed()) {
    try {
      return pipeline_module().run_surface_command(surface);
    } catch (const slurry::IoError& e) {
      return process.report(false, 3, e.what());
    }
  }
#endif
  if (merge.app->parsed()) return merge.run(process);
  if (validate.app->parsed()) return validate.run(process);
  return run_request(process, resume.app->parsed() ? resume.request : run.request);
}
