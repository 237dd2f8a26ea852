#pragma once
/// \file face_transfer.h
/// Particle <-> face transfers of the FLIP/APIC liquid solver on the staggered grid: every
/// velocity component d is transferred on its own to the axis-d faces with the linear (tent) or
/// quadratic B-spline, w_f(x_p) = prod_a N((x_p,a - x_f,a) / dx) (kernels.h).
///
/// P2G (particles_to_faces):  u_f = sum_p w_fp (v_p,d + c_p,d . (x_f - x_p)) / sum_p w_fp,
///   the c term for APIC only (Jiang et al. 2015, "The affine particle-in-cell method", sec. 6,
///   per-component affine vectors on a MAC grid); faces no particle reaches get u = 0, valid = 0.
/// G2P (faces_to_particles):  u_pic = sum_f w_fp u_f;
///   PIC  v_p,d = u_pic;
///   FLIP v_p,d = r (v_p,d + sum_f w_fp (u_f - u_f^old)) + (1 - r) u_pic (Zhu & Bridson 2005);
///   APIC v_p,d = u_pic, c_p,d = sum_f grad w_fp u_f (linear kernel) or
///        (4 / dx^2) sum_f w_fp (x_f - x_p) u_f (quadratic; D_p = dx^2/4 I, Jiang et al. sec. 5.3).
///   Both APIC forms reproduce a linear velocity field exactly.
///
/// P2G scatters from particles sorted by cell (CellSort) in slabs along axis 0 owned by one task
/// each, even slabs then odd ones: no atomics, no per-thread grids, and the summation order is
/// fixed, so results are bitwise independent of the thread count.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "slurry/engine/flip/cell_sort.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/kernels.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// One array per face axis (the alias keeps Dim deducible from the MacGrid argument only).
template <class T, int Dim>
using FaceArrays = std::array<std::vector<T>, std::size_t(Dim)>;

/// Blocks template argument deduction (pointer arguments may be nullptr).
template <class X>
struct NoDeduce {
  using type = X;
};

/// Which update G2P applies.
enum class FaceScheme { PIC, FLIP, APIC };

/// 1D B-spline N(r) of order 1 or 2 at offset r (grid units).
template <int Order, class T>
inline T kernel_1d(T r) {
  r = std::abs(r);
  if constexpr (Order == 1) {
    return r < T(1) ? T(1) - r : T(0);
  } else {
    if (r < T(0.5)) return T(0.75) - r * r;
    if (r < T(1.5)) return T(0.5) * (T(1.5) - r) * (T(1.5) - r);
    return T(0);
  }
}

/// Support radius of the kernel in cells.
template <int Order>
constexpr double kernel_radius() {
  return Order == 1 ? 1.0 : 1.5;
}

/// Stencil of one point on the axis-d faces: per axis the first face index, the weights, their
/// derivatives (per metre) and the offsets x_f - x (metres). Indices are clamped to the grid
/// (a point outside the face box reads the boundary faces; the weights still sum to 1).
template <class T, int Dim, int Order>
struct FaceStencil {
  static constexpr int N = transfer::BSpline<Order>::support;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  int idx[Dim][N];
  T w[Dim][N];
  T dw[Dim][N];
  T off[Dim][N];

  FaceStencil(const MacGrid<T, Dim>& g, int d, const Vec& x) {
    const T inv_dx = T(1) / g.dx;
    for (int a = 0; a < Dim; ++a) {
      const T s = (x[a] - g.origin[a]) * inv_dx - (a == d ? T(0) : T(0.5)) - T(g.offset[a]);
      const int base = transfer::BSpline<Order>::base(s);
      const T f = s - T(base);
      transfer::BSpline<Order>::eval(f, w[a], dw[a]);
      const int hi = g.res[a] + (a == d ? 1 : 0) - 1;
      for (int k = 0; k < N; ++k) {
        idx[a][k] = std::clamp(base + k, 0, hi);
        dw[a][k] *= inv_dx;
        off[a][k] = (T(k) - f) * g.dx;
      }
    }
  }

  /// fn(face_index, weight, gradient, offset) for every face of the stencil.
  template <class Fn>
  void for_each(const MacGrid<T, Dim>& g, int d, Fn&& fn) const {
    const auto fr = g.face_res(d);
    if constexpr (Dim == 2) {
      for (int a = 0; a < N; ++a)
        for (int b = 0; b < N; ++b) {
          const std::int64_t f = std::int64_t(idx[0][a]) * fr[1] + idx[1][b];
          fn(f, w[0][a] * w[1][b], Vec(dw[0][a] * w[1][b], w[0][a] * dw[1][b]), Vec(off[0][a], off[1][b]));
        }
    } else {
      for (int a = 0; a < N; ++a)
        for (int b = 0; b < N; ++b) {
          const T wab = w[0][a] * w[1][b], dab = dw[0][a] * w[1][b], adb = w[0][a] * dw[1][b];
          const std::int64_t row = (std::int64_t(idx[0][a]) * fr[1] + idx[1][b]) * fr[2];
          for (int c = 0; c < N; ++c)
            fn(row + idx[2][c], wab * w[2][c], Vec(dab * w[2][c], adb * w[2][c], wab * dw[2][c]),
               Vec(off[0][a], off[1][b], off[2][c]));
        }
    }
  }
};

/// Particles -> axis-d face velocities for every d. The particles must be sorted by cell with
/// `sort.start` their cell ranges. `wsum` is scratch (resized to the face counts). Sets g.u and
/// g.valid (1 where some particle reached the face).
///
/// A scatter: each particle computes its stencil once per axis (both staggerings) and adds into
/// the N^Dim faces of every component, branch-free. Slabs of kSlab cells along axis 0 own their
/// particles (one contiguous range of the cell sort); a particle reaches face rows at most one
/// cell below and two above its own, so slabs of one parity never touch the same face. The even
/// slabs run in parallel, then the odd ones: every face receives its contributions in an order
/// fixed by the slab partition and the sort alone, so the result does not depend on the thread
/// count.
template <int Order, class T, int Dim>
void particles_to_faces(MacGrid<T, Dim>& g, const FlipParticles<T, Dim>& P, const CellSort<T, Dim>& sort,
                        FaceArrays<T, Dim>& wsum) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Spline = transfer::BSpline<Order>;
  constexpr int N = Spline::support;
  static_assert(Order == 1 || Order == 2, "FLIP face transfers use the linear or quadratic B-spline");
  constexpr int kSlab = 4;  // >= 4 keeps same-parity slabs apart for both orders (see above)
  const T inv_dx = T(1) / g.dx, dx = g.dx;
  const Vec offset = g.offset.template cast<T>();  // a window's place in the whole grid (MacGrid::offset)
  const bool affine = P.affine;
  const Vec* X = P.x.data();
  const Vec* V = P.v.data();
  const std::uint32_t* start = sort.start.data();
  std::array<T*, Dim> U, W;
  std::array<std::array<std::int64_t, Dim>, Dim> stride;  // stride[d][a]: axis-a step on axis-d faces
  std::array<std::array<int, Dim>, Dim> extent;           // extent[d][a]: axis-d faces along a
  for (int d = 0; d < Dim; ++d) {
    wsum[d].resize(g.u[d].size());
    U[d] = g.u[d].data();
    W[d] = wsum[d].data();
    const auto fr = g.face_res(d);
    std::int64_t st = 1;
    for (int a = Dim - 1; a >= 0; --a) stride[d][a] = st, extent[d][a] = fr[a], st *= fr[a];
    parallel::parallel_for(0, std::int64_t(g.u[d].size()), [&](std::int64_t f) { U[d][f] = T(0), W[d][f] = T(0); });
  }
  const std::int64_t cells_per_layer = g.num_cells() / g.res[0];
  const int slabs = (g.res[0] + kSlab - 1) / kSlab;
  for (int parity = 0; parity < 2; ++parity) {
    parallel::parallel_tasks(0, (slabs + 1 - parity) / 2, [&](std::int64_t t) {
      const int s0 = int(2 * t + parity) * kSlab, s1 = std::min(g.res[0], s0 + kSlab);
      const std::int64_t p0 = start[std::int64_t(s0) * cells_per_layer], p1 = start[std::int64_t(s1) * cells_per_layer];
      for (std::int64_t p = p0; p < p1; ++p) {
        const Vec xg = (X[p] - g.origin) * inv_dx - offset;
        // Per axis and staggering (1: the faces normal to that axis, at integer positions;
        // 0: the other faces, at half-integer ones) the first stencil index, the weights and the
        // offsets x_f - x_p in metres. Far outside the grid (or NaN) no face is reached.
        bool inside = true;
        for (int a = 0; a < Dim; ++a) inside = inside && xg[a] > T(-3) && xg[a] < T(g.res[a] + 3);
        if (!inside) continue;
        int base[Dim][2];
        T w[Dim][2][N], off[Dim][2][N];
        for (int a = 0; a < Dim; ++a)
          for (int stag = 0; stag < 2; ++stag) {
            const T sa = stag ? xg[a] : xg[a] - T(0.5);
            base[a][stag] = Spline::base(sa);
            const T f = sa - T(base[a][stag]);
            T dw[N];
            Spline::eval(f, w[a][stag], dw);
            for (int k = 0; k < N; ++k) off[a][stag][k] = (T(k) - f) * dx;
          }
        for (int d = 0; d < Dim; ++d) {
          const T vd = V[p][d];
          // Per axis: the face index steps (or -1 outside the face grid), weights and the affine
          // term c_d[a] (x_f - x_p)[a].
          std::int64_t idx[Dim][N];
          T wa[Dim][N], ca[Dim][N];
          for (int a = 0; a < Dim; ++a) {
            const int stag = a == d ? 1 : 0;
            for (int k = 0; k < N; ++k) {
              const int i = base[a][stag] + k;
              const bool in = i >= 0 && i < extent[d][a];
              idx[a][k] = in ? std::int64_t(i) * stride[d][a] : -1;
              wa[a][k] = w[a][stag][k];
              ca[a][k] = affine ? P.c[d][p][a] * off[a][stag][k] : T(0);
            }
          }
          T* Ud = U[d];
          T* Wd = W[d];
          if constexpr (Dim == 2) {
            for (int i = 0; i < N; ++i) {
              if (idx[0][i] < 0) continue;
              for (int j = 0; j < N; ++j) {
                if (idx[1][j] < 0) continue;
                const std::int64_t f = idx[0][i] + idx[1][j];
                const T wk = wa[0][i] * wa[1][j];
                Ud[f] += wk * (vd + ca[0][i] + ca[1][j]);
                Wd[f] += wk;
              }
            }
          } else {
            for (int i = 0; i < N; ++i) {
              if (idx[0][i] < 0) continue;
              for (int j = 0; j < N; ++j) {
                if (idx[1][j] < 0) continue;
                const std::int64_t fij = idx[0][i] + idx[1][j];
                const T wij = wa[0][i] * wa[1][j];
                const T vij = vd + ca[0][i] + ca[1][j];
                for (int k = 0; k < N; ++k) {
                  if (idx[2][k] < 0) continue;
                  const T wk = wij * wa[2][k];
                  Ud[fij + idx[2][k]] += wk * (vij + ca[2][k]);
                  Wd[fij + idx[2][k]] += wk;
                }
              }
            }
          }
        }
      }
    });
  }
  for (int d = 0; d < Dim; ++d) {
    T* Ud = U[d];
    const T* Wd = W[d];
    std::uint8_t* valid = g.valid[d].data();
    parallel::parallel_for(0, std::int64_t(g.u[d].size()), [&](std::int64_t f) {
      const bool reached = Wd[f] > T(0);
      Ud[f] = reached ? Ud[f] / Wd[f] : T(0);
      valid[f] = reached ? 1 : 0;
    });
  }
}

/// The grid's velocity at x and, for APIC, the affine vectors c_d (linear or quadratic kernel);
/// with `old` (FLIP) also the interpolated change sum_f w (u_f - u_old_f) in `delta`.
template <int Order, class T, int Dim>
inline void gather_faces(const MacGrid<T, Dim>& g, const Eigen::Matrix<T, Dim, 1>& x,
                         const typename NoDeduce<FaceArrays<T, Dim>>::type* old, Eigen::Matrix<T, Dim, 1>& u,
                         typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* delta,
                         typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* c) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  for (int d = 0; d < Dim; ++d) {
    const FaceStencil<T, Dim, Order> s(g, d, x);
    const T* U = g.u[d].data();
    T sum = 0, dsum = 0;
    Vec cs = Vec::Zero();
    const T* O = old ? (*old)[d].data() : nullptr;
    s.for_each(g, d, [&](std::int64_t f, T w, const Vec& grad, const Vec& off) {
      const T uf = U[f];
      sum += w * uf;
      if (O) dsum += w * (uf - O[f]);
      if (c) {
        if constexpr (Order == 1)
          cs += grad * uf;
        else
          cs += (w * uf) * off;
      }
    });
    u[d] = sum;
    if (delta) (*delta)[d] = dsum;
    if (c) {
      if constexpr (Order == 1)
        c[d] = cs;
      else
        c[d] = cs * transfer::BSpline<2>::inverse_inertia(g.dx);
    }
  }
}

/// gather_faces for the linear kernel with flat index arithmetic: per component one base index
/// and 2^Dim loads (the same clamped stencil, weights and gradients as FaceStencil<.., 1>).
template <class T, int Dim>
inline void gather_faces_linear(const MacGrid<T, Dim>& g, const Eigen::Matrix<T, Dim, 1>& x,
                                const typename NoDeduce<FaceArrays<T, Dim>>::type* old,
                                Eigen::Matrix<T, Dim, 1>& u, typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* delta,
                                typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* c) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  const T inv_dx = T(1) / g.dx;
  // Per axis a, the clamped neighbours and weights for both staggerings: faces of axis a sit at
  // integer positions along a (stag = 1), faces of the other axes at half-integer ones (stag = 0).
  int idx[Dim][2][2];
  T wt[Dim][2][2];
  for (int a = 0; a < Dim; ++a) {
    const T xa = (x[a] - g.origin[a]) * inv_dx - T(g.offset[a]);
    for (int stag = 0; stag < 2; ++stag) {
      const int n = g.res[a] + stag;
      const T sa = stag ? xa : xa - T(0.5);
      const int b = int(std::floor(sa));
      const T f = sa - T(b);
      idx[a][stag][0] = std::clamp(b, 0, n - 1);
      idx[a][stag][1] = std::clamp(b + 1, 0, n - 1);
      wt[a][stag][0] = T(1) - f;
      wt[a][stag][1] = f;
    }
  }
  for (int d = 0; d < Dim; ++d) {
    std::int64_t off[Dim][2];
    T w[Dim][2];
    std::int64_t stride = 1;
    for (int a = Dim - 1; a >= 0; --a) {
      const int stag = a == d ? 1 : 0;
      off[a][0] = std::int64_t(idx[a][stag][0]) * stride;
      off[a][1] = std::int64_t(idx[a][stag][1]) * stride;
      w[a][0] = wt[a][stag][0];
      w[a][1] = wt[a][stag][1];
      stride *= g.res[a] + stag;
    }
    const T* U = g.u[d].data();
    const T* O = old ? (*old)[d].data() : nullptr;
    T sum = 0, dsum = 0;
    Vec grad = Vec::Zero();
    if constexpr (Dim == 2) {
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b) {
          const std::int64_t k = off[0][a] + off[1][b];
          const T uf = U[k], wk = w[0][a] * w[1][b];
          sum += wk * uf;
          if (O) dsum += wk * (uf - O[k]);
          if (c) {
            grad[0] += (a ? uf : -uf) * w[1][b];
            grad[1] += (b ? uf : -uf) * w[0][a];
          }
        }
    } else {
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b) {
          const T wab = w[0][a] * w[1][b];
          const std::int64_t kab = off[0][a] + off[1][b];
          for (int e = 0; e < 2; ++e) {
            const std::int64_t k = kab + off[2][e];
            const T uf = U[k];
            sum += wab * w[2][e] * uf;
            if (O) dsum += wab * w[2][e] * (uf - O[k]);
            if (c) {
              const T su = a ? uf : -uf, tu = b ? uf : -uf, ru = e ? uf : -uf;
              grad[0] += su * w[1][b] * w[2][e];
              grad[1] += tu * w[0][a] * w[2][e];
              grad[2] += ru * wab;
            }
          }
        }
    }
    u[d] = sum;
    if (delta) (*delta)[d] = dsum;
    if (c) c[d] = grad * inv_dx;
  }
}

/// gather_faces with the kernel of the given order (the linear one through gather_faces_linear).
template <int Order, class T, int Dim>
inline void gather_faces_fast(const MacGrid<T, Dim>& g, const Eigen::Matrix<T, Dim, 1>& x,
                              const typename NoDeduce<FaceArrays<T, Dim>>::type* old, Eigen::Matrix<T, Dim, 1>& u,
                              typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* delta,
                              typename NoDeduce<Eigen::Matrix<T, Dim, 1>>::type* c) {
  if constexpr (Order == 1)
    gather_faces_linear(g, x, old, u, delta, c);
  else
    gather_faces<Order>(g, x, old, u, delta, c);
}

/// faces_to_particles' default: nothing after a particle's update.
struct NoParticleStep {
  template <class Vec>
  void operator()(std::int64_t, const Vec&) const {}
};

/// Faces -> particles with the given scheme; `old` holds the face velocities before the grid
/// update (FLIP only). Returns the largest particle speed (infinity if any is non-finite).
/// `after(p, u)` runs once particle p has its new velocity (and a finite speed), with u the
/// grid velocity gathered at x_p (the PIC velocity): the caller's next step for p in the same
/// pass, e.g. advection, whose first stage u(x_p) it is for the linear kernel.
template <int Order, class T, int Dim, class After = NoParticleStep>
T faces_to_particles(const MacGrid<T, Dim>& g, const typename NoDeduce<FaceArrays<T, Dim>>::type* old,
                     FlipParticles<T, Dim>& P,
                     FaceScheme scheme, T flip_ratio, const After& after = After()) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  const std::int64_t n = std::int64_t(P.size());
  return parallel::parallel_max<T>(0, n, T(0), [&](std::int64_t lo, std::int64_t hi) {
    T vmax2 = 0;
    for (std::int64_t p = lo; p < hi; ++p) {
      Vec u, delta, c[Dim];
      switch (scheme) {
        case FaceScheme::PIC: gather_faces_fast<Order>(g, P.x[p], nullptr, u, nullptr, nullptr); P.v[p] = u; break;
        case FaceScheme::FLIP:
          gather_faces_fast<Order>(g, P.x[p], old, u, &delta, nullptr);
          P.v[p] = flip_ratio * (P.v[p] + delta) + (T(1) - flip_ratio) * u;
          break;
        case FaceScheme::APIC:
          gather_faces_fast<Order>(g, P.x[p], nullptr, u, nullptr, c);
          P.v[p] = u;
          for (int d = 0; d < Dim; ++d) P.c[d][p] = c[d];
          break;
      }
      const T s2 = P.v[p].squaredNorm();
      if (!(s2 <= std::numeric_limits<T>::max())) return std::numeric_limits<T>::infinity();
      vmax2 = std::max(vmax2, s2);
      after(p, u);
    }
    return std::sqrt(vmax2);
  });
}

}  // namespace slurry::flip
