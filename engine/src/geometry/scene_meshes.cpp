#include "geometry/scene_meshes.h"

#include <cmath>
#include <cstdio>
#include <limits>
#include <random>

#include "slurry/engine/errors.h"
#include "slurry/engine/scene/scene_files.h"

namespace slurry::detail {

geometry::TriangleMesh place_scene_mesh(const Scene& scene, const std::string& file,
                                       const Eigen::Vector3d& scale,
                                       const Eigen::Vector3d& rotation,
                                       const Eigen::Vector3d& translation,
                                       const std::string& where) {
  const std::string what = scene.source + ": " + where + ".mesh (" + file + ")";
  geometry::TriangleMesh mesh = scene_triangle_mesh(scene, file, where);
  return geometry::place_closed_mesh(std::move(mesh), scale, geometry::euler_degrees(rotation),
                                     translation, what);
}

namespace {
/// The placed mesh of body `body`, refused if it leaves the domain.
geometry::TriangleMesh placed_body_mesh(const Scene& scene, std::size_t body, Eigen::Vector3d& lo,
                                        Eigen::Vector3d& hi) {
  const BodyParams& b = scene.bodies[body];
  const std::string where = "bodies[" + std::to_string(body) + "]";
  geometry::TriangleMesh mesh =
      place_scene_mesh(scene, b.mesh, b.scale, b.rotation, b.translation, where);
  mesh.bounds(lo, hi);
  for (int d = 0; d < 3; ++d)
    if (lo[d] < scene.domain.min[d] || hi[d] > scene.domain.max[d])
      throw SceneError(scene.source + ": " + where + ": the placed mesh spans [" +
                       std::to_string(lo[0]) + ", " + std::to_string(lo[1]) + ", " +
                       std::to_string(lo[2]) + "] to [" + std::to_string(hi[0]) + ", " +
                       std::to_string(hi[1]) + ", " + std::to_string(hi[2]) +
                       "], expected it inside the domain (check scale, rotation and translation)");
  // As for box bodies: a solid narrower than one particle spacing (a flat mesh, a plate thinner
  // than the spacing, a mesh scaled far down) seeds a single row or no volume at all.
  const double spacing = scene.domain.dx / std::cbrt(b.particles_per_cell);
  for (int d = 0; d < 3; ++d)
    if (!(hi[d] - lo[d] >= spacing)) {
      char across[32], need[32];
      std::snprintf(across, sizeof across, "%.12g", hi[d] - lo[d]);
      std::snprintf(need, sizeof need, "%.12g", spacing);
      throw SceneError(scene.source + ": " + where + ": the placed mesh is " + across + " m across along axis " +
                       std::to_string(d) + ", expected at least one particle spacing (dx / particles_per_cell^(1/3) = " +
                       need + " m; check scale)");
    }
  return mesh;
}
}  // namespace

void check_scene_meshes(const Scene& scene) {
  if (scene.solver.type == SolverType::FEM) return;  // FEM bodies are TetGen meshes
  for (std::size_t i = 0; i < scene.bodies.size(); ++i) {
    if (scene.bodies[i].shape != Shape::Mesh) continue;
    Eigen::Vector3d lo, hi;
    placed_body_mesh(scene, i, lo, hi);
  }
  for (std::size_t i = 0; i < scene.colliders.size(); ++i) {
    const ColliderParams& c = scene.colliders[i];
    if (c.shape == ColliderShape::Mesh)
      place_scene_mesh(scene, c.mesh, c.scale, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(),
                      "colliders[" + std::to_string(i) + "]");
  }
}

std::vector<Eigen::Vector3d> seed_mesh_body(const Scene& scene, std::size_t body,
                                            double& cell_volume) {
  const BodyParams& b = scene.bodies[body];
  const std::string where = "bodies[" + std::to_string(body) + "]";
  Eigen::Vector3d lo, hi;
  geometry::TriangleMesh mesh = placed_body_mesh(scene, body, lo, hi);
  const double h_target = scene.domain.dx / std::cbrt(b.particles_per_cell);
  Eigen::Vector3i n;
  Eigen::Vector3d h;
  double total_d = 1;
  for (int d = 0; d < 3; ++d) {
    n[d] = std::max(1, int(std::lround(std::min((hi[d] - lo[d]) / h_target, 2e9))));
    h[d] = (hi[d] - lo[d]) / n[d];
    total_d *= n[d];
  }
  if (total_d > 2e9)
    throw ResourceError(
        scene.source + ": " + where + ": the mesh's bounding box would seed " +
        std::to_string(std::int64_t(total_d)) +
        " lattice points (limit 2e9); expected a larger domain.dx or fewer particles_per_cell");
  cell_volume = h.prod();
  const geometry::MeshSdf solid(std::move(mesh), h_target, h_target, std::int64_t(1) << 22, false);
  std::mt19937_64 rng(b.seed);
  const auto unit = [&] { return double(rng() >> 11) * 0x1.0p-53; };  // as the box bodies draw
  std::vector<Eigen::Vector3d> out;
  const std::int64_t total = std::int64_t(total_d);
  for (std::int64_t k = 0; k < total; ++k) {
    std::int64_t r = k;
    Eigen::Vector3i i;
    for (int d = 2; d >= 0; --d) i[d] = int(r % n[d]), r /= n[d];
    Eigen::Vector3d x;
    for (int d = 0; d < 3; ++d)
      x[d] = lo[d] + (i[d] + (b.sampling == Sampling::Jittered ? unit() : 0.5)) * h[d];
    if (solid.inside(x)) out.push_back(x);
  }
  if (out.empty())
    throw SceneError(
        scene.source + ": " + where +
        ": the mesh holds no particle (expected a solid wider than the particle spacing " +
        std::to_string(h_target) + " m)");
  return out;
}

MeshColliderParts make_mesh_collider(const Scene& scene, std::size_t index) {
  const ColliderParams& c = scene.colliders[index];
  const std::string where = "colliders[" + std::to_string(index) + "]";
  geometry::TriangleMesh mesh = place_scene_mesh(scene, c.mesh, c.scale, Eigen::Vector3d::Zero(),
                                                Eigen::Vector3d::Zero(), where);
  // Half the grid spacing resolves the surface between grid nodes; the margin covers the widest
  // kernel's reach (two cells) around the solid and a band beyond it.
  const double dx = scene.domain.dx;
  MeshColliderParts parts;
  // A collider that never moves is asked for its distance inside the domain only: its field is
  // sampled there, so a ground mesh far larger than the domain keeps the resolution of a small
  // one (over its whole extent the grid's spacing would grow to fit the node budget).
  const bool moves = !c.keyframes.empty() || !c.velocity.isZero();
  geometry::MeshSdf::Box region;
  if (!moves) {
    const Eigen::Matrix3d R = geometry::euler_degrees(c.rotation);
    region.lo.setConstant(std::numeric_limits<double>::infinity());
    region.hi.setConstant(-std::numeric_limits<double>::infinity());
    for (int corner = 0; corner < 8; ++corner) {
      Eigen::Vector3d x;
      for (int d = 0; d < 3; ++d) x[d] = (corner >> d) & 1 ? scene.domain.max[d] : scene.domain.min[d];
      const Eigen::Vector3d body = R.transpose() * (x - c.translation);  // the domain in the collider's frame
      region.lo = region.lo.cwiseMin(body);
      region.hi = region.hi.cwiseMax(body);
    }
  }
  parts.sdf = std::make_shared<const geometry::MeshSdf>(std::move(mesh), 0.5 * dx, 4 * dx, std::int64_t(1) << 22, true,
                                                        moves ? nullptr : &region);
  parts.motion = std::make_shared<const geometry::RigidMotion>(collider_motion(c));
  return parts;
}

geometry::RigidMotion collider_motion(const ColliderParams& c) {
  std::vector<geometry::RigidMotion::Key> keys;
  for (const auto& k : c.keyframes)
    keys.push_back({k.time, k.translation, geometry::euler_degrees(k.rotation)});
  return geometry::RigidMotion(geometry::euler_degrees(c.rotation), c.translation, c.velocity, std::move(keys));
}

}  // namespace slurry::detail
