// Triangle mesh files: Wavefront OBJ and PLY meshes read into geometry::TriangleMesh.
#include "slurry/io/triangle_mesh_file.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>

#include "input_file.h"
#include "slurry/engine/errors.h"
#include "slurry/io/ply.h"

namespace slurry::io {

namespace fs = std::filesystem;
using geometry::TriangleMesh;

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
  const Table& v = data.table("vertex");
  const auto x = v.column_as_double("x"), y = v.column_as_double("y"), z = v.column_as_double("z");
  TriangleMesh m;
  m.vertices.resize(std::size_t(v.count));
  for (std::size_t i = 0; i < m.vertices.size(); ++i) {
    m.vertices[i] = {x[i], y[i], z[i]};
    if (!m.vertices[i].allFinite())
      fail(path, "vertex " + std::to_string(i) + " is not finite (expected finite x, y, z)");
  }
  const Table& f = data.table("face");
  const ListColumn* list = f.find_list("vertex_indices");
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

}  // namespace slurry::io
