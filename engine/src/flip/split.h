#pragma once
// The FLIP liquid split over processes (private to the engine).
//
// The grid's cells, in blocks of kBlock^Dim, are cut into boxes, one per rank, by the same
// balanced cuts as the MPM split (mpm/domain_split.h), balanced by the particles per block and cut
// again at every frame. A rank owns the particles whose cell lies in its box and the faces whose upper cell does
// (an axis-d face on the domain's upper wall belongs to the cell below it). It holds a grid over
// its box widened by `band` cells on every side (its window, clipped to the domain), so that the
// phases of a substep run unchanged on it:
// - ghosts: before the particle-to-grid transfer every rank receives copies of the particles
//   within `ghost` cells of its box, enough for exact face sums, labels and level set on its own
//   cells and the ring of cells around them; the copies are dropped once the cells are labelled;
// - the pressure rows of the rank's own fluid cells go to the distributed solve
//   (Communicator::solve_spd, PETSc CG with BoomerAMG), numbered box after box; the ring's row
//   numbers and solution come from their owners;
// - after the projection the window's faces take their owners' values (velocity, validity, the
//   velocity before the projection, the transfer weights), so the extrapolation, which reaches
//   two faces per layer, is exact on the rank's own faces; after it the window's faces take
//   their owners' values again, for the particles' gather and advection;
// - particles that leave the box go to the owner of their new cell.
// Every exchange is with the ranks whose boxes lie within `band` cells of this one's.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "mpm/domain_split.h"
#include "slurry/engine/communicator.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/whitewater.h"
#include "slurry/transfer/lattice.h"

namespace slurry::flip::detail {

/// Appends the bytes of `v` (trivially copyable) to a message.
template <class V>
void put(std::string& out, const V& v) {
  out.append(reinterpret_cast<const char*>(&v), sizeof v);
}

/// Reads a message written by put(), value by value, in the order they were put.
struct MessageReader {
  std::string_view in;
  std::size_t at = 0;
  template <class V>
  void get(V& v) {
    std::memcpy(static_cast<void*>(&v), in.data() + at, sizeof v);
    at += sizeof v;
  }
  bool done() const { return at >= in.size(); }
};

/// Keeps the items of [0, n) whose owner(i) is `me`, moved to the front in their order by
/// move(kept, i), and packs every other one into out[slot[owner(i)]] by pack(i, message), in its
/// order; returns how many it kept. `owner` throws for an item it cannot send (slot < 0).
template <class Owner, class Move, class Pack>
std::size_t keep_own_pack_others(std::size_t n, int me, const std::vector<int>& slot,
                                 std::vector<std::string>& out, Owner&& owner, Move&& move, Pack&& pack) {
  std::size_t kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const int q = owner(i);
    if (q == me) {
      if (kept != i) move(kept, i);
      ++kept;
    } else {
      pack(i, out[std::size_t(slot[std::size_t(q)])]);
    }
  }
  return kept;
}

template <class T, int Dim>
struct FlipSplit {
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Vec = Eigen::Matrix<T, Dim, 1>;

  static constexpr int kBlock = 4;       ///< cells per block along each axis: the unit of the cuts
  Communicator* comm = nullptr;
  slurry::detail::BoxSplit<Dim> boxes;  ///< over the blocks
  std::vector<int> per_axis;            ///< processes along each axis
  IVec res = IVec::Zero();              ///< the domain's cells
  Vec origin = Vec::Zero();             ///< the domain's lower corner
  T dx = T(1);
  IVec lo = IVec::Zero(), hi = IVec::Zero();    ///< this rank's box of cells, [lo, hi)
  IVec wlo = IVec::Zero(), whi = IVec::Zero();  ///< its window: the box widened by band, clipped
  int band = 0, ghost = 0;
  int reach = 0;                      ///< faces a particle's gather and advection read, in cells from its cell
  std::vector<int> peers;             ///< ranks whose boxes lie within band cells of this one's
  std::vector<IVec> peer_lo, peer_hi; ///< their boxes
  std::size_t own = 0;                ///< particles owned (stored before the ghosts of a substep)
  std::uint64_t total = 0;            ///< particles over every rank
  double fewest = 0, most = 0;        ///< particles on the least and most loaded rank
  double bytes_per_substep = 0;
  mutable FlipParticles<T, Dim> gathered;  ///< rank 0: every particle in id order, as of the last frame
  mutable WhitewaterParticles<T, Dim> whitewater_gathered;  ///< rank 0: every whitewater particle, id order
  WhitewaterCounts whitewater;  ///< over every rank, as of the last advance_to()

  FlipSplit(Communicator* c, const IVec& cells, const Vec& lower, T cell) : comm(c), res(cells), origin(lower), dx(cell) {}

  /// The domain cell holding x (clamped to the domain).
  IVec cell_of(const Vec& x) const {
    IVec i;
    for (int d = 0; d < Dim; ++d) i[d] = std::clamp(int(std::floor((x[d] - origin[d]) / dx)), 0, res[d] - 1);
    return i;
  }
  int owner(const Vec& x) const { return boxes.owner(IVec(cell_of(x) / kBlock)); }
  /// Blocks along each axis.
  IVec blocks() const { return (res.array() + kBlock - 1) / kBlock; }
  /// The block of domain cell i, as a lattice index.
  std::int64_t block_index(const IVec& i) const { return transfer::lattice_index<Dim>(IVec(i / kBlock), blocks()); }
  /// Particles per block (block_index()) of the positions x.
  std::vector<double> block_counts(const std::vector<Vec>& x) const {
    std::vector<double> counts(std::size_t(blocks().prod()), 0.0);
    for (const auto& y : x) counts[std::size_t(block_index(cell_of(y)))] += 1;
    return counts;
  }
  /// Rank r's box of cells, [rlo, rhi).
  void cell_box(int r, IVec& rlo, IVec& rhi) const {
    boxes.box(r, rlo, rhi);
    rlo *= kBlock;
    rhi = (rhi * kBlock).cwiseMin(res);
  }
  bool in_box(const IVec& i) const { return (i.array() >= lo.array()).all() && (i.array() < hi.array()).all(); }
  /// Window-local cell index of domain cell i (inside the window).
  std::int64_t local_cell(const IVec& i) const { return transfer::lattice_index<Dim>(IVec(i - wlo), IVec(whi - wlo)); }
  /// Domain cell of window-local cell index k.
  IVec domain_cell(std::int64_t k) const { return IVec(transfer::lattice_coord<Dim>(k, IVec(whi - wlo)) + wlo); }

  /// Numbers new particles over every rank as one process numbers them: `mine` lists this rank's
  /// new particles per cell (domain cell index, count) in ascending cell order; each count is
  /// replaced by the cell's first id, `next` plus the counts of every rank's cells before it in
  /// the domain's order. Returns the next id after them all. Every rank calls it alike.
  std::uint32_t number_new(std::vector<std::pair<std::uint64_t, std::uint32_t>>& mine, std::uint32_t next) const {
    std::string out;
    for (const auto& [cell, count] : mine) put(out, cell), put(out, count);
    std::vector<std::pair<std::uint64_t, std::uint32_t>> every;
    for (const auto& m : comm->all_gather(out)) {
      constexpr std::size_t each = sizeof(std::uint64_t) + sizeof(std::uint32_t);
      if (m.size() % each != 0) throw SimulationError("split FLIP: a new particles' count message has a partial entry");
      for (MessageReader r{m}; !r.done();) {
        std::pair<std::uint64_t, std::uint32_t> e;
        r.get(e.first), r.get(e.second);
        every.push_back(e);
      }
    }
    std::sort(every.begin(), every.end());
    std::size_t k = 0;
    for (const auto& [cell, count] : every) {
      if (k < mine.size() && mine[k].first == cell) mine[k++].second = next;
      next += count;
    }
    return next;
  }

  /// Places the boxes by the particles per block (`counts`, block_index()), this rank's window and
  /// its peers. `summed`: the counts are this rank's particles only, summed over the ranks level by
  /// level (every rank calls alike); else every rank passes the same counts of every particle.
  void place(const std::vector<double>& counts, bool summed) {
    boxes = slurry::detail::BoxSplit<Dim>(blocks(), per_axis);
    const std::vector<double> per_rank =
        summed ? boxes.cut(counts, [this](std::vector<double>& v) { comm->sum(v.data(), int(v.size())); }) : boxes.cut(counts);
    fewest = *std::min_element(per_rank.begin(), per_rank.end());
    most = *std::max_element(per_rank.begin(), per_rank.end());
    const int me = comm->rank();
    cell_box(me, lo, hi);
    wlo = (lo.array() - band).cwiseMax(0);
    whi = (hi.array() + band).cwiseMin(res.array());
    peers.clear(), peer_lo.clear(), peer_hi.clear();
    for (int q = 0; q < comm->size(); ++q) {
      if (q == me) continue;
      IVec qlo, qhi;
      cell_box(q, qlo, qhi);
      // Within band cells along every axis (a symmetric relation: the peer lists are mutual).
      if (((qlo.array() < whi.array()) && (qhi.array() > wlo.array())).all())
        peers.push_back(q), peer_lo.push_back(qlo), peer_hi.push_back(qhi);
    }
  }

  /// The cells of box [alo, ahi) within `depth` cells of box [blo, bhi): [rlo, rhi), maybe empty.
  static bool overlap(const IVec& alo, const IVec& ahi, const IVec& blo, const IVec& bhi, int depth, IVec& rlo, IVec& rhi) {
    rlo = alo.cwiseMax(IVec(blo.array() - depth));
    rhi = ahi.cwiseMin(IVec(bhi.array() + depth));
    return (rlo.array() < rhi.array()).all();
  }

  /// Calls f(local index) for the window-local entries of region [rlo, rhi) of a field whose
  /// entries are the cells (axis -1) or the axis-d faces: a region's faces are its cells' lower
  /// faces, with the upper wall's faces added where it reaches the domain's upper end along d.
  template <class F>
  void for_region(int axis, const IVec& rlo, const IVec& rhi, F&& f) const {
    for_runs(axis, rlo, rhi, [&f](std::int64_t first, int n) {
      for (int j = 0; j < n; ++j) f(first + j);
    });
  }
  /// The same region as runs of consecutive entries along the last axis: f(first, length).
  template <class F>
  void for_runs(int axis, const IVec& rlo, IVec rhi, F&& f) const {
    IVec wres = whi - wlo;
    if (axis >= 0) {
      wres[axis] += 1;
      if (rhi[axis] == res[axis]) rhi[axis] += 1;
    }
    IVec n = rhi - rlo;
    const int run = n[Dim - 1];
    n[Dim - 1] = 1;
    std::int64_t rows = 1;
    for (int d = 0; d < Dim; ++d) rows *= n[d];
    for (std::int64_t k = 0; k < rows; ++k) {
      const IVec i = transfer::lattice_coord<Dim>(k, n) + rlo - wlo;
      f(transfer::lattice_index<Dim>(i, wres), run);
    }
  }

  /// Every peer's values of `field` (cells: axis -1; axis-d faces: axis d) over the part of its
  /// box within `depth` cells of this one's, written into this rank's window; this rank's own
  /// values go the other way.
  template <class V>
  void exchange(std::vector<V>& field, int axis, int depth) {
    std::vector<std::string> out(peers.size());
    for (std::size_t k = 0; k < peers.size(); ++k) {
      IVec rlo, rhi;
      if (!overlap(lo, hi, peer_lo[k], peer_hi[k], depth, rlo, rhi)) continue;
      std::string& m = out[k];
      for_runs(axis, rlo, rhi, [&](std::int64_t i, int n) {
        m.append(reinterpret_cast<const char*>(&field[std::size_t(i)]), sizeof(V) * std::size_t(n));
      });
    }
    const std::vector<std::string> in = comm->exchange(peers, out);
    for (std::size_t k = 0; k < peers.size(); ++k) {
      IVec rlo, rhi;
      if (!overlap(peer_lo[k], peer_hi[k], lo, hi, depth, rlo, rhi)) continue;
      const std::string& m = in[k];
      std::size_t at = 0;
      for_runs(axis, rlo, rhi, [&](std::int64_t i, int n) {
        const std::size_t bytes = sizeof(V) * std::size_t(n);
        if (at + bytes > m.size()) throw SimulationError("split FLIP: a halo message from rank " + std::to_string(peers[k]) + " is short");
        std::memcpy(static_cast<void*>(&field[std::size_t(i)]), m.data() + at, bytes);
        at += bytes;
      });
    }
  }

  /// The domain-wide field (cells: axis -1, axis-d faces: axis d) on rank 0, each rank's box
  /// from that rank; empty on the other ranks.
  template <class V>
  std::vector<V> gather(const std::vector<V>& field, int axis) const {
    std::string mine;
    for_runs(axis, lo, hi, [&](std::int64_t i, int n) {
      mine.append(reinterpret_cast<const char*>(&field[std::size_t(i)]), sizeof(V) * std::size_t(n));
    });
    const std::vector<std::string> parts = comm->gather(mine);
    if (comm->rank() != 0) return {};
    IVec full = res;
    if (axis >= 0) full[axis] += 1;
    std::vector<V> whole(std::size_t(full.prod()));
    for (int r = 0; r < int(parts.size()); ++r) {
      IVec rlo, rhi;
      cell_box(r, rlo, rhi);
      IVec n = rhi - rlo;
      if (axis >= 0 && rhi[axis] == res[axis]) n[axis] += 1;
      std::int64_t count = 1;
      for (int d = 0; d < Dim; ++d) count *= n[d];
      if (parts[std::size_t(r)].size() != std::size_t(count) * sizeof(V))
        throw SimulationError("split FLIP: rank " + std::to_string(r) + " sent a field of another size");
      for (std::int64_t k = 0; k < count; ++k) {
        const IVec i = transfer::lattice_coord<Dim>(k, n) + rlo;
        std::memcpy(static_cast<void*>(&whole[std::size_t(transfer::lattice_index<Dim>(i, full))]),
                    parts[std::size_t(r)].data() + std::size_t(k) * sizeof(V), sizeof(V));
      }
    }
    return whole;
  }

  /// This rank's window of a domain-wide field.
  template <class V>
  void crop(const std::vector<V>& whole, std::vector<V>& window, int axis) const {
    IVec full = res, wres = whi - wlo;
    if (axis >= 0) full[axis] += 1, wres[axis] += 1;
    std::int64_t count = 1;
    for (int d = 0; d < Dim; ++d) count *= wres[d];
    window.resize(std::size_t(count));
    for (std::int64_t k = 0; k < count; ++k)
      window[std::size_t(k)] = whole[std::size_t(transfer::lattice_index<Dim>(IVec(transfer::lattice_coord<Dim>(k, wres) + wlo), full))];
  }

  /// exchange() for each axis of a face field.
  template <class V>
  void exchange_faces(std::array<std::vector<V>, Dim>& faces, int depth) {
    for (int d = 0; d < Dim; ++d) exchange(faces[std::size_t(d)], d, depth);
  }
};

/// Appends particle p of P (every channel P stores) to `out`.
template <class T, int Dim>
void pack_particle(const FlipParticles<T, Dim>& P, std::size_t p, std::string& out) {
  put(out, P.x[p]), put(out, P.v[p]), put(out, P.id[p]);
  if (P.affine)
    for (int d = 0; d < Dim; ++d) put(out, P.c[std::size_t(d)][p]);
  if (P.has_material) put(out, P.material[p]);
}

/// Appends the particles packed in `in` (by pack_particle with the same channels) to P.
template <class T, int Dim>
void unpack_particles(std::string_view in, FlipParticles<T, Dim>& P) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  std::size_t each = 2 * sizeof(Vec) + sizeof(std::uint32_t) + (P.affine ? Dim * sizeof(Vec) : 0) +
                     (P.has_material ? sizeof(std::uint16_t) : 0);
  if (in.size() % each != 0) throw SimulationError("split FLIP: a particle message has a partial particle");
  for (MessageReader r{in}; !r.done();) {
    Vec x, v;
    std::uint32_t id = 0;
    r.get(x), r.get(v), r.get(id);
    P.x.push_back(x), P.v.push_back(v), P.id.push_back(id);
    if (P.affine)
      for (int d = 0; d < Dim; ++d) {
        Vec c;
        r.get(c);
        P.c[std::size_t(d)].push_back(c);
      }
    if (P.has_material) {
      std::uint16_t m = 0;
      r.get(m);
      P.material.push_back(m);
    }
  }
}

/// Cells of the ring around a box whose labels and level set the split whitewater phase takes
/// from their owners: the depth field of a cell reads labels up to ceil(bubble_depth) + 2 layers
/// away, an own cell's potentials read its neighbours' normals (2 cells more), and new particles
/// start up to 2 cells beyond their cell (whitewater.h), read trilinearly (1 more).
inline int whitewater_ring(double bubble_depth) { return int(std::ceil(bubble_depth)) + 2 + 5; }

/// Appends whitewater particle i of W to `out` (position, velocity, life, id, type).
template <class T, int Dim>
void pack_whitewater(const WhitewaterParticles<T, Dim>& W, std::size_t i, std::string& out) {
  put(out, W.x[i]), put(out, W.v[i]), put(out, W.life[i]), put(out, W.id[i]), put(out, W.type[i]);
}

/// Appends the whitewater particles packed in `in` (pack_whitewater) to W.
template <class T, int Dim>
void unpack_whitewater(std::string_view in, WhitewaterParticles<T, Dim>& W) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  constexpr std::size_t each = 2 * sizeof(Vec) + sizeof(T) + sizeof(std::uint32_t) + 1;
  if (in.size() % each != 0) throw SimulationError("split FLIP: a whitewater message has a partial particle");
  for (MessageReader r{in}; !r.done();) {
    const std::size_t i = W.size();
    W.resize(i + 1);
    r.get(W.x[i]), r.get(W.v[i]), r.get(W.life[i]), r.get(W.id[i]), r.get(W.type[i]);
  }
}

/// Whitewater particles back in ascending id (the order one process keeps: the oldest first).
template <class T, int Dim>
void sort_whitewater(WhitewaterParticles<T, Dim>& W) {
  if (std::is_sorted(W.id.begin(), W.id.end())) return;
  std::vector<std::size_t> order(W.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&W](std::size_t a, std::size_t b) { return W.id[a] < W.id[b]; });
  WhitewaterParticles<T, Dim> sorted;
  sorted.resize(W.size());
  for (std::size_t k = 0; k < order.size(); ++k) {
    const std::size_t i = order[k];
    sorted.x[k] = W.x[i], sorted.v[k] = W.v[i], sorted.life[k] = W.life[i], sorted.id[k] = W.id[i], sorted.type[k] = W.type[i];
  }
  sorted.next_id = W.next_id;
  W = std::move(sorted);
}

}  // namespace slurry::flip::detail
