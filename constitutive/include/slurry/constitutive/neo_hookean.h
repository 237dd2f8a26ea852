#pragma once
/// \file neo_hookean.h
/// Compressible neo-Hookean elasticity in the form used by Bonet and Wood, "Nonlinear continuum
/// mechanics for finite element analysis" (compressible neo-Hookean), and by most graphics MPM
/// codes:
///
///   psi(F) = mu/2 (tr(F^T F) - d) - mu log J + lambda/2 (log J)^2,   J = det F,
///   P = mu (F - F^-T) + lambda log J F^-T,
///   tau = P F^T = mu (F F^T - I) + lambda log J I,
///   dP = mu dF + (mu - lambda log J) F^-T dF^T F^-T + lambda (F^-T : dF) F^-T.
///
/// J <= 0 (inverted or degenerate F) is outside the model: log J is undefined. There energy()
/// returns +infinity and the stresses are evaluated with J replaced by machine epsilon, which
/// keeps them finite and directed to increase J. Tests cover J > 0 only.
#include <Eigen/Core>

#include <cmath>
#include <limits>

#include "kinematics.h"

namespace slurry::constitutive {

/// Compressible neo-Hookean elasticity; see the file comment for the formulas.
template <class T, int Dim>
struct NeoHookean {
  using Scalar = T;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  static constexpr int dim = Dim;

  T mu;      ///< shear modulus [Pa]
  T lambda;  ///< first Lame parameter [Pa]

  /// Energy density per unit reference volume; +infinity for J <= 0.
  T energy(const Mat& F) const {
    const T J = determinant(F);
    if (!(J > T(0))) return std::numeric_limits<T>::infinity();
    const T log_J = std::log(J);
    return T(0.5) * mu * (F.squaredNorm() - T(Dim)) - mu * log_J + T(0.5) * lambda * log_J * log_J;
  }

  /// First Piola-Kirchhoff stress P = mu F + (lambda log J - mu) F^-T.
  Mat piola(const Mat& F) const {
    const T J = safe_J(F);
    return mu * F + ((lambda * std::log(J) - mu) / J) * cofactor(F);
  }

  /// Kirchhoff stress tau = mu (F F^T - I) + lambda log J I.
  Mat kirchhoff(const Mat& F) const {
    Mat tau = mu * (F * F.transpose());
    tau.diagonal().array() += lambda * std::log(safe_J(F)) - mu;
    return tau;
  }

  /// Differential of P at F in direction dF (see the file comment).
  Mat dP(const Mat& F, const Mat& dF) const {
    const T J = safe_J(F);
    const Mat F_inv_T = cofactor(F) / J;
    return mu * dF + (mu - lambda * std::log(J)) * (F_inv_T * dF.transpose() * F_inv_T) +
           lambda * F_inv_T.cwiseProduct(dF).sum() * F_inv_T;
  }

  /// Copy with mu and lambda multiplied by factor.
  NeoHookean scaled(T factor) const { return {mu * factor, lambda * factor}; }

  /// Throws std::invalid_argument unless mu >= 0 and lambda >= -2 mu / Dim.
  void validate() const { detail::validate_lame<T, Dim>("NeoHookean", mu, lambda); }

 private:
  static T safe_J(const Mat& F) {
    const T J = determinant(F);
    return J > T(0) ? J : std::numeric_limits<T>::epsilon();
  }
};

}  // namespace slurry::constitutive
