#pragma once
// The tests' own measure of a surface mesh, independent of the library's.
#include "slurry/io/surface.h"

namespace slurry_test {

/// Volume enclosed by a closed triangle mesh (divergence theorem): positive when the triangles
/// are counter-clockwise seen from outside.
inline double signed_volume(const slurry::io::TriangleMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles) {
    const auto& a = m.vertices[std::size_t(t[0])];
    const auto& b = m.vertices[std::size_t(t[1])];
    const auto& c = m.vertices[std::size_t(t[2])];
    v += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
          double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
          double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) /
         6;
  }
  return v;
}

}  // namespace slurry_test
