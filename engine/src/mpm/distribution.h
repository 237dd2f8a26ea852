// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// The domain split over MPI ranks (mpm_solver.h, "Runs split over processes"): slab borders from
// particle counts, migrating particles to the rank that owns their slab, the grid halo (the
// border node layers' partial sums swapped with the neighbours), gathering every particle for
// frames and checkpoints.
#pragma once

namespace slurry {

template <class T, int Dim>
bool MpmSolver<T, Dim>::set_borders(const std::vector<double>& counts) {
  auto& S = *split_;
  const int ranks = S.comm->size(), rank = S.comm->rank();
  const auto cuts = detail::balanced_cuts(counts, ranks);
  S.fewest = double(S.total), S.most = 0;
  for (int r = 0; r < ranks; ++r) {
    double n = 0;
    for (int c = cuts[std::size_t(r)]; c < cuts[std::size_t(r) + 1]; ++c) n += counts[std::size_t(c)];
    S.fewest = std::min(S.fewest, n), S.most = std::max(S.most, n);
  }
  if (cuts == S.cuts) return false;
  S.cuts = cuts;
  S.lo = S.cuts[std::size_t(rank)];
  S.hi = S.cuts[std::size_t(rank) + 1];
  return true;
}

template <class T, int Dim>
std::vector<double> MpmSolver<T, Dim>::column_counts(const std::vector<Vec>& x, std::vector<double> counts) const {
  counts.resize(std::size_t(bins_.block_res()[split_->axis]), 0.0);
  for (const auto& p : x) counts[std::size_t(column(p))] += 1;
  return counts;
}

template <class T, int Dim>
bool MpmSolver<T, Dim>::owns(const Vec& x) const {
  const int c = column(x);
  return c >= split_->lo && c < split_->hi;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::split_particles() {
  // Every rank holds the same full set here, so every rank computes the same borders.
  auto& S = *split_;
  S.cuts.clear();
  set_borders(column_counts(particles_.x));
  std::vector<std::uint8_t> drop(particles_.size());
  for (std::size_t p = 0; p < drop.size(); ++p) drop[p] = !owns(particles_.x[p]);
  detail::drop_particles(particles_, drop);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::rebalance() {
  auto counts = column_counts(particles_.x);
  split_->comm->sum(counts.data(), int(counts.size()));
  if (set_borders(counts)) migrate();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::migrate() {
  auto& S = *split_;
  auto& P = particles_;
  for (;;) {
    std::vector<std::uint32_t> down, up;
    std::vector<std::uint8_t> drop(P.size(), 0);
    for (std::size_t p = 0; p < P.size(); ++p) {
      const int c = column(P.x[p]);
      if (c < S.lo) down.push_back(std::uint32_t(p)), drop[p] = 1;
      if (c >= S.hi) up.push_back(std::uint32_t(p)), drop[p] = 1;
    }
    std::string to_lower, to_upper;
    if (!down.empty()) detail::pack_particles(P, down, to_lower);
    if (!up.empty()) detail::pack_particles(P, up, to_upper);
    if (!down.empty() || !up.empty()) detail::drop_particles(P, drop);
    const auto [from_lower, from_upper] = S.comm->exchange(to_lower, to_upper);
    detail::unpack_particles(from_lower, P);
    detail::unpack_particles(from_upper, P);
    // After a substep one round settles every particle (each moved less than a column, and every
    // slab is a column wide at least); after new borders, particles pass one rank per round.
    double stray = 0;
    for (const auto& x : P.x) stray += !owns(x);
    S.comm->max(&stray, 1);
    if (stray == 0) break;
  }
}

// The grid halo. A block's patch (blocks.h) covers its own nodes and the first Order node
// layers of the next block along each axis, so along the split axis the nodes of the layers
// [size c, size c + Order) at the border column c = hi of rank r (= lo of rank r + 1) receive the
// contributions of columns c - 1 (rank r) and c (rank r + 1), and no others; every other node a
// rank's particles reach is summed from its own patches alone. One process adds the patches into
// a node colour after colour (a node takes at most one patch per colour), starting from zero.
// Each of the two ranks keeps its border blocks' patch nodes in those layers, sends them to the
// other, and adds its own and the received ones for every layer node again from zero in colour
// order: the same additions in the same order, so the node holds the one-process sum bit for bit
// on both ranks, which then update it alike. What crosses a border per substep is Order node
// layers of the occupied border blocks (4 values a node), against the particles of a whole block
// column that ghost copies would take.

namespace detail {

/// Calls fn(patch-local node index, patch-local coordinates) for the nodes of a patch whose
/// coordinate along `axis` lies in [from, from + Order), in index order.
template <class T, int Dim, int Order, class Fn>
void for_each_layer_node(int axis, int from, Fn&& fn) {
  using P = transfer::Patch<T, Dim, Order>;
  Eigen::Matrix<int, Dim, 1> l;
  for (int k = 0; k < P::count; ++k) {
    int r = k;
    for (int d = Dim - 1; d >= 0; --d) l[d] = r % P::extent, r /= P::extent;
    if (l[axis] >= from && l[axis] < from + Order) fn(k, l);
  }
}

/// Nodes of one block's slice: Order layers of the patch across the split axis.
template <class T, int Dim, int Order>
constexpr std::size_t halo_slice_nodes() {
  std::size_t n = Order;
  for (int d = 1; d < Dim; ++d) n *= std::size_t(transfer::Patch<T, Dim, Order>::extent);
  return n;
}

}  // namespace detail

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::prepare_halo() {
  auto& S = *split_;
  const int rank = S.comm->rank(), ranks = S.comm->size();
  const std::size_t groups = bins_.groups();
  for (int side = 0; side < 2; ++side) {
    auto& B = S.border[side];
    auto& slot = S.slot[side];
    B.blocks.clear();
    slot.assign(groups, -1);
    const bool shared = side == 0 ? rank > 0 : rank + 1 < ranks;
    const int column = side == 0 ? S.lo : S.hi - 1;
    for (std::size_t g = 0; shared && g < groups; ++g) {
      const auto& block = bins_.bins()[bins_.group_begin(g)].block;
      if (block[S.axis] != column) continue;
      slot[g] = std::int32_t(B.blocks.size());
      B.blocks.push_back(block);
    }
    B.nodes.resize(B.blocks.size() * detail::halo_slice_nodes<T, Dim, Order>());
  }
}

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::keep_halo_slices(std::size_t group, const transfer::Patch<T, Dim, Order>& patch) {
  auto& S = *split_;
  for (int side = 0; side < 2; ++side) {
    const std::int32_t s = S.slot[side][group];
    if (s < 0) continue;
    auto* out = S.border[side].nodes.data() + std::size_t(s) * detail::halo_slice_nodes<T, Dim, Order>();
    // The lower border's layers are the patch's first Order along the axis; the upper border's
    // are those past the block (the next column's first).
    detail::for_each_layer_node<T, Dim, Order>(S.axis, side == 0 ? 0 : transfer::BlockShape<Dim>::size,
                                               [&](int k, const auto&) { *out++ = patch.nodes[std::size_t(k)]; });
  }
}

template <class T, int Dim>
template <int Order, class G>
void MpmSolver<T, Dim>::exchange_halo(G& grid) {
  using Node = transfer::GridNode<T, Dim>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  auto& S = *split_;
  constexpr int size = transfer::BlockShape<Dim>::size;
  constexpr std::size_t slice = detail::halo_slice_nodes<T, Dim, Order>();
  // A message: the count of slices, then per slice its block (Dim int32) and its nodes.
  auto pack = [&](const typename Split::Border& B) {
    std::string out;
    if (B.blocks.empty()) return out;
    const std::uint64_t n = B.blocks.size();
    out.reserve(sizeof n + n * (Dim * sizeof(std::int32_t) + slice * sizeof(Node)));
    out.append(reinterpret_cast<const char*>(&n), sizeof n);
    for (std::size_t b = 0; b < n; ++b) {
      std::int32_t c[Dim];
      for (int d = 0; d < Dim; ++d) c[d] = B.blocks[b][d];
      out.append(reinterpret_cast<const char*>(c), sizeof c);
      out.append(reinterpret_cast<const char*>(B.nodes.data() + b * slice), slice * sizeof(Node));
    }
    return out;
  };
  std::string to_lower = pack(S.border[0]), to_upper = pack(S.border[1]);
  S.halo_bytes += to_lower.size() + to_upper.size();
  const auto [from_lower, from_upper] = S.comm->exchange(to_lower, to_upper);
  const IVec res = grid.res();
  for (int side = 0; side < 2; ++side) {
    auto& B = S.border[side];
    if (B.blocks.empty()) continue;  // no node of this border's layers is read here
    const std::string& in = side == 0 ? from_lower : from_upper;
    // The slices of both ranks: (colour, block, nodes, this rank's).
    struct Slice {
      int colour;
      IVec block;
      const Node* nodes;
      bool own;
    };
    std::vector<Slice> slices;
    for (std::size_t b = 0; b < B.blocks.size(); ++b)
      slices.push_back({transfer::BlockShape<Dim>::colour(B.blocks[b]), B.blocks[b], B.nodes.data() + b * slice, true});
    std::vector<Node> received;
    if (!in.empty()) {
      std::uint64_t n = 0;
      const std::size_t each = Dim * sizeof(std::int32_t) + slice * sizeof(Node);
      if (in.size() < sizeof n) throw SimulationError("a message of grid nodes from another rank is truncated");
      std::memcpy(&n, in.data(), sizeof n);
      if (in.size() != sizeof n + n * each)
        throw SimulationError("a message of grid nodes from another rank has " + std::to_string(in.size()) +
                              " bytes; expected " + std::to_string(sizeof n + n * each));
      received.resize(n * slice);
      for (std::size_t b = 0; b < n; ++b) {
        const char* at = in.data() + sizeof n + b * each;
        std::int32_t c[Dim];
        std::memcpy(c, at, sizeof c);
        IVec block;
        for (int d = 0; d < Dim; ++d) block[d] = c[d];
        std::memcpy(static_cast<void*>(received.data() + b * slice), at + sizeof c, slice * sizeof(Node));
        slices.push_back({transfer::BlockShape<Dim>::colour(block), block, received.data() + b * slice, false});
      }
    }
    std::stable_sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.colour < b.colour; });
    // The layers: Order nodes along the axis from `first`, every node across.
    const int first = size * (side == 0 ? S.lo : S.hi);
    IVec dims = res;
    dims[S.axis] = Order;
    std::int64_t count = 1;
    for (int d = 0; d < Dim; ++d) count *= dims[d];
    B.sum.assign(std::size_t(count), Node::Zero());
    auto layer_index = [&](IVec i) {
      i[S.axis] -= first;
      std::int64_t k = 0;
      for (int d = 0; d < Dim; ++d) k = k * dims[d] + i[d];
      return k;
    };
    // Calls fn(layer index, coordinates, value) for a slice's nodes inside the grid, in packing order.
    const auto for_each_node = [&](const Slice& sl, auto&& fn) {
      // A slice of the lower neighbour's column or this rank's upper column starts past its block.
      const int from = sl.block[S.axis] * size == first ? 0 : size;
      const IVec corner = sl.block * size;
      const Node* v = sl.nodes;
      detail::for_each_layer_node<T, Dim, Order>(S.axis, from, [&](int, const IVec& l) {
        const IVec i = corner + l;
        const Node& value = *v++;
        if ((i.array() < res.array()).all()) fn(layer_index(i), i, value);
      });
    };
    for (const auto& sl : slices)
      for_each_node(sl, [&](std::int64_t k, const IVec&, const Node& value) { B.sum[std::size_t(k)] += value; });
    // The nodes this rank's patches reach take the sums; the others are not read here.
    for (const auto& sl : slices)
      if (sl.own)
        for_each_node(sl, [&](std::int64_t k, const IVec& i, const Node&) { *grid.find(i) = B.sum[std::size_t(k)]; });
  }
}

template <class T, int Dim>
Particles<T, Dim> MpmSolver<T, Dim>::all_particles(bool on_every_rank) const {
  std::vector<std::uint32_t> mine(particles_.size());
  for (std::size_t p = 0; p < mine.size(); ++p) mine[p] = std::uint32_t(p);
  std::string packed;
  detail::pack_particles(particles_, mine, packed);
  Particles<T, Dim> all = particles_.empty_like();
  const auto parts = on_every_rank ? split_->comm->all_gather(packed) : split_->comm->gather(packed);
  for (const auto& part : parts) detail::unpack_particles(part, all);
  return all;
}

}  // namespace slurry
