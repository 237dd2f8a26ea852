#pragma once
/// \file level_set.h
/// Cell labels and the liquid level set phi at cell centres, from the particles.
///
/// Labels (marker-and-cell, Harlow & Welch 1965): a cell holding at least one particle is Fluid;
/// an empty cell whose centre lies inside a collider is Solid; an empty cell enclosed by
/// particle-holding, solid or out-of-domain face neighbours (a hole) is Fluid; any other cell
/// is Air.
///
/// phi, used by the ghost-fluid free-surface condition (theta = phi_i / (phi_i - phi_j),
/// Gibou et al. 2002, Enright et al. 2003): in a Fluid cell phi = -dx/2; in an Air cell next to
/// the liquid it is the distance from its centre to the union of the particles' spheres of
/// radius r (Zhu & Bridson 2005, sec. 3, "union of spheres"), kept >= dx/100 so its sign agrees
/// with the label. With r half the seeding spacing, a flat surface with regularly seeded
/// particles lands within a few hundredths of a cell of its true height (see flip_tests'
/// hydrostatic pool); elsewhere phi = +3 dx (far outside).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "slurry/engine/flip/cell_sort.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/solids.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// Labels and phi from particles sorted by cell (`sort.start`) at time t; r = particle radius;
/// `holes` is scratch.
template <class T, int Dim>
void label_cells(MacGrid<T, Dim>& g, const FlipParticles<T, Dim>& P, const CellSort<T, Dim>& sort,
                 const Solids<T, Dim>& solids, T t, T r, std::vector<std::uint8_t>& holes) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  const std::int64_t cells = g.num_cells();
  const T far = T(3) * g.dx, min_air = T(0.01) * g.dx;
  parallel::parallel_for(0, cells, [&](std::int64_t k) {
    if (sort.count(k) > 0) {
      g.label[k] = MacGrid<T, Dim>::Fluid;
      g.phi[k] = T(-0.5) * g.dx;
      return;
    }
    const IVec i = g.cell_coord(k);
    const Vec xc = g.cell_center(i);
    g.label[k] = !solids.empty() && solids.distance(xc, t) < T(0) ? MacGrid<T, Dim>::Solid : MacGrid<T, Dim>::Air;
    // Nearest particle among the 3^Dim neighbouring cells.
    T best2 = std::numeric_limits<T>::max();
    IVec lo, hi;
    for (int d = 0; d < Dim; ++d) lo[d] = std::max(i[d] - 1, 0), hi[d] = std::min(i[d] + 1, g.res[d] - 1);
    IVec j = lo;
    while (true) {
      const std::int64_t c = g.cell(j);
      for (std::int64_t p = sort.start[c]; p < sort.start[c + 1]; ++p) best2 = std::min(best2, (P.x[p] - xc).squaredNorm());
      int d = Dim - 1;
      while (d >= 0 && j[d] == hi[d]) j[d] = lo[d], --d;
      if (d < 0) break;
      ++j[d];
    }
    g.phi[k] = best2 == std::numeric_limits<T>::max() ? far : std::min(far, std::max(min_air, std::sqrt(best2) - r));
  });
  // Holes: an empty cell whose every face neighbour holds particles (or is solid, or is outside
  // the domain) is inside the liquid. Left as air it would be a pressure sink the liquid
  // collapses into, and the particles would clump (FLIP's sampling noise makes such holes common
  // at 4 particles per cell in 2D).
  holes.resize(std::size_t(cells));
  parallel::parallel_for(0, cells, [&](std::int64_t k) {
    holes[k] = 0;
    if (sort.count(k) > 0 || g.label[k] == MacGrid<T, Dim>::Solid) return;
    const IVec i = g.cell_coord(k);
    for (int d = 0; d < Dim; ++d)
      for (int s = -1; s <= 1; s += 2) {
        IVec j = i;
        j[d] += s;
        if (j[d] < 0 || j[d] >= g.res[d]) continue;
        const std::int64_t kj = g.cell(j);
        if (sort.count(kj) == 0 && g.label[kj] != MacGrid<T, Dim>::Solid) return;
      }
    holes[k] = 1;
  });
  parallel::parallel_for(0, cells, [&](std::int64_t k) {
    if (!holes[k]) return;
    g.label[k] = MacGrid<T, Dim>::Fluid;
    g.phi[k] = T(-0.5) * g.dx;
  });
}

}  // namespace slurry::flip
