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
///
/// Known bias: with phi = -dx/2 in every fluid cell, theta >= 1/3 at a fluid cell holding a
/// sliver of liquid, so the pressure solve sees the liquid up to about half a cell beyond its
/// particles (more where a surface cell's particles all sit in its inner half: its centre is
/// then outside the liquid). place_surface_in_fluid_cells() below takes a surface cell's phi
/// from its air neighbours instead (solver.free_surface "subcell"), and the pressure solve then
/// leaves the faces it makes nearly empty unprojected (pressure.h, set_subcell_surface). What
/// the half cell costs, measured:
/// - a standing wave's own damping (dx = 1/48, 1/64, 1/96 of a 1 m tank; viscosity_wave_test.cpp)
///   is 0.27, 0.19, 0.09 1/s with phi = -dx/2 and 0.031, 0.0097, 0.0070 1/s placed, so the
///   damping of a viscous wave only matches Lamb's rate with the surface placed;
/// - where the surface carries a pressure jump (surface tension) it misplaces the jump, and it
///   was most of what made a 3D drop's mode-2 period long (surface_tension.h).
/// The solver places the surface for scenes with surface tension or viscosity ("auto"); other
/// scenes keep phi = -dx/2 unless they ask for "subcell", since on the 3D dam break the placed
/// surface and its rule lost more volume (the filled-cell volume's worst over 120 frames -6.57%,
/// against -4.90%) and made its whitewater depend more on the substep (scene-reference.md).
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
  constexpr int L = Dim - 1;  // rows of cells run along the last axis
  const int row_len = g.res[L];
  const std::int64_t rows = cells / row_len;
  const std::uint32_t* start = sort.start.data();
  const Vec* X = P.x.data();
  std::int64_t cstride[Dim];
  for (int d = 0; d < Dim; ++d) cstride[d] = g.cell_stride(d);
  parallel::parallel_for(0, rows, [&](std::int64_t row) {
    // Row coordinates and the first cells of the 3^(Dim-1) neighbouring rows.
    IVec i;
    std::int64_t rr = row;
    for (int a = L - 1; a >= 0; --a) i[a] = int(rr % g.res[a]), rr /= g.res[a];
    std::int64_t nb[Dim == 3 ? 9 : 3];
    int n_nb = 0;
    if constexpr (Dim == 2) {
      for (int a = std::max(i[0] - 1, 0); a <= std::min(i[0] + 1, g.res[0] - 1); ++a) nb[n_nb++] = a * cstride[0];
    } else {
      for (int a = std::max(i[0] - 1, 0); a <= std::min(i[0] + 1, g.res[0] - 1); ++a)
        for (int b = std::max(i[1] - 1, 0); b <= std::min(i[1] + 1, g.res[1] - 1); ++b)
          nb[n_nb++] = a * cstride[0] + b * cstride[1];
    }
    const std::int64_t k0 = row * row_len;
    // No particle in this row or the rows beside it: every cell is air (or solid) at the far
    // distance, without the per-cell search (most of the domain, most of the time).
    bool near_particles = false;
    for (int q = 0; q < n_nb; ++q) near_particles = near_particles || start[nb[q] + row_len] > start[nb[q]];
    if (!near_particles) {
      for (int j = 0; j < row_len; ++j) {
        i[L] = j;
        g.label[k0 + j] = !solids.empty() && solids.distance(g.cell_center(i), t) < T(0) ? MacGrid<T, Dim>::Solid
                                                                                           : MacGrid<T, Dim>::Air;
        g.phi[k0 + j] = far;
      }
      return;
    }
    for (int j = 0; j < row_len; ++j) {
      const std::int64_t k = k0 + j;
      if (start[k + 1] > start[k]) {
        g.label[k] = MacGrid<T, Dim>::Fluid;
        g.phi[k] = T(-0.5) * g.dx;
        continue;
      }
      i[L] = j;
      const Vec xc = g.cell_center(i);
      g.label[k] = !solids.empty() && solids.distance(xc, t) < T(0) ? MacGrid<T, Dim>::Solid : MacGrid<T, Dim>::Air;
      // Nearest particle among the 3^Dim neighbouring cells: per neighbouring row, the cells
      // j - 1 .. j + 1 hold one contiguous range of sorted particles.
      const int j0 = std::max(j - 1, 0), j1 = std::min(j + 1, row_len - 1);
      T best2 = std::numeric_limits<T>::max();
      for (int q = 0; q < n_nb; ++q)
        for (std::int64_t p = start[nb[q] + j0], p1 = start[nb[q] + j1 + 1]; p < p1; ++p)
          best2 = std::min(best2, (X[p] - xc).squaredNorm());
      g.phi[k] = best2 == std::numeric_limits<T>::max() ? far : std::min(far, std::max(min_air, std::sqrt(best2) - r));
    }
  });
  // Holes: an empty cell whose every face neighbour holds particles (or is solid, or is outside
  // the domain) is inside the liquid. Left as air it would be a pressure sink the liquid
  // collapses into, and the particles would clump (FLIP's sampling noise makes such holes common
  // at 4 particles per cell in 2D).
  holes.resize(std::size_t(cells));
  parallel::parallel_for(0, rows, [&](std::int64_t row) {
    IVec i;
    std::int64_t rr = row;
    for (int a = L - 1; a >= 0; --a) i[a] = int(rr % g.res[a]), rr /= g.res[a];
    const auto full = [&](std::int64_t kj) {
      return start[kj + 1] > start[kj] || g.label[kj] == MacGrid<T, Dim>::Solid;
    };
    const std::int64_t k0 = row * row_len;
    // Without solids, a row of at least two cells and no particle has no hole: every cell has
    // an empty neighbour along the row.
    if (solids.empty() && row_len >= 2 && start[k0 + row_len] == start[k0]) {
      std::fill(holes.begin() + k0, holes.begin() + k0 + row_len, std::uint8_t(0));
      return;
    }
    for (int j = 0; j < row_len; ++j) {
      const std::int64_t k = k0 + j;
      holes[k] = 0;
      if (full(k)) continue;
      i[L] = j;
      bool enclosed = true;
      for (int d = 0; d < Dim && enclosed; ++d) {
        if (i[d] > 0) enclosed = full(k - cstride[d]);
        if (enclosed && i[d] + 1 < g.res[d]) enclosed = full(k + cstride[d]);
      }
      holes[k] = enclosed;
    }
  });
  parallel::parallel_for(0, cells, [&](std::int64_t k) {
    if (!holes[k]) return;
    g.label[k] = MacGrid<T, Dim>::Fluid;
    g.phi[k] = T(-0.5) * g.dx;
  });
}

/// Places the free surface inside the liquid's surface cells (the Fluid cells with an Air face
/// neighbour), whose phi label_cells() left at -dx/2: phi_c = the largest over the Air cells a of
/// the 3^Dim block around c of phi_a - |x_c - x_a|, the bound that a signed distance's unit
/// slope gives (exact for a flat surface at any height), kept <= -cap dx so that its sign
/// agrees with the label (cap = kSurfaceCap). Reads only Air cells' phi and writes only Fluid
/// cells', so the cells may be done in any order.
template <class T, int Dim>
void place_surface_in_fluid_cells(MacGrid<T, Dim>& g) {
  using IVec = Eigen::Matrix<int, Dim, 1>;
  constexpr T kSurfaceCap = T(0.01);
  const std::uint8_t fluid = MacGrid<T, Dim>::Fluid, air = MacGrid<T, Dim>::Air;
  // |x_c - x_a| by the number of axes along which a is offset from c.
  const T distance[4] = {T(0), g.dx, std::sqrt(T(2)) * g.dx, std::sqrt(T(3)) * g.dx};
  parallel::parallel_for(0, g.num_cells(), [&](std::int64_t k) {
    if (g.label[std::size_t(k)] != fluid) return;
    const IVec i = g.cell_coord(k);
    if (!g.any_face_neighbour(k, i, [&](std::int64_t j) { return g.label[std::size_t(j)] == air; })) return;
    T best = -std::numeric_limits<T>::max();
    for (int o = 0; o < (Dim == 3 ? 27 : 9); ++o) {
      IVec q = i;
      int moved = 0;
      bool inside = true;
      for (int d = 0, m = o; d < Dim; ++d, m /= 3) {
        const int step = m % 3 - 1;
        q[d] += step;
        moved += step != 0;
        inside = inside && q[d] >= 0 && q[d] < g.res[d];
      }
      if (!inside || moved == 0) continue;
      const std::int64_t a = g.cell(q);
      if (g.label[std::size_t(a)] == air) best = std::max(best, g.phi[std::size_t(a)] - distance[moved]);
    }
    g.phi[std::size_t(k)] = std::min(best, -kSurfaceCap * g.dx);
  });
}

}  // namespace slurry::flip
