// Looking up a scene's meshes as read (scene_files.h).
#include "slurry/engine/scene/scene_files.h"

#include "slurry/engine/errors.h"

namespace slurry {
namespace {

template <class Map>
const typename Map::mapped_type& find_read(const Scene& scene, const Map* map, const std::string& file,
                                           const std::string& where) {
  if (map) {
    const auto it = map->find(file);
    if (it != map->end()) return it->second;
  }
  throw SceneError(scene.source + ": " + where + ".mesh (" + file +
                   "): the scene's mesh files have not been read (expected io::read_scene_files(scene), "
                   "or make_simulation, before a solver is built)");
}

}  // namespace

const geometry::TriangleMesh& scene_triangle_mesh(const Scene& scene, const std::string& file,
                                                  const std::string& where) {
  return find_read(scene, scene.files ? &scene.files->triangle_meshes : nullptr, file, where);
}

template <>
const fem::Mesh<2>& scene_tet_mesh<2>(const Scene& scene, const std::string& file, const std::string& where) {
  return find_read(scene, scene.files ? &scene.files->tet_meshes_2 : nullptr, file, where);
}

template <>
const fem::Mesh<3>& scene_tet_mesh<3>(const Scene& scene, const std::string& file, const std::string& where) {
  return find_read(scene, scene.files ? &scene.files->tet_meshes_3 : nullptr, file, where);
}

}  // namespace slurry
