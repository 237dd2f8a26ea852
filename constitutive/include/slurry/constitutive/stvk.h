#pragma once
/// \file stvk.h
/// St. Venant-Kirchhoff elasticity: linear stress-strain law on the Green-Lagrange strain
/// (e.g. Sifakis and Barbic 2012, "FEM simulation of 3D deformable solids"):
///
///   E = (F^T F - I)/2,   psi = mu E:E + lambda/2 tr(E)^2,
///   S = 2 mu E + lambda tr(E) I (second Piola-Kirchhoff),   P = F S,   tau = F S F^T,
///   dP = dF S + F (2 mu dE + lambda tr(dE) I),   dE = (dF^T F + F^T dF)/2.
///
/// Polynomial, so defined for every F, but it softens and then fails under strong compression
/// (the energy does not go to infinity as J -> 0): use it for small strains.
#include <Eigen/Core>

#include "kinematics.h"

namespace slurry::constitutive {

/// St. Venant-Kirchhoff elasticity; see the file comment for the formulas.
template <class T, int Dim>
struct StVenantKirchhoff {
  using Scalar = T;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  static constexpr int dim = Dim;

  T mu;      ///< shear modulus [Pa]
  T lambda;  ///< first Lame parameter [Pa]

  /// Energy density per unit reference volume.
  T energy(const Mat& F) const {
    const Mat E = green_strain(F);
    const T tr = E.trace();
    return mu * E.squaredNorm() + T(0.5) * lambda * tr * tr;
  }

  /// First Piola-Kirchhoff stress P = F S.
  Mat piola(const Mat& F) const { return F * second_piola(green_strain(F)); }

  /// Kirchhoff stress tau = F S F^T.
  Mat kirchhoff(const Mat& F) const { return F * second_piola(green_strain(F)) * F.transpose(); }

  /// Differential of P at F in direction dF (see the file comment).
  Mat dP(const Mat& F, const Mat& dF) const {
    const Mat FtdF = F.transpose() * dF;
    const Mat dE = T(0.5) * (FtdF + FtdF.transpose());
    return dF * second_piola(green_strain(F)) + F * second_piola(dE);
  }

  /// Copy with mu and lambda multiplied by factor.
  StVenantKirchhoff scaled(T factor) const { return {mu * factor, lambda * factor}; }

  /// Throws std::invalid_argument unless mu >= 0 and lambda >= -2 mu / Dim.
  void validate() const { detail::validate_lame<T, Dim>("StVenantKirchhoff", mu, lambda); }

 private:
  static Mat green_strain(const Mat& F) {
    Mat E = T(0.5) * (F.transpose() * F);
    E.diagonal().array() -= T(0.5);
    return E;
  }
  /// S(E) = 2 mu E + lambda tr(E) I; linear, so also maps dE to dS.
  Mat second_piola(const Mat& E) const {
    Mat S = T(2) * mu * E;
    S.diagonal().array() += lambda * E.trace();
    return S;
  }
};

}  // namespace slurry::constitutive
