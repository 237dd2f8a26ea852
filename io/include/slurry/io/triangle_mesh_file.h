#pragma once
/// \file triangle_mesh_file.h
/// Reading the triangle meshes of mesh bodies and mesh colliders from Wavefront OBJ and PLY files.
#include <filesystem>

#include "slurry/engine/geometry/triangle_mesh.h"

namespace slurry::io {

/// Reads a triangle mesh: Wavefront OBJ (`v x y z` and `f i j k ...` lines, indices 1-based or
/// negative, `i/t/n` forms; polygons are fanned into triangles) or PLY (element `vertex` with
/// x, y, z and element `face` with a list `vertex_indices` or `vertex_index`), chosen by the
/// extension. Throws IoError naming the file and the line or element at fault: unreadable file,
/// unknown extension, malformed numbers, indices out of range, no triangles. Text quoted from the
/// file has its control and non-ASCII bytes escaped as \xNN and is cut at 80 characters.
geometry::TriangleMesh read_triangle_mesh(const std::filesystem::path& path);

}  // namespace slurry::io
