#include "slurry/mpi/mpi.h"

#include <mpi.h>

#include <algorithm>
#include <climits>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <vector>

namespace slurry::mpi {
namespace {

constexpr int kSizeTag = 7301, kDataTag = 7302;
/// Point-to-point messages go in pieces of at most this many bytes (MPI counts are int).
constexpr std::size_t kPiece = std::size_t(1) << 30;

void check(int code, const char* what) {
  if (code == MPI_SUCCESS) return;
  char text[MPI_MAX_ERROR_STRING];
  int length = 0;
  MPI_Error_string(code, text, &length);
  throw std::runtime_error(std::string("MPI: ") + what +
                           " failed: " + std::string(text, std::size_t(length)));
}

/// Displacements of a gather's pieces; refuses a total beyond MPI's int counts.
std::vector<int> displacements(const std::vector<int>& sizes, const char* what) {
  std::vector<int> at(sizes.size(), 0);
  long long total = 0;
  for (std::size_t r = 0; r < sizes.size(); ++r) {
    at[r] = int(total);
    total += sizes[r];
    if (total > INT_MAX)
      throw std::runtime_error(std::string("MPI: ") + what +
                               ": the ranks' data exceed 2 GiB, more than one gather takes");
  }
  return at;
}

std::vector<std::string> split(const std::string& all, const std::vector<int>& sizes,
                               const std::vector<int>& at) {
  std::vector<std::string> parts(sizes.size());
  for (std::size_t r = 0; r < sizes.size(); ++r)
    parts[r] = all.substr(std::size_t(at[r]), std::size_t(sizes[r]));
  return parts;
}

int mine_size(const std::string& mine) {
  if (mine.size() > std::size_t(INT_MAX))
    throw std::runtime_error("MPI: a rank's part of a gather exceeds 2 GiB");
  return int(mine.size());
}

}  // namespace

bool launched() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK", "MPI_LOCALNRANKS"})
    if (std::getenv(name)) return true;
  return false;
}

Session::Session(int& argc, char**& argv) {
  int initialised = 0;
  MPI_Initialized(&initialised);
  if (!initialised) {
    int provided = 0;
    check(MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
  }
  MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  if (const char* local = std::getenv("OMPI_COMM_WORLD_LOCAL_SIZE"))
    local_size_ = std::max(1, std::atoi(local));
}

Session::~Session() {
  finalize_petsc();
  int finalised = 0;
  MPI_Finalized(&finalised);
  if (!finalised) MPI_Finalize();
}

void Session::sum(double* values, int n) {
  check(MPI_Allreduce(MPI_IN_PLACE, values, n, MPI_DOUBLE, MPI_SUM, MPI_COMM_WORLD),
        "MPI_Allreduce (sum)");
}

void Session::max(double* values, int n) {
  check(MPI_Allreduce(MPI_IN_PLACE, values, n, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD),
        "MPI_Allreduce (max)");
}

std::vector<std::string> Session::exchange(const std::vector<int>& peers,
                                           const std::vector<std::string>& out) {
  if (peers.size() != out.size())
    throw std::invalid_argument("MPI: exchange: one message per peer expected");
  const std::size_t n = peers.size();
  // Sizes first, so that each side can receive into a buffer of the right length.
  std::vector<std::uint64_t> send(n), recv(n, 0);
  std::vector<MPI_Request> requests(2 * n);
  for (std::size_t i = 0; i < n; ++i) {
    send[i] = out[i].size();
    check(MPI_Irecv(&recv[i], 1, MPI_UINT64_T, peers[i], kSizeTag, MPI_COMM_WORLD, &requests[i]),
          "MPI_Irecv");
    check(MPI_Isend(&send[i], 1, MPI_UINT64_T, peers[i], kSizeTag, MPI_COMM_WORLD,
                    &requests[n + i]),
          "MPI_Isend");
  }
  if (n) check(MPI_Waitall(int(2 * n), requests.data(), MPI_STATUSES_IGNORE), "MPI_Waitall");
  std::vector<std::string> got(n);
  requests.clear();
  auto post = [&](bool receive, char* data, std::size_t bytes, int peer) {
    for (std::size_t at = 0, piece = 0; at < bytes; at += kPiece, ++piece) {
      const int count = int(std::min(kPiece, bytes - at));
      requests.emplace_back();
      const int tag = kDataTag + int(piece % 1000);
      check(receive ? MPI_Irecv(data + at, count, MPI_BYTE, peer, tag, MPI_COMM_WORLD,
                                &requests.back())
                    : MPI_Isend(data + at, count, MPI_BYTE, peer, tag, MPI_COMM_WORLD,
                                &requests.back()),
            receive ? "MPI_Irecv" : "MPI_Isend");
    }
  };
  for (std::size_t i = 0; i < n; ++i) {
    got[i].resize(std::size_t(recv[i]));
    post(true, got[i].data(), got[i].size(), peers[i]);
  }
  for (std::size_t i = 0; i < n; ++i)
    post(false, const_cast<char*>(out[i].data()), out[i].size(), peers[i]);
  if (!requests.empty())
    check(MPI_Waitall(int(requests.size()), requests.data(), MPI_STATUSES_IGNORE), "MPI_Waitall");
  for (const auto& m : out) exchanged_bytes_ += m.size();
  return got;
}

std::vector<std::string> Session::all_gather(const std::string& mine) {
  int n = mine_size(mine);
  std::vector<int> sizes(std::size_t(size_), 0);
  check(MPI_Allgather(&n, 1, MPI_INT, sizes.data(), 1, MPI_INT, MPI_COMM_WORLD), "MPI_Allgather");
  const auto at = displacements(sizes, "all_gather");
  std::string all(std::size_t(at.back()) + std::size_t(sizes.back()), '\0');
  check(MPI_Allgatherv(mine.data(), n, MPI_BYTE, all.data(), sizes.data(), at.data(), MPI_BYTE,
                       MPI_COMM_WORLD),
        "MPI_Allgatherv");
  return split(all, sizes, at);
}

std::vector<std::string> Session::gather(const std::string& mine) {
  int n = mine_size(mine);
  std::vector<int> sizes(std::size_t(size_), 0);
  check(MPI_Gather(&n, 1, MPI_INT, sizes.data(), 1, MPI_INT, 0, MPI_COMM_WORLD), "MPI_Gather");
  std::vector<int> at(sizes.size(), 0);
  std::string all;
  if (rank_ == 0) {
    at = displacements(sizes, "gather");
    all.resize(std::size_t(at.back()) + std::size_t(sizes.back()));
  }
  check(MPI_Gatherv(mine.data(), n, MPI_BYTE, all.data(), sizes.data(), at.data(), MPI_BYTE, 0,
                    MPI_COMM_WORLD),
        "MPI_Gatherv");
  if (rank_ != 0) return {};
  return split(all, sizes, at);
}

void Session::barrier() {
  check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
}

void Session::abort(int code) {
  MPI_Abort(MPI_COMM_WORLD, code);
  std::_Exit(code);
}

}  // namespace slurry::mpi
