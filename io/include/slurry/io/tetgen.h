#pragma once
/// \file tetgen.h
/// Reading TetGen meshes (Si, "TetGen, a Delaunay-based quality tetrahedral mesh generator",
/// ACM TOMS 41(2), 2015; file formats as in the TetGen user manual), and writing them.
///
///   .node   first line: <# of points> <dimension (3, or 2)> <# of attributes> <boundary markers (0 or 1)>
///           then one line per point: <index> <x> <y> [<z>] [attributes] [boundary marker]
///   .ele    first line: <# of elements> <vertices per element (4 in 3D, 3 in 2D)> <# of attributes>
///           then one line per element: <index> <v0> <v1> ... [attributes]
///
/// Everything after `#` on a line is a comment; blank lines are skipped. Indices are 0- or
/// 1-based, decided by the first point's index (as TetGen does); the following points must be
/// numbered consecutively. Attributes and boundary markers are read and ignored. 2D files (as
/// written by Shewchuk's Triangle, the same format with triangles in the .ele) give a Mesh<2>.
/// Only linear elements are read (10-node tetrahedra and 6-node triangles are refused). The
/// elements are oriented and checked by fem::orient_mesh (slurry/engine/fem/mesh.h).
///
/// Every error is an IoError naming the file, the line, the field and what was expected:
///   cube.ele:7: element 5, vertex 3: expected a point index in [1, 8], got 9
#include <filesystem>
#include <utility>

#include "slurry/engine/fem/mesh.h"

namespace slurry::io {
using fem::Mesh;

/// The .node and .ele files of a mesh path: `a/b.node`, `a/b.ele` and the stem `a/b` all give
/// {a/b.node, a/b.ele}.
std::pair<std::filesystem::path, std::filesystem::path> tetgen_files(const std::filesystem::path& path);

/// The dimension (2 or 3) declared by a .node file's first line. Throws IoError.
int tetgen_dimension(const std::filesystem::path& path);

/// Reads `path` (see tetgen_files) into a mesh. Throws IoError (also for a file whose
/// dimension is not Dim, and for degenerate or inconsistently oriented elements).
template <int Dim>
Mesh<Dim> read_tetgen(const std::filesystem::path& path);

/// Writes `mesh` as <stem>.node and <stem>.ele, 1-based, no attributes or markers. Throws IoError.
template <int Dim>
void write_tetgen(const std::filesystem::path& stem, const Mesh<Dim>& mesh);

extern template Mesh<2> read_tetgen<2>(const std::filesystem::path&);
extern template Mesh<3> read_tetgen<3>(const std::filesystem::path&);
extern template void write_tetgen<2>(const std::filesystem::path&, const Mesh<2>&);
extern template void write_tetgen<3>(const std::filesystem::path&, const Mesh<3>&);

}  // namespace slurry::io
