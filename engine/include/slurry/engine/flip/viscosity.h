#pragma once
/// \file viscosity.h
/// Implicit viscosity of the FLIP liquid on a MacGrid, after Batty & Bridson 2008 ("Accurate
/// viscous free surfaces for buckling, coiling, and rotating liquids", SCA 2008): the face
/// velocities are replaced by the solution u* of
///
///   rho (u* - u) / dt = div (2 mu D(u*)),   D(u) = (grad u + grad u^T) / 2,
///
/// written as the minimiser of the variational form (Batty & Bridson 2008, sec. 4)
///
///   E(u*) = 1/2 sum_f rho W_f (u*_f - u_f)^2 + dt sum_s mu_s W_s |D_s(u*)|_F^2,
///
/// where the stress components are sampled where their finite differences are centred: the
/// diagonal D_dd = du_d/dx_d at cell centres, the off-diagonal D_ab = (du_a/dx_b + du_b/dx_a) / 2
/// at the grid nodes in 2D and at the midpoints of the grid edges parallel to the third axis in
/// 3D. Every velocity sample f and stress sample s is weighted by the liquid volume fraction W of
/// its control volume (the cell-sized box centred on it): the free surface then needs no
/// explicit traction condition, and a face of the air band that touches a weighted stress
/// sample is an unknown without mass, whose value minimises the stress energy (the
/// traction-free condition in the limit). The system
///
///   (W_u + dt/rho G^T diag(mu W_tau c) G) u* = W_u u     (c = 2 on the diagonal samples, 1 else)
///
/// is symmetric positive (semi)definite; its right-hand side has no component in the null
/// space (which lives on massless faces only), and it is solved by conjugate gradients with a
/// Jacobi preconditioner on an assembled sparse matrix (a fixed number of slots per row, 32-bit
/// columns, double precision). The work is done near the liquid only: cells within one cell of
/// a cell with phi < dx/2, and the ring of samples and faces that read them (mark_active());
/// elsewhere every weight is exactly 0, as the full-grid computation gives. The pressure
/// solve's PCG (pressure.h) is specialised to one unknown per cell and its 5/7-point stencil;
/// the viscous system has one unknown per face and couples the velocity components.
///
/// Volume fractions (Batty & Bridson 2008, sec. 5: "computed by supersampling"): the liquid
/// level set phi of the cell centres (level_set.h; the one the pressure solve's ghost fluid
/// reads) is interpolated to a lattice of 2 x 2 (x 2) points per cell, at +-dx/4 from its
/// centre; each point holds the smoothed indicator H = clamp(1/2 - phi / (dx/2), 0, 1). Every
/// control volume, whichever sample it is centred on, holds exactly 2^Dim of those points, and
/// its W is their mean.
///
/// Solids, no-slip (as the paper): closed faces (MacGrid::open_weight 0: the domain walls and
/// faces next to Solid cells) keep the solid's velocity u_solid, and supersampling points in
/// Solid cells count as filled for the stress weights (not for the faces' masses), so a stress
/// sample between liquid and a collider ties the liquid to the collider's velocity. On the
/// domain walls the tangential velocity sits exactly on the wall: a node (edge) sample on a wall
/// reads the velocity outside as its mirror image, u_ghost = -u_inside (a no-slip wall at
/// rest), and its weight counts only the half of its control volume inside the domain. Plane
/// Poiseuille flow between walls is then reproduced to (dx/H)^2 (tests/flip/viscosity_test.cpp).
/// Free-slip walls (`no_slip_walls` false) mirror with u_ghost = +u_inside instead: no shear
/// stress on the wall, which is what a standing wave in a tank of free-slip walls needs to damp
/// at Lamb's rate.
///
/// Viscosity in space: the caller gives mu per cell (the FLIP solver averages its particles'
/// material viscosities per cell); a diagonal sample takes its cell's mu, an off-diagonal
/// sample the mean of the 4 cells around it that are inside the domain. With one viscosity for
/// the whole liquid, `mu_cell` is empty and `mu_uniform` is used everywhere.
///
/// Every loop is parallel over independent rows and every reduction sums fixed chunks in a
/// fixed order (parallel::parallel_sum): results are bitwise identical for any thread count.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <vector>

#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// What one viscosity solve did.
struct ViscosityReport {
  int iterations = 0;            ///< PCG iterations
  double relative_residual = 0;  ///< ||b - A u*|| / ||b|| at return
  bool converged = true;         ///< relative_residual <= tolerance
  std::int64_t unknowns = 0;     ///< faces in the system
};

/// Assembles and solves the viscous system of a MacGrid; keeps its buffers between calls.
template <class T, int Dim>
class ViscositySolver {
 public:
  using Grid = MacGrid<T, Dim>;
  using IVec = typename Grid::IVec;
  static constexpr int kPairs = Dim == 2 ? 1 : 3;  ///< off-diagonal components (a < b)
  /// Most stored entries of a row before duplicates merge: the diagonal, two diagonal samples
  /// of two faces each, and per other axis two off-diagonal samples of four faces each.
  static constexpr int kMaxRow = 1 + 2 * 2 + (Dim - 1) * 2 * 4;
  /// Distinct columns of a row: the face itself, its two neighbours along its axis, and per
  /// other axis b its two neighbours along b and the four axis-b faces around it.
  static constexpr int kWidth = 1 + 2 + (Dim - 1) * 6;
  static constexpr std::int64_t kGrain = 4096;  ///< chunk of the parallel sums (fixed)

  double tolerance = 1e-6;   ///< relative residual of the PCG
  int max_iterations = 2000;
  /// The domain walls hold the tangential velocity at zero (no-slip); otherwise they are free
  /// slip, the mirror u_ghost = +u_inside: no shear stress on the wall.
  bool no_slip_walls = true;

  /// Replaces g.u on the faces that the viscous stress reaches by u*, for the step dt, liquid
  /// density rho (kg/m^3) and viscosity mu (Pa s): `mu_cell` per cell of g, or empty and then
  /// `mu_uniform`. Reads g.label, g.phi, the open face weights and u_solid; u of closed faces
  /// is not changed (the projection sets them).
  ViscosityReport solve(Grid& g, T dt, double rho, double mu_uniform, const std::vector<T>& mu_cell = {}) {
    ViscosityReport rep;
    setup(g);
    mark_active(g);
    supersample(g);
    const double scale = double(dt) / rho;
    stress_weights(g, scale, mu_uniform, mu_cell);
    number_unknowns(g);
    rep.unknowns = std::int64_t(unknown_face_.size());
    if (rep.unknowns == 0) return rep;
    assemble(g);
    rep = pcg();
    rep.unknowns = std::int64_t(unknown_face_.size());
    const std::int64_t n = rep.unknowns;
    parallel::parallel_for(0, n, [&](std::int64_t r) {
      g.u[unknown_axis_[std::size_t(r)]][std::size_t(unknown_face_[std::size_t(r)])] = T(x_[std::size_t(r)]);
    });
    return rep;
  }

  /// Liquid volume fraction of the control volume of axis-d face i after the last solve().
  double face_fraction(int d, const IVec& i) const {
    IVec lo = 2 * i;
    lo[d] -= 1;
    return fraction(lo).first;
  }

  /// Bytes held by the work arrays (capacity).
  std::size_t bytes() const {
    std::size_t b = fine_.capacity() * sizeof(T) + kappa_cell_.capacity() * sizeof(double);
    b += active_.capacity() + reach_.capacity() + mask_scratch_.capacity();
    for (const auto& k : kappa_edge_) b += k.capacity() * sizeof(double);
    for (const auto& k : index_) b += k.capacity() * sizeof(std::int32_t);
    b += (unknown_face_.capacity() + col_.capacity()) * sizeof(std::uint32_t) + unknown_axis_.capacity() + len_.capacity();
    b += (val_.capacity() + rhs_.capacity() + diag_.capacity() + x_.capacity() + r_.capacity() + z_.capacity() +
          p_.capacity() + q_.capacity()) * sizeof(double);
    return b;
  }

 private:
  /// One face's term in a stress sample's finite difference: coefficient (1/m) on axis-d face f.
  struct Term {
    int d = 0;
    std::int64_t f = 0;
    double coef = 0;
  };

  static constexpr T kSolid = T(2);  ///< supersampling value of a point in a Solid cell

  void setup(const Grid& g) {
    res_ = g.res;
    dx_ = double(g.dx);
    for (int a = 0; a < Dim; ++a) fine_res_[a] = 2 * res_[a];
    int p = 0;
    for (int a = 0; a < Dim; ++a)
      for (int b = a + 1; b < Dim; ++b) pair_a_[p] = a, pair_b_[p] = b, ++p;
  }

  /// Lattice index of the off-diagonal samples of pair p: (res + e_a + e_b) points, row-major.
  IVec edge_res(int p) const {
    IVec r = res_;
    r[pair_a_[p]] += 1;
    r[pair_b_[p]] += 1;
    return r;
  }
  static std::int64_t linear(const IVec& i, const IVec& box) { return transfer::lattice_index<Dim>(i, box); }

  /// The cells near the liquid, where the work is done. A supersampling point's phi is a convex
  /// combination of the phi of its cell and of neighbours within one cell, so H > 0 (phi <
  /// dx/4) only at points of cells within one cell of a cell with phi < dx/2: those are
  /// `active_`, and every other point of the grid holds H = 0 (or kSolid) without
  /// interpolating. A stress sample or face whose control volumes hold only points of inactive
  /// cells has no liquid volume, so one more ring, `reach_`, bounds where kappa and unknowns can
  /// be nonzero: everything outside it is skipped by a test of one byte.
  void mark_active(const Grid& g) {
    const std::int64_t n = g.num_cells();
    const T limit = T(0.5) * g.dx;
    active_.resize(std::size_t(n));
    std::uint8_t* near = active_.data();
    parallel::parallel_for(0, n, [&](std::int64_t c) { near[c] = g.phi[std::size_t(c)] < limit ? 1 : 0; });
    dilate(g, active_);
    reach_ = active_;
    dilate(g, reach_);
  }

  /// mask |= its neighbours within one cell along every axis (a 3^Dim box, axis by axis).
  void dilate(const Grid& g, std::vector<std::uint8_t>& mask) {
    const std::int64_t n = g.num_cells();
    mask_scratch_.resize(std::size_t(n));
    for (int a = 0; a < Dim; ++a) {
      const std::int64_t stride = g.cell_stride(a);
      const std::uint8_t* in = mask.data();
      std::uint8_t* out = mask_scratch_.data();
      parallel::parallel_for(0, n, [&](std::int64_t c) {
        const int i = int((c / stride) % res_[a]);
        std::uint8_t m = in[c];
        if (i > 0) m |= in[c - stride];
        if (i + 1 < res_[a]) m |= in[c + stride];
        out[c] = m;
      });
      mask.swap(mask_scratch_);
    }
  }

  /// H at the supersampling points (2 per cell and axis), from phi interpolated multilinearly
  /// between cell centres (a point at +-dx/4 from its centre has weights 3/4 and 1/4 along each
  /// axis; outside the domain the cell's own value is used).
  void supersample(const Grid& g) {
    std::int64_t n = 1;
    for (int a = 0; a < Dim; ++a) n *= fine_res_[a];
    fine_.resize(std::size_t(n));
    const T half_dx = T(0.5) * g.dx;
    parallel::parallel_for(0, g.num_cells(), [&](std::int64_t c) {
      const IVec i = g.cell_coord(c);
      const bool solid = g.label[std::size_t(c)] == Grid::Solid;
      if (solid || !active_[std::size_t(c)]) {
        for (int o = 0; o < (1 << Dim); ++o) {
          IVec s;
          for (int a = 0; a < Dim; ++a) s[a] = (o >> a) & 1;
          fine_[std::size_t(linear(IVec(2 * i + s), fine_res_))] = solid ? kSolid : T(0);
        }
        return;
      }
      for (int o = 0; o < (1 << Dim); ++o) {
        IVec s;
        for (int a = 0; a < Dim; ++a) s[a] = (o >> a) & 1;
        T phi = T(0);
        for (int corner = 0; corner < (1 << Dim); ++corner) {
          IVec j = i;
          T w = T(1);
          for (int a = 0; a < Dim; ++a) {
            const bool far = (corner >> a) & 1;  // the neighbour on the point's side
            if (far) {
              const int nb = i[a] + (s[a] ? 1 : -1);
              if (nb >= 0 && nb < res_[a]) j[a] = nb;
              w *= T(0.25);
            } else {
              w *= T(0.75);
            }
          }
          phi += w * g.phi[std::size_t(g.cell(j))];
        }
        fine_[std::size_t(linear(IVec(2 * i + s), fine_res_))] = std::clamp(T(0.5) - phi / half_dx, T(0), T(1));
      }
    });
  }

  /// (liquid fraction, liquid-or-solid fraction) of the control volume that holds the
  /// supersampling points lo + {0, 1}^Dim; points outside the domain count as neither.
  std::pair<double, double> fraction(const IVec& lo) const {
    double liquid = 0, filled = 0;
    for (int o = 0; o < (1 << Dim); ++o) {
      IVec q = lo;
      bool inside = true;
      for (int a = 0; a < Dim; ++a) {
        q[a] += (o >> a) & 1;
        inside = inside && q[a] >= 0 && q[a] < fine_res_[a];
      }
      if (!inside) continue;
      const T h = fine_[std::size_t(linear(q, fine_res_))];
      if (h == kSolid) {
        filled += 1;
      } else {
        liquid += double(h);
        filled += double(h);
      }
    }
    constexpr double inv = 1.0 / double(1 << Dim);
    return {liquid * inv, filled * inv};
  }

  /// kappa of every stress sample: dt/rho mu W c (c = 2 diagonal, 1 off-diagonal) where the
  /// sample's control volume holds liquid, 0 elsewhere. W counts solid as filled (no-slip).
  void stress_weights(const Grid& g, double scale, double mu_uniform, const std::vector<T>& mu_cell) {
    const bool uniform = mu_cell.empty();
    kappa_cell_.resize(std::size_t(g.num_cells()));
    parallel::parallel_for(0, g.num_cells(), [&](std::int64_t c) {
      if (!active_[std::size_t(c)]) {
        kappa_cell_[std::size_t(c)] = 0.0;
        return;
      }
      const IVec i = g.cell_coord(c);
      const auto [liquid, filled] = fraction(IVec(2 * i));
      const double mu = uniform ? mu_uniform : double(mu_cell[std::size_t(c)]);
      kappa_cell_[std::size_t(c)] = liquid > 0 && mu > 0 ? 2 * scale * mu * filled : 0.0;
    });
    for (int p = 0; p < kPairs; ++p) {
      const int a = pair_a_[p], b = pair_b_[p];
      const IVec er = edge_res(p);
      std::int64_t n = 1;
      for (int k = 0; k < Dim; ++k) n *= er[k];
      kappa_edge_[p].resize(std::size_t(n));
      parallel::parallel_for(0, n, [&](std::int64_t k) {
        const IVec j = transfer::lattice_coord<Dim>(k, er);
        if (!reach_[std::size_t(g.cell(IVec(j.cwiseMin(res_ - IVec::Ones()))))]) {  // the 4 cells around j are inactive
          kappa_edge_[p][std::size_t(k)] = 0.0;
          return;
        }
        IVec lo = 2 * j;
        lo[a] -= 1;
        lo[b] -= 1;
        const auto [liquid, filled] = fraction(lo);
        double mu = mu_uniform;
        if (!uniform) {  // the mean over the (up to) 4 cells around the sample
          double sum = 0;
          int count = 0;
          for (int o = 0; o < 4; ++o) {
            IVec c = j;
            c[a] -= o & 1;
            c[b] -= (o >> 1) & 1;
            if (c[a] < 0 || c[a] >= res_[a] || c[b] < 0 || c[b] >= res_[b]) continue;
            sum += double(mu_cell[std::size_t(g.cell(c))]);
            ++count;
          }
          mu = count > 0 ? sum / count : 0.0;
        }
        kappa_edge_[p][std::size_t(k)] = liquid > 0 && mu > 0 ? scale * mu * filled : 0.0;
      });
    }
  }

  /// The pair index of axes a != b.
  static int pair_of(int a, int b) {
    if (a > b) std::swap(a, b);
    if constexpr (Dim == 2) return 0;
    return a == 0 ? b - 1 : 2;  // (0,1) -> 0, (0,2) -> 1, (1,2) -> 2
  }

  /// Calls fn(kappa, terms, count) for every stress sample with kappa > 0 that reads axis-d face
  /// i: the two diagonal samples of the cells beside it along d, and per other axis b the two
  /// off-diagonal samples (a, b) below and above it along b.
  template <class Fn>
  void for_each_sample(const Grid& g, int d, const IVec& i, Fn&& fn) const {
    Term t[4];
    for (int side = 0; side < 2; ++side) {  // cells i - e_d and i
      IVec c = i;
      c[d] -= 1 - side;
      if (c[d] < 0 || c[d] >= res_[d]) continue;
      const double kappa = kappa_cell_[std::size_t(g.cell(c))];
      if (kappa <= 0) continue;
      IVec up = c;
      up[d] += 1;
      t[0] = {d, g.face(d, up), 1 / dx_};
      t[1] = {d, g.face(d, c), -1 / dx_};
      fn(kappa, t, 2);
    }
    for (int b = 0; b < Dim; ++b) {
      if (b == d) continue;
      const int p = pair_of(d, b);
      const IVec er = edge_res(p);
      for (int side = 0; side < 2; ++side) {  // samples j = i and j = i + e_b
        IVec j = i;
        j[b] += side;
        const double kappa = kappa_edge_[p][std::size_t(linear(j, er))];
        if (kappa <= 0) continue;
        int n = 0;
        // s = du_d/dx_b + du_b/dx_d at j: each of the two differences reads the faces at
        // j and j - e_other; a face outside the domain is the mirror of the one inside.
        for (int comp = 0; comp < 2; ++comp) {
          const int u_axis = comp == 0 ? d : b, other = comp == 0 ? b : d;
          IVec hi = j, lo = j;
          lo[other] -= 1;
          const bool hi_in = hi[other] < res_[other], lo_in = lo[other] >= 0;
          if (!(hi_in && lo_in) && !no_slip_walls) continue;  // free slip: the mirror u_ghost = u_inside
          if (hi_in) t[n++] = {u_axis, g.face(u_axis, hi), (lo_in ? 1 : 2) / dx_};
          if (lo_in) t[n++] = {u_axis, g.face(u_axis, lo), -(hi_in ? 1 : 2) / dx_};
        }
        fn(kappa, t, n);
      }
    }
  }

  /// Unknowns: open faces read by a stress sample with kappa > 0, numbered axis by axis in
  /// face order.
  void number_unknowns(const Grid& g) {
    unknown_face_.clear();
    unknown_axis_.clear();
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t nf = g.num_faces(d);
      index_[d].assign(std::size_t(nf), -1);
      std::int32_t* idx = index_[d].data();
      parallel::parallel_for(0, nf, [&](std::int64_t f) {
        const IVec i = g.face_coord(d, f);
        // Every sample that reads face i lies within one cell of cell i (clamped to the grid).
        if (!reach_[std::size_t(g.cell(IVec(i.cwiseMin(res_ - IVec::Ones()))))]) return;
        if (g.open_weight(d, i) <= T(0)) return;
        bool touched = false;
        for_each_sample(g, d, i, [&](double, const Term* t, int count) {
          for (int k = 0; k < count; ++k) touched = touched || (t[k].d == d && t[k].f == f);
        });
        idx[f] = touched ? 0 : -1;
      });
      for (std::int64_t f = 0; f < nf; ++f) {
        if (idx[f] < 0) continue;
        idx[f] = std::int32_t(unknown_face_.size());
        unknown_face_.push_back(std::uint32_t(f));
        unknown_axis_.push_back(std::uint8_t(d));
      }
    }
  }

  /// Row r of the system: W_f on the diagonal plus, per sample, kappa c_f c_g; closed faces'
  /// terms move to the right-hand side with their u_solid. Stored row by row in kWidth slots
  /// (at most kWidth distinct columns, ascending, len_ of them used): no second pass to pack
  /// the rows, 32-bit columns.
  void assemble(const Grid& g) {
    const std::int64_t n = std::int64_t(unknown_face_.size());
    col_.resize(std::size_t(n * kWidth));
    val_.resize(std::size_t(n * kWidth));
    len_.resize(std::size_t(n));
    diag_.resize(std::size_t(n));
    rhs_.resize(std::size_t(n));
    x_.resize(std::size_t(n));
    parallel::parallel_for(0, n, [&](std::int64_t r) {
      const int d = unknown_axis_[std::size_t(r)];
      const std::int64_t f = unknown_face_[std::size_t(r)];
      const IVec i = g.face_coord(d, f);
      IVec lo = 2 * i;
      lo[d] -= 1;
      const double mass = fraction(lo).first;
      std::int64_t cols[kMaxRow];
      double vals[kMaxRow];
      int len = 0;
      cols[len] = r, vals[len] = mass, ++len;
      const double u0 = double(g.u[d][std::size_t(f)]);
      double b = mass * u0;
      for_each_sample(g, d, i, [&](double kappa, const Term* t, int count) {
        double self = 0;
        for (int k = 0; k < count; ++k)
          if (t[k].d == d && t[k].f == f) self = t[k].coef;
        if (self == 0) return;  // a free-slip wall dropped this face's difference
        for (int k = 0; k < count; ++k) {
          const double v = kappa * self * t[k].coef;
          const std::int32_t col = index_[t[k].d][std::size_t(t[k].f)];
          if (col >= 0) {
            assert(len < kMaxRow);
            cols[len] = col, vals[len] = v, ++len;
          } else {
            b -= v * double(g.face_u_solid(t[k].d, t[k].f));
          }
        }
      });
      // Merge duplicate columns (insertion sort of at most kMaxRow entries, then sum runs).
      for (int a = 1; a < len; ++a)
        for (int k = a; k > 0 && cols[k - 1] > cols[k]; --k) std::swap(cols[k - 1], cols[k]), std::swap(vals[k - 1], vals[k]);
      std::uint32_t* out_col = col_.data() + r * kWidth;
      double* out_val = val_.data() + r * kWidth;
      int m = 0;
      for (int k = 0; k < len; ++k) {
        if (m > 0 && std::int64_t(out_col[m - 1]) == cols[k]) {
          out_val[m - 1] += vals[k];
        } else {
          assert(m < kWidth);
          out_col[m] = std::uint32_t(cols[k]), out_val[m] = vals[k], ++m;
        }
      }
      for (int k = 0; k < m; ++k)
        if (std::int64_t(out_col[k]) == r) diag_[std::size_t(r)] = out_val[k];
      len_[std::size_t(r)] = std::uint8_t(m);
      rhs_[std::size_t(r)] = b;
      x_[std::size_t(r)] = u0;  // warm start: the velocity before the solve
    });
  }

  /// y = A x; returns x . y.
  double matvec(const double* x, double* y) const {
    const std::int64_t n = std::int64_t(diag_.size());
    return parallel::parallel_sum<double>(0, n, kGrain, [&](std::int64_t lo, std::int64_t hi) {
      double s = 0;
      for (std::int64_t r = lo; r < hi; ++r) {
        const std::uint32_t* col = col_.data() + r * kWidth;
        const double* val = val_.data() + r * kWidth;
        double v = 0;
        for (int k = 0; k < len_[std::size_t(r)]; ++k) v += val[k] * x[col[k]];
        y[r] = v;
        s += x[r] * v;
      }
      return s;
    });
  }

  /// Jacobi-preconditioned CG (Saad 2003, Alg. 9.1) on x_ with the right-hand side rhs_.
  ViscosityReport pcg() {
    ViscosityReport rep;
    const std::int64_t n = std::int64_t(diag_.size());
    r_.resize(std::size_t(n));
    z_.resize(std::size_t(n));
    p_.resize(std::size_t(n));
    q_.resize(std::size_t(n));
    double *x = x_.data(), *r = r_.data(), *z = z_.data(), *p = p_.data(), *q = q_.data();
    const double* b = rhs_.data();
    const double* diag = diag_.data();
    const auto sum = [&](auto&& term) {
      return parallel::parallel_sum<double>(0, n, kGrain, [&](std::int64_t lo, std::int64_t hi) {
        double s = 0;
        for (std::int64_t k = lo; k < hi; ++k) s += term(k);
        return s;
      });
    };
    const double b_norm = std::sqrt(sum([&](std::int64_t k) { return b[k] * b[k]; }));
    if (b_norm == 0) {
      std::fill(x_.begin(), x_.end(), 0.0);
      return rep;
    }
    matvec(x, q);
    double rr = sum([&](std::int64_t k) {
      r[k] = b[k] - q[k];
      return r[k] * r[k];
    });
    rep.relative_residual = std::sqrt(rr) / b_norm;
    rep.converged = rep.relative_residual <= tolerance;
    if (rep.converged) return rep;
    double rz = sum([&](std::int64_t k) {
      z[k] = diag[k] > 0 ? r[k] / diag[k] : r[k];
      p[k] = z[k];
      return r[k] * z[k];
    });
    while (rep.iterations < max_iterations) {
      const double pq = matvec(p, q);
      if (!(pq > 0)) break;
      const double alpha = rz / pq;
      rr = sum([&](std::int64_t k) {
        x[k] += alpha * p[k];
        r[k] -= alpha * q[k];
        return r[k] * r[k];
      });
      ++rep.iterations;
      rep.relative_residual = std::sqrt(rr) / b_norm;
      if (rep.relative_residual <= tolerance) {
        rep.converged = true;
        break;
      }
      const double rz_new = sum([&](std::int64_t k) {
        z[k] = diag[k] > 0 ? r[k] / diag[k] : r[k];
        return r[k] * z[k];
      });
      const double beta = rz_new / rz;
      rz = rz_new;
      parallel::parallel_for(0, n, [&](std::int64_t k) { p[k] = z[k] + beta * p[k]; });
    }
    rep.converged = rep.relative_residual <= tolerance;
    return rep;
  }

  IVec res_ = IVec::Zero(), fine_res_ = IVec::Zero();
  double dx_ = 1;
  std::array<int, kPairs> pair_a_{}, pair_b_{};
  std::vector<T> fine_;                            ///< H (or kSolid) at the supersampling points
  std::vector<double> kappa_cell_;                 ///< per cell: diagonal samples
  std::array<std::vector<double>, kPairs> kappa_edge_;  ///< per pair: off-diagonal samples
  std::array<std::vector<std::int32_t>, Dim> index_;   ///< per face: unknown number or -1
  std::vector<std::uint8_t> active_, reach_, mask_scratch_;  ///< per cell: see mark_active()
  std::vector<std::uint32_t> unknown_face_;
  std::vector<std::uint8_t> unknown_axis_;
  std::vector<std::uint32_t> col_;  ///< kWidth slots per row
  std::vector<std::uint8_t> len_;   ///< used slots per row
  std::vector<double> val_, rhs_, diag_, x_, r_, z_, p_, q_;
};

}  // namespace slurry::flip
