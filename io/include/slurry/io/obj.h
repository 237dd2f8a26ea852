#pragma once
/// \file obj.h
/// Writing triangle meshes as Wavefront OBJ files: `v x y z` lines, then `f i j k` lines with
/// 1-based indices, as every OBJ reader takes them (the format as Wavefront's "Advanced
/// Visualizer" manual, appendix B1, describes it). Coordinates are printed with %.9g, enough to
/// read back a float's bits. The mesh is a Frame (slurry/engine/frame.h): table "vertex" with
/// columns x, y, z and table "face" with the list vertex_indices, as the PLY writer takes it.
#include <filesystem>
#include <string>

#include "slurry/engine/frame.h"

namespace slurry::io {

/// Writes `mesh` to `path` atomically (a temporary file renamed into place), starting with the
/// comment line "# <comment>". With `object_column` (an integer column of "face"), every run of
/// consecutive faces with one value v starts an object "o <object_prefix><v>", which Blender's
/// and Houdini's importers make separate objects. Throws IoError naming the file: missing
/// tables or columns, an index out of range, a face that is not a triangle, a failed write.
void write_obj(const std::filesystem::path& path, const Frame& mesh, const std::string& comment,
               const std::string& object_column = "", const std::string& object_prefix = "");

}  // namespace slurry::io
