#pragma once
/// \file mpi.h
/// slurry::mpi: runs split over processes with MPI (OpenMPI from Debian). `Session` starts MPI
/// in a process that an MPI launcher started (mpirun, mpiexec, srun) and is the engine's
/// Communicator (communicator.h) over MPI_COMM_WORLD; pass it as RunOptions::communicator.
///
///   slurry::mpi::Session mpi(argc, argv);   // MPI_Init_thread ... MPI_Finalize
///   slurry::RunOptions options;
///   options.communicator = &mpi;
///   slurry::run_scene(scene, options);      // on every rank; rank 0 writes the frames
///
/// Neighbour exchanges are non-blocking point-to-point messages (sizes first, then the bytes in
/// pieces of at most 1 GiB); gathers are MPI_Gatherv / MPI_Allgatherv; sums and maxima
/// MPI_Allreduce. Only the calling thread talks to MPI (MPI_THREAD_FUNNELED): the solver's
/// worker threads never do. This header does not include <mpi.h>.
#include <string>
#include <utility>
#include <vector>

#include "slurry/engine/communicator.h"

namespace slurry::mpi {

/// Whether an MPI launcher started this process (its environment names the job's size: mpirun's
/// OMPI_COMM_WORLD_SIZE, a PMI/PMIx launcher's PMI_SIZE or PMIX_RANK, Slurm's srun). A process
/// started otherwise runs without MPI, as the plain CLI does.
bool launched();

class Session final : public Communicator {
 public:
  /// Initialises MPI (once per process). Throws std::runtime_error if MPI cannot start.
  Session(int& argc, char**& argv);
  /// MPI_Finalize.
  ~Session() override;
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  int rank() const override { return rank_; }
  int size() const override { return size_; }
  void sum(double* values, int n) override;
  void max(double* values, int n) override;
  std::vector<std::string> exchange(const std::vector<int>& peers,
                                    const std::vector<std::string>& out) override;
  std::vector<std::string> all_gather(const std::string& mine) override;
  std::vector<std::string> gather(const std::string& mine) override;
  void barrier() override;
  /// PETSc's KSPCG with hypre's BoomerAMG (PCHYPRE; strong threshold 0.5, hypre's advice for 3D
  /// Laplacians, unless PETSC_OPTIONS sets it), the unpreconditioned residual norm; PETSc starts
  /// on the first call, without its signal handlers, and stops with the session. The options
  /// database (PETSC_OPTIONS, e.g. -ksp_view or -pc_type gamg) applies on top. Throws
  /// std::logic_error in a build without PETSc (SLURRY_MPI_WITH_PETSC unset).
  DistributedSolve solve_spd(const DistributedSystem& A, std::vector<double>& x, double rtol,
                             int max_iterations) override;

  /// Ranks on this machine (OMPI_COMM_WORLD_LOCAL_SIZE; 1 if the launcher does not say), to
  /// share its cores among them.
  int local_size() const { return local_size_; }
  /// Ends every rank of the job with this exit code (MPI_Abort): for an error that only this
  /// rank met, while the others wait for it in a collective call.
  [[noreturn]] void abort(int code);

 private:
  int rank_ = 0, size_ = 1, local_size_ = 1;
  bool petsc_ = false;  // PETSc started by solve_spd
  void finalize_petsc();
};

}  // namespace slurry::mpi
