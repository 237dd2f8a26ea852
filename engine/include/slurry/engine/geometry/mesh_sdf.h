#pragma once
/// \file mesh_sdf.h
/// Signed distance to a closed triangle mesh, sampled on a regular grid, with the exact queries
/// colliders and seeding need beside it.
///
/// - Distance: exact point-triangle distances (closest point by Voronoi regions of the triangle,
///   Ericson, "Real-Time Collision Detection", 2005, sec. 5.1.5) in a band of `band` cells around
///   every triangle, then propagated to the rest of the grid by fast sweeping of the nearest
///   triangle (each node tries its neighbours' nearest triangles, eight sweep orders, as in the
///   closest-point sweeping of Zhao 2005 and Bridson's level-set notes): every node holds the
///   exact distance to a triangle that is nearest or nearly so.
/// - Sign: the winding number of ray crossings (entries minus exits, from the outward normals)
///   along the grid rows of all three axes, majority vote of "not zero". Overlapping closed parts
///   are filled once, as their union; a cavity bounded by an inward-facing surface stays empty. A
///   row meets a triangle where its projection falls inside the triangle's projection, with a
///   top-left rule on edges and vertices whose edge functions are computed the same way for
///   both triangles of an edge, so a ray through a shared edge or vertex of a closed mesh is
///   counted once.
/// - phi(y): trilinear interpolation, negative inside; outside the grid, phi at the nearest grid
///   point plus the distance to it (still positive, a lower bound near the grid).
/// - first_entry(y0, y1): the exact first crossing of a segment into the solid (Moller and
///   Trumbore 1997 ray-triangle test on the triangles binned near the segment), so that a
///   particle cannot pass a wall thinner than the grid spacing.
/// - inside_along_row: exact inside/outside for a row of points (body seeding).
#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "slurry/engine/geometry/triangle_mesh.h"

namespace slurry::geometry {

class MeshSdf {
 public:
  MeshSdf() = default;
  /// A box (lower and upper corners) in the mesh's frame.
  struct Box {
    Eigen::Vector3d lo, hi;
  };
  /// Samples the signed distance of `mesh` (closed, outward normals) with spacing h over its
  /// bounding box grown by `margin` on every side, cut to `region` grown by `margin` if given
  /// (the only place phi and normal are asked for: a static collider far larger than the domain
  /// is sampled over the domain only, at full resolution); h grows if the grid would exceed
  /// max_nodes. Without `distances` only the exact queries (first_entry, inside) are prepared.
  MeshSdf(TriangleMesh mesh, double h, double margin,
          std::int64_t max_nodes = std::int64_t(1) << 22, bool distances = true, const Box* region = nullptr);

  double phi(const Eigen::Vector3d& y) const;
  /// Unit outward normal: the normalized gradient of phi by central differences (h / 2); the
  /// nearest triangle's normal where that vanishes.
  Eigen::Vector3d normal(const Eigen::Vector3d& y) const;
  /// The smallest s in [0, 1] at which y0 + s (y1 - y0) crosses a triangle from outside to inside
  /// (against its outward normal), and that triangle's unit normal; false if none.
  bool first_entry(const Eigen::Vector3d& y0, const Eigen::Vector3d& y1, double& s,
                   Eigen::Vector3d& n) const;
  /// inside[i] = whether point (xs[i], b, c) lies inside the solid, along the row parallel to
  /// `axis` through the other two coordinates (b, c) in cyclic order (axis 0: y = b, z = c).
  void inside_along_row(int axis, double b, double c, const std::vector<double>& xs,
                        std::vector<char>& inside) const;
  /// Exact inside test of one point (the winding number of the crossings along its z row is not
  /// zero; consecutive points of one row reuse the row's crossings).
  bool inside(const Eigen::Vector3d& y) const;

  const TriangleMesh& mesh() const { return mesh_; }
  double spacing() const { return h_; }
  const Eigen::Vector3d& lower() const { return lo_; }
  Eigen::Vector3d upper() const { return lo_ + h_ * (n_.cast<double>() - Eigen::Vector3d::Ones()); }
  std::size_t bytes() const;

  /// A row's crossing of the surface: where, and +1 where the row leaves the solid (the
  /// triangle's outward normal along +axis), -1 where it enters.
  struct Crossing {
    double at;
    int exit;
  };

 private:
  std::int64_t index(int i, int j, int k) const {
    return (std::int64_t(k) * n_[1] + j) * n_[0] + i;
  }
  /// The crossings along the row parallel to `axis` through (b, c), sorted by position.
  void row_crossings(int axis, double b, double c, std::vector<Crossing>& out) const;
  void build_triangle_bins();

  TriangleMesh mesh_;
  std::uint64_t serial_ = 0;  ///< unique per object: keys inside()'s per-thread row cache
  std::vector<Eigen::Vector3d> normals_;  ///< unit outward normal per triangle
  double h_ = 0;
  Eigen::Vector3d lo_ = Eigen::Vector3d::Zero();
  Eigen::Vector3i n_ = Eigen::Vector3i::Zero();
  std::vector<float> phi_;
  // Triangles binned on a coarse grid (cell bin_h_) for segment and row queries.
  double bin_h_ = 0;
  Eigen::Vector3d bin_lo_ = Eigen::Vector3d::Zero();
  Eigen::Vector3i bin_n_ = Eigen::Vector3i::Zero();
  std::vector<int> bin_start_, bin_items_;
};

}  // namespace slurry::geometry
