#pragma once
/// \file surface_tension.h
/// Surface tension of the FLIP liquid as a pressure jump across its free surface: the liquid's
/// pressure at the surface is p = sigma kappa (Young-Laplace, air at p = 0), imposed by the
/// ghost-fluid pressure solve (pressure.h) where it imposed p = 0 (Hong & Kim 2005, "Discontinuous
/// fluids", ACM TOG 24(3); Enright, Nguyen, Gibou & Fedkiw 2003; Bridson, "Fluid Simulation for
/// Computer Graphics", 2nd ed., sec. on surface tension).
///
/// Curvature. The cell labels' phi (level_set.h) is -dx/2 throughout the liquid, too coarse to
/// differentiate twice. The curvature comes from a colour function of the particles instead (the
/// continuum-surface-force normal of Brackbill et al. 1992): c = the sum of the particles'
/// trilinear (cloud-in-cell) weights at each cell centre, smoothed by 3 passes of the
/// [1 2 1] / 4 filter along every axis (about a Gaussian of 1.3 dx), in the cells within 5 cells
/// of the surface. The unit normals n = -grad c / |grad c| (central differences) are taken in the
/// cells within one cell of the surface, and kappa = div n by central differences at the cells
/// of the surface on both sides (the fluid cells with an air face neighbour and the air cells
/// with a fluid one). Walls (the domain's sides and the cells labelled Solid, colliders) are
/// mirrors: the particles' mirror images across a wall's face count in the colour function of
/// the cells next to it, the smoothing and the gradient read the cell's own colour across the
/// wall (c even), and the divergence reads the cell's own normal with its wall component
/// negated (n's wall component odd, the mirror image's). The surface meets walls at 90 degrees,
/// and a half drop on a wall is the half of a drop at rest. (Repeating the edge cell's normal
/// instead, the wall component's derivative came out half of what it is: a half ball on the
/// floor had its curvature a quarter low at the contact line, and its liquid crept out along
/// the floor, 1.97 R from the centre after 6 s at R = 8 dx; flip_surface_tension_tests.) Only
/// the normals' directions are differentiated, so the colour
/// function's profile across the surface does not bias kappa: for a disk, n = x / |x| and
/// div n = 1 / |x| up to the differences' O(dx^2). On lattice-seeded disks and balls the mean
/// kappa at the surface cells is within 1.5% of the exact 1 / R (2D) or 2 / R (3D) for radii of
/// 8 to 32 cells; a cell's own kappa is noisier (up to 43% at 16 cells in 2D, 15% at 8 in 3D),
/// the staircase of the seeding that the smoothing does not remove. (A kernel-weighted mean
/// position, Zhu & Bridson 2005, in place of the colour function is flat from a cell inside the
/// surface on; with it the mean kappa at the air-side cells of a disk of 16 cells measured 24% low.) kappa > 0 where the liquid is convex.
/// kappa is then carried from each cell centre to the smoothed surface, the level c = bulk / 2
/// of the colour function (to_surface): a centre d outside that level has the curvature of the
/// level through it, (Dim - 1) / (R + d) for a ball of radius R, and the surface's is
/// kappa / (1 - d kappa / (Dim - 1)). Without this a bump of liquid narrower than the smoothing,
/// whose cells stand outside the smoothed surface, had a jump the lower the farther it stood
/// out: nothing pulled it back and the flow fed it. In 3D the outermost cells where an
/// oscillating drop's equator meets a grid axis were drawn out (their faces to air moving out
/// at 0.02-0.03 m/s while the liquid behind moved at 0.003-0.008), their particles left the
/// drop in straight lines from 7.5 s (0.85 of a period), and its kinetic energy was nearly 900
/// times its first by 29 s (a ball of 8 cells' radius in mode 2 at 5% amplitude, Rayleigh's
/// period 8.8 s). The level bulk / 2 lies inside a convex surface by about kappa s^2 / 2,
/// s^2 = 1.7 dx^2 the variance of the cloud-in-cell weights and the smoothing (a smoothed
/// indicator's levels move by their mean curvature), so the Laplace pressure comes out high by
/// the fraction kappa s^2 / (2 R) or so: 3.6% at 8 cells' radius in 3D, 1.9% at 12, 0.3% at 16
/// in 2D. Carrying kappa to the corrected level instead brought these within 0.9% but made the
/// 3D mode-2 period 9.0% long at 8 cells and 5.2% at 12 (4.7% and 3.3% at the half level):
/// another error lengthens the period, and the half level is the measured compromise.
/// |kappa| is clamped to 2 / dx in 3D and 1 / dx in 2D: a surface curved more tightly than a
/// ball of one cell's radius is not resolved (a few-particle droplet), and its jump is that of
/// the smallest resolved ball.
///
/// The surface pressure at a face from fluid cell c to air cell a is interpolated to where the
/// surface crosses it: p_gamma = (1 - theta) sigma kappa_c + theta sigma kappa_a, theta the
/// ghost-fluid fraction (pressure.h). With surface tension the solver places the surface inside
/// the liquid's surface cells (level_set.h, place_surface_in_fluid_cells; solver.free_surface
/// "subcell", which such a scene requires) rather than at least a third of a cell beyond their
/// centres, and the projection leaves the nearly empty faces this gives unprojected where liquid
/// behind them holds the cell (pressure.h, set_subcell_surface). With the curvature at the cell
/// centres, this took the Laplace pressure in a 3D ball from 2.9% to 1.2% low at 8 cells'
/// radius, the mode-2 period of the ball of 12 cells over its first period from 12.5% to 4.0%
/// long, and a glycerol puddle's height from 6.3% low to 1.0% high (flip_surface_tension_tests
/// and their validation set).
///
/// Time step: the explicit jump resolves capillary waves only if
/// dt <= sqrt(rho_avg dx^3 / (2 pi sigma)) (Brackbill, Kothe & Zemach 1992, "A continuum method
/// for modeling surface tension", J. Comput. Phys. 100, eq. 61), rho_avg the mean of the two
/// densities: rho / 2 for liquid under air. The substep keeps to half of it (kCapillarySafety);
/// FlipSolver::stable_dt() takes the minimum with it.
///
/// The capillary step is small (0.19 ms for water at dx = 0.5 mm): particles stay in their
/// cells for many substeps, which is where the solver keeps the particles' own velocities on the
/// air faces (FlipSolver::extrapolate_velocities; without that, sparse particles gained energy
/// without bound at such steps), and the volume correction removes its share of the density
/// error per advective step rather than per capillary substep (FlipSolver::project).
///
/// Known limits. A drop resolved by few cells does not hold together when it spreads thinner
/// than a cell (a 3 mm drop at dx = 0.5 mm falling at 0.3 m/s onto the floor spreads into a film
/// one particle thick and splashes up the walls). An inviscid drop's oscillation is damped a
/// little: a ball of 8 cells' radius oscillating in mode 2 at 5% amplitude (Rayleigh's period
/// 8.8 s) keeps its oscillation for 4.5 periods with its amplitude falling by 11% and its period
/// 4.6-4.9% long, and one of 12 cells its amplitude within 0.76 to 0.95 of the release's over 2
/// periods, 1.7% long (flip_surface_tension_tests and their validation set). A disk of 32
/// cells' radius stops oscillating in mode 2 in its second period and starts again later (the
/// kinetic energy at the fourth zero crossing of the mode's moment is a fifth of that at the
/// first; a tenth with the curvature at the cell centres), so its period is measured over the
/// first (flip_surface_tension_validation_tests). At 16 cells across the radius in 2D the
/// largest speed of a drop at rest stays bounded for 12 capillary times sqrt(rho R^3 / sigma).
/// The run's statistics count the surface energy sigma * area() (RunStats::surface).
///
/// Cost: only where the scene has surface tension (sigma > 0): a dozen passes over the cells
/// and one over the particles near the surface per substep.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <vector>

#include "slurry/engine/flip/cell_sort.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/kernels.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

template <class T, int Dim>
class SurfaceTension {
 public:
  using Grid = MacGrid<T, Dim>;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;

  /// Passes of the [1 2 1] / 4 filter along every axis over the colour function.
  static constexpr int kSmoothing = 3;
  /// compute(): the largest distance (cells) by which a cell centre's curvature is carried to
  /// the smoothed surface (to_surface()).
  static constexpr T kSurfaceReach = T(2);
  /// area(): cells within this many of the surface are summed (the smoothed colour's profile
  /// falls from the bulk to 0 within about 3 cells of it).
  static constexpr int kSumReach = 4;

  /// Share of Brackbill's limit the substep keeps to. At the full limit the spurious currents
  /// around a ball of 8 cells' radius grew tenfold in 10 s (to 0.1 m/s, against the mode-2
  /// oscillation's 0.01 m/s); at half of it they stayed at their initial level.
  static constexpr T kCapillarySafety = T(0.5);

  /// Half of Brackbill's capillary time step limit for a liquid of density rho under air (N/m, kg/m^3).
  static T max_dt(T dx, T rho, T sigma) {
    if (!(sigma > T(0))) return std::numeric_limits<T>::infinity();
    const T pi = T(3.14159265358979323846);
    return kCapillarySafety * std::sqrt(T(0.5) * rho * dx * dx * dx / (T(2) * pi * sigma));
  }

  /// sigma kappa (Pa) at the centres of the cells on either side of the free surface (fluid with
  /// an air face neighbour, air with a fluid one), 0 elsewhere: computed by compute().
  const std::vector<T>& pressure() const { return pressure_; }
  /// The smoothed colour function, in the cells within 5 cells of the surface; 0 elsewhere.
  const std::vector<T>& colour() const { return colour_; }

  /// Fills pressure() for surface tension sigma from the grid's labels and the particles,
  /// sorted by cell (`sort.start`, positions `P.x`); `bulk` is the colour of the bulk (the
  /// particles per cell), whose half marks the smoothed surface.
  void compute(const Grid& g, const FlipParticles<T, Dim>& P, const CellSort<T, Dim>& sort, T sigma, T bulk) {
    const std::int64_t n = g.num_cells();
    surface_.assign(std::size_t(n), 0);
    pressure_.assign(std::size_t(n), T(0));
    const auto is = [&](std::int64_t k, std::uint8_t l) { return g.label[std::size_t(k)] == l; };
    // 1. Surface cells: fluid next to air or air next to fluid, across a face.
    parallel::parallel_for(0, n, [&](std::int64_t k) {
      const bool fluid = is(k, Grid::Fluid), air = is(k, Grid::Air);
      if (!fluid && !air) return;
      const std::uint8_t other = fluid ? Grid::Air : Grid::Fluid;
      surface_[std::size_t(k)] = g.any_face_neighbour(k, [&](std::int64_t j) { return is(j, other); });
    });
    // 2. The bands: cells within one cell (normals) and 2 + kSmoothing cells (the colour
    // function) of a surface cell (per axis, so boxes).
    dilate(g, surface_, normal_band_, 1);
    dilate(g, surface_, band_, 2 + kSmoothing);
    // 3. The colour function in the outer band: the particles' trilinear (cloud-in-cell)
    // weights at the cell centres, then smoothed.
    const T inv_dx = T(1) / g.dx;
    const std::uint32_t* start = sort.start.data();
    const Vec* X = P.x.data();
    colour_.assign(std::size_t(n), T(0));
    smoothed_.assign(std::size_t(n), T(0));  // outside the band both stay 0
    parallel::parallel_for(0, n, [&](std::int64_t k) {
      if (!band_[std::size_t(k)]) return;
      const IVec i = g.cell_coord(k);
      const Vec xc = g.cell_center(i);
      // Next to a wall (the domain's side or a Solid cell) the particles' mirror images across
      // the wall's face count too (2 x_wall - x, weight hat(2 x_wall - x - x_c)).
      Vec wall_lo, wall_hi;
      bool lo[Dim], hi[Dim];
      for (int a = 0; a < Dim; ++a) {
        lo[a] = across(g, k, i, a, -1) < 0, hi[a] = across(g, k, i, a, 1) < 0;
        wall_lo[a] = T(2) * (xc[a] - T(0.5) * g.dx), wall_hi[a] = T(2) * (xc[a] + T(0.5) * g.dx);
      }
      T wsum = T(0);
      for_block(g, i, 1, [&](std::int64_t q) {
        for (std::uint32_t p = start[q]; p < start[q + 1]; ++p) {
          T w = T(1);
          for (int a = 0; a < Dim; ++a) {
            const T x = X[p][a];
            T wa = std::max(T(0), T(1) - std::abs(x - xc[a]) * inv_dx);
            if (lo[a]) wa += std::max(T(0), T(1) - std::abs(wall_lo[a] - x - xc[a]) * inv_dx);
            if (hi[a]) wa += std::max(T(0), T(1) - std::abs(wall_hi[a] - x - xc[a]) * inv_dx);
            w *= wa;
          }
          wsum += w;
        }
      });
      colour_[std::size_t(k)] = wsum;
    });
    smooth_colour(g);
    // 4. Unit normals -grad c / |grad c| in the inner band (central differences).
    normal_.assign(std::size_t(n), Vec::Zero());
    parallel::parallel_for(0, n, [&](std::int64_t k) {
      if (!normal_band_[std::size_t(k)]) return;
      const IVec i = g.cell_coord(k);
      Vec grad;
      for (int a = 0; a < Dim; ++a) grad[a] = even(g, colour_, k, i, a, -1) - even(g, colour_, k, i, a, 1);
      const T len = grad.norm();
      if (len > T(1e-9) * g.dx) normal_[std::size_t(k)] = grad / len;
    });
    // 5. kappa = div n at the surface cells (central differences), carried to the smoothed
    // surface, and sigma kappa.
    const T kmax = T(Dim - 1) / g.dx;
    parallel::parallel_for(0, n, [&](std::int64_t k) {
      if (!surface_[std::size_t(k)]) return;
      const IVec i = g.cell_coord(k);
      T div = T(0);
      Vec grad;  // -grad c, 2 dx times
      for (int a = 0; a < Dim; ++a) {
        const std::int64_t hi = across(g, k, i, a, 1), lo = across(g, k, i, a, -1);
        const T own = normal_[std::size_t(k)][a];
        div += (hi < 0 ? -own : normal_[std::size_t(hi)][a]) - (lo < 0 ? -own : normal_[std::size_t(lo)][a]);
        grad[a] = even(g, colour_, k, i, a, -1) - even(g, colour_, k, i, a, 1);
      }
      const T slope = grad.norm() / (T(2) * g.dx);  // |grad c|
      const T kappa = div / (T(2) * g.dx);
      pressure_[std::size_t(k)] = sigma * std::clamp(to_surface(kappa, colour_[std::size_t(k)], slope, bulk, g.dx), -kmax, kmax);
    });
  }

  /// The curvature at the smoothed surface, the level c = bulk / 2 of the colour function,
  /// from kappa, the curvature of the level through a cell centre of colour c where the
  /// colour's slope is |grad c|. The centre lies d = (bulk / 2 - c) / |grad c| outside that
  /// surface (kept within kSurfaceReach cells), and the levels of a ball's colour function are
  /// concentric spheres, kappa(r) = (Dim - 1) / r, so the surface's is
  /// kappa / (1 - d kappa / (Dim - 1)) (the denominator kept >= 1/2).
  static T to_surface(T kappa, T c, T slope, T bulk, T dx) {
    if (!(slope > T(1e-9) / dx)) return kappa;
    const T d = std::clamp((T(0.5) * bulk - c) / slope, -kSurfaceReach * dx, kSurfaceReach * dx);
    return kappa / std::max(T(1) - d * kappa / T(Dim - 1), T(0.5));
  }

  /// The area (3D; the length in 2D) of the liquid's free surface, for the energy sigma * area
  /// in the run's statistics: the total variation of the same smoothed colour function (but of
  /// every particle, not only those near the labelled surface), integral |grad c| dV, over the
  /// colour of the bulk `bulk` (particles per cell), since c falls from `bulk` to 0 across the
  /// surface. Walls are mirrors as in compute(), so
  /// liquid wetting a wall adds no area (at 90 degrees the wall's energy with liquid and with air
  /// are the same). Measured on lattice-seeded drops: -0.17% against 2 pi R at 16 cells across
  /// the radius (2D), -2.5% against 4 pi R^2 at 8 (3D), +0.03% against pi R / 2 for a quarter disk
  /// of 32 cells in the domain's corner (flip_surface_tension_tests). Only the cells within
  /// kSumReach of the surface count, so the interior's particle noise adds no area. Overwrites
  /// compute()'s buffers (the next compute() sets them again). `counted`: if given, only the
  /// cells it accepts are summed (a split run's own box, its window's other cells being its
  /// neighbours').
  double area(const Grid& g, const FlipParticles<T, Dim>& P, T bulk,
              const std::function<bool(std::int64_t)>& counted = {}) {
    const std::int64_t n = g.num_cells();
    colour_.assign(std::size_t(n), T(0));
    // Each particle's linear B-spline weights on the 2^Dim cell centres around it (the
    // transfers' stencil on the lattice of cell centres); weights beyond the domain's side fold
    // back onto the edge cell (the mirror image).
    Vec first_centre = g.origin + Vec::Constant(T(0.5) * g.dx);
    for (int a = 0; a < Dim; ++a)  // a window's first cell (MacGrid::offset)
      if (g.offset[a] != 0) first_centre[a] += T(g.offset[a]) * g.dx;
    for (const Vec& x : P.x) {
      const transfer::Stencil<T, Dim, 1> st(x - first_centre, T(1) / g.dx, g.dx);
      for (int corner = 0; corner < (1 << Dim); ++corner) {
        IVec c;
        T w = T(1);
        for (int a = 0; a < Dim; ++a) {
          const int bit = (corner >> a) & 1;
          c[a] = std::clamp(st.base[std::size_t(a)] + bit, 0, g.res[a] - 1);
          w *= st.w[a][bit];
        }
        colour_[std::size_t(g.cell(c))] += w;
      }
    }
    // Only the cells near the surface vary: those with colour next to one without (across a
    // face, walls aside), widened by the smoothing's reach and the sum's.
    surface_.resize(std::size_t(n));
    parallel::parallel_for(0, n, [&](std::int64_t k) {
      bool s = false;
      if (colour_[std::size_t(k)] > T(0)) {
        const IVec i = g.cell_coord(k);
        for (int a = 0; a < Dim && !s; ++a)
          for (int dir = -1; dir <= 1 && !s; dir += 2) {
            const std::int64_t q = across(g, k, i, a, dir);
            s = q >= 0 && colour_[std::size_t(q)] == T(0);
          }
      }
      surface_[std::size_t(k)] = s;
    });
    dilate(g, surface_, band_, kSumReach + kSmoothing);
    dilate(g, surface_, normal_band_, kSumReach);
    smoothed_ = colour_;  // outside the band both keep the raw colour
    smooth_colour(g);
    const double variation = parallel::parallel_sum<double>(0, n, 4096, [&](std::int64_t lo, std::int64_t hi) {
      double sum = 0;
      for (std::int64_t k = lo; k < hi; ++k) {
        if (!normal_band_[std::size_t(k)] || g.label[std::size_t(k)] == Grid::Solid) continue;
        if (counted && !counted(k)) continue;
        const IVec i = g.cell_coord(k);
        double grad2 = 0;
        for (int a = 0; a < Dim; ++a) {
          const double diff = double(even(g, colour_, k, i, a, 1)) - double(even(g, colour_, k, i, a, -1));
          grad2 += diff * diff;
        }
        sum += std::sqrt(grad2);
      }
      return sum;
    });
    // |grad c| = |central difference| / (2 dx), integrated over cells of dx^Dim.
    return variation * std::pow(double(g.dx), Dim - 1) / (2 * double(bulk));
  }

  std::size_t bytes() const {
    return surface_.capacity() + normal_band_.capacity() + band_.capacity() + scratch_.capacity() +
           (colour_.capacity() + smoothed_.capacity() + pressure_.capacity()) * sizeof(T) + normal_.capacity() * sizeof(Vec);
  }

 private:
  /// Calls f(cell index) for the cells of the (2 reach + 1)^Dim block around i inside the grid.
  template <class F>
  static void for_block(const Grid& g, const IVec& i, int reach, F&& f) {
    IVec lo, hi;
    for (int d = 0; d < Dim; ++d) lo[d] = std::max(i[d] - reach, 0), hi[d] = std::min(i[d] + reach, g.res[d] - 1);
    if constexpr (Dim == 2) {
      for (int a = lo[0]; a <= hi[0]; ++a)
        for (int b = lo[1]; b <= hi[1]; ++b) f(std::int64_t(a) * g.res[1] + b);
    } else {
      for (int a = lo[0]; a <= hi[0]; ++a)
        for (int b = lo[1]; b <= hi[1]; ++b)
          for (int c = lo[2]; c <= hi[2]; ++c) f((std::int64_t(a) * g.res[1] + b) * g.res[2] + c);
    }
  }

  /// kSmoothing passes of the [1 2 1] / 4 filter along every axis over colour_ in the band_
  /// cells (walls mirrored); smoothed_ holds what the cells outside the band keep.
  void smooth_colour(const Grid& g) {
    for (int pass = 0; pass < kSmoothing; ++pass)
      for (int d = 0; d < Dim; ++d) {
        parallel::parallel_for(0, g.num_cells(), [&](std::int64_t k) {
          if (!band_[std::size_t(k)]) return;
          const IVec i = g.cell_coord(k);
          smoothed_[std::size_t(k)] = T(0.25) * (even(g, colour_, k, i, d, 1) + even(g, colour_, k, i, d, -1)) +
                                      T(0.5) * colour_[std::size_t(k)];
        });
        colour_.swap(smoothed_);
      }
  }

  /// The neighbour of cell k (coordinates i) one step along axis a in direction dir (+1 or -1),
  /// or -1 where that is beyond the domain's side or a Solid cell: a wall.
  static std::int64_t across(const Grid& g, std::int64_t k, const IVec& i, int a, int dir) {
    const int j = i[a] + dir;
    if (j < 0 || j >= g.res[a]) return -1;
    const std::int64_t q = k + dir * g.cell_stride(a);
    return g.label[std::size_t(q)] == Grid::Solid ? -1 : q;
  }

  /// f at the neighbour across(k, i, a, dir), or at k itself across a wall: f continued as an
  /// even function of the distance to the wall's face (the mirror image).
  static T even(const Grid& g, const std::vector<T>& f, std::int64_t k, const IVec& i, int a, int dir) {
    const std::int64_t q = across(g, k, i, a, dir);
    return f[std::size_t(q < 0 ? k : q)];
  }

  /// out = the cells within `reach` cells of a set cell of `in` along every axis (a box of
  /// (2 reach + 1)^Dim), by one pass per axis: along each line of cells, a forward and a
  /// backward sweep carrying the distance to the nearest set cell (any reach, the same cost).
  void dilate(const Grid& g, const std::vector<std::uint8_t>& in, std::vector<std::uint8_t>& out, int reach) {
    const std::int64_t n = g.num_cells();
    out = in;
    scratch_.resize(std::size_t(n));
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t stride = g.cell_stride(d), length = g.res[d];
      scratch_.swap(out);
      parallel::parallel_for(0, n / length, [&](std::int64_t line) {
        const std::int64_t base = (line / stride) * stride * length + line % stride;
        std::int64_t last = -std::int64_t(reach) - 1;  // the last set cell at or before j
        for (std::int64_t j = 0; j < length; ++j) {
          const std::size_t k = std::size_t(base + j * stride);
          if (scratch_[k]) last = j;
          out[k] = j - last <= reach;
        }
        std::int64_t next = length + reach;  // the next set cell at or after j
        for (std::int64_t j = length - 1; j >= 0; --j) {
          const std::size_t k = std::size_t(base + j * stride);
          if (scratch_[k]) next = j;
          if (next - j <= reach) out[k] = 1;
        }
      });
    }
  }

  std::vector<std::uint8_t> surface_, normal_band_, band_, scratch_;
  std::vector<Vec> normal_;
  std::vector<T> colour_, smoothed_, pressure_;
};

}  // namespace slurry::flip
