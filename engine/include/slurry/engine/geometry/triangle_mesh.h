#pragma once
/// \file triangle_mesh.h
/// Closed triangle meshes for mesh bodies (`"shape": "mesh"`) and mesh colliders: the scale /
/// rotation / translation of a scene's placement, and the check that a mesh encloses a volume.
/// The files are read by io::read_triangle_mesh (slurry/io/triangle_mesh_file.h).
///
/// A mesh encloses a volume when it is closed and manifold: every edge is shared by exactly two
/// triangles, which traverse it in opposite directions (consistent orientation). Anything else
/// (a hole, a T-junction, three faces on one edge, flipped neighbours) is refused with an IoError
/// naming the file and counting what is wrong, since the inside of such a mesh is not defined and
/// a fill would be silently wrong. A mesh wound clockwise as seen from outside (negative signed
/// volume) is reversed, so that normals point out of the solid.
#include <Eigen/Core>
#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace slurry::geometry {

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<std::array<int, 3>> triangles;
  /// The file it was read from, for messages (empty if built in code).
  std::string source;

  /// Lower and upper corners of the vertices' bounding box.
  void bounds(Eigen::Vector3d& lo, Eigen::Vector3d& hi) const;
  /// Enclosed volume by the divergence theorem, sum over triangles of a . (b x c) / 6 (positive
  /// for outward normals).
  double signed_volume() const;
};

/// What the closedness check found.
struct MeshTopology {
  std::size_t boundary_edges = 0;        ///< edges with one triangle (holes)
  std::size_t nonmanifold_edges = 0;     ///< edges with three or more triangles
  std::size_t inconsistent_edges = 0;    ///< edges two triangles traverse in the same direction
  std::size_t degenerate_triangles = 0;  ///< triangles with a repeated vertex index
  bool closed() const {
    return boundary_edges == 0 && nonmanifold_edges == 0 && inconsistent_edges == 0;
  }
};

/// Counts the edges that keep `mesh` from enclosing a volume.
MeshTopology check_topology(const TriangleMesh& mesh);

/// Rotation matrix of Euler angles in degrees, applied about x first, then y, then z
/// (R = Rz Ry Rx): the order of Blender's default "XYZ Euler" mode.
Eigen::Matrix3d euler_degrees(const Eigen::Vector3d& angles);

/// Places `mesh`: x -> R (scale .* x) + translation. Drops degenerate triangles, refuses (IoError
/// naming `what`, e.g. "scene.json: bodies[0].mesh (bunny.obj)") a mesh that does not enclose a
/// volume, and reverses one wound inside out.
TriangleMesh place_closed_mesh(TriangleMesh mesh, const Eigen::Vector3d& scale,
                               const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                               const std::string& what);

}  // namespace slurry::geometry
