// Mesh bodies and mesh colliders of a scene: placing the scene's triangle meshes (as read into
// Scene::files), filling a mesh body with particles and building the colliders. Internal to the
// engine.
#pragma once
#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "slurry/engine/geometry/colliders.h"
#include "slurry/engine/geometry/mesh_sdf.h"
#include "slurry/engine/geometry/rigid_motion.h"
#include "slurry/engine/scene/scene.h"

namespace slurry::detail {

/// The scene's mesh `file` (as read into Scene::files), placed; errors name the scene file, the
/// JSON path `where` (e.g. "bodies[0]") and the mesh file.
geometry::TriangleMesh place_scene_mesh(const Scene& scene, const std::string& file,
                                       const Eigen::Vector3d& scale,
                                       const Eigen::Vector3d& rotation,
                                       const Eigen::Vector3d& translation,
                                       const std::string& where);

/// The lattice points (spacing dx / ppc^(1/3) over the mesh's bounding box, regular or jittered
/// as the body asks, in the order box bodies are seeded) inside mesh body `body`, and the volume
/// of one lattice cell. Throws SceneError if the mesh leaves the domain or holds no point, and
/// ResourceError above 2e9 lattice points.
std::vector<Eigen::Vector3d> seed_mesh_body(const Scene& scene, std::size_t body,
                                            double& cell_volume);

/// Places every triangle mesh the scene names (mesh bodies and mesh colliders, read into
/// Scene::files) and checks that it encloses a volume and, for a body, lies inside the domain:
/// what `slurry validate` checks after reading them.
void check_scene_meshes(const Scene& scene);

/// The mesh collider `index` of the scene in its own frame (scale applied) and its motion.
struct MeshColliderParts {
  std::shared_ptr<const geometry::MeshSdf> sdf;
  std::shared_ptr<const geometry::RigidMotion> motion;
};
MeshColliderParts make_mesh_collider(const Scene& scene, std::size_t index);

/// The motion of a mesh collider's frame: rotation and translation, or its keyframes, and its
/// velocity.
geometry::RigidMotion collider_motion(const ColliderParams& c);

/// Every collider of the scene, mesh colliders with their distance fields.
template <class T, int Dim>
std::vector<Collider<T, Dim>> make_colliders(const Scene& scene) {
  std::vector<Collider<T, Dim>> out;
  for (std::size_t i = 0; i < scene.colliders.size(); ++i) {
    const auto& c = scene.colliders[i];
    if (c.shape == ColliderShape::Mesh) {
      auto parts = make_mesh_collider(scene, i);
      out.emplace_back(c, std::move(parts.sdf), std::move(parts.motion));
    } else {
      out.emplace_back(c);
    }
  }
  return out;
}

}  // namespace slurry::detail
