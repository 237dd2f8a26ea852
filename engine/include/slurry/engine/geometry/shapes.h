#pragma once
/// \file shapes.h
/// Closed triangle meshes of simple solids, wound counter-clockwise seen from outside: the
/// surfaces the run writes for analytic colliders (geometry/collider_surfaces.h), and test input.
#include <Eigen/Core>

#include "slurry/engine/geometry/triangle_mesh.h"

namespace slurry::geometry {

/// The axis-aligned box [lo, hi]: 8 corners (corner k at hi along axis d where bit d of k is
/// set), each face two triangles.
TriangleMesh box_mesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi);

/// The sphere of `radius` about the origin: a regular icosahedron subdivided `levels` times (each
/// triangle into four), every vertex on the sphere; 10 * 4^levels + 2 vertices, 20 * 4^levels
/// triangles, inscribed (at 3 levels its volume is 0.86% short of the ball's and its triangles
/// dip about 0.45% of the radius inside the sphere).
TriangleMesh icosphere(double radius, int levels);

}  // namespace slurry::geometry
