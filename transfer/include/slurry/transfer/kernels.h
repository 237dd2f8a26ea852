#pragma once
/// \file kernels.h
/// B-spline interpolation kernels of the Material Point Method and the per-particle stencil that
/// P2G and G2P share.
///
/// The 1D weights are the uniform B-splines of order 1 (linear "tent", support 2 nodes),
/// 2 (quadratic, support 3) and 3 (cubic, support 4), as tabulated by Steffen, Kirby and
/// Berzins 2008 ("Analysis and reduction of quadrature errors in the material point method",
/// eqs. for N^1, N^2, N^3) and used in Jiang et al. 2016 (the SIGGRAPH MPM course, sec. 9.1).
/// Multi-dimensional weights are tensor products w_i(x) = prod_d N((x_d - x_{i,d}) / dx), so the
/// stencil stores Dim x (Order+1) numbers and recombines them per node.
///
/// With x the particle position in grid units (x / dx, the grid origin removed):
///  - linear:    base = floor(x),       f = x - base in [0,1):   N = (1-f, f)
///  - quadratic: base = floor(x - 0.5), f = x - base in [0.5,1.5):
///               N = (0.5 (1.5-f)^2, 0.75 - (f-1)^2, 0.5 (f-0.5)^2)
///  - cubic:     base = floor(x) - 1,   f = x - base in [1,2):
///               N(d) = d^3/2 - d^2 + 2/3 for |d| < 1, (2-|d|)^3/6 for 1 <= |d| < 2.
///
/// For APIC/MLS the inertia-like tensor D_p = sum_i w_ip (x_i - x_p)(x_i - x_p)^T is constant for
/// the quadratic (dx^2/4 I) and cubic (dx^2/3 I) B-splines (Jiang et al. 2015, sec. 5.3), so
/// D_p^{-1} is a scalar `inverse_inertia(dx)`. For the linear kernel D_p is position dependent
/// and singular on nodes; there APIC uses the equivalent C_p = sum_i v_i grad w_ip^T.
#include <Eigen/Core>
#include <algorithm>
#include <limits>
#include <array>
#include <cmath>
#include <cstdint>

namespace slurry::transfer {

/// Runtime name of a kernel; the transfers are templated on the order.
enum class KernelType { Linear = 1, Quadratic = 2, Cubic = 3 };

template <int Order>
struct BSpline;

template <>
struct BSpline<1> {
  static constexpr int support = 2;
  /// Index of the first node of the stencil, for x in grid units.
  template <class T>
  static int base(T x) {
    return static_cast<int>(std::floor(x));
  }
  /// Weights and derivatives (in grid units) at f = x - base.
  template <class T>
  static void eval(T f, T* w, T* dw) {
    w[0] = T(1) - f;
    w[1] = f;
    dw[0] = T(-1);
    dw[1] = T(1);
  }
  template <class T>
  static constexpr T inverse_inertia(T) {
    return T(0);  // not constant: see file comment
  }
};

template <>
struct BSpline<2> {
  static constexpr int support = 3;
  template <class T>
  static int base(T x) {
    return static_cast<int>(std::floor(x - T(0.5)));
  }
  template <class T>
  static void eval(T f, T* w, T* dw) {
    const T a = T(1.5) - f, b = f - T(1), c = f - T(0.5);
    w[0] = T(0.5) * a * a;
    w[1] = T(0.75) - b * b;
    w[2] = T(0.5) * c * c;
    dw[0] = -a;
    dw[1] = T(-2) * b;
    dw[2] = c;
  }
  /// D_p^{-1} = 4 / dx^2 (Jiang et al. 2015, sec. 5.3).
  template <class T>
  static constexpr T inverse_inertia(T dx) {
    return T(4) / (dx * dx);
  }
};

template <>
struct BSpline<3> {
  static constexpr int support = 4;
  template <class T>
  static int base(T x) {
    return static_cast<int>(std::floor(x)) - 1;
  }
  template <class T>
  static void eval(T f, T* w, T* dw) {
    // Distances to the four nodes: d0 = f in [1,2), d1 = f-1 in [0,1), d2 = 1-(f-1), d3 = 2-(f-1).
    const T d0 = f, d1 = f - T(1), d2 = T(2) - f, d3 = T(3) - f;
    const T e0 = T(2) - d0, e3 = T(2) - d3;
    w[0] = e0 * e0 * e0 / T(6);
    w[1] = T(0.5) * d1 * d1 * d1 - d1 * d1 + T(2) / T(3);
    w[2] = T(0.5) * d2 * d2 * d2 - d2 * d2 + T(2) / T(3);
    w[3] = e3 * e3 * e3 / T(6);
    // d/df of each; d2 and d3 decrease with f.
    dw[0] = T(-0.5) * e0 * e0;
    dw[1] = T(1.5) * d1 * d1 - T(2) * d1;
    dw[2] = -(T(1.5) * d2 * d2 - T(2) * d2);
    dw[3] = T(0.5) * e3 * e3;
  }
  /// D_p^{-1} = 3 / dx^2 (Jiang et al. 2015, sec. 5.3).
  template <class T>
  static constexpr T inverse_inertia(T dx) {
    return T(3) / (dx * dx);
  }
};

/// Separable weights of one particle: computed once, reused by P2G and G2P.
/// Node (a_0, ..., a_{Dim-1}) of the stencil sits at grid index base + a; its weight is
/// prod_d w[d][a_d] and its gradient has component d equal to dw[d][a_d] prod_{e != d} w[e][a_e]
/// (dw already divided by dx). `offset[d][a]` is (x_node - x_p)_d in world units.
template <class T, int Dim, int Order>
struct Stencil {
  static constexpr int N = BSpline<Order>::support;
  static constexpr int nodes = Dim == 2 ? N * N : N * N * N;
  using Vec = Eigen::Matrix<T, Dim, 1>;

  std::array<int, Dim> base;
  T w[Dim][N];
  T dw[Dim][N];
  T offset[Dim][N];

  Stencil() = default;
  /// `x_local` is the particle position relative to the grid origin, in world units.
  Stencil(const Vec& x_local, T inv_dx, T dx) {
    for (int d = 0; d < Dim; ++d) {
      const T xg = x_local[d] * inv_dx;
      base[d] = BSpline<Order>::base(xg);
      const T f = xg - T(base[d]);
      BSpline<Order>::eval(f, w[d], dw[d]);
      for (int a = 0; a < N; ++a) {
        dw[d][a] *= inv_dx;
        offset[d][a] = (T(a) - f) * dx;
      }
    }
  }
};

/// The stencils of up to `size` particles at a time, laid out particle-innermost so that the
/// compiler runs the arithmetic of Stencil's constructor (the same expressions) over SIMD lanes:
/// one particle at a time, that arithmetic was a third of the 2D transfers' time, a chain of
/// scalar instructions per axis. get(k) is particle k's Stencil.
template <class T, int Dim, int Order>
struct StencilBatch {
  static constexpr int N = BSpline<Order>::support;
  static constexpr int size = 16;
  using Vec = Eigen::Matrix<T, Dim, 1>;

  alignas(64) T xg[Dim][size];
  alignas(64) int base[Dim][size];
  alignas(64) T w[Dim][N][size];
  alignas(64) T dw[Dim][N][size];
  alignas(64) T offset[Dim][N][size];

  /// Particles ids[i0 + k] (i0 + k when ids is null), k < count <= size; the spare lanes repeat
  /// the first particle.
  ///
  /// With `base_lo` and `base_hi` (null for none) each base is clamped to [base_lo[d],
  /// base_hi[d]] per axis, and f is taken from the clamped base. A caller that scatters into a
  /// patch passes the bases whose stencils fit in it: the particle was binned by a base computed
  /// elsewhere, and GCC may fuse x inv_dx - 1/2 into one rounding there and not here (xg is
  /// stored first), so near a cell face the two can differ by one, which would index outside the
  /// patch. Clamped, such a particle keeps its bin's base, with f off its interval by round-off
  /// only, where the B-spline's pieces agree to round-off (the kernel is continuous).
  void compute(const Vec* x, const std::uint32_t* ids, std::int64_t i0, int count,
               const Vec& origin, T inv_dx, T dx, const int* base_lo = nullptr,
               const int* base_hi = nullptr) {
    for (int k = 0; k < size; ++k) {
      const std::int64_t i = i0 + (k < count ? k : 0);
      const Vec xl = x[ids ? std::int64_t(ids[i]) : i] - origin;
      for (int d = 0; d < Dim; ++d) xg[d][k] = xl[d] * inv_dx;
    }
    for (int d = 0; d < Dim; ++d) {
      T f[size], wd[N], dwd[N];
      // Branch-free (min and max per lane); no clamp is the widest range.
      const int lo = base_lo ? base_lo[d] : std::numeric_limits<int>::min();
      const int hi = base_lo ? base_hi[d] : std::numeric_limits<int>::max();
      for (int k = 0; k < size; ++k) base[d][k] = std::min(std::max(BSpline<Order>::base(xg[d][k]), lo), hi);
      for (int k = 0; k < size; ++k) f[k] = xg[d][k] - T(base[d][k]);
      for (int k = 0; k < size; ++k) {
        BSpline<Order>::eval(f[k], wd, dwd);
        for (int a = 0; a < N; ++a) {
          w[d][a][k] = wd[a];
          dw[d][a][k] = dwd[a] * inv_dx;
          offset[d][a][k] = (T(a) - f[k]) * dx;
        }
      }
    }
  }

  Stencil<T, Dim, Order> get(int k) const {
    Stencil<T, Dim, Order> s;
    for (int d = 0; d < Dim; ++d) {
      s.base[std::size_t(d)] = base[d][k];
      for (int a = 0; a < N; ++a) {
        s.w[d][a] = w[d][a][k];
        s.dw[d][a] = dw[d][a][k];
        s.offset[d][a] = offset[d][a][k];
      }
    }
    return s;
  }
};

/// Calls fn(a, b, [c,] weight, gradient, offset) for every node of the stencil, innermost axis
/// last (the contiguous one in the grid layout).
template <class T, int Order, class Fn>
inline void for_each_node(const Stencil<T, 2, Order>& s, Fn&& fn) {
  using Vec = Eigen::Matrix<T, 2, 1>;
  constexpr int N = Stencil<T, 2, Order>::N;
  for (int a = 0; a < N; ++a)
    for (int b = 0; b < N; ++b) {
      const T w = s.w[0][a] * s.w[1][b];
      const Vec g(s.dw[0][a] * s.w[1][b], s.w[0][a] * s.dw[1][b]);
      const Vec off(s.offset[0][a], s.offset[1][b]);
      fn(a, b, 0, w, g, off);
    }
}

template <class T, int Order, class Fn>
inline void for_each_node(const Stencil<T, 3, Order>& s, Fn&& fn) {
  using Vec = Eigen::Matrix<T, 3, 1>;
  constexpr int N = Stencil<T, 3, Order>::N;
  for (int a = 0; a < N; ++a)
    for (int b = 0; b < N; ++b) {
      const T wab = s.w[0][a] * s.w[1][b];
      const T dab = s.dw[0][a] * s.w[1][b];
      const T adb = s.w[0][a] * s.dw[1][b];
      for (int c = 0; c < N; ++c) {
        const T w = wab * s.w[2][c];
        const Vec g(dab * s.w[2][c], adb * s.w[2][c], wab * s.dw[2][c]);
        const Vec off(s.offset[0][a], s.offset[1][b], s.offset[2][c]);
        fn(a, b, c, w, g, off);
      }
    }
}

}  // namespace slurry::transfer
