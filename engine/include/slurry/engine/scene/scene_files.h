#pragma once
/// \file scene_files.h
/// The files a scene names, read into memory: the triangle meshes of mesh bodies and mesh
/// colliders, and the tetrahedral meshes of FEM bodies. The solvers take their geometry from
/// here (Scene::files) and never open a file themselves; io::read_scene_files reads them
/// (slurry/io/scene_file.h), and make_simulation and run_scene do so for a scene that has not.
#include <map>
#include <string>

#include "slurry/engine/fem/mesh.h"
#include "slurry/engine/geometry/triangle_mesh.h"
#include "slurry/engine/scene/scene.h"

namespace slurry {

struct SceneFiles {
  /// Keyed by the file name as the scene writes it (BodyParams::mesh, ColliderParams::mesh),
  /// as read: not yet placed (scale, rotation and translation apply later).
  std::map<std::string, geometry::TriangleMesh> triangle_meshes;
  /// FEM bodies' TetGen meshes, in the scene's dimension.
  std::map<std::string, fem::Mesh<2>> tet_meshes_2;
  std::map<std::string, fem::Mesh<3>> tet_meshes_3;
};

/// The triangle mesh `file` of `scene` as read. Throws SceneError naming the scene, `where`
/// (e.g. "bodies[0]") and the file if the scene's files have not been read.
const geometry::TriangleMesh& scene_triangle_mesh(const Scene& scene, const std::string& file,
                                                  const std::string& where);

/// The FEM body mesh `file` of `scene` in dimension Dim, as read; throws like scene_triangle_mesh.
template <int Dim>
const fem::Mesh<Dim>& scene_tet_mesh(const Scene& scene, const std::string& file, const std::string& where);

}  // namespace slurry
