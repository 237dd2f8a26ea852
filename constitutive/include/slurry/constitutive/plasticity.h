#pragma once
/// \file plasticity.h
/// Return mappings (plastic projections) applied to the elastic deformation gradient Fe after
/// each step: F = Fe Fp, and project() replaces the trial Fe in place by its projection onto
/// the yield surface, updating one scalar of plastic state per particle. Each returns whether the
/// particle yielded. All use the rotation-variant SVD of svd.h; the projection only changes the
/// singular values, so U and V (the rotations) are kept. DruckerPrager also projects 16 float (8
/// double) 3x3 Fe at once over SIMD lanes, on the eigenvectors of Fe Fe^T (svd_lanes.h's
/// left_eigen; V is never formed) or, where those are not accurate, the batched SVD.
///
/// - SnowPlasticity: singular value clamping of Stomakhin et al. 2013.
/// - DruckerPrager: cohesionless Drucker-Prager in Hencky strain, Klar et al. 2016.
/// - VonMises: radial return in Hencky strain (J2 plasticity).
///
/// The Hencky-strain models assume the St. Venant-Kirchhoff-on-Hencky elasticity of
/// hencky_stvk.h, whose principal Kirchhoff stress is tau = 2 mu eps + lambda tr(eps) 1 with
/// eps = log(sigma); their yield functions take those principal stresses.
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "kinematics.h"
#include "svd.h"
#include "svd_lanes.h"

namespace slurry::constitutive {

namespace detail {

/// Hencky strain log(sigma) with singular values floored at min_sigma. An inverted Fe (negative
/// last singular value) has no logarithmic strain; treating it as compressed to min_sigma along
/// that direction is what the return mappings below do with it.
template <class T, int Dim>
inline Eigen::Matrix<T, Dim, 1> hencky_strain(const Eigen::Matrix<T, Dim, 1>& sigma, T min_sigma) {
  return sigma.cwiseMax(min_sigma).array().log().matrix();
}

template <class T>
inline void require_in(const char* model, const char* field, T value, T lo, T hi,
                       const char* range) {
  if (!(value >= lo && value <= hi)) {
    std::ostringstream msg;
    msg << model << ": " << field << " = " << value << ", expected " << range;
    throw std::invalid_argument(msg.str());
  }
}

}  // namespace detail

/// Snow plasticity of Stomakhin, Schroeder, Chai, Teran and Selle 2013, "A material point method
/// for snow simulation": the singular values of Fe are clamped to
/// [1 - critical_compression, 1 + critical_stretch]; the deformation clamped away goes into
/// Fp, so the plastic volume ratio Jp = det Fp is updated to keep Je Jp = det F unchanged.
/// hardening_factor(Jp) = exp(hardening (1 - Jp)) multiplies mu and lambda (snow hardens when
/// compacted, Jp < 1, and softens when it fractures, Jp > 1).
template <class T>
struct SnowPlasticity {
  T critical_compression = T(2.5e-2);  ///< theta_c, dimensionless
  T critical_stretch = T(7.5e-3);      ///< theta_s, dimensionless
  T hardening = T(10);                 ///< xi, dimensionless
  /// Upper bound of hardening_factor(): exp(xi (1 - Jp)) grows without bound under sustained
  /// compaction, and the explicit time step shrinks with 1/sqrt(factor). The default, 20, allows
  /// compaction to Jp = 0.7 at xi = 10 before capping.
  T max_hardening = T(20);

  /// Clamps the singular values of Fe into the window and updates Jp (starts at 1) so that
  /// det(Fe) Jp is preserved. An inverted Fe is un-inverted by the clamp; Jp is then updated with
  /// |det Fe| so that it stays positive. Returns whether any singular value was clamped.
  ///
  /// Most particles of a snow scene are inside the window most of the time, and the SVD is then
  /// wasted: the squared singular values are the eigenvalues of A = Fe^T Fe, and every
  /// eigenvalue of a symmetric A lies within sqrt((Dim - 1) / Dim) |A - m I|_F of
  /// m = tr(A) / Dim (the deviator's eigenvalues sum to zero, so the largest squared one is at
  /// most (Dim - 1) / Dim of their sum of squares; exact in 2D). When that interval sits inside the squared
  /// window with a margin of 1e-5 (far above the SVD's round-off in sigma), no singular value can
  /// be clamped and Fe is left as the SVD path leaves it: the result is bitwise the same
  /// (tests/constitutive: SnowPlasticity.WindowTestAgreesWithTheSvdPath).
  template <int Dim>
  bool project(Eigen::Matrix<T, Dim, Dim>& Fe, T& Jp) const {
    if (inside_window(Fe)) return false;
    return project_by_svd(Fe, Jp);
  }

  /// Whether every singular value of Fe is certainly inside the window (see project()).
  /// One lane of inside_windows().
  template <int Dim>
  bool inside_window(const Eigen::Matrix<T, Dim, Dim>& Fe) const {
    bool inside = false;
    inside_windows<Dim, 1>(&Fe, nullptr, 1, &inside);
    return inside;
  }

  /// The window test of project() for n <= W gradients at once: inside[k] for F[ids[k]] (F[k]
  /// when ids is null), k < n. The arithmetic runs lane by lane over W lanes, which the compiler
  /// vectorises (one particle at a time, the test cost 8% of a 2D snow substep). Its roundings
  /// may depend on W and on the compiler's fusion: that changes no result, as the test is a
  /// sufficient condition with a margin far above round-off, and a gradient it does not clear
  /// goes through project_by_svd(), which leaves one inside the window bitwise as it is.
  template <int Dim, int W = 16>
  void inside_windows(const Eigen::Matrix<T, Dim, Dim>* F, const std::uint32_t* ids, int n, bool* inside) const {
    constexpr int E = Dim * Dim;
    using Mat = Eigen::Matrix<T, Dim, Dim>;
    // Lane k's F(r, c) at f[k * E + c * Dim + r]: the gradients in place when the batch is W
    // consecutive ones (most batches: the particles are kept in bin order), else copied.
    const T* f = nullptr;
    alignas(64) Mat copy[W];
    bool consecutive = n == W;
    for (int k = 1; k < W && consecutive && ids; ++k) consecutive = ids[k] == ids[0] + std::uint32_t(k);
    if (consecutive) {
      f = F[ids ? std::ptrdiff_t(ids[0]) : 0].data();
    } else {
      for (int k = 0; k < W; ++k) {
        const int q = k < n ? k : 0;
        copy[k] = F[ids ? std::ptrdiff_t(ids[q]) : std::ptrdiff_t(q)];
      }
      f = copy[0].data();
    }
    const T lo = T(1) - critical_compression, hi = T(1) + critical_stretch;
    const T lo2 = lo * lo, hi2 = hi * hi;
    alignas(64) T room[W], dev2[W];
    for (int k = 0; k < W; ++k) {  // the loops over i, j, r unrolled, so that k vectorises
      T a[Dim][Dim];  // A = F^T F, upper triangle
#pragma GCC unroll 3
      for (int i = 0; i < Dim; ++i)
#pragma GCC unroll 3
        for (int j = i; j < Dim; ++j) {
          T sum = 0;
#pragma GCC unroll 3
          for (int r = 0; r < Dim; ++r) sum += f[k * E + i * Dim + r] * f[k * E + j * Dim + r];
          a[i][j] = sum;
        }
      T tr = 0;
#pragma GCC unroll 3
      for (int i = 0; i < Dim; ++i) tr += a[i][i];
      const T m = tr / T(Dim);
      T d2 = 0;
#pragma GCC unroll 3
      for (int i = 0; i < Dim; ++i) {
        d2 += (a[i][i] - m) * (a[i][i] - m);
#pragma GCC unroll 3
        for (int j = i + 1; j < Dim; ++j) d2 += T(2) * a[i][j] * a[i][j];
      }
      const T up = hi2 - m, down = m - lo2;
      room[k] = (up < down ? up : down) - T(1e-5);
      dev2[k] = d2;
    }
    for (int k = 0; k < n; ++k)
      inside[k] = (room[k] > T(0)) & (dev2[k] * T(Dim - 1) < T(Dim) * room[k] * room[k]);
  }

  /// project() without the window test: always through the SVD. Out of line for the same reason
  /// as the 2x2 svd() (svd.h): its roundings must not depend on the caller.
  template <int Dim>
  __attribute__((noinline)) bool project_by_svd(Eigen::Matrix<T, Dim, Dim>& Fe, T& Jp) const {
    using Vec = Eigen::Matrix<T, Dim, 1>;
    Eigen::Matrix<T, Dim, Dim> U, V;
    Vec sigma;
    svd(Fe, U, sigma, V);
    const Vec clamped =
        sigma.cwiseMax(T(1) - critical_compression).cwiseMin(T(1) + critical_stretch);
    if (clamped == sigma) return false;
    Jp *= std::abs(sigma.prod()) / clamped.prod();
    Fe = U * clamped.asDiagonal() * V.transpose();
    return true;
  }

  /// exp(xi (1 - Jp)), capped at max_hardening (an overflow to +inf is capped too).
  T hardening_factor(T Jp) const {
    return std::min(std::exp(hardening * (T(1) - Jp)), max_hardening);
  }
  /// hardening_factor of n values in place (Jp in, factors out), with Eigen's vectorised exp
  /// (one packet instruction sequence per 16 floats under AVX-512 instead of a libm call per
  /// value). Eigen's exp may differ from std::exp in the last bit; the factor is a stiffness
  /// multiplier, and the time-step bound (return mapping) keeps its own std::exp.
  void hardening_factors(T* values, std::ptrdiff_t n) const {
    Eigen::Map<Eigen::Array<T, Eigen::Dynamic, 1>> a(values, n);
    a = (hardening * (T(1) - a)).exp().min(max_hardening);
  }

  /// <= 0 inside the window; otherwise the largest distance of a singular value outside it.
  /// 0 (to round-off) after a projection that yielded.
  template <int Dim>
  T yield_function(const Eigen::Matrix<T, Dim, 1>& sigma) const {
    return std::max((sigma.array() - (T(1) + critical_stretch)).maxCoeff(),
                    ((T(1) - critical_compression) - sigma.array()).maxCoeff());
  }

  /// Throws std::invalid_argument naming the field unless 0 <= theta_c < 1, theta_s >= 0,
  /// xi >= 0 and max_hardening >= 1.
  void validate() const {
    detail::require_in("SnowPlasticity", "critical_compression", critical_compression, T(0),
                       T(1) - std::numeric_limits<T>::epsilon(), "0 <= value < 1");
    detail::require_at_least("SnowPlasticity", "critical_stretch", critical_stretch, T(0));
    detail::require_at_least("SnowPlasticity", "hardening", hardening, T(0));
    detail::require_at_least("SnowPlasticity", "max_hardening", max_hardening, T(1));
  }
};

/// Cohesionless Drucker-Prager plasticity in Hencky strain, Klar, Gast, Pradhana, Fu, Schroeder,
/// Jiang and Teran 2016, "Drucker-Prager elastoplasticity for sand animation" (their
/// projection algorithm), for the elasticity of hencky_stvk.h.
///
/// Yield function on principal Kirchhoff stresses (tension positive):
///   y(tau) = ||dev tau||_F + alpha_d tr(tau) <= 0,
///   alpha_3 = sqrt(2/3) 2 sin(phi) / (3 - sin(phi)),   phi = friction_angle,
/// Klar et al.'s cone, which meets Mohr-Coulomb at phi in triaxial compression.
///
/// In 2D (plane strain) the stress has an out-of-plane component that the 2x2 state does not
/// carry. While the material flows plastically with zero dilatancy and no out-of-plane strain,
/// that component equals the in-plane mean stress (the out-of-plane deviator must vanish), and
/// the 3D cone on (tau1, tau2, (tau1 + tau2) / 2) reads ||dev_2 tau||_F + (3/2) alpha_3 tr_2(tau)
/// <= 0 on the in-plane stresses. So alpha_2 = (3/2) alpha_3: a 2D run is the plane-strain slice
/// of the same 3D material (in-plane Mohr-Coulomb angle asin(3 alpha_3 / sqrt 2), 43.9 degrees
/// for phi = 30, the plane-strain strength of the 3D cone). Taking alpha_3 unchanged in 2D would
/// make the 2D material weaker than its 3D self (in-plane angle asin(sqrt 2 alpha_3), 27.5
/// degrees for phi = 30); the column-collapse runout then converges 44% above Lube et al.'s 2D
/// experiments (docs/accuracy.md).
/// With eps = log(sigma), eps^ = dev eps and tau = 2 mu eps + lambda tr(eps) 1, the return map is
///   delta_gamma = ||eps^|| + (d lambda + 2 mu)/(2 mu) tr(eps) alpha_d   (= y(tau) / (2 mu)),
///   delta_gamma <= 0:  inside, unchanged;
///   tr(eps) > 0:       tension, project to the tip sigma = 1 (Fe becomes the rotation U V^T),
///                      state += ||eps||;
///   otherwise:         eps -= delta_gamma eps^ / ||eps^|| (onto the cone, same volume),
///                      state += delta_gamma.
template <class T>
struct DruckerPrager {
  T friction_angle = T(30);  ///< phi, in degrees
  /// Singular values of Fe are floored here before taking logs (an inverted or collapsed Fe is
  /// treated as compressed to this stretch along its weakest direction).
  T min_singular_value = T(1e-4);

  /// alpha_3 = sqrt(2/3) 2 sin(phi) / (3 - sin(phi)) for Dim = 3, alpha_2 = (3/2) alpha_3 for
  /// Dim = 2 (the plane-strain slice, above). Evaluated in every project() call (one sin).
  template <int Dim = 3>
  T alpha() const {
    static_assert(Dim == 2 || Dim == 3, "DruckerPrager: 2D or 3D");
    const T s = std::sin(friction_angle * T(3.14159265358979323846) / T(180));
    const T alpha3 = std::sqrt(T(2) / T(3)) * T(2) * s / (T(3) - s);
    return Dim == 2 ? T(1.5) * alpha3 : alpha3;
  }

  /// Projects Fe onto the yield cone for the Hencky St. Venant-Kirchhoff elasticity with the
  /// given mu > 0 and lambda; state accumulates the plastic strain. Returns whether it yielded.
  template <int Dim>
  bool project(Eigen::Matrix<T, Dim, Dim>& Fe, T& state, T mu, T lambda) const {
    return project_impl<Dim>(Fe, state, mu, lambda, nullptr);
  }

  /// project(), and the Kirchhoff stress of the projected Fe for HenckyStVK{mu, lambda}:
  /// tau = U (2 mu eps + lambda tr(eps) I) U^T from the projection's own SVD and strain, so a
  /// solver that applies the return mapping just before it needs the stress computes one SVD
  /// per particle instead of two (HenckyStVK::kirchhoff of the projected Fe would factor it
  /// again). Equal to that up to round-off: the same U and eps, not recomputed from U e^eps V^T.
  template <int Dim>
  bool project_with_stress(Eigen::Matrix<T, Dim, Dim>& Fe, T& state, T mu, T lambda,
                           Eigen::Matrix<T, Dim, Dim>& tau) const {
    return project_impl<Dim>(Fe, state, mu, lambda, &tau);
  }

  /// project_with_stress() for W 3x3 matrices at once, one per SIMD lane (lanes.h), with packet
  /// log and exp. Results agree with the scalar project_with_stress() to round-off, not bitwise;
  /// each lane depends only on its own Fe and state. Fe is left bitwise unchanged in the lanes
  /// that do not yield. Returns the lanes that yielded (the scalar function's return value, per
  /// lane).
  ///
  /// Two factorisations, chosen per lane:
  /// - where det Fe > 0 and sigma_min^2 >= kLeftEigenRatio sigma_max^2 and sigma_min >
  ///   2 min_singular_value (no floor applies): U and sigma^2 from the eigenvectors of Fe Fe^T
  ///   (svd_lanes.h's left_eigen, M = U^T Fe), with eps = log(sigma^2) / 2 and the projected
  ///   Fe = U diag(e^e) V^T = U diag(e^(e - eps)) M, where e - eps = -(delta_gamma /
  ///   ||eps^||) eps^ on the cone and -eps at the tip: no V and no division by sigma;
  /// - elsewhere (inverted, nearly collapsed or floored lanes) the full SVD of svd_lanes.h, as
  ///   project_with_stress_svd(); those lanes pay for both when a batch has one.
#if defined(__GNUC__) && !defined(__clang__)
// GCC 12 reports -Wuninitialized inside its AVX-512 intrinsics (the _mm512_undefined_ps()
// pass-through of unmasked operations, GCC bug 105593) when Eigen's packet log and exp are
// inlined here: a false positive, silenced for these functions.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif
  template <int W>
  lanes::Mask<T, W> project_with_stress(lanes::Mat3<T, W>& Fe, lanes::Lane<T, W>& state, T mu, T lambda,
                                        lanes::Mat3<T, W>& tau) const {
    using L = lanes::Lane<T, W>;
    using lanes::select;
    lanes::Mat3<T, W> U, M, F_new;
    lanes::Vec3<T, W> lam;
    lanes::left_eigen(Fe, U, lam, M);
    const L det = lanes::detail::dot(Fe.col(0), lanes::detail::cross(Fe.col(1), Fe.col(2)));
    const L lmax = lam.c[0].max(lam.c[1]).max(lam.c[2]), lmin = lam.c[0].min(lam.c[1]).min(lam.c[2]);
    // NaN anywhere fails the tests and goes to the SVD as before.
    const lanes::Mask<T, W> eigen = lanes::gt(det, T(0)) & lanes::ge(lmin, L(kLeftEigenRatio * lmax)) &
                                    lanes::gt(lmin, T(4) * min_singular_value * min_singular_value);
    L eps[3];
    for (int i = 0; i < 3; ++i) eps[i] = T(0.5) * lam.c[i].log();
    L state_new = state;
    const LanesReturn<W> r = return_lanes<W>(eps, state_new, mu, lambda);
    sandwich<W>(U, r.k, tau);
    L y[3];
    for (int i = 0; i < 3; ++i) y[i] = L(select(r.tip, L(-eps[i]), L(-r.scale * r.eps_hat[i]))).exp();
    lanes::Mask<T, W> yielded = ~r.inside;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        F_new.a[i][j] = select(yielded,
                               L(U.a[i][0] * y[0] * M.a[0][j] + U.a[i][1] * y[1] * M.a[1][j] + U.a[i][2] * y[2] * M.a[2][j]),
                               Fe.a[i][j]);
    if (lanes::any(~eigen)) {
      lanes::Mat3<T, W> tau_svd;
      L state_svd = state;
      const lanes::Mask<T, W> yielded_svd = project_with_stress_svd<W>(Fe, state_svd, mu, lambda, tau_svd);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          F_new.a[i][j] = select(eigen, F_new.a[i][j], Fe.a[i][j]);
          tau.a[i][j] = select(eigen, tau.a[i][j], tau_svd.a[i][j]);
        }
      state_new = select(eigen, state_new, state_svd);
      yielded = (eigen & yielded) | (~eigen & yielded_svd);
    }
    Fe = F_new;
    state = state_new;
    return yielded;
  }

  /// The lanes form of project_with_stress() on the full SVD of svd_lanes.h for every lane (the
  /// fallback of the function above; kept callable for tests and benchmarks).
  template <int W>
  lanes::Mask<T, W> project_with_stress_svd(lanes::Mat3<T, W>& Fe, lanes::Lane<T, W>& state, T mu, T lambda,
                                            lanes::Mat3<T, W>& tau) const {
    using L = lanes::Lane<T, W>;
    using lanes::select;
    lanes::Mat3<T, W> U, V;
    lanes::Vec3<T, W> sigma;
    lanes::svd(Fe, U, sigma, V);
    L eps[3];
    for (int i = 0; i < 3; ++i) eps[i] = select(lanes::lt(sigma.c[i], min_singular_value), min_singular_value, sigma.c[i]).log();
    const LanesReturn<W> r = return_lanes<W>(eps, state, mu, lambda);
    sandwich<W>(U, r.k, tau);
    const lanes::Mask<T, W> yielded = ~r.inside | lanes::lt(sigma.c[2], min_singular_value);
    // Fe = U diag(exp e) V^T, U V^T at the tip, where it yielded.
    L x[3];
    for (int i = 0; i < 3; ++i) x[i] = select(r.tip, T(1), L(r.e[i].exp()));
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        Fe.a[i][j] = select(yielded,
                            L(U.a[i][0] * x[0] * V.a[j][0] + U.a[i][1] * x[1] * V.a[j][1] + U.a[i][2] * x[2] * V.a[j][2]),
                            Fe.a[i][j]);
    return yielded;
  }
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif

  /// The batched paths use left_eigen() where sigma_min^2 >= kLeftEigenRatio sigma_max^2: there
  /// its eigenvalues' relative error, about eps sigma_max / sigma_min, stays below 32 eps.
  static constexpr T kLeftEigenRatio = T(1e-3);

  /// y(tau) = ||dev tau||_F + alpha_Dim tr(tau) for principal Kirchhoff stresses tau; <= 0 inside.
  template <int Dim>
  T yield_function(const Eigen::Matrix<T, Dim, 1>& tau) const {
    const T tr = tau.sum();
    return (tau.array() - tr / T(Dim)).matrix().norm() + alpha<Dim>() * tr;
  }

  /// Throws std::invalid_argument unless 0 <= friction_angle < 90 and min_singular_value > 0.
  void validate() const {
    detail::require_in("DruckerPrager", "friction_angle", friction_angle, T(0),
                       std::nextafter(T(90), T(0)), "0 <= value < 90 (degrees)");
    detail::require_at_least("DruckerPrager", "min_singular_value", min_singular_value, T(0),
                             /*strict=*/true);
  }

 private:
  /// The return mapping of project() on W lanes of principal Hencky strains eps: the projected
  /// strain e = eps - scale eps^ (scale 0 off the cone), the principal Kirchhoff stresses k of e
  /// (0 at the tip), and state advanced; shared by both batched paths.
  template <int W>
  struct LanesReturn {
    lanes::Lane<T, W> eps_hat[3], e[3], k[3], scale;
    lanes::Mask<T, W> inside, tip;
  };
  template <int W>
  LanesReturn<W> return_lanes(const lanes::Lane<T, W> (&eps)[3], lanes::Lane<T, W>& state, T mu, T lambda) const {
    using L = lanes::Lane<T, W>;
    using lanes::select;
    LanesReturn<W> r;
    const L tr = eps[0] + eps[1] + eps[2];
    for (int i = 0; i < 3; ++i) r.eps_hat[i] = eps[i] - tr / T(3);
    const L eps_hat_norm =
        lanes::sqrt(L(r.eps_hat[0] * r.eps_hat[0] + r.eps_hat[1] * r.eps_hat[1] + r.eps_hat[2] * r.eps_hat[2]));
    const L delta_gamma = eps_hat_norm + (T(3) * lambda + T(2) * mu) / (T(2) * mu) * tr * alpha<3>();
    r.inside = lanes::le(delta_gamma, T(0));
    r.tip = ~r.inside & (lanes::gt(tr, T(0)) | ~lanes::gt(eps_hat_norm, T(0)));
    const lanes::Mask<T, W> cone = ~r.inside & ~r.tip;
    // Onto the cone (eps - 0 eps^ = eps bitwise in the other lanes); the tip's strain is 0.
    r.scale = select(cone, L(delta_gamma / eps_hat_norm), T(0));
    for (int i = 0; i < 3; ++i) r.e[i] = eps[i] - r.scale * r.eps_hat[i];
    const L eps_norm = lanes::sqrt(L(eps[0] * eps[0] + eps[1] * eps[1] + eps[2] * eps[2]));
    state += select(r.tip, eps_norm, select(cone, delta_gamma, T(0)));
    const L tr_e = r.e[0] + r.e[1] + r.e[2];
    for (int i = 0; i < 3; ++i) r.k[i] = select(r.tip, T(0), L(T(2) * mu * r.e[i] + lambda * tr_e));
    return r;
  }
  /// tau = U diag(k) U^T per lane.
  template <int W>
  static void sandwich(const lanes::Mat3<T, W>& U, const lanes::Lane<T, W> (&k)[3], lanes::Mat3<T, W>& tau) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        tau.a[i][j] = j >= i ? lanes::Lane<T, W>(U.a[i][0] * k[0] * U.a[j][0] + U.a[i][1] * k[1] * U.a[j][1] +
                                                 U.a[i][2] * k[2] * U.a[j][2])
                             : tau.a[j][i];
  }

  template <int Dim>
  bool project_impl(Eigen::Matrix<T, Dim, Dim>& Fe, T& state, T mu, T lambda, Eigen::Matrix<T, Dim, Dim>* tau) const {
    using Vec = Eigen::Matrix<T, Dim, 1>;
    Eigen::Matrix<T, Dim, Dim> U, V;
    Vec sigma;
    svd(Fe, U, sigma, V);
    Vec eps = detail::hencky_strain<T, Dim>(sigma, min_singular_value);
    // tau = U diag(2 mu eps + lambda tr(eps)) U^T (hencky_stvk.h) for the final eps.
    const auto stress = [&](const Vec& e) {
      if (tau) *tau = U * (T(2) * mu * e.array() + lambda * e.sum()).matrix().asDiagonal() * U.transpose();
    };
    const T tr = eps.sum();
    const Vec eps_hat = eps.array() - tr / T(Dim);
    const T eps_hat_norm = eps_hat.norm();
    const T delta_gamma = eps_hat_norm + (T(Dim) * lambda + T(2) * mu) / (T(2) * mu) * tr * alpha<Dim>();
    if (delta_gamma <= T(0)) {
      // Inside the cone. If a singular value was floored, store the floored Fe so that it is
      // the one the elastic stress sees.
      stress(eps);
      if (!(sigma(Dim - 1) < min_singular_value)) return false;
    } else if (tr > T(0) || !(eps_hat_norm > T(0))) {  // the second only with alpha = 0
      state += eps.norm();
      Fe = U * V.transpose();
      if (tau) tau->setZero();  // eps = 0 at the tip
      return true;
    } else {
      eps -= (delta_gamma / eps_hat_norm) * eps_hat;
      state += delta_gamma;
      stress(eps);
    }
    Fe = U * eps.array().exp().matrix().asDiagonal() * V.transpose();
    return true;
  }
};

/// Von Mises (J2) plasticity with radial return in Hencky strain, for the elasticity of
/// hencky_stvk.h (radial return, e.g. Simo and Hughes 1998, "Computational inelasticity", in the
/// principal logarithmic-strain setting of Simo 1992, CMAME 99:61-112).
///
/// Norm convention: the Frobenius norm of the deviatoric Kirchhoff stress,
///   y(tau) = ||dev tau||_F - sqrt(2/3) tau_y <= 0,
/// so tau_y is the yield stress in uniaxial tension (the von Mises equivalent stress is
/// sqrt(3/2) ||dev tau||_F). Since dev tau = 2 mu dev(eps), the return map scales the deviatoric
/// strain back onto the surface:
///   delta_gamma = ||eps^|| - sqrt(2/3) tau_y / (2 mu),   eps -= delta_gamma eps^ / ||eps^||,
/// leaving tr(eps), hence det Fe, unchanged; state accumulates the equivalent plastic strain
/// sqrt(2/3) delta_gamma.
template <class T>
struct VonMises {
  T yield_stress;  ///< tau_y [Pa], uniaxial
  /// Floor for singular values before taking logs (see DruckerPrager::min_singular_value).
  T min_singular_value = T(1e-4);

  /// Radial return of Fe for shear modulus mu > 0; state accumulates the equivalent plastic
  /// strain. Returns whether it yielded.
  template <int Dim>
  bool project(Eigen::Matrix<T, Dim, Dim>& Fe, T& state, T mu) const {
    using Vec = Eigen::Matrix<T, Dim, 1>;
    Eigen::Matrix<T, Dim, Dim> U, V;
    Vec sigma;
    svd(Fe, U, sigma, V);
    Vec eps = detail::hencky_strain<T, Dim>(sigma, min_singular_value);
    const T tr = eps.sum();
    const Vec eps_hat = eps.array() - tr / T(Dim);
    const T eps_hat_norm = eps_hat.norm();
    const T delta_gamma = eps_hat_norm - std::sqrt(T(2) / T(3)) * yield_stress / (T(2) * mu);
    if (delta_gamma <= T(0)) {
      // Inside; store a floored Fe (see DruckerPrager::project).
      if (!(sigma(Dim - 1) < min_singular_value)) return false;
    } else {
      eps -= (delta_gamma / eps_hat_norm) * eps_hat;
      state += std::sqrt(T(2) / T(3)) * delta_gamma;
    }
    Fe = U * eps.array().exp().matrix().asDiagonal() * V.transpose();
    return true;
  }

  /// y(tau) = ||dev tau||_F - sqrt(2/3) tau_y for principal Kirchhoff stresses tau; <= 0 inside.
  template <int Dim>
  T yield_function(const Eigen::Matrix<T, Dim, 1>& tau) const {
    return (tau.array() - tau.sum() / T(Dim)).matrix().norm() -
           std::sqrt(T(2) / T(3)) * yield_stress;
  }

  /// Throws std::invalid_argument unless yield_stress >= 0 and min_singular_value > 0.
  void validate() const {
    detail::require_at_least("VonMises", "yield_stress", yield_stress, T(0));
    detail::require_at_least("VonMises", "min_singular_value", min_singular_value, T(0),
                             /*strict=*/true);
  }
};

}  // namespace slurry::constitutive
