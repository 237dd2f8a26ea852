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
#include <cstdint>
#include <string>
#include <vector>

namespace slurry {

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

  /// Payload bytes this rank has sent through exchange() (the grid halo's nodes and migrating
  /// particles), for the scaling figures of benchmarks/.
  std::uint64_t exchanged_bytes() const { return exchanged_bytes_; }

 protected:
  std::uint64_t exchanged_bytes_ = 0;
};

}  // namespace slurry
