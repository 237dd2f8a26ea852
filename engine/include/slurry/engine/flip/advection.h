#pragma once
/// \file advection.h
/// Particle advection through a velocity field u(x) frozen over the substep (the grid velocity
/// after projection), dx/dt = u(x), with one explicit Runge-Kutta step of length dt:
///   euler     x + dt u(x)                                              (order 1)
///   midpoint  x + dt u(x + dt/2 u(x))                                  (order 2)
///   heun      x + dt/2 (k1 + k2),  k2 = u(x + dt k1)  (trapezoidal)     (order 2)
///   rk3       Kutta's third-order method: k2 = u(x + dt/2 k1), k3 = u(x - dt k1 + 2 dt k2),
///             x + dt/6 (k1 + 4 k2 + k3)                               (order 3)
/// (Hairer, Norsett & Wanner, "Solving ODEs I", sec. II.1; Bridson, "Fluid Simulation for
/// Computer Graphics", 2nd ed., sec. 3.1 recommends at least RK2 for particles.) `velocity`
/// is any callable Vec(const Vec&), so the same code advects through a MacGrid or an analytic
/// field (the convergence-order test).
#include <Eigen/Core>

#include "slurry/engine/scene/scene.h"

namespace slurry::flip {

/// One step from x with the first stage k1 = u(x) already known (e.g. the velocity a PIC or
/// APIC G2P has just gathered at x from the same field): saves one evaluation of u.
template <class Vec, class T, class VelocityFn>
inline Vec advect_point(AdvectionScheme scheme, const Vec& x, const Vec& k1, T dt, VelocityFn&& velocity) {
  switch (scheme) {
    case AdvectionScheme::Euler: return x + dt * k1;
    case AdvectionScheme::Midpoint: return x + dt * velocity(Vec(x + (T(0.5) * dt) * k1));
    case AdvectionScheme::Heun: {
      const Vec k2 = velocity(Vec(x + dt * k1));
      return x + (T(0.5) * dt) * (k1 + k2);
    }
    case AdvectionScheme::RK3: {
      const Vec k2 = velocity(Vec(x + (T(0.5) * dt) * k1));
      const Vec k3 = velocity(Vec(x - dt * k1 + (T(2) * dt) * k2));
      return x + (dt / T(6)) * (k1 + T(4) * k2 + k3);
    }
  }
  return x + dt * k1;
}

template <class Vec, class T, class VelocityFn>
inline Vec advect_point(AdvectionScheme scheme, const Vec& x, T dt, VelocityFn&& velocity) {
  return advect_point(scheme, x, Vec(velocity(x)), dt, velocity);
}

}  // namespace slurry::flip
