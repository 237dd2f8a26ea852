// The OpenVDB-free half of slurry::io (surface.h): particle frames to point clouds, per-vertex
// velocities, PLY and OBJ mesh files.
#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <numeric>

#include "slurry/engine/errors.h"
#include "slurry/io/obj.h"
#include "slurry/io/surface.h"
#include "slurry/transfer/parallel.h"
#include "vdb/cell_starts.h"
#include "vdb/lanes.h"
#include "vdb/point_bounds.h"
#include "vdb/velocities.h"

namespace slurry::io {

PointCloud point_cloud(const Frame& frame, int material) {
  const Table& v = frame.table("vertex");
  const bool three_d = v.has("z");
  const auto x = v.column_as_float("x"), y = v.column_as_float("y");
  const auto z = three_d ? v.column_as_float("z") : std::vector<float>(v.count, 0.0f);
  const bool has_v = v.has("vx");
  std::vector<float> vx, vy, vz;
  if (has_v) {
    vx = v.column_as_float("vx");
    vy = v.column_as_float("vy");
    vz = three_d ? v.column_as_float("vz") : std::vector<float>(v.count, 0.0f);
  }
  std::vector<double> id;
  if (v.has("id")) id = v.column_as_double("id");
  std::vector<double> type;
  if (v.has("type")) type = v.column_as_double("type");
  std::vector<double> mat;
  if (material >= 0 && v.has("material")) mat = v.column_as_double("material");

  PointCloud c;
  for (std::size_t i = 0; i < v.count; ++i) {
    if (!mat.empty() && mat[i] != double(material)) continue;
    if (!std::isfinite(x[i]) || !std::isfinite(y[i]) || !std::isfinite(z[i]))
      throw IoError(frame.source.string() + ": vertex " + std::to_string(i) + " has a non-finite position (" +
                    std::to_string(x[i]) + ", " + std::to_string(y[i]) + ", " + std::to_string(z[i]) +
                    "); expected finite positions (a frame of a run that became unstable?)");
    if (has_v && (!std::isfinite(vx[i]) || !std::isfinite(vy[i]) || !std::isfinite(vz[i])))
      throw IoError(frame.source.string() + ": vertex " + std::to_string(i) +
                    " has a non-finite velocity; expected finite velocities");
    c.position.push_back({x[i], y[i], z[i]});
    if (has_v) c.velocity.push_back({vx[i], vy[i], vz[i]});
    if (!id.empty()) {
      if (!(id[i] >= 0 && id[i] <= double(std::numeric_limits<std::uint32_t>::max())))
        throw IoError(frame.source.string() + ": vertex " + std::to_string(i) + ": id " +
                      std::to_string(id[i]) + " is not an unsigned 32-bit integer");
      c.id.push_back(std::uint32_t(id[i]));
    }
    if (!type.empty()) c.type.push_back(std::uint8_t(std::clamp(type[i], 0.0, 255.0)));
  }
  return c;
}

std::vector<std::array<float, 3>> sample_velocities(
    const std::vector<std::array<float, 3>>& vertices, const PointCloud& points, double spacing) {
  return detail::VelocitySampler(points, spacing).sample(vertices, nullptr);
}

namespace detail {

VelocitySampler::VelocitySampler(const PointCloud& points, double spacing) : points_(points), h_(2 * spacing) {
  const std::size_t n = points.size();
  if (n == 0 || points.velocity.size() != n) return;
  const double h = h_;
  // The particles' box: its smallest coordinates, and the cells from there to its largest
  // (truncation is monotonic: the largest cell of any particle).
  const PointBounds b = point_bounds(points.position);
  for (int d = 0; d < 3; ++d) {
    lo_[d] = double(b.lo[d]);
    dims_[d] = std::max<std::int64_t>(1, std::int64_t((b.hi[d] - lo_[d]) / h) + 1);
  }
  const std::array<double, 3>& lo = lo_;
  const std::array<std::int64_t, 3>& dims = dims_;
  // (cell key, particle) sorted by key, then particle.
  keys_.resize(n);
  UninitVector<std::uint32_t> index(n);
  slurry::parallel::parallel_for(0, std::int64_t(n), [&](std::int64_t i) {
    const auto& p = points.position[std::size_t(i)];
    std::int64_t c[3];
    for (int d = 0; d < 3; ++d) c[d] = std::int64_t(std::floor((p[d] - lo[d]) / h));
    keys_[std::size_t(i)] = std::uint64_t((c[0] * dims[1] + c[1]) * dims[2] + c[2]);
    index[std::size_t(i)] = std::uint32_t(i);
  });
  // Sorted, with where each cell's particles start in `keys` when the cells of the particles' box
  // are few enough for a table (else a binary search per row).
  first_ = sort_pairs_by_cell(keys_, index, double(dims[0]) * double(dims[1]) * double(dims[2]));
  // Positions and velocities in cell order: a row of cells is one stretch of memory.
  for (auto& axis : position_) axis.resize(n);
  velocity_.resize(n);
  slurry::parallel::parallel_for(0, std::int64_t(n), [&](std::int64_t t) {
    const auto& p = points.position[index[std::size_t(t)]];
    for (int d = 0; d < 3; ++d) position_[d][std::size_t(t)] = p[std::size_t(d)];
    velocity_[std::size_t(t)] = points.velocity[index[std::size_t(t)]];
  });
}

std::vector<std::array<float, 3>> VelocitySampler::sample(const std::vector<std::array<float, 3>>& vertices,
                                                          std::vector<std::uint8_t>* found) const {
  const PointCloud& points = points_;
  const std::size_t n = points.size();
  if (found) found->assign(vertices.size(), 0);
  std::vector<std::array<float, 3>> out(vertices.size(), {0.0f, 0.0f, 0.0f});
  if (n == 0 || points.velocity.size() != n) return out;
  const double h = h_;
  const std::array<double, 3>& lo = lo_;
  const std::array<std::int64_t, 3>& dims = dims_;
  const UninitVector<std::uint64_t>& keys = keys_;
  const UninitVector<std::uint32_t>& first = first_;
  const float* const px = position_[0].data();
  const float* const py = position_[1].data();
  const float* const pz = position_[2].data();
  const UninitVector<std::array<float, 3>>& velocity = velocity_;
  const auto cell_of = [&](const std::array<float, 3>& p, std::array<std::int64_t, 3>& c) {
    for (int d = 0; d < 3; ++d) c[d] = std::int64_t(std::floor((p[d] - lo[d]) / h));
  };
  const auto key = [&](const std::array<std::int64_t, 3>& c) {
    return (c[0] * dims[1] + c[1]) * dims[2] + c[2];
  };
  const auto row_begin = [&](std::int64_t k) {
    if (!first.empty()) return std::size_t(first[std::size_t(k)]);
    return std::size_t(std::lower_bound(keys.begin(), keys.end(), std::uint64_t(k)) - keys.begin());
  };

  const auto row_end = [&](std::int64_t k_last) {
    if (!first.empty()) return std::size_t(first[std::size_t(k_last) + 1]);
    return std::size_t(std::upper_bound(keys.begin(), keys.end(), std::uint64_t(k_last)) - keys.begin());
  };
  const double h2 = h * h;

  slurry::parallel::parallel_for(0, std::int64_t(vertices.size()), [&](std::int64_t vi) {
    const auto& q = vertices[std::size_t(vi)];
    const float qf[3] = {q[0], q[1], q[2]};
    std::array<std::int64_t, 3> c;
    cell_of(q, c);
    double w_sum = 0, u[3] = {0, 0, 0}, nearest = 1e300;
    std::size_t nearest_index = 0;  // in cell order
    // The cells (a, b, c[2] - 1 .. c[2] + 1) are consecutive keys: one range per row, visited
    // in the same order as cell by cell. Per row, the squared distances and the candidates within
    // h listed in one loop (vectors), then summed in order.
    thread_local std::vector<double> r2s;
    thread_local std::vector<std::uint32_t> within;
    std::array<std::pair<std::size_t, std::size_t>, 9> rows{};
    int row_count = 0;
    for (std::int64_t a = c[0] - 1; a <= c[0] + 1; ++a)
      for (std::int64_t b = c[1] - 1; b <= c[1] + 1; ++b) {
        if (a < 0 || b < 0 || a >= dims[0] || b >= dims[1]) continue;
        const std::int64_t e0 = std::max<std::int64_t>(c[2] - 1, 0), e1 = std::min(c[2] + 1, dims[2] - 1);
        if (e0 > e1) continue;
        const std::size_t t0 = row_begin(key({a, b, e0})), t1 = row_end(key({a, b, e1}));
        if (t0 >= t1) continue;
        rows[std::size_t(row_count++)] = {t0, t1};
        const std::size_t m = t1 - t0;
        if (r2s.size() < m) r2s.resize(m), within.resize(m + 8);
        double* const r2 = r2s.data();
        const std::size_t listed = list_within(px + t0, py + t0, pz + t0, m, qf, h2, r2, within.data());
        for (std::size_t k = 0; k < listed; ++k) {
          const std::size_t j = within[k], t = t0 + j;
          const double s = 1 - r2[j] / h2,
                       w = s * s * s;  // poly6 (Mueller et al. 2003, eq. 20), unnormalized
          w_sum += w;
          for (int d = 0; d < 3; ++d) u[d] += w * velocity[t][d];
        }
      }
    if (!(w_sum > 0))  // none within h: the nearest of the rows (the first of equals)
      for (int r = 0; r < row_count; ++r)
        for (std::size_t t = rows[std::size_t(r)].first; t < rows[std::size_t(r)].second; ++t) {
          const double r2 = within_norm2(px[t], py[t], pz[t], qf);
          if (r2 < nearest) nearest = r2, nearest_index = t;
        }
    auto& o = out[std::size_t(vi)];
    if (w_sum > 0) {
      for (int d = 0; d < 3; ++d) o[d] = float(u[d] / w_sum);
    } else if (nearest < 1e300) {
      o = velocity[nearest_index];
    } else if (found) {
      return;  // left to the caller
    } else {  // no particle within 1.5 h: the closest one of all (rare; closing keeps vertices near
              // particles)
      std::size_t best = 0;
      double best_r2 = 1e300;
      for (std::size_t i = 0; i < n; ++i) {
        const auto& p = points.position[i];
        const double r2 = (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
                          (p[2] - q[2]) * (p[2] - q[2]);
        if (r2 < best_r2) best_r2 = r2, best = i;
      }
      o = points.velocity[best];
    }
    if (found) (*found)[std::size_t(vi)] = 1;
  });
  return out;
}

}  // namespace detail

namespace {
/// The mesh as a frame (vertex x y z and, with `velocities`, vx vy vz; face vertex_indices).
PlyData mesh_frame(const TriangleMesh& mesh, bool velocities) {
  PlyData data;
  data.comments.push_back("slurry surface mesh");
  Table& v = data.tables.emplace_back();
  v.name = "vertex";
  v.count = mesh.vertices.size();
  const auto column = [&](const std::vector<std::array<float, 3>>& src, int d) {
    std::vector<float> c(src.size());
    for (std::size_t i = 0; i < src.size(); ++i) c[i] = src[i][std::size_t(d)];
    return c;
  };
  v.columns.push_back({"x", column(mesh.vertices, 0)});
  v.columns.push_back({"y", column(mesh.vertices, 1)});
  v.columns.push_back({"z", column(mesh.vertices, 2)});
  if (velocities && !mesh.velocities.empty()) {
    v.columns.push_back({"vx", column(mesh.velocities, 0)});
    v.columns.push_back({"vy", column(mesh.velocities, 1)});
    v.columns.push_back({"vz", column(mesh.velocities, 2)});
  }
  Table& f = data.tables.emplace_back();
  f.name = "face";
  f.count = mesh.triangles.size();
  ListColumn list{"vertex_indices", {}};
  list.data.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) list.data.push_back({t[0], t[1], t[2]});
  f.lists.push_back(std::move(list));
  return data;
}
}  // namespace

void write_mesh_ply(const std::filesystem::path& path, const TriangleMesh& mesh, PlyFormat format) {
  if (!mesh.velocities.empty() && mesh.velocities.size() != mesh.vertices.size())
    throw IoError(path.string() + ": " + std::to_string(mesh.velocities.size()) +
                  " velocities for " + std::to_string(mesh.vertices.size()) + " vertices");
  write_ply(path, mesh_frame(mesh, true), format);
}

void write_mesh_obj(const std::filesystem::path& path, const TriangleMesh& mesh) {
  write_obj(path, mesh_frame(mesh, false),
            "slurry surface mesh: " + std::to_string(mesh.vertices.size()) + " vertices, " +
                std::to_string(mesh.triangles.size()) + " triangles");
}

}  // namespace slurry::io
