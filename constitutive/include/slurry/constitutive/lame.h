#pragma once
/// \file lame.h
/// Lame parameters from engineering constants, and the P-wave speed used for CFL limits.
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace slurry::constitutive {

/// Lame parameters: shear modulus mu and first Lame parameter lambda (both in Pa).
template <class T>
struct Lame {
  T mu;
  T lambda;
};

/// Isotropic linear elasticity: mu = E / (2 (1 + nu)), lambda = E nu / ((1 + nu) (1 - 2 nu)).
/// Throws std::invalid_argument unless E >= 0 and -1 < nu < 1/2 (outside that range the
/// material is not stable; nu = 1/2 is incompressible and has no finite lambda).
template <class T>
inline Lame<T> lame_from_young(T youngs_modulus, T poisson_ratio) {
  if (!(youngs_modulus >= T(0)) || !std::isfinite(youngs_modulus)) {
    std::ostringstream msg;
    msg << "lame_from_young: youngs_modulus = " << youngs_modulus
        << ", expected a finite value >= 0";
    throw std::invalid_argument(msg.str());
  }
  if (!(poisson_ratio > T(-1) && poisson_ratio < T(0.5))) {
    std::ostringstream msg;
    msg << "lame_from_young: poisson_ratio = " << poisson_ratio << ", expected -1 < nu < 0.5";
    throw std::invalid_argument(msg.str());
  }
  const T E = youngs_modulus, nu = poisson_ratio;
  return {E / (T(2) * (T(1) + nu)), E * nu / ((T(1) + nu) * (T(1) - T(2) * nu))};
}

/// Speed of pressure (P) waves, sqrt((lambda + 2 mu) / rho): the fastest elastic wave, which
/// bounds the explicit time step (dt < C dx / c).
template <class T>
inline T wave_speed(const Lame<T>& lame, T density) {
  return std::sqrt((lame.lambda + T(2) * lame.mu) / density);
}

}  // namespace slurry::constitutive
