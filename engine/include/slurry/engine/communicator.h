#pragma once
/// \file communicator.h
/// What a run split over several processes needs from its message-passing layer, and nothing
/// more: the engine stays free of MPI (the solver core builds and runs without it), and
/// slurry::mpi (mpi/, OpenMPI) implements this interface with MPI_COMM_WORLD.
///
/// The split MPM solver (mpm/mpm_solver.h) cuts the domain into slabs of grid-block columns along
/// its longest axis, one slab per rank in rank order, so that every exchange (the grid nodes of
/// the borders, particles that cross them) is with the two neighbouring ranks; reductions serve the time step, the health check and the
/// run statistics, gathers the frames and checkpoints. Every call is collective: all ranks make
/// the same calls in the same order.
#include <cstdint>
#include <string>
#include <utility>
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
  /// Sends `to_lower` to rank - 1 and `to_upper` to rank + 1 (nothing beyond the first and the
  /// last rank) and returns {what rank - 1 sent, what rank + 1 sent} (empty beyond the ends).
  virtual std::pair<std::string, std::string> exchange(const std::string& to_lower,
                                                       const std::string& to_upper) = 0;
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
