#pragma once
/// \file transfers.h
/// Particle-to-grid (P2G) and grid-to-particle (G2P) transfers of the hybrid particle-grid
/// methods, for one range of particles:
///  - PIC: v_p <- sum_i w_ip v_i (Harlow 1964), dissipative; loses angular momentum.
///  - FLIP blend (Brackbill & Ruppel 1986; Zhu & Bridson 2005): v_p <- a (v_p + sum_i w_ip
///    (v_i - v_i^old)) + (1 - a) sum_i w_ip v_i with flip ratio a in [0, 1].
///  - APIC (Jiang et al. 2015, "The affine particle-in-cell method"): particles carry C_p = B_p
///    D_p^{-1}; P2G adds w_ip m_p (v_p + C_p (x_i - x_p)), which conserves angular momentum, and
///    an affine field is transferred exactly. For the linear kernel D_p depends on the position,
///    so the channel holds B_p itself and P2G adds m_p B_p grad w_ip, using
///    w_ip D_p^{-1} (x_i - x_p) = grad w_ip (Jiang et al. 2015, sec. 5.3); storing C_p instead and
///    applying it at the next position is unstable.
///  - MLS-MPM (Hu et al. 2018, "A moving least squares material point method", eq. 29): the
///    stress impulse joins the affine momentum, Q_p = m_p C_p - dt V_p D_p^{-1} tau_p, and the
///    velocity gradient used to advance F is C_p itself.
/// APIC, PIC and FLIP apply the internal force of the classic MPM discretization,
/// f_i = -sum_p V_p tau_p grad w_ip (Stomakhin et al. 2013, eq. 6; tau = P F^T the Kirchhoff
/// stress), as dt f_i added to the grid momentum.
///
/// Inputs are raw channel pointers (structure of arrays). The mass of particle p is
/// m[p & mass_mask]: mass_mask -1 (the default) reads one mass per particle, 0 reads m[0] for
/// every particle (a scene whose particles all have one mass stores it once; the same code
/// reads both, without a branch). `K[i - begin]` is the stress impulse -dt V_p^0 tau_p of the
/// particle at position i, computed by the caller; null means no stress.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>

#include "slurry/transfer/kernels.h"
#include "slurry/transfer/parallel.h"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace slurry::transfer {

enum class Scheme { PIC, FLIP, APIC, MLS };

namespace detail {
/// Keeps a parameter out of template argument deduction (so nullptr can be passed).
template <class X>
struct NonDeduced {
  using type = X;
};
template <class T, int Dim>
using MatPtr = typename NonDeduced<Eigen::Matrix<T, Dim, Dim>>::type;

/// The Dim values at `p` followed by `last` (zero by default), then zeros, as one 4-vector (a
/// grid node, GridNode in blocks.h). Assembling such a vector from scalars (`n << col, 0`) makes
/// GCC 12 write the pieces to the stack and read them back as one vector, a store-to-load
/// forwarding stall on every particle (perf put a quarter of the 3D scatter's samples on those
/// loads). Where the vector is a machine register (float: SSE; double: AVX), it is loaded as a
/// pair and a single and joined in registers; the values are the same. `p` is not read past its
/// Dim values (it may be the last column of a particle's matrix).
template <class T, int Dim>
inline Eigen::Matrix<T, 4, 1> padded(const T* p, T last = T(0)) {
  static_assert(Dim == 2 || Dim == 3, "2D or 3D");
  Eigen::Matrix<T, 4, 1> n;
#if defined(__SSE2__)
  if constexpr (std::is_same_v<T, float>) {
    // (x, y, 0, 0), then (z, last, 0, 0) or (last, 0, 0, 0), joined.
    const __m128 xy = _mm_castsi128_ps(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)));
    const __m128 zw =
        Dim == 3 ? _mm_unpacklo_ps(_mm_load_ss(p + 2), _mm_set_ss(last)) : _mm_set_ss(last);
    _mm_store_ps(n.data(), _mm_movelh_ps(xy, zw));
    return n;
  }
#endif
#if defined(__AVX__)
  if constexpr (std::is_same_v<T, double>) {
    const __m128d zw =
        Dim == 3 ? _mm_unpacklo_pd(_mm_load_sd(p + 2), _mm_set_sd(last)) : _mm_set_sd(last);
    const __m256d v = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p)), zw, 1);
    _mm256_store_pd(n.data(), v);
    return n;
  }
#endif
  n.setZero();
  for (int d = 0; d < Dim; ++d) n[d] = p[d];
  n[Dim] = last;
  return n;
}

/// a b + c for a 4-vector node, with one rounding where the machine has fused multiply-add
/// (a b + c, rounded twice, where it has not). The 2D transfers spell out their multiply-adds
/// with it: left to itself, GCC fuses a vector expression differently from the same sums on
/// scalars (its Zen tuning avoids some FMA chains, `avoid-fma-max-bits`), and 2D nodes were
/// three scalars before they were padded to a vector; the spelled-out form follows the scalar
/// code's roundings (2D float frames kept their bits; 2D double ones, where GCC had vectorised
/// part of the scalar code, changed at round-off).
template <class T>
inline Eigen::Matrix<T, 4, 1> fmadd(T a, const Eigen::Matrix<T, 4, 1>& b,
                                    const Eigen::Matrix<T, 4, 1>& c) {
  Eigen::Matrix<T, 4, 1> r;
#if defined(__FMA__)
  if constexpr (std::is_same_v<T, float>) {
    _mm_store_ps(r.data(),
                 _mm_fmadd_ps(_mm_set1_ps(a), _mm_load_ps(b.data()), _mm_load_ps(c.data())));
    return r;
  }
  if constexpr (std::is_same_v<T, double>) {
    _mm256_store_pd(r.data(), _mm256_fmadd_pd(_mm256_set1_pd(a), _mm256_load_pd(b.data()),
                                              _mm256_load_pd(c.data())));
    return r;
  }
#endif
  r = a * b + c;
  return r;
}
/// Whether a gather's state functor Fn takes its queued updates at once: Fn::kBatched, with
/// Fn::batch(const std::int64_t* ids, const Mat* grads, int n).
template <class Fn, class = void>
inline constexpr bool kBatchedState = false;
template <class Fn>
inline constexpr bool kBatchedState<Fn, std::void_t<decltype(Fn::kBatched)>> = Fn::kBatched;
/// fn(p, m), called out of line (its code is then the same wherever it is called from).
template <class Fn, class M>
[[gnu::noinline]] void call_out_of_line(Fn& fn, std::int64_t p, const M& m) {
  fn(p, m);
}

#if defined(__AVX__)
/// (lo x4, hi x4): two nodes' scalars, one per 128-bit half.
inline __m256 pair_ps(float lo, float hi) { return _mm256_set_m128(_mm_set1_ps(hi), _mm_set1_ps(lo)); }
/// A float node in both 128-bit halves.
inline __m256 both_ps(const Eigen::Matrix<float, 4, 1>& n) {
  const __m128 h = _mm_load_ps(n.data());
  return _mm256_set_m128(h, h);
}
#endif
}  // namespace detail

namespace detail {
/// The stencil bases that fit in `grid` when it is a block Patch (blocks.h: it has `first` and
/// `extent`): [first, first + extent - N] per axis; false for a whole grid.
template <class G, class = void>
struct IsPatch : std::false_type {};
template <class G>
struct IsPatch<G, std::void_t<decltype(G::extent), decltype(std::declval<G>().first)>> : std::true_type {};
template <int N, class G, int Dim>
inline bool patch_bases(const G& grid, int (&lo)[Dim], int (&hi)[Dim]) {
  if constexpr (IsPatch<G>::value) {
    for (int d = 0; d < Dim; ++d) lo[d] = grid.first[d], hi[d] = grid.first[d] + G::extent - N;
    return true;
  } else {
    return false;
  }
}
}  // namespace detail

namespace detail {
/// Whether gather_particles takes its packed 3D path (float MLS on AVX2 with FMA: the sums of
/// B without those of grad v, which MLS takes from C).
template <class T, Scheme S>
inline constexpr bool kPackedGather3 =
#if defined(__AVX2__) && defined(__FMA__)
    std::is_same_v<T, float> && S == Scheme::MLS;
#else
    false;
#endif
}  // namespace detail

/// Whether particles of this scheme carry an affine matrix C.
constexpr bool carries_affine(Scheme s) {
  return s == Scheme::APIC || s == Scheme::MLS;
}

/// Scatters mass and momentum (and the stress impulse) of particles ids[begin, end) (or
/// [begin, end) when ids is null) to `grid` and widens its active box. Serial: the scatter
/// writes shared nodes. `Grid` is a DenseGrid or a block Patch (blocks.h). The stress impulses
/// K (or null) follow the range, not the particle index: K[i - begin] belongs to position i, so
/// a caller computes them for one range at a time into a small buffer.
template <int Order, Scheme S, class Grid, class T, int Dim>
void scatter_particles(Grid& grid, const Eigen::Matrix<T, Dim, 1>* x,
                       const Eigen::Matrix<T, Dim, 1>* v, const T* m,
                       const detail::MatPtr<T, Dim>* C, const detail::MatPtr<T, Dim>* K,
                       const std::uint32_t* ids, std::int64_t begin, std::int64_t end,
                       std::int64_t mass_mask = -1) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Node = typename Grid::Node;  // (m v, m), padded with zeros to 4 values (blocks.h)
  using St = Stencil<T, Dim, Order>;
  static_assert(S != Scheme::MLS || Order > 1, "MLS-MPM needs a quadratic or cubic kernel");
  if (end <= begin) return;
  const Vec origin = grid.origin();
  const T dx = grid.dx(), inv_dx = grid.inv_dx();
  const T Dinv = BSpline<Order>::inverse_inertia(dx);
  std::int64_t stride[Dim];
  for (int d = 0; d < Dim; ++d) stride[d] = grid.stride(d);
  IVec lo = IVec::Constant(std::numeric_limits<int>::max());
  IVec hi = IVec::Constant(std::numeric_limits<int>::min());
  auto* nodes = grid.data();
  // The stencils a batch at a time over SIMD lanes (kernels.h), bases clamped to the patch.
  StencilBatch<T, Dim, Order> batch;
  int base_lo[Dim], base_hi[Dim];
  const bool clamp = detail::patch_bases<St::N>(grid, base_lo, base_hi);
  auto stencil = [&](std::int64_t i) {
    const int k = int((i - begin) % StencilBatch<T, Dim, Order>::size);
    if (k == 0)
      batch.compute(x, ids, i, int(std::min<std::int64_t>(StencilBatch<T, Dim, Order>::size, end - i)),
                    origin, inv_dx, dx, clamp ? base_lo : nullptr, base_hi);
    return batch.get(k);
  };

  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t p = ids ? std::int64_t(ids[i]) : i;
    const St s = stencil(i);
    const IVec base = Eigen::Map<const IVec>(s.base.data());
    lo = lo.cwiseMin(base);
    hi = hi.cwiseMax(base);
    const T mp = m[p & mass_mask];
    // Per node: n_i += w (m v + A (x_i - x_p), m) + G grad w, with A the affine momentum and G
    // the stress impulse (and the linear kernel's B_p). With x_i - x_p = (ox_a, oy_b, oz_c)
    // and grad w = (dwx_a wy_b wz_c, wx_a dwy_b wz_c, wx_a wy_b dwz_c) the affine and gradient
    // terms are summed axis by axis (hoisted out of the inner loops), and every node update is a
    // few 4-wide multiply-adds. The columns a[d] of A and g[d] of G are 4-vectors
    // with zeros after their Dim entries (the mass takes no affine or stress term), loaded whole.
    // MLS needs Order > 1, so every MLS particle has an affine term.
    constexpr bool has_A = carries_affine(S) && Order > 1;
    const bool has_G = S != Scheme::MLS && ((carries_affine(S) && Order == 1) || K != nullptr);
    const Mat* Kp = K ? &K[i - begin] : nullptr;
    Node u0, a[Dim], g[Dim];
    if constexpr (Dim == 3) {
      u0 = mp * detail::padded<T, Dim>(v[p].data(), T(1));  // (m v, m)
      for (int d = 0; d < Dim; ++d) {
        a[d].setZero();
        g[d].setZero();
        if constexpr (carries_affine(S)) {
          if constexpr (Order > 1)
            a[d] = mp * detail::padded<T, Dim>(C[p].col(d).data());
          else
            g[d] = mp * detail::padded<T, Dim>(C[p].col(d).data());
        }
        if (Kp) {
          if constexpr (S == Scheme::MLS)
            a[d] += Dinv * detail::padded<T, Dim>(Kp->col(d).data());
          else
            g[d] += detail::padded<T, Dim>(Kp->col(d).data());
        }
      }
    } else {
      // 2D: the matrices first, then their columns (summing by columns, as 3D does, changed
      // GCC's fused multiply-adds and the last bits of 2D APIC runs).
      Mat A = Mat::Zero(), G = Mat::Zero();
      if constexpr (carries_affine(S)) {
        if constexpr (Order > 1)
          A = mp * C[p];
        else
          G = mp * C[p];
      }
      if (Kp) {
        if constexpr (S == Scheme::MLS)
          A += Dinv * *Kp;
        else
          G += *Kp;
      }
      for (int d = 0; d < Dim; ++d) {
        a[d] = detail::padded<T, Dim>(A.col(d).data());
        g[d] = detail::padded<T, Dim>(G.col(d).data());
      }
    }
    Node* n0 = nodes + grid.index(s.base);
    constexpr int N = St::N;
#if defined(__AVX__) && defined(__FMA__)
    if constexpr (Dim == 3 && std::is_same_v<T, float> && S == Scheme::MLS && N == 3) {
      // MLS in float (an affine term, no gradient term), quadratic kernel: two nodes of a row
      // per 256-bit register, as in 2D below, each lane doing the multiply-adds of the 4-wide
      // form that follows, in the same order: the same bits with fewer instructions. Not for
      // the cubic kernel: GCC compiles the 4-wide form's rows of 4 nodes with other roundings,
      // and pairs there changed its frames at round-off (4e-7 m after 6 frames).
      using detail::pair_ps, detail::both_ps;
      constexpr int pairs = N / 2;
      __m256 w2[pairs], o2[pairs];
      for (int k = 0; k < pairs; ++k) {
        w2[k] = pair_ps(s.w[2][2 * k], s.w[2][2 * k + 1]);
        o2[k] = pair_ps(s.offset[2][2 * k], s.offset[2][2 * k + 1]);
      }
      const __m256 a2 = both_ps(a[2]);
      for (int ia = 0; ia < N; ++ia) {
        const Node ua = detail::fmadd(s.offset[0][ia], a[0], u0);
        for (int ib = 0; ib < N; ++ib) {
          const T wab = s.w[0][ia] * s.w[1][ib];
          const Node uab = detail::fmadd(s.offset[1][ib], a[1], ua);
          const __m256 uab2 = both_ps(uab), wab2 = _mm256_set1_ps(wab);
          Node* row = n0 + ia * stride[0] + ib * stride[1];
          for (int k = 0; k < pairs; ++k) {
            float* r = row[2 * k].data();
            const __m256 u = _mm256_fmadd_ps(o2[k], a2, uab2);
            _mm256_storeu_ps(r, _mm256_fmadd_ps(_mm256_mul_ps(wab2, w2[k]), u, _mm256_loadu_ps(r)));
          }
          if constexpr (N % 2 == 1) {
            constexpr int ic = N - 1;
            row[ic] = detail::fmadd(wab * s.w[2][ic], detail::fmadd(s.offset[2][ic], a[2], uab), row[ic]);
          }
        }
      }
      continue;
    }
#endif
    if constexpr (Dim == 3) {
      for (int ia = 0; ia < N; ++ia) {
        const Node ua = has_A ? Node(u0 + s.offset[0][ia] * a[0]) : u0;
        for (int ib = 0; ib < N; ++ib) {
          const T wab = s.w[0][ia] * s.w[1][ib];
          const Node uab = has_A ? Node(ua + s.offset[1][ib] * a[1]) : ua;
          Node* row = n0 + ia * stride[0] + ib * stride[1];
          if (has_G) {
            const Node hab = (s.dw[0][ia] * s.w[1][ib]) * g[0] + (s.w[0][ia] * s.dw[1][ib]) * g[1];
            for (int ic = 0; ic < N; ++ic)
              row[ic] += (wab * s.w[2][ic]) * (uab + s.offset[2][ic] * a[2]) + s.w[2][ic] * hab +
                         (wab * s.dw[2][ic]) * g[2];
          } else if (has_A) {
            for (int ic = 0; ic < N; ++ic) row[ic] += (wab * s.w[2][ic]) * (uab + s.offset[2][ic] * a[2]);
          } else {
            for (int ic = 0; ic < N; ++ic) row[ic] += (wab * s.w[2][ic]) * uab;
          }
        }
      }
    } else {
      // ua = m v + ox_a a0 with m v unrounded, as in the scalar form (see fmadd).
      const Node vm = detail::padded<T, Dim>(v[p].data(), T(1));  // (v, 1, 0)
#if defined(__AVX__) && defined(__FMA__)
      if constexpr (std::is_same_v<T, float> && N >= 2) {
        // Two nodes of a row (adjacent in memory: the last axis has stride 1) per 256-bit
        // register, each lane doing the multiply-adds of the 4-wide form below, in the same
        // order: the same bits with half the instructions.
        constexpr int pairs = N / 2;
        using detail::pair_ps, detail::both_ps;
        __m256 w1[pairs], o1[pairs], d1[pairs];
        for (int k = 0; k < pairs; ++k) {
          w1[k] = pair_ps(s.w[1][2 * k], s.w[1][2 * k + 1]);
          if (has_A) o1[k] = pair_ps(s.offset[1][2 * k], s.offset[1][2 * k + 1]);
          if (has_G) d1[k] = pair_ps(s.dw[1][2 * k], s.dw[1][2 * k + 1]);
        }
        const __m256 a1 = both_ps(a[1]), g0 = both_ps(g[0]), g1 = both_ps(g[1]);
        for (int ia = 0; ia < N; ++ia) {
          const Node ua =
              has_A ? detail::fmadd(mp, vm, Node(s.offset[0][ia] * a[0])) : Node(mp * vm);
          const __m256 ua2 = both_ps(ua);
          const __m256 w0 = _mm256_set1_ps(s.w[0][ia]);
          T* row = (n0 + ia * stride[0])->data();
          for (int k = 0; k < pairs; ++k) {
            const __m256 wab = _mm256_mul_ps(w0, w1[k]);
            const __m256 uab = has_A ? _mm256_fmadd_ps(o1[k], a1, ua2) : ua2;
            T* r = row + 8 * k;
            if (has_G) {
              const __m256 c0 = _mm256_mul_ps(_mm256_set1_ps(s.dw[0][ia]), w1[k]);
              const __m256 c1 = _mm256_mul_ps(w0, d1[k]);
              const __m256 h = _mm256_fmadd_ps(c0, g0, _mm256_mul_ps(c1, g1));
              _mm256_storeu_ps(r, _mm256_add_ps(_mm256_loadu_ps(r), _mm256_fmadd_ps(wab, uab, h)));
            } else {
              _mm256_storeu_ps(r, _mm256_fmadd_ps(wab, uab, _mm256_loadu_ps(r)));
            }
          }
          if constexpr (N % 2 == 1) {
            constexpr int ib = N - 1;
            Node* rn = n0 + ia * stride[0];
            const T wab = s.w[0][ia] * s.w[1][ib];
            const Node uab = has_A ? detail::fmadd(s.offset[1][ib], a[1], ua) : ua;
            if (has_G) {
              const Node h = detail::fmadd(s.dw[0][ia] * s.w[1][ib], g[0],
                                           Node((s.w[0][ia] * s.dw[1][ib]) * g[1]));
              rn[ib] += detail::fmadd(wab, uab, h);
            } else {
              rn[ib] = detail::fmadd(wab, uab, rn[ib]);
            }
          }
        }
        continue;
      }
#endif
      for (int ia = 0; ia < N; ++ia) {
        const Node ua = has_A ? detail::fmadd(mp, vm, Node(s.offset[0][ia] * a[0])) : Node(mp * vm);
        Node* row = n0 + ia * stride[0];
        for (int ib = 0; ib < N; ++ib) {
          const T wab = s.w[0][ia] * s.w[1][ib];
          const Node uab = has_A ? detail::fmadd(s.offset[1][ib], a[1], ua) : ua;
          if (has_G) {
            const Node h = detail::fmadd(s.dw[0][ia] * s.w[1][ib], g[0],
                                         Node((s.w[0][ia] * s.dw[1][ib]) * g[1]));
            row[ib] += detail::fmadd(wab, uab, h);
          } else {
            row[ib] = detail::fmadd(wab, uab, row[ib]);
          }
        }
      }
    }
  }
  grid.touch(lo, hi + IVec::Constant(St::N - 1));
}

/// Scatters particles [begin, end) to a whole grid (serial; the engine scatters block by block
/// in parallel, see blocks.h).
template <int Order, Scheme S, class Grid, class T, int Dim>
void particles_to_grid(Grid& grid, const Eigen::Matrix<T, Dim, 1>* x,
                       const Eigen::Matrix<T, Dim, 1>* v, const T* m,
                       const detail::MatPtr<T, Dim>* C, const detail::MatPtr<T, Dim>* K,
                       std::int64_t begin, std::int64_t end, std::int64_t mass_mask = -1) {
  scatter_particles<Order, S>(grid, x, v, m, C, K, nullptr, begin, end, mass_mask);
}

/// Gathers velocity (and C for APIC/MLS) back to particles ids[begin, end) (or [begin, end)
/// when ids is null), advects them by dt * (PIC velocity), and calls `state(p, grad_v)` for the
/// caller's deformation update (where the updates are queued and the functor has `kBatched`
/// true, `state.batch(ids, grads, n)` for a queue at once). Reads the grid velocity from the
/// node's first Dim entries and, for FLIP, the pre-update velocity from `grid.old_velocity(k)`.
/// Serial; each particle writes only itself, so callers run disjoint ranges in parallel. Returns the largest squared particle
/// speed, or +infinity if any velocity is not finite or any particle left the box [x_lo, x_hi]
/// (the caller then finds and names the particle).
template <int Order, Scheme S, class Grid, class T, int Dim, class StateFn>
T gather_particles(const Grid& grid, Eigen::Matrix<T, Dim, 1>* x, Eigen::Matrix<T, Dim, 1>* v,
                   detail::MatPtr<T, Dim>* C, T dt, T flip_ratio,
                   const Eigen::Matrix<T, Dim, 1>& x_lo, const Eigen::Matrix<T, Dim, 1>& x_hi,
                   const std::uint32_t* ids, std::int64_t begin, std::int64_t end,
                   StateFn&& state) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using Node = typename Grid::Node;
  using St = Stencil<T, Dim, Order>;
  static_assert(S != Scheme::MLS || Order > 1, "MLS-MPM needs a quadratic or cubic kernel");
  const Vec origin = grid.origin();
  const T dx = grid.dx(), inv_dx = grid.inv_dx();
  const T Dinv = BSpline<Order>::inverse_inertia(dx);
  std::int64_t stride[Dim];
  for (int d = 0; d < Dim; ++d) stride[d] = grid.stride(d);
  const Node* nodes = grid.data();
  // Which sums each scheme needs: B for APIC/MLS (stored as C = B D^-1 for Order > 1, as B for
  // the linear kernel); grad v from grad w except for MLS, which uses C (Hu et al. 2018, eq. 17).
  constexpr bool need_B = carries_affine(S);
  constexpr bool need_grad = S != Scheme::MLS;

  // The stencils a batch at a time over SIMD lanes (kernels.h), bases clamped to the patch,
  // computed before any particle of the batch moves.
  StencilBatch<T, Dim, Order> batch;
  int base_lo[Dim], base_hi[Dim];
  const bool clamp = detail::patch_bases<St::N>(grid, base_lo, base_hi);
  auto stencil = [&](std::int64_t i) {
    const int k = int((i - begin) % StencilBatch<T, Dim, Order>::size);
    if (k == 0)
      batch.compute(x, ids, i, int(std::min<std::int64_t>(StencilBatch<T, Dim, Order>::size, end - i)),
                    origin, inv_dx, dx, clamp ? base_lo : nullptr, base_hi);
    return batch.get(k);
  };

  // The caller's state update runs a batch behind, 16 particles at a time, in 2D and on the
  // packed 3D path. Called once per particle from the sums' loop, it cost 9% of a 2D snow
  // substep (G2P 0.33 -> 0.31 ms); in 3D it read C back just after the loop had stored it, a
  // store-to-load forwarding stall per particle. Nothing in the loop reads what it writes. In 3D
  // the update is called out of line, as from the loop: inlined into the queue's loop, GCC fused
  // its multiply-adds differently (frames changed at round-off) and G2P was slower (1 M
  // particles, one thread: 42.5-43.4 -> 45.3-46.0 ms per substep, when C was copied in).
  constexpr bool packed3 = Dim == 3 && detail::kPackedGather3<T, S> && Order > 1;
  constexpr bool queue_state = Dim == 2 || packed3;
  constexpr int Q = StencilBatch<T, Dim, Order>::size;
  std::int64_t queued[Q];
  Mat queued_grad[Q];
  int nq = 0;
  auto flush = [&] {
    if constexpr (detail::kBatchedState<std::decay_t<StateFn>>) {
      state.batch(queued, queued_grad, nq);
    } else {
      for (int j = 0; j < nq; ++j) {
        if constexpr (Dim == 3)
          detail::call_out_of_line(state, queued[j], queued_grad[j]);
        else
          state(queued[j], queued_grad[j]);
      }
    }
    nq = 0;
  };

  T vmax2 = 0;
  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t p = ids ? std::int64_t(ids[i]) : i;
    const St s = stencil(i);
    // Sums over the stencil, axis by axis: for each row (a, b) of nodes along the last axis,
    // T_ab = sum_c wz_c v, O_ab = sum_c wz_c oz_c v and U_ab = sum_c dwz_c v; then
    // v_pic = sum wab T_ab, B = sum w v (x_i - x_p)^T has columns sum wab ox_a T_ab,
    // sum wab oy_b T_ab, sum wab O_ab, and grad v = sum v grad w^T has columns
    // sum dwx_a wy_b T_ab, sum wx_a dwy_b T_ab, sum wab U_ab. Node vectors carry the mass as a
    // last component (and a zero pad in 2D), which the sums ignore; they are 4-wide for the vector
    // units.
    constexpr int N = St::N;
    const std::int64_t k0 = grid.index(s.base);
    const Node* n0 = nodes + k0;
    Node vp = Node::Zero(), bc[Dim], gc[Dim];
    for (int d = 0; d < Dim; ++d) bc[d].setZero(), gc[d].setZero();
    Vec old_sum = Vec::Zero();
    if constexpr (Dim == 3 && detail::kPackedGather3<T, S>) {
#if defined(__AVX2__) && defined(__FMA__)
      // MLS in float: the sums below two to a 256-bit register, [Tab | Oab], [vp | bc2]
      // and [bc0 | bc1], each lane doing the multiply-adds of the 4-wide form below in the same
      // order (the same bits with half the instructions).
      __m256 ww[N];
      for (int ic = 0; ic < N; ++ic)
        ww[ic] = _mm256_set_m128(_mm_set1_ps(s.w[2][ic] * s.offset[2][ic]), _mm_set1_ps(s.w[2][ic]));
      __m256 vb2 = _mm256_setzero_ps(), b01 = _mm256_setzero_ps();
      for (int ia = 0; ia < N; ++ia) {
        const __m256 o0 = _mm256_set1_ps(s.offset[0][ia]);
        for (int ib = 0; ib < N; ++ib) {
          const float* row = (n0 + ia * stride[0] + ib * stride[1])->data();
          __m256 to = _mm256_setzero_ps();
          for (int ic = 0; ic < N; ++ic) to = _mm256_fmadd_ps(ww[ic], _mm256_broadcast_ps(reinterpret_cast<const __m128*>(row + 4 * ic)), to);
          const __m256 wab = _mm256_set1_ps(s.w[0][ia] * s.w[1][ib]);
          vb2 = _mm256_fmadd_ps(wab, to, vb2);
          const __m256 o01 = _mm256_blend_ps(o0, _mm256_set1_ps(s.offset[1][ib]), 0xF0);
          b01 = _mm256_fmadd_ps(_mm256_mul_ps(wab, o01), _mm256_permute2f128_ps(to, to, 0x00), b01);
        }
      }
      _mm_store_ps(vp.data(), _mm256_castps256_ps128(vb2));
      _mm_store_ps(bc[0].data(), _mm256_castps256_ps128(b01));
      _mm_store_ps(bc[1].data(), _mm256_extractf128_ps(b01, 1));
      _mm_store_ps(bc[2].data(), _mm256_extractf128_ps(vb2, 1));
#endif
    } else if constexpr (Dim == 3) {
      T woz[N];
      for (int ic = 0; ic < N; ++ic) woz[ic] = s.w[2][ic] * s.offset[2][ic];
      for (int ia = 0; ia < N; ++ia)
        for (int ib = 0; ib < N; ++ib) {
          const std::int64_t r = ia * stride[0] + ib * stride[1];
          const Node* row = n0 + r;
          Node Tab = Node::Zero(), Oab = Node::Zero(), Uab = Node::Zero();
          for (int ic = 0; ic < N; ++ic) {
            Tab += s.w[2][ic] * row[ic];
            if constexpr (need_B) Oab += woz[ic] * row[ic];
            if constexpr (need_grad) Uab += s.dw[2][ic] * row[ic];
          }
          const T wab = s.w[0][ia] * s.w[1][ib];
          vp += wab * Tab;
          if constexpr (need_B) {
            bc[0] += (wab * s.offset[0][ia]) * Tab;
            bc[1] += (wab * s.offset[1][ib]) * Tab;
            bc[2] += wab * Oab;
          }
          if constexpr (need_grad) {
            gc[0] += (s.dw[0][ia] * s.w[1][ib]) * Tab;
            gc[1] += (s.w[0][ia] * s.dw[1][ib]) * Tab;
            gc[2] += wab * Uab;
          }
          if constexpr (S == Scheme::FLIP) {
            const std::int64_t k = k0 + r;
            for (int ic = 0; ic < N; ++ic) old_sum += (wab * s.w[2][ic]) * grid.old_velocity(k + ic);
          }
        }
    } else {
      for (int ia = 0; ia < N; ++ia) {
        const std::int64_t r = ia * stride[0];
        const Node* row = n0 + r;
        Node Ta = Node::Zero(), Oa = Node::Zero(), Ua = Node::Zero();
        // Every sum is a fused multiply-add, as in the scalar form (see fmadd).
        for (int ib = 0; ib < N; ++ib) {
          Ta = detail::fmadd(s.w[1][ib], row[ib], Ta);
          if constexpr (need_B) Oa = detail::fmadd(s.w[1][ib] * s.offset[1][ib], row[ib], Oa);
          if constexpr (need_grad) Ua = detail::fmadd(s.dw[1][ib], row[ib], Ua);
          if constexpr (S == Scheme::FLIP)
            old_sum += (s.w[0][ia] * s.w[1][ib]) * grid.old_velocity(k0 + r + ib);
        }
        vp = detail::fmadd(s.w[0][ia], Ta, vp);
        if constexpr (need_B) {
          bc[0] = detail::fmadd(s.w[0][ia] * s.offset[0][ia], Ta, bc[0]);
          bc[1] = detail::fmadd(s.w[0][ia], Oa, bc[1]);
        }
        if constexpr (need_grad) {
          gc[0] = detail::fmadd(s.dw[0][ia], Ta, gc[0]);
          gc[1] = detail::fmadd(s.w[0][ia], Ua, gc[1]);
        }
      }
    }
    const Vec vpic = vp.template head<Dim>();
    Mat B, gv;
    for (int d = 0; d < Dim; ++d) {
      if constexpr (need_B) B.col(d) = bc[d].template head<Dim>();
      if constexpr (need_grad) gv.col(d) = gc[d].template head<Dim>();
    }
    Vec dv = Vec::Zero();
    if constexpr (S == Scheme::FLIP) dv = vpic - old_sum;
    if constexpr (carries_affine(S)) {
      if constexpr (Order > 1 && detail::kPackedGather3<T, S> && Dim == 3) {
#if defined(__AVX2__) && defined(__FMA__)
        // C = D^-1 B written as 8 values and 1: a store the caller's state update can read back
        // in one piece (built from 3 columns on the stack and stored in pieces, B and C stalled
        // every particle's store-to-load forwarding).
        const __m256 c01 = _mm256_set_m128(_mm_load_ps(bc[1].data()), _mm_load_ps(bc[0].data()));
        const __m256 c2 = _mm256_castps128_ps256(_mm_load_ps(bc[2].data()));
        const __m256 lo = _mm256_permutevar8x32_ps(c01, _mm256_setr_epi32(0, 1, 2, 4, 5, 6, 0, 0));
        const __m256 hi = _mm256_permutevar8x32_ps(c2, _mm256_setr_epi32(0, 0, 0, 0, 0, 0, 0, 1));
        const __m256 c8 = _mm256_mul_ps(_mm256_set1_ps(Dinv), _mm256_blend_ps(lo, hi, 0xC0));
        const float c9 = Dinv * bc[2][2];
        for (float* c : {C[p].data(), queued_grad[nq].data()}) {  // the queue's copy from registers
          _mm256_storeu_ps(c, c8);
          c[8] = c9;
        }
#endif
      } else if constexpr (Order > 1) {
        C[p] = Dinv * B;
      } else {
        C[p] = B;
      }
    }
    Vec vnew = vpic;
    if constexpr (S == Scheme::FLIP) vnew = flip_ratio * (v[p] + dv) + (T(1) - flip_ratio) * vpic;
    v[p] = vnew;
    if constexpr (Dim == 3 && detail::kPackedGather3<T, S>) {
      // Inline, with the one rounding GCC gave the out-of-line x[p] += dt * vpic.
      for (int d = 0; d < Dim; ++d) x[p][d] = std::fma(dt, vpic[d], x[p][d]);
    } else {
      x[p] += dt * vpic;
    }
    if (!((x[p].array() >= x_lo.array()).all() && (x[p].array() <= x_hi.array()).all())) {
      if constexpr (queue_state) flush();
      return std::numeric_limits<T>::infinity();
    }
    if constexpr (queue_state) {
      queued[nq] = p;  // packed3: queued_grad[nq] was stored with C, from registers
      if constexpr (!packed3) queued_grad[nq] = S == Scheme::MLS ? C[p] : gv;
      if (++nq == Q) flush();
    } else if constexpr (S == Scheme::MLS) {
      state(p, C[p]);
    } else {
      state(p, gv);
    }
    const T s2 = vnew.squaredNorm();
    if (!(s2 <= std::numeric_limits<T>::max())) {
      if constexpr (queue_state) flush();
      return std::numeric_limits<T>::infinity();
    }
    vmax2 = std::max(vmax2, s2);
  }
  if constexpr (queue_state) flush();
  return vmax2;
}

/// gather_particles over [begin, end) of a whole grid, in parallel.
template <int Order, Scheme S, class Grid, class T, int Dim, class StateFn>
T grid_to_particles(const Grid& grid, Eigen::Matrix<T, Dim, 1>* x, Eigen::Matrix<T, Dim, 1>* v,
                    detail::MatPtr<T, Dim>* C, T dt, T flip_ratio,
                    const Eigen::Matrix<T, Dim, 1>& x_lo, const Eigen::Matrix<T, Dim, 1>& x_hi,
                    std::int64_t begin, std::int64_t end, StateFn&& state) {
  return parallel::parallel_max<T>(begin, end, T(0), [&](std::int64_t lo, std::int64_t hi) {
    return gather_particles<Order, S>(grid, x, v, C, dt, flip_ratio, x_lo, x_hi, nullptr, lo, hi,
                                      state);
  });
}

}  // namespace slurry::transfer
