// The surfaces of a scene's colliders at any time, for the effects pipeline: every collider as
// triangles in world coordinates, with the velocity of the collider's material at each vertex
// (for motion blur), so that a shot can be assembled around the simulated material. Internal to
// the engine; the run loop writes them (colliders_NNNN.ply / .obj, docs/pipeline-outputs.md).
#pragma once
#include <memory>
#include <vector>

#include "slurry/engine/frame.h"
#include "slurry/engine/geometry/rigid_motion.h"
#include "slurry/engine/geometry/triangle_mesh.h"
#include "slurry/engine/scene/scene.h"

namespace slurry::detail {

class ColliderSurfaces {
 public:
  /// The colliders of 3D scene `scene` (mesh files read into Scene::files). Each is tessellated
  /// once in its own frame:
  /// - half_space: the convex polygon where its plane cuts the domain box (nothing if it misses),
  ///   facing out of the solid;
  /// - box: its 6 faces, 12 triangles;
  /// - sphere: geometry::icosphere at 3 levels (642 vertices, 1280 triangles, its triangles
  ///   about 0.45% of the radius inside the sphere at most);
  /// - mesh: the mesh file with the collider's scale, as the solver places it.
  explicit ColliderSurfaces(const Scene& scene);

  /// Whether there is anything to write (a 3D scene with colliders).
  bool empty() const { return parts_.empty(); }

  /// The surfaces at time t as one frame: table "vertex" (x, y, z, vx, vy, vz as float) and table
  /// "face" (list vertex_indices, outward winding; column "collider", the index in
  /// scene.colliders). Analytic colliders move by velocity * t; a mesh collider by its keyframes
  /// and velocity (geometry/rigid_motion.h).
  Frame at(double t) const;

 private:
  struct Part {
    int index = 0;                  ///< in scene.colliders
    geometry::TriangleMesh mesh;    ///< in the collider's frame
    geometry::RigidMotion motion;   ///< its frame's pose at any time
  };
  std::vector<Part> parts_;
};

}  // namespace slurry::detail
