// Closed triangle meshes made in code for the mesh tests: boxes, icospheres, and OBJ files of
// them for scenes; and the message a call throws.
#pragma once
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <string>

#include "slurry/engine/errors.h"
#include "slurry/engine/geometry/shapes.h"
#include "slurry/engine/geometry/triangle_mesh.h"

namespace slurry::test {

/// The box [lo, hi] and the sphere of radius r (an icosahedron subdivided `levels` times) as
/// closed meshes (slurry/engine/geometry/shapes.h).
inline geometry::TriangleMesh box_mesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  return geometry::box_mesh(lo, hi);
}
inline geometry::TriangleMesh icosphere(double r, int levels) { return geometry::icosphere(r, levels); }

/// The message of the slurry::Error `f` throws, or "" if it throws none.
inline std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const slurry::Error& e) {
    return e.what();
  }
  return "";
}

inline void write_obj(const std::filesystem::path& path, const geometry::TriangleMesh& m) {
  std::ofstream out(path);
  out.precision(17);
  for (const auto& v : m.vertices) out << "v " << v[0] << ' ' << v[1] << ' ' << v[2] << '\n';
  for (const auto& t : m.triangles)
    out << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
}

}  // namespace slurry::test
