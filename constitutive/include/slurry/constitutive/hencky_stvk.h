#pragma once
/// \file hencky_stvk.h
/// St. Venant-Kirchhoff elasticity on the Hencky (logarithmic) strain, the elastic part of the
/// sand model of Klar, Gast, Pradhana, Fu, Schroeder, Jiang and Teran 2016, "Drucker-Prager
/// elastoplasticity for sand animation". With F = U Sigma V^T and eps = log Sigma:
///
///   psi = mu tr(eps^2) + lambda/2 tr(eps)^2,
///   P = U (2 mu Sigma^-1 eps + lambda tr(eps) Sigma^-1) V^T,
///   tau = P F^T = U (2 mu eps + lambda tr(eps) I) U^T.
///
/// The Kirchhoff stress is linear in the Hencky strain, which is what makes the Drucker-Prager
/// return mapping of plasticity.h a projection in eps.
///
/// Needs positive singular values. An inverted or degenerate F is outside the model; singular
/// values are floored at machine epsilon there so the stresses stay finite (the Drucker-Prager
/// projection keeps Fe away from that). Tests cover J > 0 only.
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>

#include "kinematics.h"
#include "svd.h"

namespace slurry::constitutive {

/// St. Venant-Kirchhoff on Hencky strain (Klar et al. 2016); see the file comment.
template <class T, int Dim>
struct HenckyStVK {
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
    const Vec eps = log_strain(sigma);
    return mu * eps.squaredNorm() + T(0.5) * lambda * eps.sum() * eps.sum();
  }

  /// First Piola-Kirchhoff stress.
  Mat piola(const Mat& F) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    return U * principal_piola(sigma).asDiagonal() * V.transpose();
  }

  /// Kirchhoff stress tau = U (2 mu eps + lambda tr(eps) I) U^T.
  Mat kirchhoff(const Mat& F) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    return U * principal_kirchhoff(log_strain(sigma)).asDiagonal() * U.transpose();
  }

  /// Principal Kirchhoff stresses 2 mu eps + lambda tr(eps) for a Hencky strain eps; used by the
  /// return mappings of plasticity.h.
  Vec principal_kirchhoff(const Vec& eps) const {
    return (T(2) * mu * eps.array() + lambda * eps.sum()).matrix();
  }

  /// Differential of P at F in direction dF, by principal_stress_differential with
  /// p_i = (2 mu eps_i + lambda tr eps) / s_i,
  /// dp_i/ds_j = (2 mu delta_ij + lambda) / (s_i s_j) - delta_ij p_i / s_i, and the divided
  /// difference (p_i - p_j)/(s_i - s_j) = 2 mu D[log(x)/x](s_i, s_j) - lambda tr(eps)/(s_i s_j).
  Mat dP(const Mat& F, const Mat& dF) const {
    Mat U, V;
    Vec sigma;
    svd(F, U, sigma, V);
    const Vec s = clamp_sigma(sigma);
    const Vec eps = s.array().log().matrix();
    const T tr = eps.sum();
    const Vec p = principal_piola(sigma);
    Mat hessian, divided;
    for (int i = 0; i < Dim; ++i) {
      for (int j = 0; j < Dim; ++j) {
        hessian(i, j) =
            ((i == j ? T(2) * mu : T(0)) + lambda) / (s(i) * s(j)) - (i == j ? p(i) / s(i) : T(0));
        divided(i, j) = T(2) * mu * divided_log_over_x(s(i), s(j)) - lambda * tr / (s(i) * s(j));
      }
    }
    return principal_stress_differential<T, Dim>(U, s, V, p, hessian, divided, dF);
  }

  /// Copy with mu and lambda multiplied by factor.
  HenckyStVK scaled(T factor) const { return {mu * factor, lambda * factor}; }

  /// Throws std::invalid_argument unless mu >= 0 and lambda >= -2 mu / Dim.
  void validate() const { detail::validate_lame<T, Dim>("HenckyStVK", mu, lambda); }

 private:
  static Vec clamp_sigma(const Vec& sigma) {
    return sigma.cwiseMax(std::numeric_limits<T>::epsilon());
  }
  static Vec log_strain(const Vec& sigma) { return clamp_sigma(sigma).array().log().matrix(); }
  Vec principal_piola(const Vec& sigma) const {
    const Vec s = clamp_sigma(sigma);
    return (principal_kirchhoff(s.array().log().matrix()).array() / s.array()).matrix();
  }
  /// (log a - log b) / (a - b) = log1p(z) / (z b) with z = (a - b) / b; 1/b at a = b.
  static T divided_log(T a, T b) {
    const T z = (a - b) / b;
    return z == T(0) ? T(1) / b : std::log1p(z) / (z * b);
  }
  /// (log(a)/a - log(b)/b) / (a - b) = (b D[log](a, b) - log b) / (a b).
  static T divided_log_over_x(T a, T b) { return (b * divided_log(a, b) - std::log(b)) / (a * b); }
};

}  // namespace slurry::constitutive
