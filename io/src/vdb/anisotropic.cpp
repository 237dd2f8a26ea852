// The anisotropic-kernel field (anisotropic.h), after Yu & Turk 2013, section 3:
//  - neighbourhood of particle i: the particles j within R (2 spacings), weighted
//    w_ij = 1 - (|x_j - x_i| / R)^3 (their eq. 11);
//  - smoothed centre x_i + lambda (m_i - x_i), m_i the weighted mean (eq. 6);
//  - weighted covariance C_i about m_i (eq. 7-8), eigenvalues s_1 >= s_2 >= s_3, clamped below at
//    s_1 / k_r^2 so that no axis is shorter than 1/k_r of the longest (eq. 10, with k_r on axis
//    lengths here); axis lengths a_k = H sqrt(s_k / s_bulk), where s_bulk = 0.15 R^2 is the
//    variance of this weighting over a uniformly filled ball of radius R (int_0^R w r^4 dr /
//    (3 int_0^R w r^2 dr) = (3 R^5 / 40) / (3 R^3 / 6)): a kernel in the bulk is the round one of
//    radius H, one at a flat surface keeps H along the surface and is shorter across it;
//  - fewer than N_eps neighbours: a round kernel, of radius `droplet_support` spacings for a lone
//    particle, growing linearly to H at N_eps (Yu & Turk use a fixed radius there);
//  - kernel W(x) = K P(|A^-1 V^T (x - c)|) / (a_1 a_2 a_3) with P(q) = (1 - q^2)^3 on q < 1 and
//    K = 315 / (64 pi), so that it integrates to 1 (Mueller et al. 2003's poly6 with unit support).
#include "vdb/anisotropic.h"

#include <Eigen/Dense>

#include <algorithm>
#include <optional>
#include <utility>
#include <cmath>
#include <stdexcept>
#include <string>

#include "slurry/transfer/parallel.h"
#include "vdb/cell_starts.h"
#include "vdb/kernel_shape.h"
#include "vdb/lanes.h"
#include "vdb/point_bounds.h"

namespace slurry::io::detail {

namespace {

constexpr int kBits = 21;
/// Particles a neighbourhood cell (side 2 spacings, 8 particles at rest) holds at least around a
/// particle treated as deep (a round kernel, no neighbour sums).
constexpr std::uint32_t kDeepCell = 6;
constexpr std::int64_t kRange = std::int64_t(1) << kBits;
/// A padding coordinate for the candidates: beyond any neighbourhood, its square still finite.
constexpr float kFar = 1e15f;

/// Integer cells of side `side` (m) holding `pos`, numbered x fastest over the box of cells they
/// span plus `pad` cells on each side (so that a row of cells along x is a contiguous key range,
/// and the keys use as few bits as the box needs: fewer radix-sort passes). Coordinates are
/// offset so that the lowest cell minus `pad` is 0.
struct CellGrid {
  double side = 1;
  std::array<std::int64_t, 3> lo{};
  std::array<std::int64_t, 3> n{};  ///< cells per axis, pads included
  template <class Points>
  CellGrid(const Points& pos, double side_, std::int64_t pad,
           const char* what)
      : side(side_) {
    // The cells of the points' bounds (floor is monotonic: the smallest and largest cells).
    const PointBounds b = point_bounds(pos);
    std::array<std::int64_t, 3> mn{}, mx{};
    for (int d = 0; d < 3; ++d) {
      mn[d] = std::int64_t(std::floor(double(b.lo[d]) / side));
      mx[d] = std::int64_t(std::floor(double(b.hi[d]) / side));
    }
    for (int d = 0; d < 3; ++d) {
      lo[d] = mn[d] - pad;
      n[d] = mx[d] + pad - lo[d] + 1;
      if (mx[d] + pad - lo[d] >= kRange - 1)
        throw std::invalid_argument(std::string("points: they span more than 2^20 ") + what +
                                    " along axis " + std::to_string(d) +
                                    " (expected the particles of one liquid; a particle far from "
                                    "the others?)");
    }
  }
  std::array<std::int64_t, 3> cell(const std::array<float, 3>& p) const {
    std::array<std::int64_t, 3> c;
    for (int d = 0; d < 3; ++d) c[d] = std::int64_t(std::floor(double(p[d]) / side)) - lo[d];
    return c;
  }
  std::uint64_t key(std::int64_t x, std::int64_t y, std::int64_t z) const {
    return std::uint64_t(x + n[0] * (y + n[1] * z));
  }
  std::uint64_t key(const std::array<std::int64_t, 3>& c) const { return key(c[0], c[1], c[2]); }
  std::array<std::int64_t, 3> unpack(std::uint64_t k) const {
    const std::int64_t i = std::int64_t(k);
    return {i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1])};
  }
};

/// Indices of `pos` sorted by key (ties by index), and the sorted keys; returns where each of the
/// grid's cells starts (cell_starts.h) when the grid's cells are few enough for a table, else an
/// empty table.
template <class Points>
UninitVector<std::uint32_t> sort_by_cell(const Points& pos, const CellGrid& grid,
                                         UninitVector<std::uint64_t>& keys,
                                         UninitVector<std::uint32_t>& order) {
  const std::size_t n = pos.size();
  keys.resize(n);
  order.resize(n);
  parallel::parallel_for(0, std::int64_t(n), [&](std::int64_t i) {
    keys[std::size_t(i)] = grid.key(grid.cell(pos[std::size_t(i)]));
    order[std::size_t(i)] = std::uint32_t(i);
  });
  return sort_pairs_by_cell(keys, order, double(grid.n[0]) * double(grid.n[1]) * double(grid.n[2]));
}

/// Starts of the runs of equal keys in `keys`, with keys.size() appended.
template <class Keys>
std::vector<std::uint32_t> runs(const Keys& keys) {
  std::vector<std::uint32_t> start;
  for (std::size_t i = 0; i < keys.size(); ++i)
    if (i == 0 || keys[i] != keys[i - 1]) start.push_back(std::uint32_t(i));
  start.push_back(std::uint32_t(keys.size()));
  return start;
}

/// Cell key to its run of particles: open addressing over a power-of-two table at most half
/// full (a probe per lookup on average), built once, read by every task.
class CellIndex {
 public:
  CellIndex(const UninitVector<std::uint64_t>& keys, const std::vector<std::uint32_t>& runs) {
    std::size_t size = 16;
    int bits = 4;
    while (size < 2 * runs.size()) size *= 2, ++bits;
    mask_ = size - 1;
    shift_ = 64 - bits;
    slot_key_.assign(size, kEmpty);
    slot_run_.assign(size, 0);
    for (std::size_t r = 0; r + 1 < runs.size(); ++r) {
      const std::uint64_t k = keys[runs[r]];
      std::size_t at = hash(k);
      while (slot_key_[at] != kEmpty) at = (at + 1) & mask_;
      slot_key_[at] = k, slot_run_[at] = std::uint32_t(r);
    }
  }
  /// The run of `key`, or -1 when no particle lies in that cell.
  std::int64_t find(std::uint64_t key) const {
    for (std::size_t at = hash(key);; at = (at + 1) & mask_) {
      if (slot_key_[at] == key) return slot_run_[at];
      if (slot_key_[at] == kEmpty) return -1;
    }
  }

 private:
  static constexpr std::uint64_t kEmpty = ~std::uint64_t(0);  // never a key: keys use 63 bits
  /// Fibonacci hashing: the top bits of the product depend on every bit of the key.
  std::size_t hash(std::uint64_t k) const { return std::size_t((k * 0x9E3779B97F4A7C15ull) >> shift_); }
  std::size_t mask_ = 0;
  int shift_ = 60;
  Buffer<std::uint64_t> slot_key_;
  Buffer<std::uint32_t> slot_run_;
};

/// Cell key to its particles' range in sorted order: a dense table of every cell's start
/// (cell_starts.h) when the cells' box is small enough, else CellIndex's hash.
class CellRanges {
 public:
  /// `first`: sort_by_cell's table (empty: a hash of the runs instead).
  CellRanges(UninitVector<std::uint32_t> first, const UninitVector<std::uint64_t>& keys,
             const std::vector<std::uint32_t>& runs)
      : runs_(runs), first_(std::move(first)) {
    if (first_.empty()) index_.emplace(keys, runs);
  }
  /// The particles of the `count` consecutive cells from `key`, [begin, end) of the sorted
  /// order (begin == end when they are all empty).
  std::pair<std::uint32_t, std::uint32_t> range(std::uint64_t key, int count) const {
    if (!first_.empty()) return {first_[key], first_[key + std::uint64_t(count)]};
    std::uint32_t first = UINT32_MAX, last = 0;
    for (int e = 0; e < count; ++e) {
      const std::int64_t run = index_->find(key + std::uint64_t(e));
      if (run < 0) continue;
      first = std::min(first, runs_[std::size_t(run)]), last = std::max(last, runs_[std::size_t(run) + 1]);
    }
    return first == UINT32_MAX ? std::pair<std::uint32_t, std::uint32_t>{0, 0}
                               : std::pair<std::uint32_t, std::uint32_t>{first, last};
  }

 private:
  const std::vector<std::uint32_t>& runs_;
  UninitVector<std::uint32_t> first_;
  std::optional<CellIndex> index_;
};

}  // namespace

FieldBlocks anisotropic_field(const PointCloud& points, double voxel_size, double spacing,
                              const AnisotropyConstants& k) {
  const std::size_t n = points.size();
  FieldBlocks out;
  if (n == 0) return out;
  const double s = spacing, R = k.neighbourhood * s, H = k.support * s, h = voxel_size;
  const double volume = s * s * s, K = 315.0 / (64.0 * M_PI), s_bulk = 0.15 * R * R;
  const ShapeConstants shape_constants{k.smoothing, k.min_neighbours, k.max_stretch, s_bulk, H, volume, K};

  // 1. Kernels, from each particle's neighbourhood (cells of side R: neighbours lie in the 3 x 3
  //    rows of 3 cells around a particle's cell). One task per cell of particles.
  UninitVector<Kernel> kernel(n);  // every kernel but a deep particle's is written below
  // A deep particle's kernel is the round one at its position, not written: `deep` marks it.
  std::vector<std::uint8_t> deep(n, 0);
  Kernel round{};
  round.map = {float(1 / H), 0, 0, 0, float(1 / H), 0, 0, 0, float(1 / H)};
  round.weight = float(volume * K / (H * H * H));
  round.reach = float(H);
  const auto kernel_of = [&](std::size_t i) {
    if (!deep[i]) return kernel[i];
    Kernel ker = round;
    ker.centre = points.position[i];
    return ker;
  };
  out.neighbours.assign(n, 0);
  {
    const CellGrid grid(points.position, R, 1, "neighbourhoods");
    UninitVector<std::uint64_t> keys;
    UninitVector<std::uint32_t> order;
    UninitVector<std::uint32_t> first = sort_by_cell(points.position, grid, keys, order);
    const std::vector<std::uint32_t> cells = runs(keys);
    const CellRanges ranges(std::move(first), keys, cells);
    // Positions in cell order, by coordinate: a row of cells is one range of each.
    UninitVector<float> sorted[3];
    for (auto& axis : sorted) axis.resize(n);
    parallel::parallel_for(0, std::int64_t(n), [&](std::int64_t a) {
      const auto& p = points.position[order[std::size_t(a)]];
      for (int d = 0; d < 3; ++d) sorted[d][std::size_t(a)] = p[d];
    });
    parallel::parallel_for_grain(0, std::int64_t(cells.size()) - 1, 16, [&](std::int64_t c) {
      const auto cc = grid.unpack(keys[cells[std::size_t(c)]]);
      std::array<std::pair<std::uint32_t, std::uint32_t>, 9> rows;
      std::uint32_t fewest = UINT32_MAX;  // particles in the emptiest of the 27 cells
      for (int dy = -1, r = 0; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz, ++r) {
          // The row's cells are consecutive keys, so its particles are one range of `order`.
          const std::uint64_t row = grid.key(cc[0] - 1, cc[1] + dy, cc[2] + dz);
          rows[std::size_t(r)] = ranges.range(row, 3);
          if (fewest > 0)
            for (int e = 0; e < 3; ++e) {
              const auto [b, en] = ranges.range(row + std::uint64_t(e), 1);
              fewest = std::min(fewest, en - b);
            }
        }
      // Deep in the liquid (each of the 27 cells holds at least 3/4 of the 8 particles a cell
      // of side 2 spacings holds at rest): a particle's neighbourhood fills its ball, so its
      // kernel is the round one of radius H at its position, without the neighbour sums.
      if (fewest >= kDeepCell) {
        for (std::uint32_t a = cells[std::size_t(c)]; a < cells[std::size_t(c) + 1]; ++a) {
          const std::uint32_t i = order[a];
          deep[i] = 1;
          out.neighbours[i] = 255;
        }
        return;
      }
      // The neighbourhood's particles, gathered once for the cell's particles, in the order of
      // the rows (the sums below add them in that order).
      // Padded to whole vectors of kLanes with far points (weight 0, squares still finite).
      thread_local std::vector<float> gathered[3];
      std::size_t m_all = 0;
      for (const auto& [b, e] : rows) m_all += e - b;
      m_all = (m_all + kLanes - 1) / kLanes * kLanes;
      for (int d = 0; d < 3; ++d) {
        std::vector<float>& g = gathered[d];
        g.resize(m_all);
        std::size_t at = 0;
        for (const auto& [b, e] : rows) {
          std::copy(sorted[d].begin() + b, sorted[d].begin() + e, g.begin() + std::ptrdiff_t(at));
          at += e - b;
        }
        std::fill(g.begin() + std::ptrdiff_t(at), g.end(), kFar);
      }
      const float* const px = gathered[0].data();
      const float* const py = gathered[1].data();
      const float* const pz = gathered[2].data();
      const float R2 = float(R * R), inv_R = float(1 / R);
      thread_local NeighbourSums sums;
      const std::uint32_t first = cells[std::size_t(c)];
      sums.resize(cells[std::size_t(c) + 1] - first);
      for (std::uint32_t a = first; a < cells[std::size_t(c) + 1]; ++a) {
        const std::uint32_t i = order[a];
        const float xi0 = sorted[0][a], xi1 = sorted[1][a], xi2 = sorted[2][a];
        // Every candidate, branch-free (one beyond R weighs 0), in kLanes partial sums.
        // The particle itself is inside, counted once.
        float W[kLanes] = {}, m0[kLanes] = {}, m1[kLanes] = {}, m2[kLanes] = {}, c00[kLanes] = {},
              c11[kLanes] = {}, c22[kLanes] = {}, c01[kLanes] = {}, c02[kLanes] = {}, c12[kLanes] = {};
        std::int32_t in[kLanes] = {};
        for (std::size_t q0 = 0; q0 < m_all; q0 += kLanes)
          for (std::size_t l = 0; l < kLanes; ++l) {
            const std::size_t q = q0 + l;
            const float d0 = px[q] - xi0, d1 = py[q] - xi1, d2 = pz[q] - xi2;
            const float r2 = d0 * d0 + d1 * d1 + d2 * d2;
            const float r = std::sqrt(r2) * inv_R;
            const float w = r2 < R2 ? 1.0f - r * r * r : 0.0f;
            in[l] += r2 < R2 ? 1 : 0;
            W[l] += w;
            m0[l] += w * d0, m1[l] += w * d1, m2[l] += w * d2;
            c00[l] += w * d0 * d0, c11[l] += w * d1 * d1, c22[l] += w * d2 * d2;
            c01[l] += w * d0 * d1, c02[l] += w * d0 * d2, c12[l] += w * d1 * d2;
          }
        int inside = 0;  // exact in any order
        for (const std::int32_t n_in : in) inside += n_in;
        const std::size_t p = a - first;
        sums.W[p] = lane_total(W);
        sums.m[0][p] = lane_total(m0), sums.m[1][p] = lane_total(m1), sums.m[2][p] = lane_total(m2);
        sums.s[0][p] = lane_total(c00), sums.s[1][p] = lane_total(c11), sums.s[2][p] = lane_total(c22);
        sums.s[3][p] = lane_total(c01), sums.s[4][p] = lane_total(c02), sums.s[5][p] = lane_total(c12);
        sums.x[0][p] = xi0, sums.x[1][p] = xi1, sums.x[2][p] = xi2;
        sums.neighbours[p] = inside - 1;
        sums.index[p] = i;
        out.neighbours[i] = std::uint8_t(std::min(inside - 1, 255));
      }
      // The centres, and the kernels whose covariance needs no clamp, several at a time
      // (kernel_shape.h); the others here: by the eigendecomposition, or round.
      shape_kernels(sums, shape_constants, kernel.data());
      for (std::size_t p = 0; p < sums.size(); ++p) {
        if (sums.shaped[p]) continue;
        const double mean[3] = {sums.mean[0][p], sums.mean[1][p], sums.mean[2][p]};
        const double second[6] = {sums.s[0][p], sums.s[1][p], sums.s[2][p], sums.s[3][p], sums.s[4][p], sums.s[5][p]};
        const double W_sum = sums.W[p];
        const int count = sums.neighbours[p];
        Kernel& ker = kernel[sums.index[p]];
        std::array<double, 3> axis;
        Eigen::Matrix3d V = Eigen::Matrix3d::Identity();
        if (count >= k.min_neighbours) {  // a clamp may apply: the eigendecomposition
          Eigen::Matrix3d C;
          C(0, 0) = second[0] / W_sum - mean[0] * mean[0];
          C(1, 1) = second[1] / W_sum - mean[1] * mean[1];
          C(2, 2) = second[2] / W_sum - mean[2] * mean[2];
          C(0, 1) = C(1, 0) = second[3] / W_sum - mean[0] * mean[1];
          C(0, 2) = C(2, 0) = second[4] / W_sum - mean[0] * mean[2];
          C(1, 2) = C(2, 1) = second[5] / W_sum - mean[1] * mean[2];
          Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
          es.computeDirect(C);
          V = es.eigenvectors();
          const Eigen::Vector3d ev = es.eigenvalues();  // ascending
          const double largest = std::max(ev[2], 1e-30);
          for (int m = 0; m < 3; ++m) {
            const double sk = std::max(ev[m], largest / (k.max_stretch * k.max_stretch));
            axis[std::size_t(m)] = std::min(H * std::sqrt(sk / s_bulk), k.max_stretch * H);
          }
        } else {
          const double r = s * (k.droplet_support +
                                (k.support - k.droplet_support) * double(count) / k.min_neighbours);
          axis = {r, r, r};
        }
        double reach = 0;
        for (int row = 0; row < 3; ++row) {
          for (int col = 0; col < 3; ++col)
            ker.map[std::size_t(3 * row + col)] = float(V(col, row) / axis[std::size_t(row)]);
          reach = std::max(reach, axis[std::size_t(row)]);
        }
        ker.weight = float(volume * K / (axis[0] * axis[1] * axis[2]));
        ker.reach = float(reach);
      }
    });
  }

  // 2. The field on blocks of 8^3 voxels: kernels sorted by the block of their centre (then by
  //    index); each kernel listed under every block its voxel range reaches, in that order, so a
  //    block sums its kernels in ascending order of their centres' blocks.
  constexpr int B = FieldBlocks::kSize;
  // The kernels' centres, and their longest reach, in one pass.
  UninitVector<std::array<float, 3>> centres(n);
  const float reach_max = parallel::parallel_max(0, std::int64_t(n), 0.0f, [&](std::int64_t b, std::int64_t e) {
    float m = 0;
    for (std::size_t i = std::size_t(b); i < std::size_t(e); ++i) {
      const Kernel ker = kernel_of(i);
      centres[i] = ker.centre, m = std::max(m, ker.reach);
    }
    return m;
  });
  const std::int64_t rb = std::int64_t(std::ceil(double(reach_max) / h / B + 1e-9));
  const CellGrid blocks(centres, B * h, rb + 1, "blocks of 8 voxels");
  UninitVector<std::uint64_t> keys;
  UninitVector<std::uint32_t> order;
  sort_by_cell(centres, blocks, keys, order);  // blocks' starts unused: the runs below
  const float inv_h = float(1.0 / h);
  /// Kernel i's voxels: [lo, hi] per axis (empty when lo > hi on an axis).
  const auto voxel_range = [&](const Kernel& ker, std::int64_t lo[3], std::int64_t hi[3]) {
    const float P[3] = {ker.centre[0] * inv_h, ker.centre[1] * inv_h, ker.centre[2] * inv_h};
    const float r = ker.reach * inv_h;
    for (int d = 0; d < 3; ++d) {
      lo[d] = std::int64_t(std::ceil(P[d] - r));
      hi[d] = std::int64_t(std::floor(P[d] + r));
    }
  };
  const auto block_of = [](std::int64_t v) { return v >= 0 ? v / B : -((-v + B - 1) / B); };
  // The kernels in that order, so that a block reads its own kernels from one stretch of memory;
  // with each kernel's blocks, its first block and the blocks it spans per axis (none when its
  // voxel range is empty).
  struct Span {
    std::int32_t first[3];
    std::int32_t count[3];
  };
  UninitVector<Kernel> by_block(n);
  UninitVector<Span> span(n);
  parallel::parallel_for(0, std::int64_t(n), [&](std::int64_t q) {
    const Kernel ker = kernel_of(order[std::size_t(q)]);
    by_block[std::size_t(q)] = ker;
    Span& sp = span[std::size_t(q)];
    std::int64_t lo[3], hi[3];
    voxel_range(ker, lo, hi);
    const bool empty = lo[0] > hi[0] || lo[1] > hi[1] || lo[2] > hi[2];
    for (int d = 0; d < 3; ++d) {
      const std::int64_t b0 = block_of(lo[d]) - blocks.lo[d];
      sp.first[d] = std::int32_t(b0);
      sp.count[d] = empty ? 0 : std::int32_t(block_of(hi[d]) - blocks.lo[d] - b0 + 1);
    }
  });
  // Each block's kernels without a sort of (block, kernel) pairs: a kernel reaches only blocks
  // within `around` blocks of its centre's block, so the kernels of a centre's block are listed
  // by the offset of each block they reach (slot), in their order; a block then reads, for each
  // centre's block around it in ascending order, the list under its own offset from it. Its
  // kernels come in ascending order of their centres' blocks, then of their place in by_block.
  const std::vector<std::uint32_t> centre_runs = runs(keys);
  const std::size_t nc = centre_runs.size() - 1;
  const std::int64_t around = rb + 1, side = 2 * around + 1;  // the CellGrid's pad
  const std::size_t slots = std::size_t(side * side * side);
  const auto slot_of = [&](const std::array<std::int64_t, 3>& c, std::int64_t x, std::int64_t y, std::int64_t z) {
    return std::size_t(((z - c[2] + around) * side + (y - c[1] + around)) * side + (x - c[0] + around));
  };
  const auto for_each_block = [&](std::size_t q, auto&& f) {
    const Span& sp = span[q];
    for (std::int32_t z = sp.first[2]; z < sp.first[2] + sp.count[2]; ++z)
      for (std::int32_t y = sp.first[1]; y < sp.first[1] + sp.count[1]; ++y)
        for (std::int32_t x = sp.first[0]; x < sp.first[0] + sp.count[0]; ++x) f(x, y, z);
  };
  std::vector<std::uint32_t> slot_start(nc * slots + 1, 0);  // counts, then starts in `listed`
  parallel::parallel_tasks(0, std::int64_t(nc), [&](std::int64_t c) {
    const auto cc = blocks.unpack(keys[centre_runs[std::size_t(c)]]);
    std::uint32_t* count = slot_start.data() + 1 + std::size_t(c) * slots;
    for (std::uint32_t q = centre_runs[std::size_t(c)]; q < centre_runs[std::size_t(c) + 1]; ++q)
      for_each_block(q, [&](std::int64_t x, std::int64_t y, std::int64_t z) { ++count[slot_of(cc, x, y, z)]; });
  });
  for (std::size_t k = 0; k < nc * slots; ++k) slot_start[k + 1] += slot_start[k];
  UninitVector<std::uint32_t> listed(slot_start[nc * slots]);  // kernels, by their place in by_block
  parallel::parallel_tasks(0, std::int64_t(nc), [&](std::int64_t c) {
    const auto cc = blocks.unpack(keys[centre_runs[std::size_t(c)]]);
    std::vector<std::uint32_t> at(slot_start.begin() + std::ptrdiff_t(std::size_t(c) * slots),
                                  slot_start.begin() + std::ptrdiff_t(std::size_t(c + 1) * slots));
    for (std::uint32_t q = centre_runs[std::size_t(c)]; q < centre_runs[std::size_t(c) + 1]; ++q)
      for_each_block(q, [&](std::int64_t x, std::int64_t y, std::int64_t z) { listed[at[slot_of(cc, x, y, z)]++] = q; });
  });
  // The blocks: (block key, list) for every non-empty list, by block key, then centre's block.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> part;  // list: c * slots + slot
  for (std::size_t c = 0; c < nc; ++c) {
    const auto cc = blocks.unpack(keys[centre_runs[c]]);
    for (std::int64_t z = -around; z <= around; ++z)
      for (std::int64_t y = -around; y <= around; ++y)
        for (std::int64_t x = -around; x <= around; ++x) {
          const std::size_t k = c * slots + slot_of(cc, cc[0] + x, cc[1] + y, cc[2] + z);
          if (slot_start[k + 1] > slot_start[k])
            part.push_back({blocks.key(cc[0] + x, cc[1] + y, cc[2] + z), std::uint32_t(k)});
        }
  }
  std::sort(part.begin(), part.end());  // list numbers ascend with the centre's block
  std::vector<std::uint32_t> lists;  // starts of each block's parts, then part.size()
  for (std::size_t i = 0; i < part.size(); ++i)
    if (i == 0 || part[i].first != part[i - 1].first) lists.push_back(std::uint32_t(i));
  lists.push_back(std::uint32_t(part.size()));
  const std::size_t nb = lists.size() - 1;
  out.value.resize(nb * B * B * B);  // each block's task zeroes its own values
  out.origin.resize(nb);
  parallel::parallel_tasks(0, std::int64_t(nb), [&](std::int64_t bi) {
    const auto bc = blocks.unpack(part[lists[std::size_t(bi)]].first);
    // Index-space origin of the block.
    const std::int64_t o[3] = {(bc[0] + blocks.lo[0]) * B, (bc[1] + blocks.lo[1]) * B,
                               (bc[2] + blocks.lo[2]) * B};
    out.origin[std::size_t(bi)] = {std::int32_t(o[0]), std::int32_t(o[1]), std::int32_t(o[2])};
    float* v = out.value.data() + std::size_t(bi) * B * B * B;
    std::fill(v, v + B * B * B, 0.0f);
    for (std::uint32_t at = lists[std::size_t(bi)]; at < lists[std::size_t(bi) + 1]; ++at) {
      const std::uint32_t list = part[at].second;
      for (std::uint32_t item = slot_start[list]; item < slot_start[list + 1]; ++item) {
        const Kernel& ker = by_block[listed[item]];
        const float P[3] = {ker.centre[0] * inv_h, ker.centre[1] * inv_h, ker.centre[2] * inv_h};
        std::int64_t lo_i[3], hi_i[3];
        voxel_range(ker, lo_i, hi_i);
        for (int d = 0; d < 3; ++d) {
          lo_i[d] = std::max<std::int64_t>(o[d], lo_i[d]);
          hi_i[d] = std::min<std::int64_t>(o[d] + B - 1, hi_i[d]);
        }
        // Map scaled to index space: q = M h (i - P).
        float M[9];
        for (int m = 0; m < 9; ++m) M[m] = ker.map[std::size_t(m)] * float(h);
        const float m_z[3] = {M[2], M[5], M[8]};
        static_assert(B == 8);  // a row of the block along z is splat_row's 8 voxels
        for (std::int64_t x = lo_i[0]; x <= hi_i[0]; ++x) {
          const float dxv = float(x) - P[0];
          for (std::int64_t y = lo_i[1]; y <= hi_i[1]; ++y) {
            const float dyv = float(y) - P[1];
            const float a[3] = {M[0] * dxv + M[1] * dyv, M[3] * dxv + M[4] * dyv, M[6] * dxv + M[7] * dyv};
            splat_row(v + ((x - o[0]) * B + (y - o[1])) * B, std::int32_t(o[2]), int(lo_i[2] - o[2]),
                      int(hi_i[2] - o[2]), P[2], a, m_z, ker.weight);
          }
        }
      }
    }
  });
  return out;
}

}  // namespace slurry::io::detail
