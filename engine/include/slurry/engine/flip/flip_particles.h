#pragma once
/// \file flip_particles.h
/// Marker particles of the FLIP/APIC liquid solver, as a structure of arrays with only the
/// channels FLIP needs: position, velocity, and for APIC the affine vectors c_d (one per velocity
/// component: u_d(x) ~ v_d + c_d . (x - x_p), Jiang et al. 2015, sec. 6 for staggered grids);
/// a material id only when the scene has more than one liquid; a persistent id (a counter:
/// every new particle, seeded, emitted or reseeded, takes the next one) that survives the
/// reordering by cell of every substep, so a particle can be followed across frames. No
/// deformation gradient, no mass (every particle carries the same volume dx^Dim /
/// particles_per_cell).
#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "slurry/transfer/parallel.h"

namespace slurry::flip {

template <class T, int Dim>
struct FlipParticles {
  using Vec = Eigen::Matrix<T, Dim, 1>;

  bool affine = false;        ///< c channels exist (APIC)
  bool has_material = false;  ///< material channel exists
  std::vector<Vec> x;         ///< position (m)
  std::vector<Vec> v;         ///< velocity (m/s)
  std::array<std::vector<Vec>, Dim> c;  ///< APIC: c[d][p] = affine vector of component d (1/s)
  std::vector<std::uint16_t> material;
  std::vector<std::uint32_t> id;  ///< persistent particle id
  std::uint32_t next_id = 0;      ///< id of the next particle added

  std::size_t size() const { return x.size(); }

  void push_back(const Vec& pos, const Vec& vel, std::uint16_t mat) {
    x.push_back(pos);
    v.push_back(vel);
    id.push_back(next_id++);
    if (affine)
      for (int d = 0; d < Dim; ++d) c[d].push_back(Vec::Zero());
    if (has_material) material.push_back(mat);
  }

  /// Keeps the first n particles.
  void truncate(std::size_t n) {
    x.resize(n);
    v.resize(n);
    id.resize(n);
    if (affine)
      for (int d = 0; d < Dim; ++d) c[d].resize(n);
    if (has_material) material.resize(n);
  }

  /// Copies particle `from` to slot `to` (to <= from; used by in-place compaction).
  void move(std::size_t to, std::size_t from) {
    x[to] = x[from];
    v[to] = v[from];
    id[to] = id[from];
    if (affine)
      for (int d = 0; d < Dim; ++d) c[d][to] = c[d][from];
    if (has_material) material[to] = material[from];
  }

  /// Spare storage for permute(): one channel of each value type, kept between calls.
  struct PermuteBuffers {
    std::vector<Vec> vec;
    std::vector<std::uint32_t> u32;
    std::vector<std::uint16_t> u16;
    std::size_t bytes() const { return vec.capacity() * sizeof(Vec) + u32.capacity() * 4 + u16.capacity() * 2; }
  };

  /// this[i] = old this[order[i]] for every channel (each channel gathered in parallel into the
  /// spare buffer of its type, which then takes its place): one channel's worth of extra memory
  /// instead of a second copy of every particle.
  void permute(const std::vector<std::uint32_t>& order, PermuteBuffers& spare) {
    const std::int64_t n = std::int64_t(order.size());
    const std::uint32_t* o = order.data();
    const auto apply = [&](auto& channel, auto& buffer) {
      buffer.resize(std::size_t(n));
      auto* dst = buffer.data();
      const auto* src = channel.data();
      parallel::parallel_for(0, n, [&](std::int64_t i) { dst[i] = src[o[i]]; });
      channel.swap(buffer);
    };
    apply(x, spare.vec);
    apply(v, spare.vec);
    apply(id, spare.u32);
    if (affine)
      for (int d = 0; d < Dim; ++d) apply(c[d], spare.vec);
    if (has_material) apply(material, spare.u16);
  }

  /// Bytes held (capacity).
  std::size_t bytes() const {
    std::size_t b = x.capacity() * sizeof(Vec) + v.capacity() * sizeof(Vec) + material.capacity() * 2 + id.capacity() * 4;
    for (int d = 0; d < Dim; ++d) b += c[d].capacity() * sizeof(Vec);
    return b;
  }
};

}  // namespace slurry::flip
