// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// The domain split over MPI ranks (mpm_solver.h, "Runs split over processes"): box borders from
// particle counts, migrating particles to the rank that owns their box, the grid halo (the
// border nodes' partial sums swapped with the ranks whose boxes touch), gathering every particle
// for frames and checkpoints.
#pragma once

namespace slurry {

template <class T, int Dim>
bool MpmSolver<T, Dim>::set_borders(const std::vector<double>& lattice, bool summed) {
  auto& S = *split_;
  const int ranks = S.comm->size(), rank = S.comm->rank();
  auto next = S.boxes;
  const auto per_rank = summed ? next.cut(lattice)
                               : next.cut(lattice, [&](std::vector<double>& c) { S.comm->sum(c.data(), int(c.size())); });
  S.fewest = *std::min_element(per_rank.begin(), per_rank.end());
  S.most = *std::max_element(per_rank.begin(), per_rank.end());
  if (next.cuts == S.boxes.cuts) return false;
  S.boxes = std::move(next);
  S.boxes.box(rank, S.lo, S.hi);
  // The peers: the owners of the blocks that touch this box (faces, edges, corners).
  std::vector<std::uint8_t> peer(std::size_t(ranks), 0);
  IVec from, to;
  for (int d = 0; d < Dim; ++d) from[d] = std::max(S.lo[d] - 1, 0), to[d] = std::min(S.hi[d] + 1, S.boxes.res[d]);
  for (IVec b = from;;) {
    if (!((b.array() >= S.lo.array()).all() && (b.array() < S.hi.array()).all())) peer[std::size_t(S.boxes.owner(b))] = 1;
    int d = Dim - 1;
    while (d >= 0 && ++b[d] == to[d]) b[d] = from[d], --d;
    if (d < 0) break;
  }
  S.peers.clear();
  for (int r = 0; r < ranks; ++r)
    if (peer[std::size_t(r)] && r != rank) S.peers.push_back(r);
  return true;
}

template <class T, int Dim>
std::vector<double> MpmSolver<T, Dim>::block_counts(const std::vector<Vec>& x, std::vector<double> counts) const {
  const IVec& res = split_->boxes.res;
  counts.resize(std::size_t(res.prod()), 0.0);
  for (const auto& p : x) {
    const IVec b = block_of(p);
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k = k * res[d] + b[d];
    counts[std::size_t(k)] += 1;
  }
  return counts;
}

template <class T, int Dim>
bool MpmSolver<T, Dim>::owns(const Vec& x) const {
  const IVec b = block_of(x);
  return (b.array() >= split_->lo.array()).all() && (b.array() < split_->hi.array()).all();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::split_particles() {
  // Every rank holds the same full set here, so every rank computes the same borders.
  auto& S = *split_;
  for (auto& c : S.boxes.cuts) c.clear();
  set_borders(block_counts(particles_.x), true);
  std::vector<std::uint8_t> drop(particles_.size());
  for (std::size_t p = 0; p < drop.size(); ++p) drop[p] = !owns(particles_.x[p]);
  detail::drop_particles(particles_, drop);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::rebalance() {
  if (set_borders(block_counts(particles_.x), false)) migrate();
}

template <class T, int Dim>
void MpmSolver<T, Dim>::migrate() {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: migrate_order<1>(); return;
    case KernelKind::Quadratic: migrate_order<2>(); return;
    case KernelKind::Cubic: break;
  }
  migrate_order<3>();
}

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::migrate_order() {
  auto& S = *split_;
  auto& P = particles_;
  const int ranks = S.comm->size(), rank = S.comm->rank();
  // Which particles left the box (in parallel: every particle is looked at every substep): the
  // base node of block_order against the box's node bounds, whose clamp at the lattice's ends
  // leaves the box unbounded there; branch-free.
  const T inv_dx = T(1) / dx_;
  constexpr int size = transfer::BlockShape<Dim>::size;
  IVec low, high;
  for (int d = 0; d < Dim; ++d) {
    low[d] = S.lo[d] == 0 ? std::numeric_limits<int>::min() : size * S.lo[d];
    high[d] = S.hi[d] == S.boxes.res[d] ? std::numeric_limits<int>::max() : size * S.hi[d];
  }
  std::vector<std::uint8_t> drop(P.size(), 0);
  // Captured by value: the byte stores may alias any reference, which would be read again per particle.
  const Vec* xs = P.x.data();
  std::uint8_t* flags = drop.data();
  const Vec origin = origin_;
  parallel::parallel_for(0, std::int64_t(P.size()), [=](std::int64_t p) {
    const Vec& x = xs[p];
    bool inside = true;
    for (int d = 0; d < Dim; ++d) {
      const int base = transfer::BSpline<Order>::base((x[d] - origin[d]) * inv_dx);
      inside &= base >= low[d] && base < high[d];
    }
    flags[p] = !inside;
  });
  // Each leaving particle goes straight to the owner of its block: after a substep that is a
  // peer (a particle moves less than a block), after new borders it may be any rank.
  std::vector<std::vector<std::uint32_t>> leaving(static_cast<std::size_t>(ranks));
  bool left = false;
  for (std::size_t p = 0; p < P.size(); ++p)
    if (drop[p]) leaving[std::size_t(S.boxes.owner(block_order<Order>(P.x[p])))].push_back(std::uint32_t(p)), left = true;
  double far = 0;
  for (int r = 0; r < ranks; ++r)
    if (!leaving[std::size_t(r)].empty() && !std::binary_search(S.peers.begin(), S.peers.end(), r)) far = 1;
  S.comm->max(&far, 1);
  std::vector<int> peers;
  if (far > 0) {
    for (int r = 0; r < ranks; ++r)
      if (r != rank) peers.push_back(r);
  } else {
    peers = S.peers;
  }
  std::vector<std::string> out(peers.size());
  for (std::size_t i = 0; i < peers.size(); ++i)
    if (!leaving[std::size_t(peers[i])].empty()) detail::pack_particles(P, leaving[std::size_t(peers[i])], out[i]);
  if (left) detail::drop_particles(P, drop);
  for (const auto& in : S.comm->exchange(peers, out)) detail::unpack_particles(in, P);
}

// The grid halo. A block's patch (blocks.h) covers its own nodes and the first Order node
// layers of the next block along each axis, so a node is reached by the patches of at most 2^Dim
// blocks, all touching one another (each differs from the node's own block by 0 or -1 per
// axis). Along axis d, the patch node at local coordinate l is shared with the patch of the
// block before when l < Order and with the block after when l >= size; a node's class records
// that per axis, and the neighbours b + delta whose patches hold the node are those with
// delta_d in {0} plus -1 or +1 as its class allows. One process adds the patches into a node
// colour after colour (a node takes at most one patch per colour), starting from zero. In a split
// run a rank keeps the patches of its blocks that touch another rank's box, sends each such rank
// the nodes the two share, and for every node it shares sums its own and the received
// contributions again from zero in colour order: the same additions in the same order, so the
// node holds the one-process sum bit for bit on every rank that reaches it, and they update it
// alike. What crosses a border per substep is the shared nodes of the occupied border blocks (4
// values a node), against the particles of a whole block layer that ghost copies would take.

namespace detail {

/// 3^Dim: the neighbours of a block, itself included (offset index: sum (delta_d + 1) 3^(Dim-1-d)).
template <int Dim>
constexpr int kNeighbours = Dim == 3 ? 27 : 9;

/// For each class of patch node (per axis: 0 shared with the block before, 1 with neither, 2
/// with the block after; class index sum c_d 3^(Dim-1-d)), the bit set of the neighbour offsets
/// (bit = offset index) whose patches also hold such a node, the block itself excluded.
template <int Dim>
std::array<std::uint32_t, kNeighbours<Dim>> class_offsets() {
  std::array<std::uint32_t, kNeighbours<Dim>> out{};
  for (int c = 0; c < kNeighbours<Dim>; ++c)
    for (int o = 0; o < kNeighbours<Dim>; ++o) {
      bool fits = o != kNeighbours<Dim> / 2;
      for (int d = Dim - 1, cc = c, oo = o; d >= 0; --d, cc /= 3, oo /= 3) {
        const int cls = cc % 3, delta = oo % 3 - 1;
        fits = fits && (delta == 0 || (delta == -1 && cls == 0) || (delta == 1 && cls == 2));
      }
      if (fits) out[std::size_t(c)] |= std::uint32_t(1) << o;
    }
  return out;
}

/// Each patch node's class (class_offsets), in patch order.
template <class T, int Dim, int Order>
std::array<std::uint8_t, transfer::Patch<T, Dim, Order>::count> patch_node_classes() {
  using P = transfer::Patch<T, Dim, Order>;
  constexpr int size = transfer::BlockShape<Dim>::size;
  std::array<std::uint8_t, P::count> out{};
  for (int k = 0; k < P::count; ++k) {
    int r = k, c = 0, scale = 1;
    for (int d = Dim - 1; d >= 0; --d, scale *= 3) {
      const int l = r % P::extent;
      r /= P::extent;
      c += scale * (l < Order ? 0 : l >= size ? 2 : 1);
    }
    out[std::size_t(k)] = std::uint8_t(c);
  }
  return out;
}

}  // namespace detail

template <class T, int Dim>
void MpmSolver<T, Dim>::neighbour_owners(const IVec& block, int* owners) const {
  const auto& S = *split_;
  for (int o = 0; o < detail::kNeighbours<Dim>; ++o) {
    IVec b = block;
    bool inside = true;
    for (int d = Dim - 1, oo = o; d >= 0; --d, oo /= 3) {
      b[d] += oo % 3 - 1;
      inside = inside && b[d] >= 0 && b[d] < S.boxes.res[d];
    }
    owners[o] = inside ? S.boxes.owner(b) : -1;
  }
}

namespace detail {

/// Bit o set: owners[o] (neighbour_owners) is `rank` (others: is a rank other than `rank`), the
/// block itself (the middle offset) aside.
template <int Dim>
std::uint32_t offsets_owned_by(const int* owners, int rank, bool others = false) {
  std::uint32_t bits = 0;
  for (int o = 0; o < kNeighbours<Dim>; ++o)
    if ((others ? owners[o] >= 0 && owners[o] != rank : owners[o] == rank) && o != kNeighbours<Dim> / 2)
      bits |= std::uint32_t(1) << o;
  return bits;
}

}  // namespace detail

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::prepare_halo() {
  auto& S = *split_;
  const std::size_t groups = bins_.groups();
  S.slot.assign(groups, -1);
  S.border.clear();
  S.border_owners.clear();
  const int me = S.comm->rank();
  int owners[detail::kNeighbours<Dim>];
  for (std::size_t g = 0; g < groups; ++g) {
    const IVec& block = bins_.bins()[bins_.group_begin(g)].block;
    // A block one or more blocks inside the box touches no other box.
    if (((block.array() > S.lo.array()).all() && (block.array() + 1 < S.hi.array()).all())) continue;
    neighbour_owners(block, owners);
    if (!detail::offsets_owned_by<Dim>(owners, me, true)) continue;
    S.slot[g] = std::int32_t(S.border.size());
    S.border.push_back(block);
    S.border_owners.insert(S.border_owners.end(), owners, owners + detail::kNeighbours<Dim>);
  }
  S.kept.resize(S.border.size() * std::size_t(transfer::Patch<T, Dim, Order>::count));
}

template <class T, int Dim>
template <int Order>
void MpmSolver<T, Dim>::keep_halo_patch(std::size_t group, const transfer::Patch<T, Dim, Order>& patch) {
  auto& S = *split_;
  const std::int32_t s = S.slot[group];
  if (s < 0) return;
  std::copy(patch.nodes.begin(), patch.nodes.end(), S.kept.begin() + std::ptrdiff_t(std::size_t(s) * patch.nodes.size()));
}

template <class T, int Dim>
template <int Order, class G>
void MpmSolver<T, Dim>::exchange_halo(G& grid) {
  using Node = transfer::GridNode<T, Dim>;
  using Patch = transfer::Patch<T, Dim, Order>;
  auto& S = *split_;
  constexpr int size = transfer::BlockShape<Dim>::size;
  static const auto offsets = detail::class_offsets<Dim>();
  static const auto classes = detail::patch_node_classes<T, Dim, Order>();
  const int me = S.comm->rank();
  // A message to a peer: per border block of this rank next to the peer's box, the block (Dim
  // int32) and its patch nodes that the peer's patches also hold, in patch order. The receiver
  // knows which nodes those are from the block and the split.
  std::vector<std::string> out(S.peers.size());
  for (std::size_t b = 0; b < S.border.size(); ++b) {
    const int* owners = S.border_owners.data() + b * std::size_t(detail::kNeighbours<Dim>);
    for (int o = 0; o < detail::kNeighbours<Dim>; ++o) {
      const int r = owners[o];
      // Each other rank once per block, at its first offset.
      if (r < 0 || r == me || std::find(owners, owners + o, r) != owners + o) continue;
      const std::uint32_t bits = detail::offsets_owned_by<Dim>(owners, r);
      const auto peer = std::lower_bound(S.peers.begin(), S.peers.end(), r);
      if (peer == S.peers.end() || *peer != r) throw SimulationError("a border block's neighbour belongs to a rank that is not a peer");
      std::string& m = out[std::size_t(peer - S.peers.begin())];
      std::int32_t c[Dim];
      for (int d = 0; d < Dim; ++d) c[d] = S.border[b][d];
      m.append(reinterpret_cast<const char*>(c), sizeof c);
      const Node* nodes = S.kept.data() + b * std::size_t(Patch::count);
      for (int k = 0; k < Patch::count; ++k)
        if (offsets[classes[std::size_t(k)]] & bits) m.append(reinterpret_cast<const char*>(nodes + k), sizeof(Node));
    }
  }
  for (const auto& m : out) S.halo_bytes += m.size();
  const auto in = S.comm->exchange(S.peers, out);
  // Every contribution to a shared node: (node and colour as node 2^Dim + colour, value, this
  // rank's), sorted by node, then colour.
  struct Entry {
    std::uint64_t key;
    const void* value;  // a received node need not be aligned as a Node
    bool own;
  };
  constexpr int kColourBits = Dim;
  std::vector<Entry> entries;
  const IVec res = grid.res();
  auto key = [&](const IVec& i) {
    std::int64_t k = 0;
    for (int d = 0; d < Dim; ++d) k = k * res[d] + i[d];
    return k;
  };
  // Calls fn(node coordinates, patch index k, index among the shared nodes) for the nodes of
  // block's patch in the classes that `bits` admits and that lie in the grid; returns how many
  // nodes those classes hold (as a message carries them, the grid's edge included).
  auto for_each_shared = [&](const IVec& block, std::uint32_t bits, auto&& fn) {
    std::size_t n = 0;
    const IVec corner = block * size;
    for (int k = 0; k < Patch::count; ++k) {
      if (!(offsets[classes[std::size_t(k)]] & bits)) continue;
      IVec i = corner;
      for (int d = Dim - 1, r = k; d >= 0; --d, r /= Patch::extent) i[d] += r % Patch::extent;
      if ((i.array() < res.array()).all()) fn(i, k, n);
      ++n;
    }
    return n;
  };
  for (std::size_t b = 0; b < S.border.size(); ++b) {
    const Node* nodes = S.kept.data() + b * std::size_t(Patch::count);
    const int colour = transfer::BlockShape<Dim>::colour(S.border[b]);
    const std::uint32_t foreign =
        detail::offsets_owned_by<Dim>(S.border_owners.data() + b * std::size_t(detail::kNeighbours<Dim>), me, true);
    for_each_shared(S.border[b], foreign, [&](const IVec& node, int k, std::size_t) {
      entries.push_back({(std::uint64_t(key(node)) << kColourBits) | std::uint64_t(colour), nodes + k, true});
    });
  }
  int owners[detail::kNeighbours<Dim>];
  for (std::size_t i = 0; i < in.size(); ++i) {
    const std::string& m = in[i];
    std::size_t at = 0;
    while (at < m.size()) {
      std::int32_t c[Dim];
      if (m.size() - at < sizeof c) throw SimulationError("a message of grid nodes from another rank is truncated");
      std::memcpy(c, m.data() + at, sizeof c);
      at += sizeof c;
      IVec block;
      for (int d = 0; d < Dim; ++d) block[d] = c[d];
      if ((block.array() < 0).any() || (block.array() >= S.boxes.res.array()).any())
        throw SimulationError("a message of grid nodes from another rank names a block outside the grid");
      neighbour_owners(block, owners);
      const std::uint32_t bits = detail::offsets_owned_by<Dim>(owners, me);
      const int colour = transfer::BlockShape<Dim>::colour(block);
      const char* base = m.data() + at;
      const std::size_t n = for_each_shared(block, bits, [&](const IVec& node, int, std::size_t j) {
        entries.push_back({(std::uint64_t(key(node)) << kColourBits) | std::uint64_t(colour), base + j * sizeof(Node), false});
      });
      if (m.size() - at < n * sizeof(Node)) throw SimulationError("a message of grid nodes from another rank is truncated");
      at += n * sizeof(Node);
    }
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) { return a.key < b.key; });
  // A node that this rank's patches reach and another rank's too takes the sum of all in colour
  // order; one that only this rank reaches holds it already, one it does not reach is not read.
  for (std::size_t j = 0; j < entries.size();) {
    std::size_t e = j;
    bool own = false, other = false;
    const std::uint64_t node = entries[j].key >> kColourBits;
    while (e < entries.size() && entries[e].key >> kColourBits == node) own |= entries[e].own, other |= !entries[e].own, ++e;
    if (own && other) {
      Node sum = Node::Zero();
      for (std::size_t k = j; k < e; ++k) {
        Node v;
        std::memcpy(static_cast<void*>(&v), entries[k].value, sizeof v);
        sum += v;
      }
      *grid.find(transfer::lattice_coord<Dim>(std::int64_t(node), res)) = sum;
    }
    j = e;
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
