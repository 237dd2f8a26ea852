#pragma once
/// \file fixed_corotated.h
/// Fixed corotated elasticity, Stomakhin, Howes, Schroeder and Teran 2012, "Energetically
/// consistent invertible elasticity" (SCA), the model of the MPM snow paper (Stomakhin et al.
/// 2013):
///
///   psi(F) = mu ||F - R||_F^2 + lambda/2 (J - 1)^2,   F = R S (rotation-variant polar), J = det F,
///   P = 2 mu (F - R) + lambda (J - 1) J F^-T,
///   tau = P F^T = 2 mu (F - R) F^T + lambda (J - 1) J I = U diag(2 mu (sigma - 1) sigma) U^T
///         + lambda (J - 1) J I.
///
/// Defined and smooth through inversion (J <= 0): J F^-T is the cofactor matrix, and the
/// rotation-variant SVD gives the R that keeps the energy minimal for inverted F.
#include <Eigen/Core>

#include "kinematics.h"
#include "svd.h"

namespace slurry::constitutive {

/// Fixed corotated elasticity (Stomakhin et al. 2012); see the file comment for the formulas.
template <class T, int Dim>
struct FixedCorotated {
  using Scalar = T;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  static constexpr int dim = Dim;

  T mu;      ///< shear modulus [Pa]
  T lambda;  ///< first Lame parameter [Pa]

  /// Energy density per unit reference volume.
  T energy(const Mat& F) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    const T J = sigma.prod();
    return mu * (sigma.array() - T(1)).square().sum() + T(0.5) * lambda * (J - T(1)) * (J - T(1));
  }

  /// First Piola-Kirchhoff stress P = d psi / dF.
  Mat piola(const Mat& F) const {
    Mat R, S;
    polar(F, R, S);
    const T J = determinant(F);
    return T(2) * mu * (F - R) + lambda * (J - T(1)) * cofactor(F);
  }

  /// Kirchhoff stress tau = P F^T = 2 mu (F - R) F^T + lambda (J - 1) J I, with R from the
  /// Newton polar iteration (the hot path of MPM's P2G).
  Mat kirchhoff(const Mat& F) const {
    Mat R;
    polar_rotation<T, Dim>(F, R);
    const T J = determinant(F);
    if constexpr (Dim == 2) {
      // Entry by entry: R's four values stay in registers. As a matrix expression, GCC stored
      // them one by one and read them back as one vector (a store-forwarding stall that took
      // half of this function's time in a 2D snow profile).
      const T d00 = F(0, 0) - R(0, 0), d01 = F(0, 1) - R(0, 1), d10 = F(1, 0) - R(1, 0),
              d11 = F(1, 1) - R(1, 1);
      const T two_mu = T(2) * mu, p = lambda * (J - T(1)) * J;
      const T t01 = two_mu * (d00 * F(1, 0) + d01 * F(1, 1));
      Mat tau;
      tau(0, 0) = two_mu * (d00 * F(0, 0) + d01 * F(0, 1)) + p;
      tau(0, 1) = t01;
      tau(1, 0) = two_mu * (d10 * F(0, 0) + d11 * F(0, 1));
      tau(1, 1) = two_mu * (d10 * F(1, 0) + d11 * F(1, 1)) + p;
      return tau;
    }
    Mat tau = T(2) * mu * (F - R) * F.transpose();
    tau.diagonal().array() += lambda * (J - T(1)) * J;
    return tau;
  }

  /// Differential of P at F in direction dF:
  /// dP = 2 mu (dF - dR) + lambda (cof(F) : dF) cof(F) + lambda (J - 1) dcof(F)[dF].
  Mat dP(const Mat& F, const Mat& dF) const { return differential(F)(dF); }

  /// dP(F, .) with its F-dependent factors (SVD, cofactor, J) computed once, for evaluating many
  /// directions (the implicit MPM solve builds its per-particle stiffness from Dim^2 of them).
  struct Differential {
    Mat F, U, V, C;
    Vec sigma;
    T J, mu, lambda;
    Mat operator()(const Mat& dF) const {
      const Mat dR = rotation_differential<T, Dim>(U, sigma, V, dF);
      return T(2) * mu * (dF - dR) + lambda * C.cwiseProduct(dF).sum() * C +
             lambda * (J - T(1)) * cofactor_differential(F, dF);
    }
  };
  Differential differential(const Mat& F) const {
    Differential d;
    d.F = F;
    svd(F, d.U, d.sigma, d.V);
    d.C = cofactor(F);
    d.J = determinant(F);
    d.mu = mu;
    d.lambda = lambda;
    return d;
  }

  /// Copy with mu and lambda multiplied by factor (e.g. snow hardening).
  FixedCorotated scaled(T factor) const { return {mu * factor, lambda * factor}; }

  /// Throws std::invalid_argument unless mu >= 0 and lambda >= -2 mu / Dim.
  void validate() const { detail::validate_lame<T, Dim>("FixedCorotated", mu, lambda); }
};

}  // namespace slurry::constitutive
