#include "geometry/collider_surfaces.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <utility>

#include "geometry/scene_meshes.h"
#include "slurry/engine/geometry/shapes.h"

namespace slurry::detail {

namespace {

using geometry::TriangleMesh;

/// The polygon where the plane through `point` with normal `n` cuts the box [lo, hi], fanned into
/// triangles whose normal is n (out of the half-space's solid); empty if the plane misses the box.
TriangleMesh plane_in_box(const Eigen::Vector3d& point, const Eigen::Vector3d& normal, const Eigen::Vector3d& lo,
                          const Eigen::Vector3d& hi) {
  const Eigen::Vector3d n = normal.normalized();
  const double scale = (hi - lo).norm();
  std::vector<Eigen::Vector3d> cut;
  for (int c = 0; c < 8; ++c)
    for (int d = 0; d < 3; ++d) {
      if (c & (1 << d)) continue;  // each of the 12 edges once, from its lower corner along axis d
      Eigen::Vector3d a, b;
      for (int e = 0; e < 3; ++e) a[e] = c & (1 << e) ? hi[e] : lo[e];
      b = a;
      b[d] = hi[d];
      const double sa = (a - point).dot(n), sb = (b - point).dot(n);
      if ((sa < 0) == (sb < 0) && sa != 0 && sb != 0) continue;
      const Eigen::Vector3d x = sa == sb ? a : Eigen::Vector3d(a + (b - a) * (sa / (sa - sb)));
      bool seen = false;
      for (const auto& y : cut) seen = seen || (y - x).norm() <= 1e-9 * scale;
      if (!seen) cut.push_back(x);
    }
  TriangleMesh m;
  if (cut.size() < 3) return m;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const auto& x : cut) centre += x;
  centre /= double(cut.size());
  // Sorted by angle about n, counter-clockwise seen from the side n points to.
  const Eigen::Vector3d u = n.unitOrthogonal(), w = n.cross(u);
  std::sort(cut.begin(), cut.end(), [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    return std::atan2((a - centre).dot(w), (a - centre).dot(u)) < std::atan2((b - centre).dot(w), (b - centre).dot(u));
  });
  m.vertices = cut;
  for (int i = 1; i + 1 < int(cut.size()); ++i) m.triangles.push_back({0, i, i + 1});
  return m;
}

}  // namespace

ColliderSurfaces::ColliderSurfaces(const Scene& scene) {
  if (scene.solver.dimension != 3) return;
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity();
  for (std::size_t i = 0; i < scene.colliders.size(); ++i) {
    const ColliderParams& c = scene.colliders[i];
    TriangleMesh mesh;
    switch (c.shape) {
      case ColliderShape::HalfSpace: mesh = plane_in_box(c.point, c.normal, scene.domain.min, scene.domain.max); break;
      case ColliderShape::Box: mesh = geometry::box_mesh(c.min, c.max); break;
      case ColliderShape::Sphere:
        mesh = geometry::icosphere(c.radius, 3);
        for (auto& v : mesh.vertices) v += c.center;
        break;
      case ColliderShape::Mesh:
        mesh = place_scene_mesh(scene, c.mesh, c.scale, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(),
                                "colliders[" + std::to_string(i) + "]");
        break;
    }
    if (c.shape == ColliderShape::Mesh) {
      parts_.push_back({int(i), std::move(mesh), collider_motion(c)});
    } else {
      // An analytic collider translates at its velocity; its vertices are already in the world.
      parts_.push_back({int(i), std::move(mesh), geometry::RigidMotion(I, Eigen::Vector3d::Zero(), c.velocity)});
    }
  }
}

Frame ColliderSurfaces::at(double t) const {
  Frame out;
  out.comments.push_back("slurry colliders t=" + std::to_string(t));
  out.tables.resize(2);  // both made before either is referenced
  Table& v = out.tables[0];
  v.name = "vertex";
  Table& f = out.tables[1];
  f.name = "face";
  std::vector<float> c[6];
  std::vector<std::int32_t> which;
  ListColumn faces{"vertex_indices", {}};
  for (const Part& part : parts_) {
    const geometry::Pose pose = part.motion.at(t);
    const auto base = std::int32_t(c[0].size());
    for (const Eigen::Vector3d& y : part.mesh.vertices) {
      const Eigen::Vector3d x = pose.to_world(y), u = pose.velocity_at(x);
      for (int d = 0; d < 3; ++d) c[d].push_back(float(x[d])), c[3 + d].push_back(float(u[d]));
    }
    for (const auto& tri : part.mesh.triangles) {
      faces.data.push_back({base + tri[0], base + tri[1], base + tri[2]});
      which.push_back(part.index);
    }
  }
  v.count = c[0].size();
  f.count = which.size();
  const char* names[6] = {"x", "y", "z", "vx", "vy", "vz"};
  for (int k = 0; k < 6; ++k) v.columns.push_back({names[k], std::move(c[k])});
  f.lists.push_back(std::move(faces));
  f.columns.push_back({"collider", std::move(which)});
  return out;
}

}  // namespace slurry::detail
