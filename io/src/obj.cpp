#include "slurry/io/obj.h"

#include <cstdio>
#include <vector>

#include "atomic_file.h"
#include "slurry/engine/errors.h"

namespace slurry::io {

namespace fs = std::filesystem;

void write_obj(const fs::path& path, const Frame& mesh, const std::string& comment, const std::string& object_column,
               const std::string& object_prefix) {
  const auto fail = [&](const std::string& what) { throw IoError(path.string() + ": " + what); };
  const Table* v = mesh.find("vertex");
  const Table* f = mesh.find("face");
  if (!v || !f) fail("the mesh has no \"vertex\" or no \"face\" table (expected both)");
  const ListColumn* faces = f->find_list("vertex_indices");
  if (!faces || faces->data.size() != f->count) fail("the \"face\" table has no vertex_indices list of its row count");
  std::vector<double> xyz[3];
  const char* names[3] = {"x", "y", "z"};
  for (int d = 0; d < 3; ++d) {
    if (!v->has(names[d])) fail(std::string("the vertices have no column ") + names[d]);
    xyz[d] = v->column_as_double(names[d]);
  }
  std::vector<double> object;
  if (!object_column.empty()) {
    if (!f->has(object_column)) fail("the faces have no column " + object_column);
    object = f->column_as_double(object_column);
  }
  detail::AtomicFile file(path);
  char line[128];
  const auto put = [&](int n) { file.write(line, std::size_t(n)); };
  const std::string head = "# " + comment + "\n";
  file.write(head.data(), head.size());
  for (std::size_t i = 0; i < v->count; ++i) put(std::snprintf(line, sizeof line, "v %.9g %.9g %.9g\n", xyz[0][i], xyz[1][i], xyz[2][i]));
  for (std::size_t i = 0; i < f->count; ++i) {
    if (!object.empty() && (i == 0 || object[i] != object[i - 1])) {
      const std::string o = "o " + object_prefix + std::to_string(static_cast<long long>(object[i])) + "\n";
      file.write(o.data(), o.size());
    }
    const auto& t = faces->data[i];
    if (t.size() != 3) fail("face " + std::to_string(i) + " has " + std::to_string(t.size()) + " vertices (expected triangles)");
    for (int k = 0; k < 3; ++k)
      if (t[std::size_t(k)] < 0 || std::size_t(t[std::size_t(k)]) >= v->count)
        fail("face " + std::to_string(i) + " names vertex " + std::to_string(t[std::size_t(k)]) + " of " +
             std::to_string(v->count));
    put(std::snprintf(line, sizeof line, "f %d %d %d\n", t[0] + 1, t[1] + 1, t[2] + 1));
  }
  file.commit();
}

}  // namespace slurry::io
