#pragma once
/// \file communicator.h
/// What a run split over several processes needs from its message-passing layer, and nothing
/// more: the engine stays free of MPI (the solver core builds and runs without it), and
/// slurry::mpi (mpi/, OpenMPI) implements this interface with MPI_COMM_WORLD.
///
/// The split MPM solver (mpm/mpm_solver.h) cuts the domain into boxes of grid blocks, one per rank,
/// so that the exchanges of a substep (the grid nodes of the borders, particles that cross them)
/// are with the ranks whose boxes touch this one's; reductions serve the time step, the health
/// check and the run statistics, gathers the frames and checkpoints. Every call is collective:
/// all ranks make the same calls in the same order.
///
/// The split FLIP solver (flip/flip_solver.h) cuts the grid's cells into boxes the same way and
/// exchanges ghost particles and face values with the ranks near its box. A linear system too
/// large for one process (a liquid's pressure) is solved through the same layer: slurry::mpi
/// hands it to PETSc's conjugate gradients preconditioned by hypre's BoomerAMG (solve_spd), so
/// that no distributed Krylov solver is written here.
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace slurry {

/// A sparse symmetric positive (semi)definite system A x = b split by rows over the ranks: this
/// rank holds the global rows [first, first + rhs.size()), rank r's rows right after rank
/// r - 1's, in compressed rows with global column indices.
struct DistributedSystem {
  std::int64_t first = 0;
  std::vector<std::int64_t> row_start{0};  ///< rhs.size() + 1 offsets into columns and values
  std::vector<std::int64_t> columns;
  std::vector<double> values;
  std::vector<double> rhs;
  /// A's null space is the constant vector (the pressure of a closed container): b's component
  /// along it is removed and x is the solution orthogonal to it.
  bool constant_null_space = false;
};

/// What solve_spd did: iterations, the final ||b - A x|| / ||b||, and whether it met rtol.
struct DistributedSolve {
  int iterations = 0;
  double residual = 0;
  bool converged = false;
};

class Communicator {
 public:
  virtual ~Communicator() = default;
  /// This process's index in [0, size()).
  virtual int rank() const = 0;
  virtual int size() const = 0;
  /// Element-wise sum over the ranks of values[0, n), in place; the same result on every rank.
  virtual void sum(double* values, int n) = 0;
  /// Element-wise maximum over the ranks, in place.
  virtual void max(double* values, int n) = 0;
  /// Sends out[i] to rank peers[i] and returns what each peers[i] sent this rank, in the same
  /// order. The lists must be mutual (rank a names b exactly when b names a); peers are distinct
  /// and exclude this rank; a message may be empty.
  virtual std::vector<std::string> exchange(const std::vector<int>& peers,
                                            const std::vector<std::string>& out) = 0;
  /// Every rank's `mine`, in rank order, on every rank.
  virtual std::vector<std::string> all_gather(const std::string& mine) = 0;
  /// Every rank's `mine`, in rank order, on rank 0; an empty list on the others.
  virtual std::vector<std::string> gather(const std::string& mine) = 0;
  /// Returns when every rank has called it.
  virtual void barrier() = 0;
  /// Solves A x = b (A symmetric positive definite, or semidefinite with constant_null_space) by
  /// conjugate gradients with an algebraic multigrid preconditioner, to ||b - A x|| <= rtol ||b||
  /// or max_iterations; x is this rank's rows of the solution, its start value on entry (resized
  /// to the rank's rows if it differs). Throws std::logic_error where this layer has no
  /// distributed solver.
  virtual DistributedSolve solve_spd(const DistributedSystem& A, std::vector<double>& x, double rtol,
                                     int max_iterations) {
    (void)A, (void)x, (void)rtol, (void)max_iterations;
    throw std::logic_error("this build has no distributed linear solver (slurry::mpi without PETSc)");
  }

  /// Payload bytes this rank has sent through exchange() (the grid halo's nodes and migrating
  /// particles), for the scaling figures of benchmarks/.
  std::uint64_t exchanged_bytes() const { return exchanged_bytes_; }

 protected:
  std::uint64_t exchanged_bytes_ = 0;
};

}  // namespace slurry
