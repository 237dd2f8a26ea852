#pragma once
/// \file scene_file.h
/// Scene files (JSON; every key is a field of scene.h, docs/scene-reference.md) and the mesh
/// files a scene names.
///
/// load_scene and parse_scene type-check every key, refuse unknown ones, then validate the scene
/// (Scene::validate). The JSON is parsed with limits checked while parsing: nesting at most
/// kMaxSceneDepth, no duplicate keys, numbers in the range of double, a file of at most
/// kMaxSceneBytes. Errors are SceneError (content) or IoError (the file), naming the source, the
/// JSON path and what was expected.
#include <filesystem>
#include <string>
#include <string_view>

#include "slurry/engine/scene/scene.h"

namespace slurry {

/// Reads, parses and validates a scene file. Throws SceneError (invalid content) or IoError.
Scene load_scene(const std::filesystem::path& path);
/// Parses and validates scene JSON text; `source` names it in messages.
Scene parse_scene(std::string_view json_text, const std::string& source);

namespace io {

/// Reads the mesh files `scene` names into scene.files (scene_files.h): the OBJ or PLY triangle
/// meshes of mesh bodies and mesh colliders, the TetGen meshes of FEM bodies, each file once, as
/// written (placement applies later). Paths are relative to the scene file unless absolute.
/// Throws IoError naming the scene, the JSON path (e.g. "bodies[0].mesh") and the file.
void read_scene_files(Scene& scene);

/// Whether the scene names a mesh file at all.
bool names_files(const Scene& scene);

}  // namespace io
}  // namespace slurry
