#pragma once
/// \file colliders.h
/// Analytic colliders (half-space, box, sphere; each may translate at a constant velocity) and
/// the velocity boundary conditions applied on grid nodes inside them and inside the domain
/// walls: sticky, slip, and separating with Coulomb friction (Stomakhin et al. 2013, sec. 8;
/// the friction rule of Jiang et al. 2016 course notes, sec. 12.1).
#include <Eigen/Core>
#include <cmath>
#include <limits>

#include "slurry/engine/scene.h"

namespace slurry {

/// Applies condition `c` to velocity v at a boundary with outward normal n (pointing out of the
/// solid, into the material) moving at vb.
template <class T, int Dim>
Eigen::Matrix<T, Dim, 1> apply_condition(const Eigen::Matrix<T, Dim, 1>& v,
                                         const Eigen::Matrix<T, Dim, 1>& vb,
                                         const Eigen::Matrix<T, Dim, 1>& n, Condition c,
                                         T friction) {
  if (c == Condition::Sticky) return vb;
  Eigen::Matrix<T, Dim, 1> vr = v - vb;
  const T vn = vr.dot(n);
  if (c == Condition::Slip) return v - vn * n;
  if (vn >= T(0)) return v;  // separating: leave it alone
  Eigen::Matrix<T, Dim, 1> vt = vr - vn * n;
  const T t = vt.norm();
  // Coulomb: the tangential speed drops by friction * |v_n|, and stops at zero.
  if (friction > T(0)) {
    if (t > -friction * vn)
      vt *= T(1) + friction * vn / t;
    else
      vt.setZero();
  }
  return vt + vb;
}

/// A collider in the scene's dimension, at time t translated by velocity * t.
template <class T, int Dim>
struct Collider {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  ColliderShape shape = ColliderShape::HalfSpace;
  Vec point, normal, lo, hi, center, velocity;
  T radius = 0;
  Condition condition = Condition::Separate;
  T friction = 0;

  explicit Collider(const ColliderParams& p) {
    shape = p.shape;
    point = p.point.head<Dim>().template cast<T>();
    normal = p.normal.head<Dim>().normalized().template cast<T>();
    lo = p.min.head<Dim>().template cast<T>();
    hi = p.max.head<Dim>().template cast<T>();
    center = p.center.head<Dim>().template cast<T>();
    velocity = p.velocity.head<Dim>().template cast<T>();
    radius = T(p.radius);
    condition = p.condition;
    friction = T(p.friction);
  }

  /// True if x is inside the solid at time t; then n is the outward normal of the nearest surface.
  bool inside(const Vec& x, T t, Vec& n) const {
    const Vec y = x - velocity * t;  // position in the collider's frame
    switch (shape) {
      case ColliderShape::HalfSpace:
        n = normal;
        return (y - point).dot(normal) < T(0);
      case ColliderShape::Sphere: {
        const Vec r = y - center;
        const T d = r.norm();
        if (d >= radius) return false;
        n = d > T(0) ? Vec(r / d) : Vec(Vec::UnitX());
        return true;
      }
      case ColliderShape::Box: {
        if ((y.array() <= lo.array()).any() || (y.array() >= hi.array()).any()) return false;
        // Nearest face decides the normal.
        T best = std::numeric_limits<T>::max();
        for (int d = 0; d < Dim; ++d) {
          if (y[d] - lo[d] < best) best = y[d] - lo[d], n = -Vec::Unit(d);
          if (hi[d] - y[d] < best) best = hi[d] - y[d], n = Vec::Unit(d);
        }
        return true;
      }
    }
    return false;
  }
};

}  // namespace slurry
