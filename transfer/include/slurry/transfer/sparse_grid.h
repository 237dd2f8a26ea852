#pragma once
/// \file sparse_grid.h
/// Sparse blocked background grid: only the blocks of nodes that particles reach are stored, so
/// memory follows the occupied volume, not the domain's bounding box.
///
/// The lattice is cut into blocks of BlockShape<Dim>::nodes nodes (4^3 in 3D, 8^2 in 2D). A
/// dense page table (one int32 per block of the domain: 69 MB for a 1024^3-cell domain) maps a
/// block to its slot in a pool of node blocks, or -1. Each step `activate` allocates the blocks
/// b + {0,1}^Dim of every occupied particle block b (the nodes their stencils reach; blocks.h),
/// in key order, so slot order and results do not depend on the thread count. The pool only
/// grows: a steady scene allocates nothing after its first steps. This is the layout idea of
/// SPGrid (Setaluri et al. 2014) and of Gao et al. 2018's GPU MPM, with an explicit page table
/// instead of virtual-memory tricks.
///
/// Same node layout and transfer interface as DenseGrid (grid.h): add_patch / read_patch for the
/// block transfers, for_each_active_node for the grid update.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cstdint>
#include <stdexcept>
#include <utility>
#include <vector>

#include "slurry/transfer/blocks.h"
#include "slurry/transfer/parallel.h"

namespace slurry::transfer {

template <class T, int Dim>
class SparseGrid {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Node = GridNode<T, Dim>;
  using Shape = BlockShape<Dim>;
  using Bin = typename ParticleBins<Dim>::Bin;

  SparseGrid() = default;
  SparseGrid(const Vec& origin, T dx, const IVec& res) { resize(origin, dx, res); }

  /// `res` nodes per axis, spaced dx apart from `origin`; no block is allocated yet.
  void resize(const Vec& origin, T dx, const IVec& res) {
    origin_ = origin;
    dx_ = dx;
    inv_dx_ = T(1) / dx;
    res_ = res;
    std::int64_t total = 1;
    for (int d = 0; d < Dim; ++d) {
      block_res_[d] = (res[d] + Shape::size - 1) / Shape::size;
      total *= block_res_[d];
    }
    if (total >= std::int64_t(1) << 31) throw std::length_error("SparseGrid: more than 2^31 blocks; use a larger dx");
    table_.assign(std::size_t(total), -1);
    active_.clear();
    nodes_.clear();
    old_.clear();
  }

  const Vec& origin() const { return origin_; }
  T dx() const { return dx_; }
  T inv_dx() const { return inv_dx_; }
  const IVec& res() const { return res_; }
  Vec position(const IVec& i) const { return origin_ + dx_ * i.template cast<T>(); }

  /// FLIP keeps each node's velocity from before the grid update.
  void keep_old_velocity(bool keep) {
    keep_old_ = keep;
    old_.assign(keep ? nodes_.size() : 0, Vec::Zero());
  }
  bool keeps_old_velocity() const { return keep_old_; }

  /// Allocates and zeroes the blocks that the particles of `bins` reach; frees the others.
  void activate(const std::vector<Bin>& bins) {
    for (const auto& b : active_) table_[std::size_t(key(b))] = -1;
    active_.clear();
    for (const auto& bin : bins) {
      for (int o = 0; o < Shape::colours; ++o) {
        IVec b = bin.block;
        bool inside = true;
        for (int d = 0; d < Dim; ++d) {
          b[d] += (o >> (Dim - 1 - d)) & 1;
          inside = inside && b[d] < block_res_[d];
        }
        if (!inside) continue;
        auto& t = table_[std::size_t(key(b))];
        if (t < 0) {
          t = 0;
          active_.push_back(b);
        }
      }
    }
    std::sort(active_.begin(), active_.end(), [&](const IVec& a, const IVec& b) { return key(a) < key(b); });
    for (std::size_t s = 0; s < active_.size(); ++s) table_[std::size_t(key(active_[s]))] = std::int32_t(s);
    const std::size_t n = active_.size() * Shape::nodes;
    if (nodes_.size() < n) {
      // Grow with head room, so that a scene spreading slowly does not reallocate every step.
      nodes_.resize(std::max(n, nodes_.size() + nodes_.size() / 2));
      if (keep_old_) old_.resize(nodes_.size());
    }
    Node* nodes = nodes_.data();
    parallel::parallel_for(0, std::int64_t(active_.size()), [&](std::int64_t s) {
      std::fill(nodes + s * Shape::nodes, nodes + (s + 1) * Shape::nodes, Node::Zero());
    });
  }

  /// Allocated blocks and their nodes.
  std::size_t active_blocks() const { return active_.size(); }
  std::size_t size() const { return active_.size() * Shape::nodes; }
  /// Bytes held: page table, node pool (with its head room) and old velocities.
  std::size_t bytes() const {
    return table_.capacity() * sizeof(std::int32_t) + active_.capacity() * sizeof(IVec) +
           nodes_.capacity() * sizeof(Node) + old_.capacity() * sizeof(Vec);
  }

  /// Adds a patch of scattered particle contributions into the grid.
  template <int Order>
  void add_patch(const Patch<T, Dim, Order>& patch) {
    for_each_patch_part<Order>(patch.first, [&](std::int64_t slot, const int* lo, const int* hi, const int* shift) {
      Node* block = nodes_.data() + slot * Shape::nodes;
      walk_part<Order>(lo, hi, shift, [&](int pk, int bk) { block[bk] += patch.nodes[std::size_t(pk)]; });
    });
  }

  /// Copies the grid nodes (and old velocities, if kept) of a patch; nodes outside allocated
  /// blocks read as zero.
  template <int Order>
  void read_patch(Patch<T, Dim, Order>& patch) const {
    patch.zero();
    for_each_patch_part<Order>(patch.first, [&](std::int64_t slot, const int* lo, const int* hi, const int* shift) {
      const Node* block = nodes_.data() + slot * Shape::nodes;
      const Vec* old = keep_old_ ? old_.data() + slot * Shape::nodes : nullptr;
      walk_part<Order>(lo, hi, shift, [&](int pk, int bk) {
        patch.nodes[std::size_t(pk)] = block[bk];
        if (old) patch.old[std::size_t(pk)] = old[bk];
      });
    });
  }

  /// The grid update's loop over every allocated node, in parallel over blocks (each call touches
  /// only its own nodes). A block for which free(lowest, highest node coordinates) holds goes to
  /// inner(nodes, old velocity slots or nullptr, count) at once; every node of the other blocks to
  /// fn(node, node coordinates, old velocity slot or nullptr).
  template <class Free, class Inner, class Fn>
  void for_each_active_node(Free&& free, Inner&& inner, Fn&& fn) {
    Node* nodes = nodes_.data();
    Vec* old = keep_old_ ? old_.data() : nullptr;
    parallel::parallel_for(0, std::int64_t(active_.size()), [&](std::int64_t s) {
      const IVec first = active_[std::size_t(s)] * Shape::size;
      Node* block = nodes + s * Shape::nodes;
      Vec* block_old = old ? old + s * Shape::nodes : nullptr;
      if (free(first, IVec(first.array() + (Shape::size - 1)))) {
        inner(block, block_old, std::int64_t(Shape::nodes));
        return;
      }
      IVec idx;
      for (int k = 0; k < Shape::nodes; ++k) {
        int r = k;
        for (int d = Dim - 1; d >= 0; --d) {
          idx[d] = first[d] + (r & (Shape::size - 1));
          r >>= Shape::log2;
        }
        fn(block[k], idx, block_old ? block_old + k : nullptr);
      }
    });
  }

  /// The node at lattice coordinates i, or nullptr if its block is not allocated.
  const Node* find(const IVec& i) const {
    IVec b;
    for (int d = 0; d < Dim; ++d) {
      if (i[d] < 0 || i[d] >= res_[d]) return nullptr;
      b[d] = i[d] >> Shape::log2;
    }
    const std::int32_t s = table_[std::size_t(key(b))];
    if (s < 0) return nullptr;
    int local = 0;
    for (int d = 0; d < Dim; ++d) local = local * Shape::size + (i[d] & (Shape::size - 1));
    return nodes_.data() + std::int64_t(s) * Shape::nodes + local;
  }
  Node* find(const IVec& i) { return const_cast<Node*>(std::as_const(*this).find(i)); }

 private:
  std::int64_t key(const IVec& b) const {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k = k * block_res_[d] + b[d];
    return k;
  }

  /// Splits a patch starting at node `first` (a block corner) into its parts in the 2^Dim blocks
  /// it overlaps: fn(slot, lo, hi, shift) with patch-local ranges [lo, hi) per axis and the
  /// shift from patch-local to block-local coordinates.
  template <int Order, class Fn>
  void for_each_patch_part(const IVec& first, Fn&& fn) const {
    constexpr int E = Patch<T, Dim, Order>::extent;
    const IVec b0 = first / Shape::size;
    for (int o = 0; o < Shape::colours; ++o) {
      IVec b;
      int lo[Dim], hi[Dim], shift[Dim];
      bool inside = true;
      for (int d = 0; d < Dim; ++d) {
        const int od = (o >> (Dim - 1 - d)) & 1;
        b[d] = b0[d] + od;
        inside = inside && b[d] < block_res_[d];
        lo[d] = od * Shape::size;
        hi[d] = od ? E : Shape::size;
        shift[d] = -od * Shape::size;
      }
      if (!inside) continue;
      const std::int32_t s = table_[std::size_t(key(b))];
      if (s < 0) continue;
      fn(std::int64_t(s), lo, hi, shift);
    }
  }

  template <int Order, class Fn>
  static void walk_part(const int* lo, const int* hi, const int* shift, Fn&& fn) {
    constexpr int E = Patch<T, Dim, Order>::extent;
    constexpr int S = Shape::size;
    if constexpr (Dim == 3) {
      for (int a = lo[0]; a < hi[0]; ++a)
        for (int b = lo[1]; b < hi[1]; ++b) {
          const int pk = (a * E + b) * E, bk = ((a + shift[0]) * S + (b + shift[1])) * S + shift[2];
          for (int c = lo[2]; c < hi[2]; ++c) fn(pk + c, bk + c);
        }
    } else {
      for (int a = lo[0]; a < hi[0]; ++a) {
        const int pk = a * E, bk = (a + shift[0]) * S + shift[1];
        for (int b = lo[1]; b < hi[1]; ++b) fn(pk + b, bk + b);
      }
    }
  }

  Vec origin_ = Vec::Zero();
  T dx_ = T(1), inv_dx_ = T(1);
  IVec res_ = IVec::Zero();
  IVec block_res_ = IVec::Zero();
  std::vector<std::int32_t> table_;  // block key -> slot, -1 if not allocated
  std::vector<IVec> active_;         // allocated blocks, in key order (slot order)
  std::vector<Node> nodes_;          // slot s holds nodes [s * nodes, (s + 1) * nodes)
  std::vector<Vec> old_;
  bool keep_old_ = false;
};

}  // namespace slurry::transfer
