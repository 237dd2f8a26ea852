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
/// Inputs are raw channel pointers (structure of arrays). `K[p]` is the stress impulse
/// -dt V_p^0 tau_p computed by the caller; null means no stress.
#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <limits>

#include "slurry/transfer/kernels.h"
#include "slurry/transfer/parallel.h"

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
}  // namespace detail

/// Whether particles of this scheme carry an affine matrix C.
constexpr bool carries_affine(Scheme s) {
  return s == Scheme::APIC || s == Scheme::MLS;
}

/// Scatters mass and momentum (and the stress impulse) of particles ids[begin, end) (or
/// [begin, end) when ids is null) to `grid` and widens its active box. Serial: the scatter
/// writes shared nodes. `Grid` is a DenseGrid or a block Patch (blocks.h).
template <int Order, Scheme S, class Grid, class T, int Dim>
void scatter_particles(Grid& grid, const Eigen::Matrix<T, Dim, 1>* x,
                       const Eigen::Matrix<T, Dim, 1>* v, const T* m,
                       const detail::MatPtr<T, Dim>* C, const detail::MatPtr<T, Dim>* K,
                       const std::uint32_t* ids, std::int64_t begin, std::int64_t end) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
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

  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t p = ids ? std::int64_t(ids[i]) : i;
    const St s(x[p] - origin, inv_dx, dx);
    const IVec base = Eigen::Map<const IVec>(s.base.data());
    lo = lo.cwiseMin(base);
    hi = hi.cwiseMax(base);
    const T mp = m[p];
    const Vec mv = mp * v[p];
    Mat A = Mat::Zero();  // affine momentum, applied to (x_i - x_p)
    Mat G = Mat::Zero();  // stress impulse (and linear-kernel B_p), applied to grad w
    if constexpr (carries_affine(S)) {
      if constexpr (Order > 1)
        A = mp * C[p];
      else
        G = mp * C[p];
    }
    if (K) {
      if constexpr (S == Scheme::MLS)
        A += Dinv * K[p];
      else
        G += K[p];
    }
    const std::int64_t k0 = grid.index(s.base);
    for_each_node(s, [&](int a, int b, int c, T w, const Vec& grad, const Vec& off) {
      std::int64_t k = k0 + a * stride[0] + b * stride[1];
      if constexpr (Dim == 3) k += c;
      auto& n = nodes[k];
      Vec mom = w * (mv + A * off);
      if constexpr (S != Scheme::MLS) mom.noalias() += G * grad;
      n.template head<Dim>() += mom;
      n[Dim] += w * mp;
    });
  }
  grid.touch(lo, hi + IVec::Constant(St::N - 1));
}

/// Scatters particles [begin, end) to a whole grid (serial; the engine scatters block by block
/// in parallel, see blocks.h).
template <int Order, Scheme S, class Grid, class T, int Dim>
void particles_to_grid(Grid& grid, const Eigen::Matrix<T, Dim, 1>* x,
                       const Eigen::Matrix<T, Dim, 1>* v, const T* m,
                       const detail::MatPtr<T, Dim>* C, const detail::MatPtr<T, Dim>* K,
                       std::int64_t begin, std::int64_t end) {
  scatter_particles<Order, S>(grid, x, v, m, C, K, nullptr, begin, end);
}

/// Gathers velocity (and C for APIC/MLS) back to particles ids[begin, end) (or [begin, end)
/// when ids is null), advects them by dt * (PIC velocity), and calls `state(p, grad_v)` for the
/// caller's deformation update. Reads the grid velocity from the node's first Dim entries and,
/// for FLIP, the pre-update velocity from `grid.old_velocity(k)`. Serial; each particle writes
/// only itself, so callers run disjoint ranges in parallel. Returns the largest squared particle
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
  using St = Stencil<T, Dim, Order>;
  static_assert(S != Scheme::MLS || Order > 1, "MLS-MPM needs a quadratic or cubic kernel");
  const Vec origin = grid.origin();
  const T dx = grid.dx(), inv_dx = grid.inv_dx();
  const T Dinv = BSpline<Order>::inverse_inertia(dx);
  std::int64_t stride[Dim];
  for (int d = 0; d < Dim; ++d) stride[d] = grid.stride(d);
  const auto* nodes = grid.data();
  // Which sums each scheme needs: B for APIC/MLS (stored as C = B D^-1 for Order > 1, as B for
  // the linear kernel); grad v from grad w except for MLS, which uses C (Hu et al. 2018, eq. 17).
  constexpr bool need_B = carries_affine(S);
  constexpr bool need_grad = S != Scheme::MLS;

  T vmax2 = 0;
  for (std::int64_t i = begin; i < end; ++i) {
    const std::int64_t p = ids ? std::int64_t(ids[i]) : i;
    const St s(x[p] - origin, inv_dx, dx);
    Vec vpic = Vec::Zero(), dv = Vec::Zero();
    Mat B = Mat::Zero(), gv = Mat::Zero();
    const std::int64_t k0 = grid.index(s.base);
    for_each_node(s, [&](int a, int b, int c, T w, const Vec& grad, const Vec& off) {
      std::int64_t k = k0 + a * stride[0] + b * stride[1];
      if constexpr (Dim == 3) k += c;
      const Vec vi = nodes[k].template head<Dim>();
      const Vec wv = w * vi;
      vpic += wv;
      // Outer products written out: Eigen's generic product path is not inlined here.
      for (int j = 0; j < Dim; ++j)
        for (int r = 0; r < Dim; ++r) {
          if constexpr (need_B) B(r, j) += wv[r] * off[j];
          if constexpr (need_grad) gv(r, j) += vi[r] * grad[j];
        }
      if constexpr (S == Scheme::FLIP) dv += w * (vi - grid.old_velocity(k));
    });
    if constexpr (carries_affine(S)) {
      if constexpr (Order > 1)
        C[p] = Dinv * B;
      else
        C[p] = B;
    }
    Vec vnew = vpic;
    if constexpr (S == Scheme::FLIP) vnew = flip_ratio * (v[p] + dv) + (T(1) - flip_ratio) * vpic;
    v[p] = vnew;
    x[p] += dt * vpic;
    if (!((x[p].array() >= x_lo.array()).all() && (x[p].array() <= x_hi.array()).all()))
      return std::numeric_limits<T>::infinity();
    if constexpr (S == Scheme::MLS)
      state(p, C[p]);
    else
      state(p, gv);
    const T s2 = vnew.squaredNorm();
    if (!(s2 <= std::numeric_limits<T>::max())) return std::numeric_limits<T>::infinity();
    vmax2 = std::max(vmax2, s2);
  }
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
