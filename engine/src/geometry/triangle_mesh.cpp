#include "slurry/engine/geometry/triangle_mesh.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>
#include <unordered_map>

#include "slurry/engine/errors.h"

namespace slurry::geometry {

namespace fs = std::filesystem;

void TriangleMesh::bounds(Eigen::Vector3d& lo, Eigen::Vector3d& hi) const {
  lo.setConstant(std::numeric_limits<double>::infinity());
  hi = -lo;
  for (const auto& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
}

double TriangleMesh::signed_volume() const {
  double v = 0;
  for (const auto& t : triangles) v += vertices[t[0]].dot(vertices[t[1]].cross(vertices[t[2]]));
  return v / 6;
}

MeshTopology check_topology(const TriangleMesh& mesh) {
  MeshTopology r;
  // Each undirected edge: how many triangles use it, and the sum of +1 (a < b) / -1 (a > b)
  // over its uses; a consistently oriented closed mesh has count 2 and sum 0 on every edge.
  struct Use {
    int count = 0, direction = 0;
  };
  std::unordered_map<std::uint64_t, Use> edges;
  edges.reserve(mesh.triangles.size() * 2);
  for (const auto& t : mesh.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      ++r.degenerate_triangles;
      continue;
    }
    for (int e = 0; e < 3; ++e) {
      const int a = t[e], b = t[(e + 1) % 3];
      const std::uint64_t key =
          (std::uint64_t(std::uint32_t(std::min(a, b))) << 32) | std::uint32_t(std::max(a, b));
      auto& u = edges[key];
      ++u.count;
      u.direction += a < b ? 1 : -1;
    }
  }
  for (const auto& [key, u] : edges) {
    if (u.count == 1)
      ++r.boundary_edges;
    else if (u.count > 2)
      ++r.nonmanifold_edges;
    else if (u.direction != 0)
      ++r.inconsistent_edges;
  }
  return r;
}

Eigen::Matrix3d euler_degrees(const Eigen::Vector3d& angles) {
  const double k = 3.14159265358979323846 / 180;
  const auto axis_rotation = [](int axis, double a) {
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    const int i = (axis + 1) % 3, j = (axis + 2) % 3;
    r(i, i) = std::cos(a);
    r(i, j) = -std::sin(a);
    r(j, i) = std::sin(a);
    r(j, j) = std::cos(a);
    return r;
  };
  return axis_rotation(2, k * angles[2]) * axis_rotation(1, k * angles[1]) *
         axis_rotation(0, k * angles[0]);
}

TriangleMesh place_closed_mesh(TriangleMesh mesh, const Eigen::Vector3d& scale,
                               const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                               const std::string& what) {
  for (auto& v : mesh.vertices) v = rotation * scale.cwiseProduct(v) + translation;
  // A scale with a negative component mirrors the mesh and so turns it inside out: the signed
  // volume below catches that too.
  auto& tris = mesh.triangles;
  tris.erase(
      std::remove_if(tris.begin(), tris.end(),
                     [](const auto& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }),
      tris.end());
  const MeshTopology topo = check_topology(mesh);
  if (!topo.closed()) {
    std::ostringstream s;
    s << what
      << ": the mesh does not enclose a volume (expected a closed, manifold, consistently oriented "
         "triangle mesh): ";
    const char* sep = "";
    if (topo.boundary_edges)
      s << sep << topo.boundary_edges << " edges on a hole (one triangle)", sep = ", ";
    if (topo.nonmanifold_edges)
      s << sep << topo.nonmanifold_edges << " edges shared by three or more triangles", sep = ", ";
    if (topo.inconsistent_edges)
      s << sep << topo.inconsistent_edges << " edges where neighbours are wound in opposite senses";
    s << "; close it (e.g. Blender's \"Fill Holes\" and \"Recalculate Outside\") or use a box, "
         "sphere or cylinder";
    throw IoError(s.str());
  }
  const double volume = mesh.signed_volume();
  if (!(std::abs(volume) > 0))
    throw IoError(what + ": the mesh encloses no volume (expected a solid)");
  if (volume < 0)
    for (auto& t : tris) std::swap(t[1], t[2]);
  return mesh;
}

}  // namespace slurry::geometry
