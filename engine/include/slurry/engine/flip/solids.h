#pragma once
/// \file solids.h
/// Solids of the FLIP liquid solver: the scene's colliders (colliders.h: analytic shapes and
/// meshes, moving ones included) as signed distances, and from them the open fraction of every face and the solid
/// velocity there. The domain walls close the faces on the domain boundary.
///
/// Face fractions follow the variational treatment of Batty, Bertails & Bridson 2007 ("A fast
/// variational framework for accurate solid-fluid coupling"): the weight of a face is the part of
/// its area outside the solid, computed from the solid signed distance at the face's corners
/// (grid nodes) assuming it is linear along an edge (2D) or on each of four triangles fanned
/// around the face centre (3D, centre value the mean of the corners).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

#include "slurry/engine/geometry/colliders.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// Signed distance to collider k at time t: negative inside the solid.
template <class T, int Dim>
T signed_distance(const Collider<T, Dim>& k, const Eigen::Matrix<T, Dim, 1>& x, T t) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  if constexpr (Dim == 3) {
    if (k.shape == ColliderShape::Mesh)  // a rigid motion keeps distances
      return T(k.sdf->phi(k.motion->at(double(t)).to_body(x.template cast<double>())));
  }
  const Vec y = x - k.velocity * t;
  switch (k.shape) {
    case ColliderShape::Mesh: break;  // 3D only
    case ColliderShape::HalfSpace: return (y - k.point).dot(k.normal);
    case ColliderShape::Sphere: return (y - k.center).norm() - k.radius;
    case ColliderShape::Box: {
      // Standard box distance: outside, the length of the positive part of q; inside, max q.
      const Vec q = (k.lo - y).cwiseMax(y - k.hi);
      const T inside = std::min(q.maxCoeff(), T(0));
      return q.cwiseMax(Vec::Zero()).norm() + inside;
    }
  }
  return std::numeric_limits<T>::max();
}

/// Fraction of the segment [a, b] where a linear function with these end values is positive.
template <class T>
T open_fraction(T a, T b) {
  if (a >= T(0) && b >= T(0)) return T(1);
  if (a < T(0) && b < T(0)) return T(0);
  return (a >= T(0) ? a : b) / (std::abs(a) + std::abs(b));
}

/// Fraction of a triangle where a linear function with these vertex values is positive.
template <class T>
T open_fraction(T a, T b, T c) {
  const int neg = (a < T(0)) + (b < T(0)) + (c < T(0));
  if (neg == 0) return T(1);
  if (neg == 3) return T(0);
  // Rotate so that `a` is the odd one out.
  if (neg == 1) {
    if (b < T(0)) std::swap(a, b);
    else if (c < T(0)) std::swap(a, c);
    // a < 0 <= b, c: the negative corner triangle has area (a/(a-b)) (a/(a-c)).
    return T(1) - (a / (a - b)) * (a / (a - c));
  }
  if (b >= T(0)) std::swap(a, b);
  else if (c >= T(0)) std::swap(a, c);
  // a >= 0 > b, c: the positive corner triangle.
  return (a / (a - b)) * (a / (a - c));
}

/// Solid geometry of a scene on a MacGrid: node distances, face weights and solid velocities.
template <class T, int Dim>
struct Solids {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  std::vector<Collider<T, Dim>> colliders;
  std::vector<T> node_phi;  ///< min signed distance over colliders at grid nodes (res + 1 per axis)

  bool empty() const { return colliders.empty(); }

  /// Minimum signed distance over colliders and the index of the nearest one.
  T distance(const Vec& x, T t, int* which = nullptr) const {
    T best = std::numeric_limits<T>::max();
    for (int i = 0; i < int(colliders.size()); ++i) {
      const T s = signed_distance(colliders[i], x, t);
      if (s < best) {
        best = s;
        if (which) *which = i;
      }
    }
    return best;
  }

  /// Sets g.weight and g.u_solid for time t: domain-boundary faces closed (weight 0, u_solid 0),
  /// other faces open by the fraction of their area outside every collider.
  void update_faces(MacGrid<T, Dim>& g, T t) {
    if (!g.has_solid_faces()) {
      if (!colliders.empty()) throw std::logic_error("Solids::update_faces: colliders need a grid with solid faces");
      return;  // no collider: every face inside the domain is open (MacGrid::face_weight)
    }
    const IVec nres = g.res + IVec::Ones();
    std::int64_t nodes = 1;
    for (int d = 0; d < Dim; ++d) nodes *= nres[d];
    if (!colliders.empty()) {
      node_phi.resize(std::size_t(nodes));
      parallel::parallel_for(0, nodes, [&](std::int64_t k) {
        IVec i;
        std::int64_t r = k;
        for (int d = Dim - 1; d >= 0; --d) i[d] = int(r % nres[d]), r /= nres[d];
        node_phi[k] = distance(Vec(g.origin + g.dx * (i + g.offset).template cast<T>()), t);
      });
    }
    auto node = [&](const IVec& i) {
      std::int64_t k = i[0];
      for (int d = 1; d < Dim; ++d) k = k * nres[d] + i[d];
      return node_phi[std::size_t(k)];
    };
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t nf = g.num_faces(d);
      parallel::parallel_for(0, nf, [&](std::int64_t f) {
        const IVec i = g.face_coord(d, f);
        if (i[d] == 0 || i[d] == g.res[d]) {
          g.weight[d][f] = T(0);
          g.u_solid[d][f] = T(0);
          return;
        }
        if (colliders.empty()) {
          g.weight[d][f] = T(1);
          g.u_solid[d][f] = T(0);
          return;
        }
        T w;
        if constexpr (Dim == 2) {
          const int a = 1 - d;
          w = open_fraction(node(i), node(IVec(i + IVec::Unit(a))));
        } else {
          const int a = (d + 1) % 3, b = (d + 2) % 3;
          const T p00 = node(i), p10 = node(IVec(i + IVec::Unit(a))), p01 = node(IVec(i + IVec::Unit(b))),
                  p11 = node(IVec(i + IVec::Unit(a) + IVec::Unit(b)));
          const T pc = T(0.25) * (p00 + p10 + p01 + p11);
          w = T(0.25) * (open_fraction(p00, p10, pc) + open_fraction(p10, p11, pc) + open_fraction(p11, p01, pc) +
                         open_fraction(p01, p00, pc));
        }
        g.weight[d][f] = w;
        // The solid velocity enters the projection as (1 - w) u_solid and closed faces take it:
        // a fully open face never reads it.
        if (w >= T(1)) {
          g.u_solid[d][f] = T(0);
          return;
        }
        int which = 0;
        const Vec xf = g.face_position(d, i);
        if (colliders.size() > 1) distance(xf, t, &which);
        g.u_solid[d][f] = colliders[which].velocity_at(xf, t)[d];
      });
    }
  }

  /// Moves x out of every collider (to just outside the nearest surface) and into the domain box
  /// [lo, hi]; `margin` is how far inside the free side it lands.
  Vec push_out(Vec x, T t, const Vec& lo, const Vec& hi, T margin) const {
    for (int pass = 0; pass < 2 && !colliders.empty(); ++pass) {
      int which = 0;
      const T s = distance(x, t, &which);
      if (s >= T(0)) break;
      // Normal by central differences of the chosen collider's distance.
      const T h = margin;
      Vec n;
      for (int d = 0; d < Dim; ++d) {
        const Vec e = Vec::Unit(d) * h;
        n[d] = signed_distance(colliders[which], Vec(x + e), t) - signed_distance(colliders[which], Vec(x - e), t);
      }
      const T len = n.norm();
      if (!(len > T(0))) break;
      x += (margin - s) * (n / len);
    }
    return x.cwiseMax(lo).cwiseMin(hi);
  }
};

}  // namespace slurry::flip
