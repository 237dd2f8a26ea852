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
#include "slurry/engine/geometry/triangle_mesh.h"

namespace slurry::test {

/// The box [lo, hi] as 12 triangles wound counter-clockwise seen from outside.
inline geometry::TriangleMesh box_mesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  geometry::TriangleMesh m;
  for (int k = 0; k < 8; ++k)
    m.vertices.emplace_back(k & 1 ? hi[0] : lo[0], k & 2 ? hi[1] : lo[1], k & 4 ? hi[2] : lo[2]);
  // Each face as a quad (a, b, c, d) counter-clockwise from outside, split along a-c.
  const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
  for (const auto& q : quads) {
    m.triangles.push_back({q[0], q[1], q[2]});
    m.triangles.push_back({q[0], q[2], q[3]});
  }
  return m;
}

/// A sphere of radius r: an icosahedron subdivided `levels` times, vertices on the sphere.
inline geometry::TriangleMesh icosphere(double r, int levels) {
  const double g = (1 + std::sqrt(5.0)) / 2;
  geometry::TriangleMesh m;
  m.vertices = {{-1, g, 0},  {1, g, 0},  {-1, -g, 0}, {1, -g, 0}, {0, -1, g},  {0, 1, g},
                {0, -1, -g}, {0, 1, -g}, {g, 0, -1},  {g, 0, 1},  {-g, 0, -1}, {-g, 0, 1}};
  m.triangles = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                 {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                 {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                 {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& v : m.vertices) v.normalize();
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<int, int>, int> mid;
    const auto midpoint = [&](int a, int b) {
      const auto key = std::make_pair(std::min(a, b), std::max(a, b));
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      m.vertices.push_back((m.vertices[std::size_t(a)] + m.vertices[std::size_t(b)]).normalized());
      return mid[key] = int(m.vertices.size()) - 1;
    };
    std::vector<std::array<int, 3>> next;
    for (const auto& t : m.triangles) {
      const int ab = midpoint(t[0], t[1]), bc = midpoint(t[1], t[2]), ca = midpoint(t[2], t[0]);
      next.push_back({t[0], ab, ca});
      next.push_back({t[1], bc, ab});
      next.push_back({t[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    m.triangles = next;
  }
  for (auto& v : m.vertices) v *= r;
  return m;
}

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
