#pragma once
/// \file corotated_linear.h
/// Corotated linear elasticity as defined in Sifakis and Barbic 2012, "FEM simulation of 3D
/// deformable solids: a practitioner's guide to theory, discretization and model reduction"
/// (SIGGRAPH course notes), section on corotated linear elasticity: with the polar decomposition F
/// = Q F~ (Q a rotation, F~ symmetric; rotation-variant, so F~ is indefinite when det F < 0),
///
///   eps = (F~ + F~^T)/2 - I = F~ - I,     sigma_c = lambda tr(eps) I + 2 mu eps,
///   psi = mu eps:eps + lambda/2 tr(eps)^2 = mu sum_i (s_i - 1)^2 + lambda/2 (sum_i (s_i - 1))^2,
///   P = Q sigma_c = 2 mu (F - Q) + lambda tr(F~ - I) Q,
///
/// with s_i the (signed) singular values of F. P is the exact derivative of psi, not only the
/// "Q held fixed" one: differentiating Q adds sigma_c : (omega F~ - F~ omega)/2 with
/// omega = Q^T dQ skew, which vanishes because sigma_c commutes with F~. The tests check P
/// against finite differences of psi.
///
/// tau = P F^T = U diag(2 mu (s - 1) s + lambda tr(s - 1) s) U^T (since Q F^T = U diag(s) U^T).
/// dP = 2 mu dF + (lambda tr(F~ - I) - 2 mu) dQ + lambda (Q : dF) Q, using d tr(F~) = Q : dF.
#include <Eigen/Core>

#include "kinematics.h"
#include "svd.h"

namespace slurry::constitutive {

/// Corotated linear elasticity (Sifakis and Barbic 2012); see the file comment for the formulas.
template <class T, int Dim>
struct CorotatedLinear {
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
    const Eigen::Array<T, Dim, 1> e = sigma.array() - T(1);
    return mu * e.square().sum() + T(0.5) * lambda * e.sum() * e.sum();
  }

  /// First Piola-Kirchhoff stress P = Q (2 mu eps + lambda tr(eps) I).
  Mat piola(const Mat& F) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    const Mat Q = U * V.transpose();
    return T(2) * mu * (F - Q) + lambda * (sigma.sum() - T(Dim)) * Q;
  }

  /// Kirchhoff stress tau = P F^T.
  Mat kirchhoff(const Mat& F) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    const T tr_eps = sigma.sum() - T(Dim);
    const Vec d = (T(2) * mu * (sigma.array() - T(1)) + lambda * tr_eps) * sigma.array();
    return U * d.asDiagonal() * U.transpose();
  }

  /// Differential of P at F in direction dF (see the file comment).
  Mat dP(const Mat& F, const Mat& dF) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    const Mat Q = U * V.transpose();
    const Mat dQ = rotation_differential<T, Dim>(U, sigma, V, dF);
    const T tr_eps = sigma.sum() - T(Dim);
    return T(2) * mu * dF + (lambda * tr_eps - T(2) * mu) * dQ +
           lambda * Q.cwiseProduct(dF).sum() * Q;
  }

  /// Copy with mu and lambda multiplied by factor.
  CorotatedLinear scaled(T factor) const { return {mu * factor, lambda * factor}; }

  /// Throws std::invalid_argument unless mu >= 0 and lambda >= -2 mu / Dim.
  void validate() const { detail::validate_lame<T, Dim>("CorotatedLinear", mu, lambda); }
};

}  // namespace slurry::constitutive
