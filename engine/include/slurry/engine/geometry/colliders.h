#pragma once
/// \file colliders.h
/// Colliders: analytic (half-space, box, sphere; each may translate at a constant velocity) and
/// closed triangle meshes (3D; placed, and moved rigidly through keyframes: geometry/), and the
/// velocity boundary conditions applied on grid nodes inside them and inside the domain walls:
/// sticky, slip, and separating with Coulomb friction (Stomakhin et al. 2013, sec. 8; the
/// friction rule of Jiang et al. 2016 course notes, sec. 12.1). A mesh collider is its signed
/// distance field in its own frame (geometry/mesh_sdf.h): inside where phi < 0, normal grad phi,
/// boundary velocity that of the rigid motion at the contact point, v = dc/dt + omega x (x - c).
#include <Eigen/Core>
#include <cmath>
#include <limits>
#include <algorithm>
#include <memory>
#include <vector>

#include "slurry/engine/geometry/mesh_sdf.h"
#include "slurry/engine/geometry/rigid_motion.h"
#include "slurry/engine/scene/scene.h"

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
  /// Mesh shape: the signed distance in the collider's frame and the motion of that frame.
  std::shared_ptr<const geometry::MeshSdf> sdf;
  std::shared_ptr<const geometry::RigidMotion> motion;

  /// A mesh collider needs its `sdf` and `motion` (make_colliders in the engine builds them from
  /// the scene's mesh file); the analytic shapes need nothing else.
  explicit Collider(const ColliderParams& p, std::shared_ptr<const geometry::MeshSdf> mesh_sdf = nullptr,
                    std::shared_ptr<const geometry::RigidMotion> mesh_motion = nullptr)
      : sdf(std::move(mesh_sdf)), motion(std::move(mesh_motion)) {
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

  /// Velocity of the collider's material at x at time t.
  Vec velocity_at(const Vec& x, T t) const {
    if constexpr (Dim == 3) {
      if (shape == ColliderShape::Mesh) return motion->at(double(t)).velocity_at(x.template cast<double>()).template cast<T>();
    }
    (void)x, (void)t;
    return velocity;
  }

  /// False only if no point of the box [box_lo, box_hi] lies within `slack` of the solid at time
  /// t (a mesh always may reach it). The grid update skips the per-node tests of such boxes; the
  /// slack covers the round-off between this test and inside().
  bool may_reach(const Vec& box_lo, const Vec& box_hi, T t, T slack) const {
    const Vec ylo = box_lo - velocity * t, yhi = box_hi - velocity * t;  // in the collider's frame
    switch (shape) {
      case ColliderShape::Mesh: return true;
      case ColliderShape::HalfSpace: {  // the box's least signed distance, at one of its corners
        T s = 0;
        for (int d = 0; d < Dim; ++d) s += normal[d] * ((normal[d] >= T(0) ? ylo[d] : yhi[d]) - point[d]);
        return !(s >= slack);
      }
      case ColliderShape::Sphere: {  // the box's nearest point to the centre
        const Vec q = center.cwiseMax(ylo).cwiseMin(yhi);
        return !((q - center).norm() >= radius + slack);
      }
      case ColliderShape::Box:
        return !((yhi.array() + slack <= lo.array()).any() || (ylo.array() - slack >= hi.array()).any());
    }
    return true;
  }

  /// True if x is inside the solid at time t; then n is the outward normal of the nearest surface.
  bool inside(const Vec& x, T t, Vec& n) const {
    if constexpr (Dim == 3) {
      if (shape == ColliderShape::Mesh) {
        const geometry::Pose pose = motion->at(double(t));
        const Eigen::Vector3d y = pose.to_body(x.template cast<double>());
        if (!(sdf->phi(y) < 0)) return false;
        n = (pose.rotation * sdf->normal(y)).template cast<T>();
        return true;
      }
    }
    const Vec y = x - velocity * t;  // position in the collider's frame
    switch (shape) {
      case ColliderShape::Mesh: return false;  // 3D only (Scene::validate)
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

/// The fraction s in [0, 1] of the straight path y0 -> y1 (in the collider's frame) at which it
/// enters collider c's solid, and the outward normal there; false if it does not enter (or
/// starts inside). Slab test for the box, the smaller root of |y0 + s d - c|^2 = r^2 for the
/// sphere, the sign change of the signed distance for the half-space.
template <class T, int Dim>
bool collider_entry(const Collider<T, Dim>& c, const Eigen::Matrix<T, Dim, 1>& y0, const Eigen::Matrix<T, Dim, 1>& y1,
                    T& s, Eigen::Matrix<T, Dim, 1>& n) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  const Vec d = y1 - y0;
  switch (c.shape) {
    case ColliderShape::Mesh: return false;  // stop_at_collider handles meshes
    case ColliderShape::HalfSpace: {
      const T phi0 = (y0 - c.point).dot(c.normal), phi1 = (y1 - c.point).dot(c.normal);
      if (!(phi0 >= T(0) && phi1 < T(0))) return false;
      s = phi0 / (phi0 - phi1);
      n = c.normal;
      return true;
    }
    case ColliderShape::Sphere: {
      const Vec r = y0 - c.center;
      const T a = d.squaredNorm(), b = r.dot(d), q = r.squaredNorm() - c.radius * c.radius;
      if (q < T(0) || a <= T(0)) return false;  // starts inside, or does not move
      const T disc = b * b - a * q;
      if (disc < T(0)) return false;
      s = (-b - std::sqrt(disc)) / a;
      if (!(s >= T(0) && s <= T(1))) return false;
      const Vec e = r + s * d;
      n = e.norm() > T(0) ? Vec(e.normalized()) : Vec(Vec::UnitX());
      return true;
    }
    case ColliderShape::Box: {
      T enter = T(0), leave = T(1);
      int axis = -1;
      for (int k = 0; k < Dim; ++k) {
        if (d[k] == T(0)) {
          if (y0[k] <= c.lo[k] || y0[k] >= c.hi[k]) return false;
          continue;
        }
        T t0 = (c.lo[k] - y0[k]) / d[k], t1 = (c.hi[k] - y0[k]) / d[k];
        if (t0 > t1) std::swap(t0, t1);
        if (t0 > enter) enter = t0, axis = k;
        leave = std::min(leave, t1);
        if (enter > leave) return false;
      }
      if (axis < 0) return false;  // starts inside (or on) the box: the grid condition holds it
      s = enter;
      n = Vec::Zero();
      n[axis] = d[axis] > T(0) ? T(-1) : T(1);
      return true;
    }
  }
  return false;
}

/// Whether collider c is thinner than the widest kernel stencil (4 cells, the cubic B-spline)
/// along some axis: then particles beside it reach grid nodes on its far side.
template <class T, int Dim>
bool thin_collider(const Collider<T, Dim>& c, T dx) {
  const T reach = T(4) * dx;
  if (c.shape == ColliderShape::Box) return (c.hi - c.lo).minCoeff() < reach;
  if (c.shape == ColliderShape::Sphere) return T(2) * c.radius < reach;
  // A mesh may have thin parts anywhere: its particles' paths are always checked (cheaply, by
  // the distance field first).
  if (c.shape == ColliderShape::Mesh) return true;
  return false;  // a half-space is never thin
}

template <class T, int Dim>
bool any_thin_collider(const std::vector<Collider<T, Dim>>& colliders, T dx) {
  for (const auto& c : colliders)
    if (thin_collider(c, dx)) return true;
  return false;
}


/// The pose of every mesh collider at time t (identity for the analytic ones), computed once
/// per substep for the per-particle path checks.
template <class T, int Dim>
std::vector<geometry::Pose> collider_poses(const std::vector<Collider<T, Dim>>& colliders, T t) {
  std::vector<geometry::Pose> poses(colliders.size());
  for (std::size_t k = 0; k < colliders.size(); ++k)
    if (colliders[k].shape == ColliderShape::Mesh) poses[k] = colliders[k].motion->at(double(t));
  return poses;
}

/// If a particle's straight path x0 (at t0) -> x1 (at t1) enters collider c, seen in the
/// collider's frame (which moves between t0 and t1: pose0, pose1 for a mesh, velocity * t for
/// the analytic shapes), moves x1 to where the path entered, `margin` short of it (in the
/// collider's frame, carried to t1: a wall that sweeps over a particle pushes it along), sets n
/// to the world outward normal there and returns true. A mesh is tested exactly against its
/// triangles, after a distance-field test that rules out paths ending more than their length
/// plus two field cells from the surface.
template <class T, int Dim>
bool stop_at_collider(const Collider<T, Dim>& c, const Eigen::Matrix<T, Dim, 1>& x0, T t0, const geometry::Pose& pose0,
                      Eigen::Matrix<T, Dim, 1>& x1, T t1, const geometry::Pose& pose1, T margin, Eigen::Matrix<T, Dim, 1>& n) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  if constexpr (Dim == 3) {
    if (c.shape == ColliderShape::Mesh) {
      const Eigen::Vector3d y0 = pose0.to_body(x0.template cast<double>()), y1 = pose1.to_body(x1.template cast<double>());
      const double len = (y1 - y0).norm();
      if (c.sdf->phi(y0) > len + 2 * c.sdf->spacing()) return false;
      double s;
      Eigen::Vector3d nl;
      if (!c.sdf->first_entry(y0, y1, s, nl)) return false;
      s = len > 0 ? std::max(0.0, s - double(margin) / len) : 0.0;
      x1 = pose1.to_world(y0 + s * (y1 - y0)).template cast<T>();
      n = (pose1.rotation * nl).template cast<T>();
      return true;
    }
  }
  (void)pose0, (void)pose1;
  const Vec y0 = x0 - c.velocity * t0, y1 = x1 - c.velocity * t1;
  T s;
  if (!collider_entry(c, y0, y1, s, n)) return false;
  if (c.velocity.isZero()) {
    const Vec step = x1 - x0;
    const T len = step.norm();
    s = len > T(0) ? std::max(T(0), s - margin / len) : T(0);
    x1 = x0 + s * step;
  } else {
    const Vec step = y1 - y0;
    const T len = step.norm();
    s = len > T(0) ? std::max(T(0), s - margin / len) : T(0);
    x1 = y0 + s * step + c.velocity * t1;
  }
  return true;
}
}  // namespace slurry
