#pragma once
/// \file fixed_corotated_lanes.h
/// FixedCorotated::kirchhoff (fixed_corotated.h, Stomakhin et al. 2012) for W deformation
/// gradients at once, one per SIMD lane (lanes.h), for MPM's P2G:
///
///   tau = 2 mu (F - R) F^T + lambda (J - 1) J I,
///
/// with R from the Newton polar iteration X_{k+1} = (X_k + cof(X_k) / det X_k) / 2, X_0 = F
/// (Higham 1986; kinematics.h's polar_rotation), run per lane until ||X_{k+1} - X_k||_F^2 < eps
/// (each lane stops at its own iteration; the batch at its slowest lane, at most 8). mu and lambda
/// are per lane (snow scales them by its hardening factor). Lanes where polar_rotation leaves the
/// iteration for the SVD (det F <= 1e-2, or no convergence in 8 iterations) are returned in a
/// mask: the caller computes those with the scalar kirchhoff. Agrees with the scalar kirchhoff to
/// round-off (tests/constitutive/fixed_corotated_lanes_test.cpp). The 2D form (Mat2) takes the
/// closed-form rotation of polar_rotation instead of the iteration (kinematics.h), and flags
/// only the lanes where that form falls back to the SVD.
#include <limits>

#include "kinematics.h"
#include "lanes.h"
#include "svd_lanes.h"

namespace slurry::constitutive::lanes {

/// Sets tau to the fixed corotated Kirchhoff stress of F in every lane; returns the lanes left to
/// the scalar path (their tau is not meaningful).
template <class T, int W>
inline Mask<T, W> fixed_corotated_kirchhoff(const Mat3<T, W>& F, const Lane<T, W>& mu,
                                            const Lane<T, W>& lambda, Mat3<T, W>& tau) {
  using L = Lane<T, W>;
  using detail::cross;
  using detail::dot;
  constexpr T tol = std::numeric_limits<T>::epsilon();
  const L J = dot(F.col(0), cross(F.col(1), F.col(2)));
  const Mask<T, W> newton = gt(J, polar_newton::min_det<T>);
  Mask<T, W> active = newton;
  Mat3<T, W> X = F;
  for (int it = 0; it < polar_newton::max_iterations && any(active); ++it) {
    const auto x0 = X.col(0), x1 = X.col(1), x2 = X.col(2);
    const Vec3<T, W> c[3] = {cross(x1, x2), cross(x2, x0), cross(x0, x1)};  // cof(X), by columns
    const L d = dot(x0, c[0]);
    L change = L::Zero();
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) {
        const L y = T(0.5) * (X.a[i][j] + c[j].c[i] / d);
        change += (y - X.a[i][j]).square();
        X.a[i][j] = select(active, y, X.a[i][j]);
      }
    active = active & ~lt(change, L(L::Constant(tol)));
  }
  for (int i = 0; i < 3; ++i) {
    L A[3];
    for (int k = 0; k < 3; ++k) A[k] = (T(2) * mu) * (F.a[i][k] - X.a[i][k]);
    for (int j = 0; j < 3; ++j)
      tau.a[i][j] = A[0] * F.a[j][0] + A[1] * F.a[j][1] + A[2] * F.a[j][2];
  }
  const L pressure = lambda * (J - T(1)) * J;
  for (int i = 0; i < 3; ++i) tau.a[i][i] += pressure;
  return ~newton | active;
}

/// W 2x2 matrices: a[i][j] holds entry (i, j) of each.
template <class T, int W>
struct Mat2 {
  Lane<T, W> a[2][2];
  /// Lane l as an Eigen matrix, and back.
  Eigen::Matrix<T, 2, 2> get(int l) const {
    Eigen::Matrix<T, 2, 2> m;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j) m(i, j) = a[i][j][l];
    return m;
  }
  void put(int l, const Eigen::Matrix<T, 2, 2>& m) {
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j) a[i][j][l] = m(i, j);
  }
};

/// The 2D form: R = [c -s; s c] with (c, s) = (F00 + F11, F10 - F01) normalised (kinematics.h's
/// polar_rotation), then tau = 2 mu (F - R) F^T + lambda (J - 1) J I entry by entry. Flags the
/// lanes where |(F00 + F11, F10 - F01)|^2 is outside the normal range (F = [p q; q -p], or an
/// overflow, or NaN): the caller computes those with the scalar kirchhoff, which takes the SVD.
template <class T, int W>
inline Mask<T, W> fixed_corotated_kirchhoff(const Mat2<T, W>& F, const Lane<T, W>& mu,
                                            const Lane<T, W>& lambda, Mat2<T, W>& tau) {
  using L = Lane<T, W>;
  const L& f00 = F.a[0][0];
  const L& f01 = F.a[0][1];
  const L& f10 = F.a[1][0];
  const L& f11 = F.a[1][1];
  const L a = f00 + f11, b = f10 - f01;
  const L n2 = a * a + b * b;
  const Mask<T, W> closed =
      ge(n2, std::numeric_limits<T>::min()) & le(n2, std::numeric_limits<T>::max());
  const L inv = L(L::Ones()) / sqrt(n2);
  const L c = a * inv, s = b * inv;
  const L d00 = f00 - c, d01 = f01 + s, d10 = f10 - s, d11 = f11 - c;
  const L two_mu = T(2) * mu;
  const L J = f00 * f11 - f01 * f10;
  const L p = lambda * (J - T(1)) * J;
  tau.a[0][0] = two_mu * (d00 * f00 + d01 * f01) + p;
  tau.a[0][1] = two_mu * (d00 * f10 + d01 * f11);
  tau.a[1][0] = two_mu * (d10 * f00 + d11 * f01);
  tau.a[1][1] = two_mu * (d10 * f10 + d11 * f11) + p;
  return ~closed;
}

}  // namespace slurry::constitutive::lanes
