#pragma once
// The MPM domain split over processes (private to the engine): boxes of grid blocks balanced by
// particle counts, and whole particles packed into bytes for another rank and unpacked there.
//
// A rank owns the particles whose stencil base node lies in its box of grid blocks (blocks.h);
// the grid halo that joins the boxes' node sums is in distribution.h.
#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "slurry/engine/errors.h"
#include "slurry/engine/mpm/particles.h"
#include "slurry/transfer/lattice.h"

namespace slurry::detail {

/// Borders of `ranks` slabs of consecutive columns over columns [0, counts.size()), each holding
/// about sum(counts) / ranks particles: rank r owns [cuts[r], cuts[r + 1]). Every slab has at least
/// one column (so that a particle, which moves less than a column per substep, only ever passes
/// to a neighbouring rank); requires ranks <= counts.size(). The same counts give the same cuts on
/// every rank.
inline std::vector<int> balanced_cuts(const std::vector<double>& counts, int ranks) {
  const int columns = int(counts.size());
  std::vector<int> cuts(std::size_t(ranks) + 1, 0);
  cuts[std::size_t(ranks)] = columns;
  double total = 0;
  for (const double c : counts) total += c;
  double below = 0;  // particles in columns [0, k)
  int k = 0;
  for (int r = 1; r < ranks; ++r) {
    const double target = total * r / ranks;
    // The border after which the first r slabs hold closest to r / ranks of the particles, at
    // least one column past the previous border and leaving one column for each later slab.
    const int lo = cuts[std::size_t(r) - 1] + 1, hi = columns - (ranks - r);
    while (k < lo) below += counts[std::size_t(k++)];
    while (k < hi && below + counts[std::size_t(k)] <= target) below += counts[std::size_t(k++)];
    if (k < hi && target - below > below + counts[std::size_t(k)] - target)
      below += counts[std::size_t(k++)];
    cuts[std::size_t(r)] = k;
  }
  return cuts;
}

/// Processes along each axis for `ranks` processes over a lattice of `blocks` grid blocks: of the
/// factorisations ranks = p_0 ... p_{Dim-1} with every p_a <= blocks[a], the one whose cuts cross
/// the fewest block faces, sum_a (p_a - 1) x (the lattice's section across a), so that a cube is
/// cut into boxes and a long channel into slabs; among equals, the most processes along the
/// lowest axis. Empty if no factorisation fits (more processes than the lattice can give a block
/// each along some axis).
template <int Dim>
std::vector<int> process_grid(int ranks, const Eigen::Matrix<int, Dim, 1>& blocks) {
  std::vector<int> best, p(Dim, 1);
  double best_faces = std::numeric_limits<double>::infinity();
  std::function<void(int, int)> place = [&](int axis, int left) {
    if (axis == Dim - 1) {
      if (left > blocks[axis]) return;
      p[std::size_t(axis)] = left;
      double faces = 0;
      for (int a = 0; a < Dim; ++a) {
        double section = 1;
        for (int b = 0; b < Dim; ++b)
          if (b != a) section *= blocks[b];
        faces += (p[std::size_t(a)] - 1) * section;
      }
      if (faces < best_faces) best_faces = faces, best = p;
      return;
    }
    for (int n = std::min(left, int(blocks[axis])); n >= 1; --n)
      if (left % n == 0) p[std::size_t(axis)] = n, place(axis + 1, left / n);
  };
  place(0, ranks);
  return best;
}

/// The split of a lattice of grid blocks into boxes, one per rank: cut along the axis with the
/// most processes into slabs of whole block columns, each slab along the next axis into pencils,
/// each pencil along the last (3D) into boxes, every cut balanced by the particle counts of what
/// it cuts (balanced_cuts). Rank r is the box reached by the digits of r in the mixed radix of
/// the processes per cut axis, the first cut's digit the most significant. Every box is at least
/// one block thick along every axis, so a particle, which moves less than a block per substep,
/// only ever passes to a rank whose box touches its own.
template <int Dim>
struct BoxSplit {
  using IVec = Eigen::Matrix<int, Dim, 1>;
  IVec res = IVec::Zero();    ///< blocks along each axis
  IVec procs = IVec::Ones();  ///< processes along each axis
  std::array<int, Dim> order{};  ///< the axes in the order they are cut
  /// cuts[k]: for each box of level k (boxes(k) of them, those that the cuts before level k make),
  /// the procs[order[k]] + 1 borders of its parts along axis order[k].
  std::array<std::vector<int>, Dim> cuts;

  BoxSplit() = default;
  BoxSplit(const IVec& blocks, const std::vector<int>& per_axis) : res(blocks) {
    for (int a = 0; a < Dim; ++a) procs[a] = per_axis[std::size_t(a)], order[std::size_t(a)] = a;
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return procs[a] > procs[b]; });
  }
  int ranks() const { return procs.prod(); }
  /// Boxes before level k's cuts.
  int boxes(int k) const {
    int n = 1;
    for (int j = 0; j < k; ++j) n *= procs[order[std::size_t(j)]];
    return n;
  }
  /// The level-k box (index in [0, boxes(k))) that holds block b: the cuts of levels < k applied.
  int box_of(const IVec& b, int k) const {
    int at = 0;
    for (int j = 0; j < k; ++j) {
      const int a = order[std::size_t(j)], n = procs[a];
      const int* c = cuts[std::size_t(j)].data() + std::size_t(at) * std::size_t(n + 1);
      const int i = int(std::upper_bound(c + 1, c + n, b[a]) - (c + 1));
      at = at * n + i;
    }
    return at;
  }
  /// Places every level's cuts by the particle counts per block in `lattice` (linear index, the
  /// last axis fastest): level k cuts each box the levels before it made, along axis order[k],
  /// by balanced_cuts of that box's counts per block column. `sum`, if given, adds a level's
  /// column counts over the ranks in place (for a lattice of this rank's particles only); every
  /// rank must then call cut alike. Returns each rank's particles.
  std::vector<double> cut(const std::vector<double>& lattice,
                          const std::function<void(std::vector<double>&)>& sum = {}) {
    std::vector<double> per_rank(std::size_t(ranks()), 0.0);
    for (int k = 0; k < Dim; ++k) {
      const int a = order[std::size_t(k)], n = procs[a], parts = boxes(k);
      const std::size_t columns = std::size_t(res[a]);
      std::vector<double> counts(std::size_t(parts) * columns, 0.0);
      for (std::size_t j = 0; j < lattice.size(); ++j) {
        if (lattice[j] == 0) continue;
        const IVec b = transfer::lattice_coord<Dim>(std::int64_t(j), res);
        counts[std::size_t(box_of(b, k)) * columns + std::size_t(b[a])] += lattice[j];
      }
      if (sum) sum(counts);
      auto& level = cuts[std::size_t(k)];
      level.clear();
      for (int i = 0; i < parts; ++i) {
        const auto first = counts.begin() + std::ptrdiff_t(std::size_t(i) * columns);
        const std::vector<double> column(first, first + std::ptrdiff_t(columns));
        const auto c = balanced_cuts(column, n);
        level.insert(level.end(), c.begin(), c.end());
        if (k == Dim - 1)
          for (int r = 0; r < n; ++r)
            for (int j = c[std::size_t(r)]; j < c[std::size_t(r) + 1]; ++j)
              per_rank[std::size_t(i * n + r)] += column[std::size_t(j)];
      }
    }
    return per_rank;
  }
  /// The rank owning block b (any block of the lattice; outside it, the nearest box's).
  int owner(const IVec& b) const { return box_of(b, Dim); }
  /// Rank r's box of blocks, [lo, hi).
  void box(int r, IVec& lo, IVec& hi) const {
    std::array<int, Dim> digit{};
    for (int k = Dim - 1; k >= 0; --k) {
      const int n = procs[order[std::size_t(k)]];
      digit[std::size_t(k)] = r % n, r /= n;
    }
    int at = 0;
    for (int k = 0; k < Dim; ++k) {
      const int a = order[std::size_t(k)], n = procs[a];
      const int* c = cuts[std::size_t(k)].data() + std::size_t(at) * std::size_t(n + 1);
      lo[a] = c[digit[std::size_t(k)]], hi[a] = c[digit[std::size_t(k)] + 1];
      at = at * n + digit[std::size_t(k)];
    }
  }
};

/// How a message stores a ScalarChannel: a flag (1 = one value for every particle) and that value.
template <class T>
void pack_scalar_layout(const ScalarChannel<T>& c, std::string& out) {
  const std::uint8_t uniform = c.uniform() ? 1 : 0;
  const T value = c.uniform() ? c.value() : T(0);
  out.append(reinterpret_cast<const char*>(&uniform), sizeof uniform);
  out.append(reinterpret_cast<const char*>(&value), sizeof value);
}

/// Reads what pack_scalar_layout wrote and makes P's channel `c` store the same way: an empty
/// set takes the message's layout; a set with particles must already have it (ranks of one run
/// seed or load the same particles, so they decide alike whether mass and rest volume are
/// uniform, and only particles of the run move between them).
template <class T>
void unpack_scalar_layout(std::string_view in, std::size_t& at, ScalarChannel<T>& c,
                          std::size_t count, const char* name) {
  std::uint8_t uniform = 0;
  T value = T(0);
  if (in.size() - at < sizeof uniform + sizeof value)
    throw SimulationError("a message of particles from another rank is truncated");
  std::memcpy(&uniform, in.data() + at, sizeof uniform);
  std::memcpy(static_cast<void*>(&value), in.data() + at + sizeof uniform, sizeof value);
  at += sizeof uniform + sizeof value;
  if (count == 0) {
    c.assign_uniform(value);
    if (!uniform) c.materialize(0);
    return;
  }
  if (bool(uniform) != c.uniform() || (uniform && !ScalarChannel<T>::same_bits(value, c.value())))
    throw SimulationError(std::string("a message of particles from another rank stores ") + name +
                          (uniform ? " as one value for every particle" : " per particle") +
                          ", where this rank stores " +
                          (c.uniform() ? "one value for every particle" : "it per particle") +
                          (uniform && c.uniform() ? " of another value" : ""));
}

/// Appends the particles `which` (every stored channel) to `out`: a count, how mass and rest
/// volume are stored (once, with the value, or per particle), then channel after channel in
/// Particles::for_each_channel order. Ranks of one run store the same channels.
template <class T, int Dim>
void pack_particles(const Particles<T, Dim>& P, const std::vector<std::uint32_t>& which,
                    std::string& out) {
  const std::uint64_t n = which.size();
  out.append(reinterpret_cast<const char*>(&n), sizeof n);
  pack_scalar_layout(P.m, out);
  pack_scalar_layout(P.vol0, out);
  P.for_each_channel([&](const auto& channel) {
    using V = typename std::decay_t<decltype(channel)>::value_type;
    const std::size_t at = out.size();
    out.resize(at + which.size() * sizeof(V));
    char* dst = out.data() + at;
    for (std::size_t i = 0; i < which.size(); ++i, dst += sizeof(V))
      std::memcpy(dst, static_cast<const void*>(&channel[which[i]]), sizeof(V));
  });
}

/// Appends the particles packed in `in` (by pack_particles with the same channels) to P. An
/// empty P takes the message's way of storing mass and rest volume; otherwise it must match.
template <class T, int Dim>
void unpack_particles(std::string_view in, Particles<T, Dim>& P) {
  if (in.empty()) return;
  std::uint64_t n = 0;
  if (in.size() < sizeof n)
    throw SimulationError("a message of particles from another rank is truncated");
  std::memcpy(&n, in.data(), sizeof n);
  std::size_t at = sizeof n;
  unpack_scalar_layout(in, at, P.m, P.size(), "mass");
  unpack_scalar_layout(in, at, P.vol0, P.size(), "rest volume");
  P.for_each_channel([&](auto& channel) {
    using V = typename std::decay_t<decltype(channel)>::value_type;
    if (in.size() - at < n * sizeof(V))
      throw SimulationError("a message of particles from another rank is truncated");
    const std::size_t old = channel.size();
    channel.resize(old + n);
    std::memcpy(static_cast<void*>(channel.data() + old), in.data() + at, n * sizeof(V));
    at += n * sizeof(V);
  });
  if (at != in.size())
    throw SimulationError("a message of particles from another rank has trailing bytes");
}

/// Removes the particles whose `drop` flag is set, keeping the others' order.
template <class T, int Dim>
void drop_particles(Particles<T, Dim>& P, const std::vector<std::uint8_t>& drop) {
  P.for_each_channel([&](auto& channel) {
    std::size_t k = 0;
    for (std::size_t p = 0; p < channel.size(); ++p)
      if (!drop[p]) channel[k++] = channel[p];
    channel.resize(k);
  });
}

/// Keeps the first n particles.
template <class T, int Dim>
void truncate_particles(Particles<T, Dim>& P, std::size_t n) {
  P.for_each_channel([&](auto& channel) { channel.resize(n); });
}

}  // namespace slurry::detail
