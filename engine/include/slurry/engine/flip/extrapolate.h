#pragma once
/// \file extrapolate.h
/// Extends face velocities from the faces where they are known (`valid`, set by the pressure
/// projection on faces next to fluid) into the air, layer by layer, so that particles near the
/// free surface and the advection read fluid velocities (Bridson, "Fluid Simulation for Computer
/// Graphics", 2nd ed., sec. 4.4 and 7.x: breadth-first extrapolation).
///
/// Layer L fills every invalid, open face that has a neighbour (along any axis, in the same
/// component's face grid) valid before layer L. Its value:
/// - Linear (default): the mean over axes and directions of the linear extrapolations
///   2 u(f - s) - u(f - 2s) where both faces behind f were valid; this reproduces a linear field
///   exactly. Faces without such a pair take the constant rule below.
/// - Constant: the mean of the valid neighbours (Bridson's rule).
/// A layer reads only faces valid before it, so the result does not depend on the order or the
/// thread count. Faces of open weight 0 (MacGrid::open_weight: walls, solids) keep u = u_solid
/// and are neither sources nor targets. Filled faces are marked valid.
#include <array>
#include <cstdint>
#include <vector>

#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

enum class Extrapolation { Constant, Linear };

/// Fills up to `layers` layers of invalid faces from valid neighbours; returns the number of faces
/// filled.
template <class T, int Dim>
std::int64_t extrapolate(MacGrid<T, Dim>& g, int layers, Extrapolation rule = Extrapolation::Linear) {
  using IVec = typename MacGrid<T, Dim>::IVec;
  std::int64_t filled = 0;
  for (int d = 0; d < Dim; ++d) {
    const std::int64_t nf = g.num_faces(d);
    const IVec fr = g.face_res(d);
    std::array<std::int64_t, Dim> stride;
    for (int a = 0; a < Dim; ++a) stride[a] = g.face_stride(d, a);
    // stamp: -2 closed, -1 unknown, 0 valid on entry, L filled by layer L.
    std::vector<int> stamp(static_cast<std::size_t>(nf));
    std::vector<std::uint8_t> fill(std::size_t(nf), 0);
    parallel::parallel_for(0, nf, [&](std::int64_t f) {
      const IVec fi = g.face_coord(d, f);
      if (g.open_weight(d, fi) <= T(0)) {
        stamp[std::size_t(f)] = -2;
        g.u[d][std::size_t(f)] = g.u_solid[d][std::size_t(f)];
      } else {
        stamp[std::size_t(f)] = g.valid[d][std::size_t(f)] ? 0 : -1;
      }
    });
    for (int layer = 1; layer <= layers; ++layer) {
      const auto known = [&](std::int64_t f) { return stamp[std::size_t(f)] >= 0 && stamp[std::size_t(f)] < layer; };
      filled += parallel::parallel_sum<std::int64_t>(0, nf, 4096, [&](std::int64_t lo, std::int64_t hi) {
        std::int64_t count = 0;
        for (std::int64_t f = lo; f < hi; ++f) {
          if (stamp[std::size_t(f)] != -1) continue;
          const IVec fi = g.face_coord(d, f);
          double lin = 0, con = 0;
          int n_lin = 0, n_con = 0;
          for (int a = 0; a < Dim; ++a) {
            for (int dir = -1; dir <= 1; dir += 2) {
              const int i1 = fi[a] + dir, i2 = fi[a] + 2 * dir;
              if (i1 < 0 || i1 >= fr[a]) continue;
              const std::int64_t f1 = f + dir * stride[a];
              if (!known(f1)) continue;
              const double u1 = double(g.u[d][std::size_t(f1)]);
              con += u1;
              ++n_con;
              if (rule == Extrapolation::Linear && i2 >= 0 && i2 < fr[a]) {
                const std::int64_t f2 = f + 2 * dir * stride[a];
                if (known(f2)) {
                  lin += 2 * u1 - double(g.u[d][std::size_t(f2)]);
                  ++n_lin;
                }
              }
            }
          }
          if (n_con == 0) continue;
          // Writing f is safe: this layer reads only faces known before it, and f is not one.
          g.u[d][std::size_t(f)] = T(n_lin > 0 ? lin / n_lin : con / n_con);
          fill[std::size_t(f)] = 1;
          ++count;
        }
        return count;
      });
      // Mark after the whole layer was computed (the reads above saw only older layers).
      parallel::parallel_for(0, nf, [&](std::int64_t f) {
        if (fill[std::size_t(f)]) stamp[std::size_t(f)] = layer, fill[std::size_t(f)] = 0;
      });
    }
    parallel::parallel_for(0, nf, [&](std::int64_t f) {
      if (stamp[std::size_t(f)] >= 0) g.valid[d][std::size_t(f)] = 1;
    });
  }
  return filled;
}

}  // namespace slurry::flip
