#pragma once
/// \file fluid.h
/// Weakly compressible fluid with a Tait-type equation of state on the volume ratio J = det F,
/// as in Becker and Teschner 2007, "Weakly compressible SPH for free surface flows" (Tait
/// equation, with density ratio rho/rho0 = 1/J), and in MPM by Tampubolon, Gast, Klar, Fu, Teran,
/// Jiang and Museth 2017, "Multi-species simulation of porous sand and water mixtures":
///
///   p(J) = K/gamma (J^-gamma - 1),       tau = -J p I,       P = -p J F^-T = -p cof(F),
///   psi(J) = K/gamma ((J - 1) - (J^(1-gamma) - 1)/(1 - gamma))   (gamma != 1),
///   psi(J) = K ((J - 1) - log J)                                  (gamma = 1),
///
/// so that d psi / dJ = -p and psi(1) = p(1) = 0. K is the bulk modulus (dp/dJ = -K at J = 1)
/// and gamma the stiffness exponent (7 for water in Becker and Teschner).
///
/// The speed of sound follows from c^2 = dp/drho with rho = rho0 / J:
///
///   c(J)^2 = K J^(1-gamma) / rho0,   so   c(J) / c(1) = J^((1-gamma)/2),
///
/// which for gamma > 1 grows as the liquid is compressed (1.75 c(1) at J = 0.83 for gamma = 7);
/// an explicit step must respect the fastest of these, not c(1) alone.
///
/// A fluid particle stores only J, so the scalar functions pressure(J), energy_J(J) and
/// kirchhoff_pressure(J) are the hot path; the matrix versions take J = det F and exist for
/// uniformity with the solid models (and the tests). J <= 0 is outside the model; J is floored
/// at the smallest normal number there.
#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>

#include "kinematics.h"

namespace slurry::constitutive {

/// Weakly compressible (Tait) fluid; see the file comment for the formulas.
template <class T, int Dim>
struct WeaklyCompressibleFluid {
  using Scalar = T;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  static constexpr int dim = Dim;

  T bulk_modulus;  ///< K [Pa]
  T gamma = T(7);  ///< stiffness exponent (dimensionless)

  /// Pressure p(J) = K/gamma (J^-gamma - 1).
  T pressure(T J) const { return bulk_modulus / gamma * (std::pow(floor_J(J), -gamma) - T(1)); }

  /// J p(J), so that the Kirchhoff stress is tau = -J p I.
  T kirchhoff_pressure(T J) const { return J * pressure(J); }

  /// Energy density per unit reference volume as a function of J.
  T energy_J(T J) const {
    const T j = floor_J(J);
    const T a = T(1) - gamma;
    // expm1 keeps (J^a - 1)/a accurate for J near 1 and gamma near 1.
    const T integral = a == T(0) ? std::log(j) : std::expm1(a * std::log(j)) / a;
    return bulk_modulus / gamma * ((j - T(1)) - integral);
  }

  /// dp/dJ = -K J^(-gamma-1).
  T pressure_derivative(T J) const { return -bulk_modulus * std::pow(floor_J(J), -gamma - T(1)); }

  T energy(const Mat& F) const { return energy_J(determinant(F)); }

  /// P = d psi/dF = -p(J) cof(F).
  Mat piola(const Mat& F) const { return -pressure(determinant(F)) * cofactor(F); }

  /// tau = -J p(J) I.
  Mat kirchhoff(const Mat& F) const {
    return Mat::Identity() * (-kirchhoff_pressure(determinant(F)));
  }

  /// dP = -p'(J) (cof(F) : dF) cof(F) - p(J) dcof(F)[dF].
  Mat dP(const Mat& F, const Mat& dF) const {
    const T J = determinant(F);
    const Mat C = cofactor(F);
    return -pressure_derivative(J) * C.cwiseProduct(dF).sum() * C -
           pressure(J) * cofactor_differential(F, dF);
  }

  /// c(J) / c(1) = J^((1-gamma)/2): the speed of sound at volume ratio J relative to the rest
  /// state's sqrt(K / rho0).
  T sound_speed_ratio(T J) const { return std::pow(floor_J(J), (T(1) - gamma) / T(2)); }

  /// Copy with the bulk modulus multiplied by factor.
  WeaklyCompressibleFluid scaled(T factor) const { return {bulk_modulus * factor, gamma}; }

  /// Throws std::invalid_argument unless bulk_modulus >= 0 and gamma > 0.
  void validate() const {
    detail::require_at_least("WeaklyCompressibleFluid", "bulk_modulus", bulk_modulus, T(0));
    detail::require_at_least("WeaklyCompressibleFluid", "gamma", gamma, T(0), /*strict=*/true);
  }

 private:
  static T floor_J(T J) { return std::max(J, std::numeric_limits<T>::min()); }
};

}  // namespace slurry::constitutive
