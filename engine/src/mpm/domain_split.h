#pragma once
// The MPM domain split over processes (private to the engine): slab borders balanced by particle
// counts, and whole particles packed into bytes for another rank and unpacked there.
//
// A rank owns the particles whose stencil base node lies in its slab of grid-block columns
// (blocks.h) along the split axis; the grid halo that joins the slabs' node sums is in
// distribution.h.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/mpm/particles.h"

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
