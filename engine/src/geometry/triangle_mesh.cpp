#include "slurry/engine/geometry/triangle_mesh.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>
#include <unordered_map>

#include "../input_file.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/ply.h"

namespace slurry::geometry {

namespace fs = std::filesystem;

void TriangleMesh::bounds(Eigen::Vector3d& lo, Eigen::Vector3d& hi) const {
  lo.setConstant(std::numeric_limits<double>::infinity());
  hi = -lo;
  for (const auto& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
}

double TriangleMesh::signed_volume() const {
  double v = 0;
  for (const auto& t : triangles) v += vertices[t[0]].dot(vertices[t[1]].cross(vertices[t[2]]));
  return v / 6;
}

MeshTopology check_topology(const TriangleMesh& mesh) {
  MeshTopology r;
  // Each undirected edge: how many triangles use it, and the sum of +1 (a < b) / -1 (a > b)
  // over its uses; a consistently oriented closed mesh has count 2 and sum 0 on every edge.
  struct Use {
    int count = 0, direction = 0;
  };
  std::unordered_map<std::uint64_t, Use> edges;
  edges.reserve(mesh.triangles.size() * 2);
  for (const auto& t : mesh.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      ++r.degenerate_triangles;
      continue;
    }
    for (int e = 0; e < 3; ++e) {
      const int a = t[e], b = t[(e + 1) % 3];
      const std::uint64_t key =
          (std::uint64_t(std::uint32_t(std::min(a, b))) << 32) | std::uint32_t(std::max(a, b));
      auto& u = edges[key];
      ++u.count;
      u.direction += a < b ? 1 : -1;
    }
  }
  for (const auto& [key, u] : edges) {
    if (u.count == 1)
      ++r.boundary_edges;
    else if (u.count > 2)
      ++r.nonmanifold_edges;
    else if (u.direction != 0)
      ++r.inconsistent_edges;
  }
  return r;
}

namespace {

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw IoError(path.string() + ": " + what);
}

/// Text from the file for a message: control and non-ASCII bytes as \xNN (terminal escapes are
/// not replayed on the user's screen), and at most 80 characters.
std::string safe_text(const std::string& text) {
  std::string out;
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (out.size() >= 80) return out + "...(" + std::to_string(text.size()) + " bytes in all)";
    const auto c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += char(c);
    } else {
      char hex[8];
      std::snprintf(hex, sizeof hex, "\\x%02x", c);
      out += hex;
    }
  }
  return out;
}

TriangleMesh read_obj(const fs::path& path) {
  std::ifstream in(path);
  if (!in) fail(path, "cannot be opened (expected a readable OBJ file)");
  TriangleMesh m;
  std::string line;
  long lineno = 0;
  std::vector<int> face;
  while (std::getline(in, line)) {
    ++lineno;
    const auto where = [&] { return path.string() + ":" + std::to_string(lineno); };
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag) || tag[0] == '#') continue;
    if (tag == "v") {
      Eigen::Vector3d v;
      if (!(ls >> v[0] >> v[1] >> v[2]) || !v.allFinite())
        throw IoError(where() + ": expected a vertex \"v x y z\" of three finite numbers, got \"" +
                      safe_text(line) + "\"");
      m.vertices.push_back(v);
    } else if (tag == "f") {
      face.clear();
      std::string item;
      while (ls >> item) {
        // "i", "i/t", "i//n", "i/t/n": the vertex index comes first.
        const std::string head = item.substr(0, item.find('/'));
        long idx = 0;
        std::size_t used = 0;
        try {
          idx = std::stol(head, &used);
        } catch (const std::exception&) {
          used = 0;
        }
        if (used != head.size() || head.empty())
          throw IoError(where() + ": expected a vertex index in the face, got \"" + safe_text(item) + "\"");
        const long n = long(m.vertices.size());
        const long zero_based = idx > 0 ? idx - 1 : n + idx;
        if (idx == 0 || zero_based < 0 || zero_based >= n)
          throw IoError(where() + ": vertex index " + std::to_string(idx) +
                        " out of range (expected 1.." + std::to_string(n) + " or -1..-" +
                        std::to_string(n) + " for the vertices read so far)");
        face.push_back(int(zero_based));
      }
      if (face.size() < 3)
        throw IoError(where() + ": a face needs at least 3 vertices, got " +
                      std::to_string(face.size()));
      for (std::size_t k = 1; k + 1 < face.size(); ++k)
        m.triangles.push_back({face[0], face[k], face[k + 1]});
    }
    // Other statements (vn, vt, o, g, s, usemtl, mtllib, l, ...) carry nothing a solid needs.
  }
  return m;
}

TriangleMesh read_ply_mesh(const fs::path& path) {
  const io::PlyData data = io::read_ply(path);
  const io::PlyElement& v = data.element("vertex");
  const auto x = v.column_as_double("x"), y = v.column_as_double("y"), z = v.column_as_double("z");
  TriangleMesh m;
  m.vertices.resize(std::size_t(v.count));
  for (std::size_t i = 0; i < m.vertices.size(); ++i) {
    m.vertices[i] = {x[i], y[i], z[i]};
    if (!m.vertices[i].allFinite())
      fail(path, "vertex " + std::to_string(i) + " is not finite (expected finite x, y, z)");
  }
  const io::PlyElement& f = data.element("face");
  const io::PlyListProperty* list = f.find_list("vertex_indices");
  if (!list) list = f.find_list("vertex_index");
  if (!list) fail(path, "element \"face\" has no list \"vertex_indices\" (or \"vertex_index\")");
  const long n = long(m.vertices.size());
  for (std::size_t r = 0; r < list->data.size(); ++r) {
    const auto& face = list->data[r];
    if (face.size() < 3)
      fail(path, "face " + std::to_string(r) + " has " + std::to_string(face.size()) +
                     " vertices (expected at least 3)");
    for (const auto i : face)
      if (i < 0 || i >= n)
        fail(path, "face " + std::to_string(r) + " names vertex " + std::to_string(i) +
                       " (expected 0.." + std::to_string(n - 1) + ")");
    for (std::size_t k = 1; k + 1 < face.size(); ++k)
      m.triangles.push_back({int(face[0]), int(face[k]), int(face[k + 1])});
  }
  return m;
}

}  // namespace

TriangleMesh read_triangle_mesh(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char ch) { return char(std::tolower(ch)); });
  if (slurry::detail::regular_file_size(path, "a triangle mesh, .obj or .ply") > (std::uintmax_t(1) << 30))
    fail(path, "larger than 1 GiB (expected a triangle mesh)");
  TriangleMesh m;
  if (ext == ".obj")
    m = read_obj(path);
  else if (ext == ".ply")
    m = read_ply_mesh(path);
  else
    fail(path, "unknown mesh extension \"" + ext + "\" (expected .obj or .ply)");
  if (m.triangles.empty()) fail(path, "has no faces (expected a closed triangle mesh)");
  m.source = path.string();
  return m;
}

Eigen::Matrix3d euler_degrees(const Eigen::Vector3d& angles) {
  const double k = 3.14159265358979323846 / 180;
  const auto axis_rotation = [](int axis, double a) {
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    const int i = (axis + 1) % 3, j = (axis + 2) % 3;
    r(i, i) = std::cos(a);
    r(i, j) = -std::sin(a);
    r(j, i) = std::sin(a);
    r(j, j) = std::cos(a);
    return r;
  };
  return axis_rotation(2, k * angles[2]) * axis_rotation(1, k * angles[1]) *
         axis_rotation(0, k * angles[0]);
}

TriangleMesh place_closed_mesh(TriangleMesh mesh, const Eigen::Vector3d& scale,
                               const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                               const std::string& what) {
  for (auto& v : mesh.vertices) v = rotation * scale.cwiseProduct(v) + translation;
  // A scale with a negative component mirrors the mesh and so turns it inside out: the signed
  // volume below catches that too.
  auto& tris = mesh.triangles;
  tris.erase(
      std::remove_if(tris.begin(), tris.end(),
                     [](const auto& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }),
      tris.end());
  const MeshTopology topo = check_topology(mesh);
  if (!topo.closed()) {
    std::ostringstream s;
    s << what
      << ": the mesh does not enclose a volume (expected a closed, manifold, consistently oriented "
         "triangle mesh): ";
    const char* sep = "";
    if (topo.boundary_edges)
      s << sep << topo.boundary_edges << " edges on a hole (one triangle)", sep = ", ";
    if (topo.nonmanifold_edges)
      s << sep << topo.nonmanifold_edges << " edges shared by three or more triangles", sep = ", ";
    if (topo.inconsistent_edges)
      s << sep << topo.inconsistent_edges << " edges where neighbours are wound in opposite senses";
    s << "; close it (e.g. Blender's \"Fill Holes\" and \"Recalculate Outside\") or use a box, "
         "sphere or cylinder";
    throw IoError(s.str());
  }
  const double volume = mesh.signed_volume();
  if (!(std::abs(volume) > 0))
    throw IoError(what + ": the mesh encloses no volume (expected a solid)");
  if (volume < 0)
    for (auto& t : tris) std::swap(t[1], t[2]);
  return mesh;
}

}  // namespace slurry::geometry
