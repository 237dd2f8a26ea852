#pragma once
/// \file blocks.h
/// Grid blocks and particle binning: the spatial structure behind Slurry's race-free parallel
/// transfers.
///
/// The node lattice is cut into blocks of `BlockShape<Dim>::size` nodes per axis (4^3 in 3D,
/// 8^2 in 2D: about 512 particles per block at the usual 8 (3D) or 4-9 (2D) particles per cell).
/// A particle belongs to the block holding the first node of its B-spline stencil ("base"), so
/// its stencil nodes lie in [size b, size b + size - 1 + Order] along each axis: in its own block
/// or the next one. Scattering one block's particles therefore writes at most the 2^Dim blocks
/// b + {0,1}^Dim, and two blocks whose coordinates have equal parities (the same "colour") and
/// differ somewhere never write the same node. P2G runs the 2^Dim colours one after the other
/// and the blocks of one colour in parallel: no atomics, no per-thread grids, and every node
/// receives its contributions in the same order whatever the thread count (the block-colouring
/// scheme of Gao et al. 2018, "GPU optimization of material point methods", and of Fei et al.
/// 2021's multi-colour scatter, here on CPU threads).
///
/// `ParticleBins` sorts particle indices by block with a stable counting sort (Knuth, TAOCP
/// vol. 3, 5.2 "distribution counting"), in fixed chunks so that the order never depends on the
/// thread count. Buffers are reused between steps; after the first steps a rebuild allocates
/// nothing unless the particles spread over more blocks than ever before.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <type_traits>
#include <vector>

#include "slurry/transfer/kernels.h"
#include "slurry/transfer/lattice.h"
#include "slurry/transfer/parallel.h"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

namespace slurry::transfer {

template <int Dim>
struct BlockShape {
  static_assert(Dim == 2 || Dim == 3, "2D or 3D");
  static constexpr int log2 = Dim == 3 ? 2 : 3;
  static constexpr int size = 1 << log2;  ///< nodes per axis
  static constexpr int nodes = Dim == 3 ? size * size * size : size * size;
  static constexpr int colours = 1 << Dim;
  /// The colour of block b in [0, colours): the parities of its coordinates, the first axis's
  /// the highest bit. P2G adds the blocks' patches colour after colour.
  template <class IVec>
  static int colour(const IVec& b) {
    int c = 0;
    for (int d = 0; d < Dim; ++d) c = 2 * c + (b[d] & 1);
    return c;
  }
};

/// The values of one grid node: momentum (or, after the grid update, velocity) in entries
/// [0, Dim), mass in entry Dim. A 2D node carries a fourth entry, always zero, so that a node is
/// one vector register in both dimensions (SSE for float, AVX for double): the transfers add or
/// read a node with one vector instruction instead of three scalar ones.
template <class T, int Dim>
using GridNode = Eigen::Matrix<T, 4, 1>;

/// A ParticleBins `base_of` for particles at positions x: per axis the B-spline stencil base
/// BSpline<Order>::base((x[p] - origin) inv_dx) (kernels.h). A type of its own (not a lambda)
/// so that ParticleBins::update can check 8 particles at a time with the same roundings.
template <int Order, class T, int Dim>
struct PositionBases {
  const Eigen::Matrix<T, Dim, 1>* x;
  Eigen::Matrix<T, Dim, 1> origin;
  T inv_dx;
  Eigen::Matrix<int, Dim, 1> operator()(std::int64_t p) const {
    Eigen::Matrix<int, Dim, 1> b;
    for (int d = 0; d < Dim; ++d) b[d] = BSpline<Order>::base((x[p][d] - origin[d]) * inv_dx);
    return b;
  }
};
/// A ParticleBins `material_of` or `rank_of`: a per-particle channel of unsigned integers; when
/// Optional, 0 for every particle if `values` is null (a channel stored only when it varies).
template <class U, bool Optional = true>
struct ChannelValues {
  const U* values;
  std::uint32_t operator()(std::int64_t p) const {
    if constexpr (Optional)
      return values ? std::uint32_t(values[p]) : 0u;
    else
      return std::uint32_t(values[p]);
  }
};

/// Particle indices sorted by the block of their stencil base node, and within a block by
/// material: bins are (block, material) pairs, block-major, so the bins of one block are
/// adjacent ("groups") and each bin is one material (the model is dispatched once per bin).
template <int Dim>
class ParticleBins {
 public:
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Shape = BlockShape<Dim>;
  /// Particles order()[begin, end) belong to block `block` and material `material`.
  struct Bin {
    IVec block;
    std::uint32_t material;
    std::uint32_t begin, end;
  };

  /// Blocks covering a lattice of `node_res` nodes per axis.
  void resize(const IVec& node_res) {
    std::int64_t total = 1;
    for (int d = 0; d < Dim; ++d) {
      block_res_[d] = (node_res[d] + Shape::size - 1) / Shape::size;
      total *= block_res_[d];
    }
    if (total >= std::numeric_limits<std::int32_t>::max())
      throw std::length_error("ParticleBins: more than 2^31 blocks; use a larger dx");
    table_.assign(std::size_t(total), -1);
    distinct_.clear();
    ranked_ = false;
  }
  const IVec& block_res() const { return block_res_; }

  /// Bins particles [0, n); `base_of(p)` returns the particle's stencil base node (IVec), which
  /// must lie inside the lattice; `material_of(p)` its material in [0, materials).
  template <class BaseOf, class MaterialOf>
  void build(std::int64_t n, BaseOf&& base_of, MaterialOf&& material_of, int materials) {
    if (n > std::int64_t(std::numeric_limits<std::uint32_t>::max()))
      throw std::length_error("ParticleBins: more than 2^32 particles");
    order_.resize(std::size_t(n));
    for (auto k : distinct_) table_[std::size_t(k)] = -1;
    distinct_.clear();
    const std::int64_t nm = std::max(1, materials);
    // 1. Block key of every particle, and per fixed chunk of particles the keys that start a run
    //    of equal keys (neighbouring particles mostly share a block, so runs are few). The keys
    //    live in order_ until the last pass, which computes them again from base_of while it
    //    fills order_: no key array of its own (4 bytes per particle).
    auto block_key = [&](std::int64_t p) { return key_of(block_of_base(base_of(p))); };
    std::int32_t* key = reinterpret_cast<std::int32_t*>(order_.data());
    const std::int64_t scan_chunks = (n + kScanChunk - 1) / kScanChunk;
    if (std::int64_t(runs_.size()) < scan_chunks) runs_.resize(std::size_t(scan_chunks));
    parallel::parallel_tasks(0, scan_chunks, [&](std::int64_t c) {
      auto& runs = runs_[std::size_t(c)];
      runs.clear();
      const std::int64_t lo = c * kScanChunk, hi = std::min(n, (c + 1) * kScanChunk);
      for (std::int64_t p = lo; p < hi; ++p) key[p] = block_key(p);  // free of branches: it vectorises
      std::int32_t prev = -1;
      for (std::int64_t p = lo; p < hi; ++p)
        if (key[p] != prev) runs.push_back(prev = key[p]);
    });
    // 2. The occupied blocks, sorted by key: the table is read once per run.
    for (std::int64_t c = 0; c < scan_chunks; ++c)
      for (const std::int32_t k : runs_[std::size_t(c)])
        if (table_[std::size_t(k)] < 0) {
          table_[std::size_t(k)] = 0;
          distinct_.push_back(k);
        }
    std::sort(distinct_.begin(), distinct_.end());
    const std::int64_t nb = std::int64_t(distinct_.size());
    for (std::int64_t j = 0; j < nb; ++j) table_[std::size_t(distinct_[std::size_t(j)])] = std::int32_t(j);
    // 3. Stable counting sort on (block, material) in fixed chunks: per-chunk histograms,
    //    offsets in (slot, chunk) order, then each chunk scatters its particles. The chunk count
    //    depends on n and the slot count only (never on threads), and is capped so that the
    //    histograms stay small beside the particles when they are widely spread.
    const std::int64_t slots = nb * nm;
    if (slots > std::numeric_limits<std::int32_t>::max()) throw std::length_error("ParticleBins: too many (block, material) bins");
    std::int64_t chunks = n == 0 ? 0 : std::min<std::int64_t>(kMaxChunks, (n + kMinChunk - 1) / kMinChunk);
    while (chunks > 1 && chunks * slots > 4 * n) chunks /= 2;
    const std::int64_t chunk = chunks == 0 ? 1 : (n + chunks - 1) / chunks;
    count_.assign(std::size_t(chunks * slots), 0);
    std::uint32_t* count = count_.data();
    const std::int32_t* table = table_.data();
    auto slot_of = [&](std::int64_t p, std::int32_t k) { return std::int64_t(table[k]) * nm + std::int64_t(material_of(p)); };
    parallel::parallel_tasks(0, chunks, [&](std::int64_t c) {
      std::uint32_t* h = count + c * slots;
      for (std::int64_t p = c * chunk, e = std::min(n, (c + 1) * chunk); p < e; ++p) ++h[slot_of(p, key[p])];
    });
    // Offsets in (slot, chunk) order: each slot's total over the chunks, an exclusive scan over
    // the slots, then each chunk's start within its slot. The histograms are walked row by row
    // over ranges of slots, in parallel; only the scan over slots is serial.
    start_.resize(std::size_t(slots) + 1);
    std::uint32_t* start = start_.data();
    parallel::parallel_chunks(0, slots, [&](std::int64_t lo, std::int64_t hi) {
      std::fill(start + lo, start + hi, 0u);
      for (std::int64_t c = 0; c < chunks; ++c)
        for (std::int64_t sl = lo; sl < hi; ++sl) start[sl] += count[c * slots + sl];
    });
    std::uint32_t offset = 0;
    for (std::int64_t sl = 0; sl < slots; ++sl) {
      const std::uint32_t cnt = start[sl];
      start[sl] = offset;
      offset += cnt;
    }
    start[slots] = offset;
    running_.resize(std::size_t(slots));
    std::uint32_t* running = running_.data();
    parallel::parallel_chunks(0, slots, [&](std::int64_t lo, std::int64_t hi) {
      std::copy(start + lo, start + hi, running + lo);
      for (std::int64_t c = 0; c < chunks; ++c)
        for (std::int64_t sl = lo; sl < hi; ++sl) {
          std::uint32_t& h = count[c * slots + sl];
          const std::uint32_t cnt = h;
          h = running[sl];
          running[sl] += cnt;
        }
    });
    bins_.clear();
    groups_.clear();
    for (std::int64_t j = 0; j < nb; ++j) {
      const IVec block = block_of_key(distinct_[std::size_t(j)]);
      groups_.push_back(std::uint32_t(bins_.size()));
      for (std::int64_t m = 0; m < nm; ++m) {
        const std::uint32_t begin = start[j * nm + m], end = start[j * nm + m + 1];
        if (end > begin) bins_.push_back({block, std::uint32_t(m), begin, end});
      }
    }
    groups_.push_back(std::uint32_t(bins_.size()));
    std::uint32_t* order = order_.data();
    parallel::parallel_tasks(0, chunks, [&](std::int64_t c) {
      std::uint32_t* h = count + c * slots;
      for (std::int64_t p = c * chunk, e = std::min(n, (c + 1) * chunk); p < e; ++p)
        order[h[slot_of(p, block_key(p))]++] = std::uint32_t(p);  // the keys in order_ are overwritten
    });
    // 4. Blocks (groups) by colour (the parities of their block coordinates).
    colour_blocks();
    ranked_ = false;
  }

  /// Orders the particles of every bin by `rank_of(p)` (distinct unsigned integers, e.g.
  /// persistent ids). The counting sort leaves a bin in storage order, which depends on the
  /// history of the storage (re-sorts, arrivals); ordered by a persistent key, a bin's
  /// particles (and so every sum a patch accumulates) depend on the set of particles alone, so
  /// that a domain split over processes reproduces a single process bit for bit. A bin that is
  /// already in order (the common case right after a re-sort by bins) costs one pass.
  ///
  /// Otherwise a bin is mostly in order: the counting sort is stable, and most of its particles
  /// were there at the last re-sort, stored in rank order. Its particles that extend the
  /// ascending run from the front stay, in place; the others (mostly the few that arrived from
  /// other bins) are sorted on their own and merged in from the back: O(n + r log r) for r
  /// particles out of place, where a full sort cost O(n log n) (the sorts took 6% of a 2D snow
  /// substep). Ranks are distinct, so the result is the one order that a full sort gives.
  template <class RankOf>
  void sort_within_bins(RankOf&& rank_of) {
    ranked_ = true;
    std::uint32_t* order = order_.data();
    parallel::parallel_tasks(0, std::int64_t(bins_.size()), [&](std::int64_t b) {
      std::uint32_t* first = order + bins_[std::size_t(b)].begin;
      std::uint32_t* last = order + bins_[std::size_t(b)].end;
      const auto less = [&](std::uint32_t p, std::uint32_t q) { return rank_of(p) < rank_of(q); };
      if (std::is_sorted(first, last, less)) return;
      // The others go to a stack buffer (a warm substep allocates nothing); more of them than
      // it holds, and the bin is put back as it was and fully sorted.
      constexpr std::size_t kRest = 256;
      std::uint32_t rest[kRest];
      std::size_t nr = 0;
      std::uint32_t* kept = first;  // [first, kept): the ascending run, compacted in place
      std::uint32_t* it = first;
      for (; it != last; ++it) {
        if (kept == first || !less(*it, kept[-1]))
          *kept++ = *it;
        else if (nr < kRest)
          rest[nr++] = *it;
        else
          break;
      }
      if (it != last) {  // [kept, it) holds exactly the nr others' places
        std::copy(rest, rest + nr, kept);
        std::sort(first, last, less);
        return;
      }
      std::sort(rest, rest + nr, less);
      // Merge from the back into [first, last): the free tail has nr places.
      std::uint32_t* out = last;
      std::uint32_t* k = kept;
      for (std::size_t j = nr; j > 0;) {
        if (k != first && less(rest[j - 1], k[-1]))
          *--out = *--k;
        else
          *--out = rest[--j];
      }
    });
  }

  /// Re-bins particles [0, n) as build() followed by sort_within_bins(rank_of) would, from the
  /// bins of the last such pair, when few particles changed bins since: with small substeps (the
  /// 88-line reference's 2D set-up moves a particle a hundredth of a cell per substep) a few
  /// dozen of 24 k particles cross a block face, and a counting sort of all of them took 10% of a
  /// substep. One parallel pass checks every particle against its bin (block, material, and the
  /// rank order of the bin's particles that stay); the movers are sorted on their own, the
  /// others compacted in place, and the movers merged into their new bins from the back, in
  /// place (every particle's new position is at or after its compacted one). The bins, their
  /// order and the colour lists are then exactly those of build() and sort_within_bins():
  /// bins hold the same particles in rank order, and are listed by block key and material.
  ///
  /// Returns false, changing nothing, when it cannot: no bins from build() and
  /// sort_within_bins() for n particles, or more than n / 16 movers (a full build is cheaper);
  /// the caller then calls those two. The check covers anything a caller may have changed
  /// between substeps (positions, materials, ranks), so the result never depends on whether
  /// this path was taken.
  template <class BaseOf, class MaterialOf, class RankOf>
  bool update(std::int64_t n, BaseOf&& base_of, MaterialOf&& material_of, RankOf&& rank_of) {
    if (!ranked_ || n != std::int64_t(order_.size()) || n == 0) return false;
    // 1. Per bin: which of its particles moved (another block or material), and whether the
    //    ones that stay are still in rank order.
    //    Nothing is stored per particle in this pass (a byte store may alias anything, and made
    //    GCC reload every pointer per particle); the movers' places are marked in pass 2.
    const std::int64_t nbins = std::int64_t(bins_.size());
    moved_.resize(std::size_t(n));
    bin_moved_.resize(std::size_t(nbins));
    std::uint32_t* order = order_.data();
    std::uint8_t* moved = moved_.data();
    const Bin* bins = bins_.data();
    std::uint32_t* bin_moved = bin_moved_.data();
    parallel::parallel_for_grain(0, nbins, kCheckGrain, [&, order, bins, bin_moved](std::int64_t b) {
      const Bin bin = bins[b];
      const std::int32_t k = key_of(bin.block);
      if constexpr (kVectorCheck<BaseOf, MaterialOf, RankOf>) {
        if (still_in_place(bin, k, order, base_of, material_of, rank_of)) {
          bin_moved[b] = 0;
          return;
        }
      }
      std::uint32_t count = 0;
      bool ranked = true, any_kept = false;
      auto last_rank = rank_of(order[bin.begin]);
      for (std::uint32_t i = bin.begin; i < bin.end; ++i) {
        const std::uint32_t p = order[i];
        const bool m = left_bin(p, k, bin.material, base_of, material_of);
        count += m;
        if (!m) {
          const auto r = rank_of(p);
          ranked &= !any_kept || last_rank < r;
          last_rank = r, any_kept = true;
        }
      }
      bin_moved[b] = ranked ? count : kUnranked;
    });
    std::int64_t movers = 0;
    for (const std::uint32_t c : bin_moved_) {
      if (c == kUnranked) return false;
      movers += c;
    }
    if (movers == 0) return true;
    if (movers > n / 16) return false;
    // 2. The movers with their new (block key, material), sorted by that and by rank. The
    //    buffers are sized for the most movers this path takes, once.
    movers_.clear();
    if (movers_.capacity() < std::size_t(n / 16)) movers_.reserve(std::size_t(n / 16));
    if (slots_.capacity() < std::size_t(nbins + n / 16))
      slots_.reserve(std::size_t(nbins + n / 16));
    for (std::int64_t b = 0; b < nbins; ++b) {
      if (bin_moved_[std::size_t(b)] == 0) continue;
      const Bin& bin = bins_[std::size_t(b)];
      const std::int32_t k = key_of(bin.block);
      for (std::uint32_t i = bin.begin; i < bin.end; ++i) {
        const std::uint32_t p = order[i];
        moved[i] = left_bin(p, k, bin.material, base_of, material_of);
        if (moved[i]) {
          const IVec base = base_of(p);
          for (int d = 0; d < Dim; ++d)
            if (base[d] < 0 || (base[d] >> Shape::log2) >= block_res_[d])
              return false;  // build() throws on it
          movers_.push_back({key_of(block_of_base(base)), std::uint32_t(material_of(p)), p});
        }
      }
    }
    std::sort(movers_.begin(), movers_.end(), [&](const Mover& a, const Mover& b) {
      if (a.key != b.key) return a.key < b.key;
      if (a.material != b.material) return a.material < b.material;
      return rank_of(a.p) < rank_of(b.p);
    });
    // 3. Compact the particles that stay, bin by bin, to the front (a forward pass: positions
    //    only decrease). kept_end_[b]: where bin b's kept particles end.
    kept_end_.resize(std::size_t(nbins));
    std::uint32_t out = 0;
    for (std::int64_t b = 0; b < nbins; ++b) {
      const Bin& bin = bins_[std::size_t(b)];
      if (bin_moved_[std::size_t(b)] == 0) {  // moved_ is marked for bins with movers only
        if (out != bin.begin) std::copy(order + bin.begin, order + bin.end, order + out);
        out += bin.end - bin.begin;
      } else {
        for (std::uint32_t i = bin.begin; i < bin.end; ++i)
          if (!moved[i]) order[out++] = order[i];
      }
      kept_end_[std::size_t(b)] = out;
    }
    // 4. The new slots (block key, material): the old bins that keep particles and the movers'
    //    slots, in (key, material) order, each with its kept range and its movers.
    slots_.clear();
    {
      std::int64_t b = 0;
      std::size_t m = 0;
      const std::size_t nm = movers_.size();
      auto bin_key = [&](std::int64_t bi) { return key_of(bins_[std::size_t(bi)].block); };
      while (b < nbins || m < nm) {
        Slot sl{};
        const bool from_bin = b < nbins;
        const bool from_mover = m < nm;
        std::int32_t bk = from_bin ? bin_key(b) : 0;
        const std::uint32_t bmat = from_bin ? bins_[std::size_t(b)].material : 0;
        bool take_bin = from_bin, take_mover = from_mover;
        if (from_bin && from_mover) {
          const bool bin_first =
              bk < movers_[m].key || (bk == movers_[m].key && bmat < movers_[m].material);
          const bool same = bk == movers_[m].key && bmat == movers_[m].material;
          take_bin = bin_first || same;
          take_mover = !bin_first || same;
        }
        sl.key = take_bin ? bk : movers_[m].key;
        sl.material = take_bin ? bmat : movers_[m].material;
        sl.kept_begin = sl.kept_end = 0;
        if (take_bin) {
          sl.kept_begin = b == 0 ? 0 : kept_end_[std::size_t(b - 1)];
          sl.kept_end = kept_end_[std::size_t(b)];
          ++b;
        }
        sl.movers_begin = sl.movers_end = std::uint32_t(m);
        if (take_mover) {
          while (m < nm && movers_[m].key == sl.key && movers_[m].material == sl.material) ++m;
          sl.movers_end = std::uint32_t(m);
        }
        if (sl.kept_end > sl.kept_begin || sl.movers_end > sl.movers_begin) slots_.push_back(sl);
      }
    }
    // 5. From the last slot to the first: merge its kept particles (still at their compacted
    //    places) and its movers by rank into the slot's final range, from the back. A kept
    //    particle's final place is its compacted place plus the movers of the slots up to its
    //    own, so writes never overtake the reads still to come.
    std::uint32_t end = std::uint32_t(n);
    for (std::size_t j = slots_.size(); j > 0; --j) {
      Slot& sl = slots_[j - 1];
      std::uint32_t k = sl.kept_end, q = sl.movers_end;
      std::uint32_t w = end;
      while (q > sl.movers_begin) {
        if (k > sl.kept_begin && rank_of(movers_[q - 1].p) < rank_of(order[k - 1]))
          order[--w] = order[--k];
        else
          order[--w] = movers_[--q].p;
      }
      while (k > sl.kept_begin) order[--w] = order[--k];
      sl.kept_begin = w;  // now the slot's final begin
      sl.kept_end = end;
      end = w;
    }
    // 6. Bins, groups, the occupied blocks and the colour lists, as build() leaves them.
    for (auto key : distinct_) table_[std::size_t(key)] = -1;
    distinct_.clear();
    bins_.clear();
    groups_.clear();
    for (const Slot& sl : slots_) {
      if (distinct_.empty() || distinct_.back() != sl.key) {
        distinct_.push_back(sl.key);
        groups_.push_back(std::uint32_t(bins_.size()));
      }
      const IVec block = block_of_key(sl.key);
      bins_.push_back({block, sl.material, sl.kept_begin, sl.kept_end});
    }
    groups_.push_back(std::uint32_t(bins_.size()));
    for (std::size_t j = 0; j < distinct_.size(); ++j)
      table_[std::size_t(distinct_[j])] = std::int32_t(j);
    colour_blocks();
    return true;
  }

  /// Call after the caller permuted its particle arrays by order(): particle i is now order()[i]'s
  /// data, so the order becomes the identity (the bins stay valid).
  void reset_order() {
    std::uint32_t* order = order_.data();
    parallel::parallel_for(0, std::int64_t(order_.size()), [&](std::int64_t i) { order[i] = std::uint32_t(i); });
  }

  const std::vector<Bin>& bins() const { return bins_; }
  /// Particle indices, bin after bin.
  const std::uint32_t* order() const { return order_.data(); }
  /// Number of occupied blocks; block g's bins are bins()[group_begin(g), group_begin(g + 1)).
  std::size_t groups() const { return groups_.empty() ? 0 : groups_.size() - 1; }
  std::uint32_t group_begin(std::size_t g) const { return groups_[g]; }
  /// Block g's linear index in the block lattice (block_res()), stable across rebuilds.
  std::int32_t group_key(std::size_t g) const { return distinct_[g]; }
  /// The occupied blocks (group indices) of colour c in [0, 2^Dim).
  const std::vector<std::uint32_t>& colour(int c) const { return colour_[std::size_t(c)]; }

  /// Bytes held (capacity).
  std::size_t bytes() const {
    std::size_t b = table_.capacity() * sizeof(std::int32_t) +
                    order_.capacity() * sizeof(std::uint32_t) + distinct_.capacity() * sizeof(std::int32_t) +
                    count_.capacity() * sizeof(std::uint32_t) + bins_.capacity() * sizeof(Bin) +
                    groups_.capacity() * sizeof(std::uint32_t);
    for (const auto& c : colour_) b += c.capacity() * sizeof(std::uint32_t);
    for (const auto& r : runs_) b += r.capacity() * sizeof(std::int32_t);
    b += (start_.capacity() + running_.capacity()) * sizeof(std::uint32_t);
    b += moved_.capacity() +
         (bin_moved_.capacity() + kept_end_.capacity()) * sizeof(std::uint32_t) +
         movers_.capacity() * sizeof(Mover) + slots_.capacity() * sizeof(Slot);
    return b;
  }

 private:
  /// Whether update() can check bins 8 particles at a time (still_in_place): 3D float positions
  /// binned by PositionBases, materials and ranks from ChannelValues, on AVX2 with FMA.
  template <class BaseOf, class MaterialOf, class RankOf>
  static constexpr bool kVectorCheck =
#if defined(__AVX2__) && defined(__FMA__)
      Dim == 3 && (std::is_same_v<std::decay_t<BaseOf>, PositionBases<1, float, 3>> ||
                   std::is_same_v<std::decay_t<BaseOf>, PositionBases<2, float, 3>> ||
                   std::is_same_v<std::decay_t<BaseOf>, PositionBases<3, float, 3>>) &&
      std::is_same_v<std::decay_t<MaterialOf>, ChannelValues<std::uint16_t>> &&
      std::is_same_v<std::decay_t<RankOf>, ChannelValues<std::uint32_t, false>>;
#else
      false;
#endif

#if defined(__AVX2__) && defined(__FMA__)
  /// update()'s check of one bin in the common case, 8 particles at a time: true when the bin's
  /// particles are stored one after the other (as reset_order() leaves them), none of them
  /// changed block or material, and their ranks ascend; false when any of that fails to hold,
  /// and the per-particle check decides. The bases are BSpline<Order>::base((x - origin)
  /// inv_dx) as PositionBases computes them, with the roundings GCC gives that expression when
  /// FMA is available: x - origin rounded, then the product and the quadratic kernel's -1/2 in
  /// one fused multiply-add (tests/mpm/parallel_test.cpp:
  /// ParticleBins.VectorBinCheckMatchesThePerParticleOne).
  template <int Order>
  bool still_in_place(const Bin& bin, std::int32_t k, const std::uint32_t* order,
                      const PositionBases<Order, float, 3>& bases, const ChannelValues<std::uint16_t>& material_of,
                      const ChannelValues<std::uint32_t, false>& rank_of) const {
    const std::uint32_t* at = order + bin.begin;
    const std::int64_t len = std::int64_t(bin.end) - std::int64_t(bin.begin), first = at[0];
    // The last index in 64 bits: then the 32-bit comparisons below cannot wrap.
    if (std::int64_t(at[len - 1]) != first + len - 1) return false;
    {
      // at[j] == first + j for every j.
      const __m256i step = _mm256_set1_epi32(8);
      __m256i want = _mm256_add_epi32(_mm256_set1_epi32(std::int32_t(first)), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
      __m256i off = _mm256_setzero_si256();
      std::int64_t j = 0;
      for (; j + 8 <= len; j += 8, want = _mm256_add_epi32(want, step))
        off = _mm256_or_si256(off, _mm256_xor_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(at + j)), want));
      if (!_mm256_testz_si256(off, off)) return false;
      for (; j < len; ++j)
        if (std::int64_t(at[j]) != first + j) return false;
    }
    const float* xs = bases.x[first].data();
    const std::uint16_t* material = material_of.values ? material_of.values + first : nullptr;
    const __m256 o[3] = {_mm256_set1_ps(bases.origin[0]), _mm256_set1_ps(bases.origin[1]),
                         _mm256_set1_ps(bases.origin[2])};
    const __m256 s = _mm256_set1_ps(bases.inv_dx), half = _mm256_set1_ps(-0.5f);
    const __m256i r1 = _mm256_set1_epi32(block_res_[1]), r2 = _mm256_set1_epi32(block_res_[2]);
    const __m256i key = _mm256_set1_epi32(k), mat = _mm256_set1_epi32(std::int32_t(bin.material));
    // Lanes line up by particle after the blends: particles (0, 3, 6, 1, 4, 7, 2, 5) of the 8,
    // enough to compare each one's key.
    const __m256i rot1 = _mm256_setr_epi32(1, 2, 3, 4, 5, 6, 7, 0), rot2 = _mm256_setr_epi32(2, 3, 4, 5, 6, 7, 0, 1);
    __m256i differ = _mm256_setzero_si256();
    std::int64_t j = 0;
    for (; j + 8 <= len; j += 8, xs += 24) {
      const __m256 a = _mm256_loadu_ps(xs), b = _mm256_loadu_ps(xs + 8), c = _mm256_loadu_ps(xs + 16);
      const __m256 u[3] = {
          _mm256_blend_ps(_mm256_blend_ps(a, b, 0x92), c, 0x24),
          _mm256_permutevar8x32_ps(_mm256_blend_ps(_mm256_blend_ps(a, b, 0x24), c, 0x49), rot1),
          _mm256_permutevar8x32_ps(_mm256_blend_ps(_mm256_blend_ps(a, b, 0x49), c, 0x92), rot2)};
      __m256i blk[3];
      for (int d = 0; d < 3; ++d) {
        const __m256 g = _mm256_sub_ps(u[d], o[d]);
        const __m256 y = Order == 2 ? _mm256_fmadd_ps(g, s, half) : _mm256_mul_ps(g, s);
        __m256i base = _mm256_cvttps_epi32(_mm256_floor_ps(y));
        if constexpr (Order == 3) base = _mm256_sub_epi32(base, _mm256_set1_epi32(1));
        blk[d] = _mm256_srai_epi32(base, Shape::log2);
      }
      // key_of in 32-bit arithmetic: the same low 32 bits as its 64-bit sum, which it truncates.
      const __m256i kk = _mm256_add_epi32(
          _mm256_mullo_epi32(_mm256_add_epi32(_mm256_mullo_epi32(blk[0], r1), blk[1]), r2), blk[2]);
      differ = _mm256_or_si256(differ, _mm256_xor_si256(kk, key));
      if (material) {
        const __m256i m = _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(material + j)));
        differ = _mm256_or_si256(differ, _mm256_xor_si256(m, mat));
      }
    }
    if (!_mm256_testz_si256(differ, differ)) return false;
    for (; j < len; ++j)
      if (left_bin(first + j, k, bin.material, bases, material_of)) return false;
    // rank[i - 1] < rank[i] for every i, unsigned (compared as signed with the sign bits flipped).
    const std::uint32_t* rank = rank_of.values + first;
    const __m256i flip = _mm256_set1_epi32(std::numeric_limits<std::int32_t>::min());
    __m256i ascending = _mm256_set1_epi32(-1);
    std::int64_t i = 1;
    for (; i + 8 <= len; i += 8) {
      const __m256i lo = _mm256_xor_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(rank + i - 1)), flip);
      const __m256i hi = _mm256_xor_si256(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(rank + i)), flip);
      ascending = _mm256_and_si256(ascending, _mm256_cmpgt_epi32(hi, lo));
    }
    if (_mm256_movemask_epi8(ascending) != -1) return false;
    for (; i < len; ++i)
      if (!(rank[i - 1] < rank[i])) return false;
    return true;
  }
#else
  template <class... A>
  bool still_in_place(const A&...) const {
    return false;
  }
#endif

  /// Whether particle p is no longer in the bin of block key k and material `material` (it
  /// changed block or material): update()'s test, in both of its passes and in still_in_place.
  template <class BaseOf, class MaterialOf>
  bool left_bin(std::int64_t p, std::int32_t k, std::uint32_t material, const BaseOf& base_of,
                const MaterialOf& material_of) const {
    return (key_of(block_of_base(base_of(p))) != k) | (std::uint32_t(material_of(p)) != material);
  }

  /// The block holding stencil base node `base`.
  static IVec block_of_base(IVec base) {
    for (int d = 0; d < Dim; ++d) base[d] >>= Shape::log2;
    return base;
  }
  /// Block b's linear index in the block lattice (block_res()), the last axis fastest; and back.
  std::int32_t key_of(const IVec& b) const {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k = k * block_res_[d] + b[d];
    return std::int32_t(k);
  }
  IVec block_of_key(std::int64_t k) const { return lattice_coord<Dim>(k, block_res_); }

  void colour_blocks() {
    for (auto& c : colour_) c.clear();
    const std::size_t nb = distinct_.size();
    for (std::size_t j = 0; j < nb; ++j) {
      colour_[std::size_t(BlockShape<Dim>::colour(bins_[groups_[j]].block))].push_back(std::uint32_t(j));
    }
  }
  struct Mover {
    std::int32_t key;
    std::uint32_t material, p;
  };
  struct Slot {
    std::int32_t key;
    std::uint32_t material, kept_begin, kept_end, movers_begin, movers_end;
  };
  static constexpr std::uint32_t kUnranked = std::numeric_limits<std::uint32_t>::max();
  bool ranked_ = false;              // the bins are build()'s, ordered by sort_within_bins() since
  std::vector<std::uint8_t> moved_;  // update(): per position, whether its particle moved
  std::vector<std::uint32_t> bin_moved_;  // update(): movers per bin (kUnranked: out of order)
  std::vector<std::uint32_t> kept_end_;   // update(): end of each bin's compacted stayers
  std::vector<Mover> movers_;
  std::vector<Slot> slots_;
  // Bins per hand-out in update()'s check: a bin of 500 particles takes about half a
  // microsecond there, where one at a time made the two threads contend for the counter.
  static constexpr std::int64_t kCheckGrain = 16;
  static constexpr std::int64_t kMinChunk = 16384;
  static constexpr std::int64_t kScanChunk = 16384;
  static constexpr std::int64_t kMaxChunks = 64;
  IVec block_res_ = IVec::Zero();
  std::vector<std::int32_t> table_;  // block key -> block index during build, -1 when unused
  std::vector<std::uint32_t> order_;
  std::vector<std::int32_t> distinct_;
  std::vector<std::uint32_t> start_;    // per (block, material) slot: first index in order_
  std::vector<std::uint32_t> running_;  // per slot: next free index while offsets are built
  std::vector<std::vector<std::int32_t>> runs_;  // per scan chunk: keys starting a run (reused)
  std::vector<std::uint32_t> count_;
  std::vector<Bin> bins_;
  std::vector<std::uint32_t> groups_;
  std::array<std::vector<std::uint32_t>, BlockShape<Dim>::colours> colour_;
};

}  // namespace slurry::transfer

namespace slurry::transfer {

/// The nodes that one block's particles reach: `extent` = size + Order nodes per axis starting at
/// node `first` = size * block. P2G scatters a block's particles into a patch on the stack and
/// adds it to the grid (`Grid::add_patch`); G2P copies the patch out of the grid
/// (`Grid::read_patch`) and gathers from it. The patch offers the grid interface the per-particle
/// kernels of transfers.h use (origin, dx, inv_dx, stride, index, data, old_velocity), with
/// indices local to the patch, so the same kernels serve a dense grid, a sparse grid and a patch.
template <class T, int Dim, int Order>
struct Patch {
  static constexpr int extent = BlockShape<Dim>::size + Order;
  // Race freedom of the colour phases: two blocks of one colour are at least two blocks apart
  // along some axis, so their patches (nodes [size b, size b + extent)) are disjoint exactly when
  // extent <= 2 size. Checked here, at compile time, for every kernel order that is instantiated.
  static_assert(extent <= 2 * BlockShape<Dim>::size, "a patch must not reach a same-colour block's patch");
  static constexpr int count = Dim == 3 ? extent * extent * extent : extent * extent;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Node = GridNode<T, Dim>;

  std::array<Node, count> nodes;
  std::array<Vec, count> old;  ///< pre-update velocities (FLIP only)
  IVec first;                  ///< global coordinates of nodes[0]
  Vec origin_;                 ///< the grid's origin (node (0, ..., 0) in world units)
  T dx_, inv_dx_;

  Patch(const IVec& block, const Vec& grid_origin, T dx, T inv_dx)
      : first(block * BlockShape<Dim>::size), origin_(grid_origin), dx_(dx), inv_dx_(inv_dx) {}

  static constexpr std::int64_t stride(int d) {
    return Dim == 3 ? (d == 0 ? extent * extent : d == 1 ? extent : 1) : (d == 0 ? extent : 1);
  }
  const Vec& origin() const { return origin_; }
  T dx() const { return dx_; }
  T inv_dx() const { return inv_dx_; }
  template <class Base>
  std::int64_t index(const Base& base) const {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k += stride(d) * (base[d] - first[d]);
    return k;
  }
  Node* data() { return nodes.data(); }
  const Node* data() const { return nodes.data(); }
  const Vec& old_velocity(std::int64_t k) const { return old[std::size_t(k)]; }
  void touch(const IVec&, const IVec&) {}
  void zero() { nodes.fill(Node::Zero()); }
};

}  // namespace slurry::transfer
