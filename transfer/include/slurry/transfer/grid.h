#pragma once
/// \file grid.h
/// Dense background grid of MPM nodes: node i sits at origin + i dx.
///
/// Each node stores (momentum or velocity, mass) packed in one 4-vector (GridNode, blocks.h; a 2D
/// node pads it with a zero), so that P2G adds one small vector per node (the layout of Hu et al.
/// 2018's mls-mpm88). The grid tracks the box of nodes touched since the last clear, so clearing
/// and the grid update cost the occupied box, not the whole domain.
///
/// Two interfaces: the whole-grid one of the serial transfers (`origin()`, `dx()`, `inv_dx()`,
/// `res()`, `index()`, `stride()`, `node()`, `touch()`), and the block one of the engine's
/// parallel transfers, shared with SparseGrid (sparse_grid.h): `activate(bins)`,
/// `add_patch`, `read_patch`, `for_each_active_node`.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#include "slurry/transfer/blocks.h"
#include "slurry/transfer/parallel.h"

namespace slurry::transfer {

template <class T, int Dim>
class DenseGrid {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  /// (m v_x, m v_y[, m v_z], m) during P2G; (v_x, v_y[, v_z], m) after the grid update.
  using Node = GridNode<T, Dim>;

  DenseGrid() = default;
  /// `res` nodes per axis, spaced dx apart from `origin`.
  DenseGrid(const Vec& origin, T dx, const IVec& res) { resize(origin, dx, res); }

  void resize(const Vec& origin, T dx, const IVec& res) {
    origin_ = origin;
    dx_ = dx;
    inv_dx_ = T(1) / dx;
    res_ = res;
    stride_[Dim - 1] = 1;
    for (int d = Dim - 2; d >= 0; --d) stride_[d] = stride_[d + 1] * std::int64_t(res[d + 1]);
    nodes_.assign(std::size_t(stride_[0] * res[0]), Node::Zero());
    if (!old_.empty()) old_.assign(nodes_.size(), Vec::Zero());
    lo_ = res_;
    hi_ = IVec::Constant(-1);
  }

  const Vec& origin() const { return origin_; }
  T dx() const { return dx_; }
  T inv_dx() const { return inv_dx_; }
  const IVec& res() const { return res_; }
  std::int64_t stride(int d) const { return stride_[d]; }
  std::size_t size() const { return nodes_.size(); }

  std::int64_t index(const IVec& i) const {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k += stride_[d] * i[d];
    return k;
  }
  template <class Base>
  std::int64_t index(const Base& base) const {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k += stride_[d] * base[d];
    return k;
  }
  Vec position(const IVec& i) const { return origin_ + dx_ * i.template cast<T>(); }

  Node& node(std::int64_t k) { return nodes_[std::size_t(k)]; }
  const Node& node(std::int64_t k) const { return nodes_[std::size_t(k)]; }
  /// The node at lattice coordinates i, or nullptr outside the grid (SparseGrid's interface).
  Node* find(const IVec& i) {
    for (int d = 0; d < Dim; ++d)
      if (i[d] < 0 || i[d] >= res_[d]) return nullptr;
    return &nodes_[std::size_t(index(i))];
  }
  Node* data() { return nodes_.data(); }
  const Node* data() const { return nodes_.data(); }

  /// FLIP keeps each node's velocity from before the grid update; other schemes do not pay for it.
  void keep_old_velocity(bool keep) { old_.assign(keep ? nodes_.size() : 0, Vec::Zero()); }
  bool keeps_old_velocity() const { return !old_.empty(); }
  Vec& old_velocity(std::int64_t k) { return old_[std::size_t(k)]; }
  const Vec& old_velocity(std::int64_t k) const { return old_[std::size_t(k)]; }

  /// Widens the active box to nodes [lo, hi] (inclusive).
  void touch(const IVec& lo, const IVec& hi) {
    lo_ = lo_.cwiseMin(lo);
    hi_ = hi_.cwiseMax(hi);
  }
  bool empty() const { return (hi_.array() < lo_.array()).any(); }
  const IVec& active_lo() const { return lo_; }
  const IVec& active_hi() const { return hi_; }

  /// Zeroes the nodes of the active box and empties it.
  void clear() {
    const int n = active_row_length();
    for (std::int64_t r = 0; r < active_rows(); ++r) {
      const auto first = nodes_.begin() + active_row_start(r);
      std::fill(first, first + n, Node::Zero());
    }
    lo_ = res_;
    hi_ = IVec::Constant(-1);
  }

  /// Number of rows (along the last axis) of the active box, and the index of row r's first
  /// node. Rows are independent, so callers may run them in parallel.
  std::int64_t active_rows() const {
    if (empty()) return 0;
    std::int64_t r = 1;
    for (int d = 0; d < Dim - 1; ++d) r *= hi_[d] - lo_[d] + 1;
    return r;
  }
  std::int64_t active_row_start(std::int64_t r) const {
    std::int64_t k = lo_[Dim - 1];
    for (int d = Dim - 2; d >= 0; --d) {
      const std::int64_t n = hi_[d] - lo_[d] + 1;
      k += stride_[d] * (lo_[d] + r % n);
      r /= n;
    }
    return k;
  }
  int active_row_length() const { return empty() ? 0 : hi_[Dim - 1] - lo_[Dim - 1] + 1; }
  /// Block interface (see SparseGrid): zeroes the previous active box and makes the active box
  /// the nodes that the particles of `bins` reach.
  void activate(const std::vector<typename ParticleBins<Dim>::Bin>& bins) {
    clear();
    if (bins.empty()) return;
    IVec lo = IVec::Constant(std::numeric_limits<int>::max()), hi = IVec::Constant(-1);
    for (const auto& b : bins) {
      lo = lo.cwiseMin(b.block);
      hi = hi.cwiseMax(b.block);
    }
    constexpr int S = BlockShape<Dim>::size;
    touch(lo * S, (hi * S + IVec::Constant(2 * S - 1)).cwiseMin(res_ - IVec::Ones()));
  }

  template <int Order>
  void add_patch(const Patch<T, Dim, Order>& patch) {
    walk_patch<Order>(patch.first, [&](int pk, std::int64_t k) { nodes_[std::size_t(k)] += patch.nodes[std::size_t(pk)]; });
  }

  template <int Order>
  void read_patch(Patch<T, Dim, Order>& patch) const {
    patch.zero();
    const bool old = keeps_old_velocity();
    walk_patch<Order>(patch.first, [&](int pk, std::int64_t k) {
      patch.nodes[std::size_t(pk)] = nodes_[std::size_t(k)];
      if (old) patch.old[std::size_t(pk)] = old_[std::size_t(k)];
    });
  }

  /// The grid update's loop over every node of the active box, in parallel over rows. A row for
  /// which free(first, last node coordinates) holds goes to inner(nodes, old velocity slots or
  /// nullptr, count) at once; every node of the other rows to fn(node, node coordinates, old
  /// velocity slot or nullptr).
  template <class Free, class Inner, class Fn>
  void for_each_active_node(Free&& free, Inner&& inner, Fn&& fn) {
    const int n = active_row_length();
    parallel::parallel_for(0, active_rows(), [&](std::int64_t r) {
      const std::int64_t k0 = active_row_start(r);
      IVec idx = coord(k0);
      Node* row = nodes_.data() + k0;
      Vec* row_old = old_.empty() ? nullptr : old_.data() + k0;
      IVec last = idx;
      last[Dim - 1] += n - 1;
      if (free(idx, last)) {
        inner(row, row_old, std::int64_t(n));
        return;
      }
      for (int k = 0; k < n; ++k, ++idx[Dim - 1]) fn(row[k], idx, row_old ? row_old + k : nullptr);
    });
  }

  /// Bytes held.
  std::size_t bytes() const { return nodes_.capacity() * sizeof(Node) + old_.capacity() * sizeof(Vec); }

  /// Grid coordinates of node index k.
  IVec coord(std::int64_t k) const {
    IVec i;
    for (int d = 0; d < Dim; ++d) {
      i[d] = int(k / stride_[d]);
      k -= stride_[d] * i[d];
    }
    return i;
  }

 private:
  /// fn(patch index, grid index) over the patch nodes inside the lattice.
  template <int Order, class Fn>
  void walk_patch(const IVec& first, Fn&& fn) const {
    constexpr int E = Patch<T, Dim, Order>::extent;
    int hi[Dim];
    for (int d = 0; d < Dim; ++d) hi[d] = std::min(E, res_[d] - first[d]);
    const std::int64_t k0 = index(first);
    if constexpr (Dim == 3) {
      for (int a = 0; a < hi[0]; ++a)
        for (int b = 0; b < hi[1]; ++b) {
          const std::int64_t k = k0 + a * stride_[0] + b * stride_[1];
          const int pk = (a * E + b) * E;
          for (int c = 0; c < hi[2]; ++c) fn(pk + c, k + c);
        }
    } else {
      for (int a = 0; a < hi[0]; ++a) {
        const std::int64_t k = k0 + a * stride_[0];
        for (int b = 0; b < hi[1]; ++b) fn(a * E + b, k + b);
      }
    }
  }

  Vec origin_ = Vec::Zero();
  T dx_ = T(1), inv_dx_ = T(1);
  IVec res_ = IVec::Zero();
  std::array<std::int64_t, Dim> stride_{};
  std::vector<Node> nodes_;
  std::vector<Vec> old_;
  IVec lo_ = IVec::Zero(), hi_ = IVec::Constant(-1);
};

}  // namespace slurry::transfer
