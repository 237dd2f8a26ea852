#pragma once
/// \file kinematics.h
/// Small tensor helpers shared by the constitutive models: the cofactor matrix J F^-T and its
/// differential, the differential of the polar rotation, and the differential of an isotropic
/// stress given through its singular values. Depends on Eigen only.
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "svd.h"

namespace slurry::constitutive {

/// det F (2x2), without pulling in Eigen/LU.
template <class T>
inline T determinant(const Eigen::Matrix<T, 2, 2>& F) {
  return F(0, 0) * F(1, 1) - F(0, 1) * F(1, 0);
}

/// det F (3x3), as the triple product of the columns.
template <class T>
inline T determinant(const Eigen::Matrix<T, 3, 3>& F) {
  return F.col(0).dot(detail::cross<T>(F.col(1), F.col(2)));
}

/// cof(F) = det(F) F^-T = d det(F) / dF, defined (and smooth) for singular F too.
template <class T>
inline Eigen::Matrix<T, 2, 2> cofactor(const Eigen::Matrix<T, 2, 2>& F) {
  Eigen::Matrix<T, 2, 2> C;
  C << F(1, 1), -F(1, 0), -F(0, 1), F(0, 0);
  return C;
}

/// cof(F) = det(F) F^-T: column k is the cross product of the other two columns of F.
template <class T>
inline Eigen::Matrix<T, 3, 3> cofactor(const Eigen::Matrix<T, 3, 3>& F) {
  Eigen::Matrix<T, 3, 3> C;
  C.col(0) = detail::cross<T>(F.col(1), F.col(2));
  C.col(1) = detail::cross<T>(F.col(2), F.col(0));
  C.col(2) = detail::cross<T>(F.col(0), F.col(1));
  return C;
}

/// Differential of cof at F in direction dF. In 2D cof is linear, so this is cof(dF).
template <class T>
inline Eigen::Matrix<T, 2, 2> cofactor_differential(const Eigen::Matrix<T, 2, 2>& /*F*/,
                                                    const Eigen::Matrix<T, 2, 2>& dF) {
  return cofactor(dF);
}

/// Differential of cof at F in direction dF (product rule on the column cross products).
template <class T>
inline Eigen::Matrix<T, 3, 3> cofactor_differential(const Eigen::Matrix<T, 3, 3>& F,
                                                    const Eigen::Matrix<T, 3, 3>& dF) {
  Eigen::Matrix<T, 3, 3> C;
  for (int k = 0; k < 3; ++k) {
    const int i = (k + 1) % 3, j = (k + 2) % 3;
    C.col(k) = detail::cross<T>(dF.col(i), F.col(j)) + detail::cross<T>(F.col(i), dF.col(j));
  }
  return C;
}

/// Differential dR of the rotation R = U V^T of the (rotation-variant) polar decomposition
/// F = R S, given the SVD F = U diag(sigma) V^T, in direction dF.
///
/// From dF = dR S + R dS with R^T dR skew: writing A = U^T dF V and dR = U X V^T, X is skew with
/// X_ij = (A_ij - A_ji) / (sigma_i + sigma_j) (see e.g. Sifakis and Barbic 2012, "FEM simulation
/// of 3D deformable solids", or the technical report of Stomakhin et al. 2012). R is not
/// differentiable where sigma_i + sigma_j = 0 (an inverted F with two singular values of equal
/// magnitude); the denominator is floored at eps there to stay finite.
template <class T, int Dim>
inline Eigen::Matrix<T, Dim, Dim> rotation_differential(const Eigen::Matrix<T, Dim, Dim>& U,
                                                        const Eigen::Matrix<T, Dim, 1>& sigma,
                                                        const Eigen::Matrix<T, Dim, Dim>& V,
                                                        const Eigen::Matrix<T, Dim, Dim>& dF) {
  const Eigen::Matrix<T, Dim, Dim> A = U.transpose() * dF * V;
  Eigen::Matrix<T, Dim, Dim> X = Eigen::Matrix<T, Dim, Dim>::Zero();
  for (int i = 0; i < Dim; ++i) {
    for (int j = i + 1; j < Dim; ++j) {
      const T den = std::max(sigma(i) + sigma(j), std::numeric_limits<T>::epsilon());
      X(i, j) = (A(i, j) - A(j, i)) / den;
      X(j, i) = -X(i, j);
    }
  }
  return U * X * V.transpose();
}

/// Differential of an isotropic stress given in principal form, P = U diag(p(sigma)) V^T with
/// F = U diag(sigma) V^T, in direction dF. With A = U^T dF V, dP = U M V^T where
///   M_ii = sum_j (dp_i/dsigma_j) A_jj,
///   M_ij = (a_ij + b_ij)/2 A_ij + (a_ij - b_ij)/2 A_ji   (i != j),
///   a_ij = (p_i - p_j) / (sigma_i - sigma_j),  b_ij = (p_i + p_j) / (sigma_i + sigma_j).
/// This is the formula of Xu, Sin, Zhu and Barbic 2015, "Nonlinear material design using
/// principal stretches", with the two fractions split into a_ij and b_ij so that only
/// a_ij is 0/0 at repeated singular values. The caller supplies dp/dsigma (hessian) and a_ij
/// (divided_difference, read for i != j), evaluated stably for its own p.
template <class T, int Dim>
inline Eigen::Matrix<T, Dim, Dim> principal_stress_differential(
    const Eigen::Matrix<T, Dim, Dim>& U, const Eigen::Matrix<T, Dim, 1>& sigma,
    const Eigen::Matrix<T, Dim, Dim>& V, const Eigen::Matrix<T, Dim, 1>& p,
    const Eigen::Matrix<T, Dim, Dim>& hessian, const Eigen::Matrix<T, Dim, Dim>& divided_difference,
    const Eigen::Matrix<T, Dim, Dim>& dF) {
  const Eigen::Matrix<T, Dim, Dim> A = U.transpose() * dF * V;
  Eigen::Matrix<T, Dim, Dim> M;
  for (int i = 0; i < Dim; ++i) {
    M(i, i) = hessian.row(i).dot(A.diagonal().transpose());
    for (int j = 0; j < Dim; ++j) {
      if (j == i) continue;
      const T a = divided_difference(i, j);
      const T b = (p(i) + p(j)) / std::max(sigma(i) + sigma(j), std::numeric_limits<T>::epsilon());
      M(i, j) = T(0.5) * ((a + b) * A(i, j) + (a - b) * A(j, i));
    }
  }
  return U * M * V.transpose();
}

namespace detail {

/// Throws std::invalid_argument naming the model, field and value unless lo <= value (or
/// lo < value when strict) and value is finite.
template <class T>
inline void require_at_least(const char* model, const char* field, T value, T lo,
                             bool strict = false) {
  const bool ok = std::isfinite(value) && (strict ? value > lo : value >= lo);
  if (!ok) {
    std::ostringstream msg;
    msg << model << ": " << field << " = " << value << ", expected a finite value "
        << (strict ? "> " : ">= ") << lo;
    throw std::invalid_argument(msg.str());
  }
}

/// Validation shared by the models parametrised by Lame constants: mu >= 0 and a non-negative
/// bulk modulus lambda + 2 mu / Dim (the energy is then convex near the rest state).
template <class T, int Dim>
inline void validate_lame(const char* model, T mu, T lambda) {
  require_at_least(model, "mu", mu, T(0));
  if (!std::isfinite(lambda) || !(lambda + T(2) * mu / T(Dim) >= T(0))) {
    std::ostringstream msg;
    msg << model << ": lambda = " << lambda << ", expected a finite value >= -2 mu / " << Dim
        << " = " << -T(2) * mu / T(Dim);
    throw std::invalid_argument(msg.str());
  }
}

}  // namespace detail

/// The limits of polar_rotation's Newton iteration, shared with its lanes form
/// (fixed_corotated_lanes.h): it runs where det F > min_det, at most max_iterations times.
namespace polar_newton {
template <class T>
inline constexpr T min_det = T(1e-2);
inline constexpr int max_iterations = 8;
}  // namespace polar_newton

/// Rotation R of the polar decomposition F = R S by Newton's iteration
/// X_{k+1} = (X_k + X_k^{-T}) / 2, X_0 = F (Higham 1986, "Computing the polar decomposition -
/// with applications", SIAM J. Sci. Stat. Comput. 7(4)), which converges quadratically to R
/// when det F > 0. Near the identity, the usual state of an elastic particle, it needs two or
/// three iterations of a cofactor matrix, several times cheaper than the SVD. Falls back to
/// polar() (the rotation-variant SVD) when F is inverted or nearly singular (J <= 1e-2, where
/// the rotation-variant R differs from the Newton limit) or when 8 iterations do not converge.
///
/// 2D has a closed form instead, for every F: the rotation-variant polar rotation maximises
/// tr(R^T F) over rotations (R = U V^T, with the SVD's sign on the smallest singular value),
/// and with R = [c -s; s c] that trace is c (F00 + F11) + s (F10 - F01), largest at
/// (c, s) = (F00 + F11, F10 - F01) / |(F00 + F11, F10 - F01)|. One square root and one division
/// against two or three Newton iterations of a division each. Only when that vector vanishes
/// (F = [p q; q -p], where every rotation is as good) does it fall back to polar().
template <class T, int Dim>
inline void polar_rotation(const Eigen::Matrix<T, Dim, Dim>& F, Eigen::Matrix<T, Dim, Dim>& R) {
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  if constexpr (Dim == 2) {
    const T a = F(0, 0) + F(1, 1), b = F(1, 0) - F(0, 1);
    const T n2 = a * a + b * b;
    // Also false for NaN or an overflow; the normal range keeps the quotient's precision.
    if (n2 >= std::numeric_limits<T>::min() && n2 <= std::numeric_limits<T>::max()) {
      const T inv = T(1) / std::sqrt(n2);
      const T c = a * inv, s = b * inv;
      R(0, 0) = c, R(0, 1) = -s, R(1, 0) = s, R(1, 1) = c;
      return;
    }
    Mat S;
    polar(F, R, S);
    return;
  }
  // ||X_{k+1} - X_k||^2 < eps means the next error is about eps: converged to round-off.
  constexpr T tol = std::numeric_limits<T>::epsilon();
  if (determinant(F) > polar_newton::min_det<T>) {
    Mat X = F;
    for (int it = 0; it < polar_newton::max_iterations; ++it) {
      const Mat Y = T(0.5) * (X + cofactor(X) / determinant(X));
      const T change = (Y - X).squaredNorm();
      X = Y;
      if (change < tol) {
        R = X;
        return;
      }
    }
  }
  Mat S;
  polar(F, R, S);
}

}  // namespace slurry::constitutive
