#include "slurry/engine/geometry/mesh_sdf.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "slurry/transfer/parallel.h"

namespace slurry::geometry {

namespace {

using Vec3 = Eigen::Vector3d;

/// Closest point to p on triangle abc by its Voronoi regions (Ericson 2005, sec. 5.1.5); returns
/// the squared distance.
double point_triangle_distance2(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.squaredNorm();
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.squaredNorm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (ap - (d1 / (d1 - d3)) * ab).squaredNorm();
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.squaredNorm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (ap - (d2 / (d2 - d6)) * ac).squaredNorm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return (bp - w * (c - b)).squaredNorm();
  }
  const double denom = 1 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return (ap - ab * v - ac * w).squaredNorm();
}

/// Whether an edge from p to q of a counter-clockwise triangle owns the points on it (a top-left
/// rule: of the two opposite directions a shared edge has, exactly one owns it).
bool owns_edge(double dx, double dy) {
  return dy < 0 || (dy == 0 && dx < 0);
}

}  // namespace

namespace {

/// floor(x) clamped to [lo, hi] before it becomes an int (a mesh far larger than its grid puts
/// cell coordinates beyond the range of int).
int clamped_floor(double x, int lo, int hi) {
  x = std::floor(x);
  if (!(x >= lo)) return lo;  // NaN too
  if (x > hi) return hi;
  return int(x);
}

}  // namespace

MeshSdf::MeshSdf(TriangleMesh mesh, double h, double margin, std::int64_t max_nodes, bool distances,
                 const Box* region)
    : mesh_(std::move(mesh)) {
  static std::atomic<std::uint64_t> serials{0};
  serial_ = ++serials;
  const auto& V = mesh_.vertices;
  const auto& tris = mesh_.triangles;
  normals_.resize(tris.size());
  for (std::size_t t = 0; t < tris.size(); ++t) {
    const Vec3 n = (V[tris[t][1]] - V[tris[t][0]]).cross(V[tris[t][2]] - V[tris[t][0]]);
    const double len = n.norm();
    normals_[t] = len > 0 ? Vec3(n / len) : Vec3::UnitY();
  }
  Vec3 lo, hi;
  mesh_.bounds(lo, hi);
  lo.array() -= margin;
  hi.array() += margin;
  if (region) {
    for (int d = 0; d < 3; ++d) {
      const double rlo = region->lo[d] - margin, rhi = region->hi[d] + margin;
      lo[d] = std::max(lo[d], rlo);
      hi[d] = std::min(hi[d], rhi);
      if (!(hi[d] > lo[d])) lo[d] = rlo, hi[d] = rhi;  // the mesh lies beside the region: sample all of it
    }
  }
  h_ = h;
  for (int attempt = 0; attempt < 64; ++attempt) {
    for (int d = 0; d < 3; ++d) n_[d] = std::max(2, clamped_floor(std::ceil((hi[d] - lo[d]) / h_), 0, 1 << 30) + 1);
    const double nodes = double(n_[0]) * n_[1] * n_[2];
    if (nodes <= double(max_nodes)) break;
    h_ *= std::cbrt(nodes / double(max_nodes)) * 1.01;
  }
  lo_ = lo;
  build_triangle_bins();
  if (!distances) return;

  const std::int64_t total = std::int64_t(n_[0]) * n_[1] * n_[2];
  std::vector<double> dist(std::size_t(total), std::numeric_limits<double>::infinity());
  std::vector<int> nearest(std::size_t(total), -1);
  const auto node_position = [&](int i, int j, int k) { return Vec3(lo_ + h_ * Vec3(i, j, k)); };
  // Exact distances in a band of two cells around every triangle.
  const int band = 2;
  for (std::size_t t = 0; t < tris.size(); ++t) {
    const Vec3 &a = V[tris[t][0]], &b = V[tris[t][1]], &c = V[tris[t][2]];
    const Vec3 tlo = a.cwiseMin(b).cwiseMin(c), thi = a.cwiseMax(b).cwiseMax(c);
    Eigen::Vector3i i0, i1;
    for (int d = 0; d < 3; ++d) {
      i0[d] = std::clamp(clamped_floor((tlo[d] - lo_[d]) / h_, -2 * band, n_[d] + band) - band, 0, n_[d] - 1);
      i1[d] = std::clamp(clamped_floor(std::ceil((thi[d] - lo_[d]) / h_), -2 * band, n_[d] + band) + band, 0, n_[d] - 1);
    }
    for (int k = i0[2]; k <= i1[2]; ++k)
      for (int j = i0[1]; j <= i1[1]; ++j)
        for (int i = i0[0]; i <= i1[0]; ++i) {
          const std::int64_t id = index(i, j, k);
          const double d2 = point_triangle_distance2(node_position(i, j, k), a, b, c);
          if (d2 < dist[std::size_t(id)])
            dist[std::size_t(id)] = d2, nearest[std::size_t(id)] = int(t);
        }
  }
  // Elsewhere: sweep the nearest triangle through the grid in the eight diagonal orders; a node
  // takes a neighbour's nearest triangle when that one is closer to it.
  for (int sweep = 0; sweep < 8; ++sweep) {
    const int si = sweep & 1 ? -1 : 1, sj = sweep & 2 ? -1 : 1, sk = sweep & 4 ? -1 : 1;
    for (int kk = 0; kk < n_[2]; ++kk) {
      const int k = sk > 0 ? kk : n_[2] - 1 - kk;
      for (int jj = 0; jj < n_[1]; ++jj) {
        const int j = sj > 0 ? jj : n_[1] - 1 - jj;
        for (int ii = 0; ii < n_[0]; ++ii) {
          const int i = si > 0 ? ii : n_[0] - 1 - ii;
          const std::size_t id = std::size_t(index(i, j, k));
          const auto try_from = [&](int a, int b, int c) {
            if (a < 0 || b < 0 || c < 0 || a >= n_[0] || b >= n_[1] || c >= n_[2]) return;
            const int t = nearest[std::size_t(index(a, b, c))];
            if (t < 0 || t == nearest[id]) return;
            const double d2 = point_triangle_distance2(node_position(i, j, k), V[tris[t][0]],
                                                       V[tris[t][1]], V[tris[t][2]]);
            if (d2 < dist[id]) dist[id] = d2, nearest[id] = t;
          };
          try_from(i - si, j, k);
          try_from(i, j - sj, k);
          try_from(i, j, k - sk);
        }
      }
    }
  }
  // Sign: crossings along the rows of each axis, majority of three votes.
  std::vector<unsigned char> votes(std::size_t(total), 0);
  for (int axis = 0; axis < 3; ++axis) {
    const int ab = (axis + 1) % 3, ac = (axis + 2) % 3;
    const std::int64_t rows = std::int64_t(n_[ab]) * n_[ac];
    parallel::parallel_chunks(0, rows, [&](std::int64_t r0, std::int64_t r1) {
      std::vector<Crossing> cross;
      for (std::int64_t r = r0; r < r1; ++r) {
        const int ib = int(r % n_[ab]), ic = int(r / n_[ab]);
        row_crossings(axis, lo_[ab] + h_ * ib, lo_[ac] + h_ * ic, cross);
        std::size_t next = 0;
        int winding = 0;
        for (int ia = 0; ia < n_[axis]; ++ia) {
          const double x = lo_[axis] + h_ * ia;
          while (next < cross.size() && cross[next].at < x) winding -= cross[next++].exit;
          if (winding == 0) continue;
          Eigen::Vector3i c;
          c[axis] = ia, c[ab] = ib, c[ac] = ic;
          ++votes[std::size_t(index(c[0], c[1], c[2]))];  // rows of one axis never share a node
        }
      }
    });
  }
  phi_.resize(std::size_t(total));
  for (std::int64_t id = 0; id < total; ++id) {
    const double d = std::sqrt(dist[std::size_t(id)]);
    phi_[std::size_t(id)] = float(votes[std::size_t(id)] >= 2 ? -d : d);
  }
}

void MeshSdf::build_triangle_bins() {
  // Bins of about two grid cells, at most 64 per axis.
  const Vec3 extent = upper() - lo_;
  bin_h_ = std::max(2 * h_, extent.maxCoeff() / 64);
  bin_lo_ = lo_;
  for (int d = 0; d < 3; ++d) bin_n_[d] = std::max(1, int(std::ceil(extent[d] / bin_h_)));
  const std::size_t nb = std::size_t(bin_n_[0]) * bin_n_[1] * bin_n_[2];
  const auto& V = mesh_.vertices;
  const auto range = [&](const std::array<int, 3>& t, Eigen::Vector3i& b0, Eigen::Vector3i& b1) {
    const Vec3 tlo = V[t[0]].cwiseMin(V[t[1]]).cwiseMin(V[t[2]]),
               thi = V[t[0]].cwiseMax(V[t[1]]).cwiseMax(V[t[2]]);
    for (int d = 0; d < 3; ++d) {
      b0[d] = clamped_floor((tlo[d] - bin_lo_[d]) / bin_h_, 0, bin_n_[d] - 1);
      b1[d] = clamped_floor((thi[d] - bin_lo_[d]) / bin_h_, 0, bin_n_[d] - 1);
    }
  };
  bin_start_.assign(nb + 1, 0);
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<int> fill;
    if (pass == 1) {
      for (std::size_t b = 0; b < nb; ++b) bin_start_[b + 1] += bin_start_[b];
      bin_items_.resize(std::size_t(bin_start_[nb]));
      fill.assign(bin_start_.begin(), bin_start_.end() - 1);
    }
    for (std::size_t t = 0; t < mesh_.triangles.size(); ++t) {
      Eigen::Vector3i b0, b1;
      range(mesh_.triangles[t], b0, b1);
      for (int k = b0[2]; k <= b1[2]; ++k)
        for (int j = b0[1]; j <= b1[1]; ++j)
          for (int i = b0[0]; i <= b1[0]; ++i) {
            const std::size_t b = (std::size_t(k) * bin_n_[1] + j) * bin_n_[0] + i;
            if (pass == 0)
              ++bin_start_[b + 1];
            else
              bin_items_[std::size_t(fill[b]++)] = int(t);
          }
    }
  }
}

void MeshSdf::row_crossings(int axis, double b, double c, std::vector<Crossing>& out) const {
  out.clear();
  const int ab = (axis + 1) % 3, ac = (axis + 2) % 3;
  const int jb = clamped_floor((b - bin_lo_[ab]) / bin_h_, -2, bin_n_[ab] + 1),
            jc = clamped_floor((c - bin_lo_[ac]) / bin_h_, -2, bin_n_[ac] + 1);
  // Rows just past the last bin still see its triangles (their boxes end inside it).
  const int kb = std::clamp(jb, 0, bin_n_[ab] - 1), kc = std::clamp(jc, 0, bin_n_[ac] - 1);
  if (jb < -1 || jc < -1 || jb > bin_n_[ab] || jc > bin_n_[ac]) return;
  thread_local std::vector<int> candidates;
  candidates.clear();
  for (int ia = 0; ia < bin_n_[axis]; ++ia) {
    Eigen::Vector3i q;
    q[axis] = ia, q[ab] = kb, q[ac] = kc;
    const std::size_t bin = (std::size_t(q[2]) * bin_n_[1] + q[1]) * bin_n_[0] + q[0];
    candidates.insert(candidates.end(), bin_items_.begin() + bin_start_[bin],
                      bin_items_.begin() + bin_start_[bin + 1]);
  }
  std::sort(candidates.begin(), candidates.end());
  candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
  const auto& V = mesh_.vertices;
  for (const int t : candidates) {
    const auto& tri = mesh_.triangles[std::size_t(t)];
    Eigen::Vector2d p[3];
    double along[3];
    for (int e = 0; e < 3; ++e) {
      const Vec3& v = V[std::size_t(tri[e])];
      p[e] = {v[ab] - b, v[ac] - c};  // the row passes through the origin of this plane
      along[e] = v[axis];
    }
    double area = (p[1] - p[0]).x() * (p[2] - p[0]).y() - (p[1] - p[0]).y() * (p[2] - p[0]).x();
    if (area == 0) continue;  // seen edge-on: the row crosses its neighbours instead
    // Counter-clockwise in the (ab, ac) plane: the outward normal points along +axis, so the row
    // leaves the solid there.
    const int exit = area > 0 ? 1 : -1;
    if (area < 0) std::swap(p[1], p[2]), std::swap(along[1], along[2]), area = -area;
    double w[3];
    bool inside = true;
    for (int e = 0; e < 3 && inside; ++e) {
      // The edge opposite vertex e, from s to q. Its edge function is computed from the edge's
      // lexicographically smaller end, whichever way this triangle runs along it, and negated
      // for the other way: the two triangles that share the edge then get exactly opposite
      // values, so a row through the edge is counted once. Computed from each triangle's own
      // end, round-off could make both values negative (a cube's face diagonal dropped whole
      // rows of particles) or both positive.
      const Eigen::Vector2d &s = p[(e + 1) % 3], &q = p[(e + 2) % 3];
      const bool flip = q.x() < s.x() || (q.x() == s.x() && q.y() < s.y());
      const Eigen::Vector2d& a = flip ? q : s;
      const Eigen::Vector2d d = (flip ? s : q) - a;
      const double wa = d.x() * (-a.y()) - d.y() * (-a.x());  // cross(d, origin - a)
      w[e] = flip ? -wa : wa;
      inside = w[e] > 0 || (w[e] == 0 && (flip ? owns_edge(-d.x(), -d.y()) : owns_edge(d.x(), d.y())));
    }
    if (!inside) continue;
    out.push_back({(w[0] * along[0] + w[1] * along[1] + w[2] * along[2]) / (w[0] + w[1] + w[2]), exit});
  }
  std::sort(out.begin(), out.end(),
            [](const Crossing& a, const Crossing& b) { return a.at < b.at || (a.at == b.at && a.exit < b.exit); });
}

namespace {
/// Whether a point at `x` along a row is inside: the row's winding number there (entries minus
/// exits before it) is not zero. Overlapping closed parts are filled once (winding 2), a cavity
/// bounded by an inward-facing surface stays empty (winding 0).
bool winding_inside(const std::vector<MeshSdf::Crossing>& cross, double x) {
  int winding = 0;
  for (const auto& c : cross) {
    if (!(c.at <= x)) break;
    winding -= c.exit;
  }
  return winding != 0;
}
}  // namespace

void MeshSdf::inside_along_row(int axis, double b, double c, const std::vector<double>& xs,
                               std::vector<char>& inside) const {
  thread_local std::vector<Crossing> cross;
  row_crossings(axis, b, c, cross);
  inside.resize(xs.size());
  for (std::size_t i = 0; i < xs.size(); ++i) inside[i] = char(winding_inside(cross, xs[i]));
}

bool MeshSdf::inside(const Vec3& y) const {
  thread_local std::uint64_t cached_for = 0;
  thread_local double cached_b = 0, cached_c = 0;
  thread_local std::vector<Crossing> cross;
  if (cached_for != serial_ || cached_b != y[0] || cached_c != y[1]) {
    row_crossings(2, y[0], y[1], cross);
    cached_for = serial_, cached_b = y[0], cached_c = y[1];
  }
  return winding_inside(cross, y[2]);
}

double MeshSdf::phi(const Vec3& y) const {
  Vec3 g = (y - lo_) / h_;
  double extra = 0;
  const Vec3 top = (n_ - Eigen::Vector3i::Ones()).cast<double>();
  if ((g.array() < 0).any() || (g.array() > top.array()).any()) {
    const Vec3 c = g.cwiseMax(Vec3::Zero()).cwiseMin(top);
    extra = (g - c).norm() * h_;
    g = c;
  }
  int i[3];
  double f[3];
  for (int d = 0; d < 3; ++d) {
    i[d] = std::min(int(g[d]), n_[d] - 2);
    f[d] = g[d] - i[d];
  }
  double v = 0;
  for (int c = 0; c < 8; ++c) {
    const int a = c & 1, b = (c >> 1) & 1, e = (c >> 2) & 1;
    const double w = (a ? f[0] : 1 - f[0]) * (b ? f[1] : 1 - f[1]) * (e ? f[2] : 1 - f[2]);
    v += w * double(phi_[std::size_t(index(i[0] + a, i[1] + b, i[2] + e))]);
  }
  return v + extra;
}

Vec3 MeshSdf::normal(const Vec3& y) const {
  for (double step : {0.5 * h_, 2 * h_}) {
    Vec3 g;
    for (int d = 0; d < 3; ++d) {
      const Vec3 e = Vec3::Unit(d) * step;
      g[d] = phi(y + e) - phi(y - e);
    }
    const double len = g.norm();
    if (len > 0) return g / len;
  }
  return Vec3::UnitY();
}

bool MeshSdf::first_entry(const Vec3& y0, const Vec3& y1, double& s, Vec3& n) const {
  const Vec3 lo = y0.cwiseMin(y1), hi = y0.cwiseMax(y1);
  Eigen::Vector3i b0, b1;
  for (int d = 0; d < 3; ++d) {
    const double a = (lo[d] - bin_lo_[d]) / bin_h_, c = (hi[d] - bin_lo_[d]) / bin_h_;
    if (c < 0 || a >= bin_n_[d]) return false;
    b0[d] = clamped_floor(a, 0, bin_n_[d] - 1);
    b1[d] = clamped_floor(c, 0, bin_n_[d] - 1);
  }
  const Vec3 dir = y1 - y0;
  const auto& V = mesh_.vertices;
  constexpr double eps =
      1e-9;  // barycentric slack: a segment through a shared edge hits both sides
  bool hit = false;
  double best = 2;
  for (int k = b0[2]; k <= b1[2]; ++k)
    for (int j = b0[1]; j <= b1[1]; ++j)
      for (int i = b0[0]; i <= b1[0]; ++i) {
        const std::size_t bin = (std::size_t(k) * bin_n_[1] + j) * bin_n_[0] + i;
        for (int q = bin_start_[bin]; q < bin_start_[bin + 1]; ++q) {
          const int t = bin_items_[std::size_t(q)];
          const auto& tri = mesh_.triangles[std::size_t(t)];
          const Vec3& a = V[std::size_t(tri[0])];
          const Vec3 e1 = V[std::size_t(tri[1])] - a, e2 = V[std::size_t(tri[2])] - a;
          const Vec3 pv = dir.cross(e2);
          const double det =
              e1.dot(pv);  // = -dir . (e1 x e2): positive when moving against the normal
          if (!(det > 0)) continue;
          const double inv = 1 / det;
          const Vec3 tv = y0 - a;
          const double u = tv.dot(pv) * inv;
          if (u < -eps || u > 1 + eps) continue;
          const Vec3 qv = tv.cross(e1);
          const double v = dir.dot(qv) * inv;
          if (v < -eps || u + v > 1 + eps) continue;
          const double st = e2.dot(qv) * inv;
          if (st < 0 || st > 1 || st >= best) continue;
          best = st;
          n = normals_[std::size_t(t)];
          hit = true;
        }
      }
  if (hit) s = best;
  return hit;
}

std::size_t MeshSdf::bytes() const {
  return phi_.capacity() * sizeof(float) +
         (bin_start_.capacity() + bin_items_.capacity()) * sizeof(int) +
         mesh_.vertices.capacity() * sizeof(Vec3) +
         mesh_.triangles.capacity() * sizeof(std::array<int, 3>) +
         normals_.capacity() * sizeof(Vec3);
}

}  // namespace slurry::geometry
