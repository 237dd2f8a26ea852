// The narrow band of distances to a mesh (io/src/vdb/mesh_band.h): the band it builds, skipping the
// seeds' exact distances that a bounding box rules out and the voxels no new neighbour reached, is
// the band of the exhaustive search (every exact distance, every voxel tried), bit for bit. The
// squared distance to a triangle for a row of 8 voxels in one vector is the one-point definition's,
// bit for bit, in every Voronoi region and for degenerate triangles (triangle_distance.h).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "slurry/io/surface.h"
#include "slurry/transfer/parallel.h"
#include "vdb/mesh_band.h"
#include "vdb/triangle_distance.h"

namespace {

using slurry::io::detail::mesh_band;
using slurry::io::detail::MeshBand;
using Vertices = std::vector<std::array<float, 3>>;
using Triangles = std::vector<std::array<std::int32_t, 3>>;

/// The same band, bit for bit: blocks, distances and closest triangles.
void expect_same(const MeshBand& fast, const MeshBand& reference, const char* what) {
  ASSERT_FALSE(reference.origin.empty()) << what;
  ASSERT_EQ(fast.origin, reference.origin) << what;
  ASSERT_EQ(fast.distance.size(), reference.distance.size()) << what;
  EXPECT_EQ(std::memcmp(fast.distance.data(), reference.distance.data(), fast.distance.size() * sizeof(float)), 0)
      << what << ": distances";
  std::size_t differ = 0;
  for (std::size_t i = 0; i < fast.triangle.size(); ++i) differ += fast.triangle[i] != reference.triangle[i];
  EXPECT_EQ(differ, 0u) << what << ": closest triangles";
}

/// A liquid's surface: the anisotropic mesh of a jittered slab of particles with spray above it.
void liquid(double h, Vertices& v, Triangles& t) {
  const double s = h / 2;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.3f * float(s), 0.3f * float(s));
  slurry::io::PointCloud c;
  for (double x = -0.06; x < 0.06; x += s)
    for (double y = -0.02; y < 0.01 + 0.01 * std::sin(40 * x); y += s)
      for (double z = -0.04; z < 0.04; z += s) c.position.push_back({float(x) + u(rng), float(y) + u(rng), float(z) + u(rng)});
  for (int k = 0; k < 12; ++k) c.position.push_back({float(0.008 * k - 0.05), float(0.03 + 0.004 * k), float(0.003 * k)});
  slurry::io::SurfaceParams p;
  p.voxel_size = h;
  p.spacing = s;
  const slurry::io::Surface sf = slurry::io::surface_mesh(c, p);
  v = sf.mesh.vertices;
  t = sf.mesh.triangles;
}

/// Triangles of every kind a bound could misjudge: small and large, slivers whose sides are
/// nearly parallel, ones with two equal corners, at negative and positive coordinates.
void assorted(double h, Vertices& v, Triangles& t) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> where(-40.0f * float(h), 40.0f * float(h)), unit(-1.0f, 1.0f);
  const auto add = [&](std::array<float, 3> a, std::array<float, 3> b, std::array<float, 3> c) {
    const auto n = std::int32_t(v.size());
    v.push_back(a), v.push_back(b), v.push_back(c);
    t.push_back({n, n + 1, n + 2});
  };
  for (int i = 0; i < 3000; ++i) {
    const std::array<float, 3> a{where(rng), where(rng), where(rng)};
    const float size = float(h) * (i % 10 == 0 ? 12.0f : i % 3 == 0 ? 2.0f : 0.6f);
    std::array<float, 3> b, c;
    for (int d = 0; d < 3; ++d) b[std::size_t(d)] = a[std::size_t(d)] + size * unit(rng);
    switch (i % 4) {
      case 0:  // a sliver: c nearly on the line through a and b
        for (int d = 0; d < 3; ++d)
          c[std::size_t(d)] = a[std::size_t(d)] + 0.5f * (b[std::size_t(d)] - a[std::size_t(d)]) + 1e-4f * float(h) * unit(rng);
        break;
      case 1:  // two equal corners
        c = b;
        break;
      default:
        for (int d = 0; d < 3; ++d) c[std::size_t(d)] = a[std::size_t(d)] + size * unit(rng);
    }
    add(a, b, c);
  }
}

TEST(MeshBand, SkippingGivesTheExhaustiveBandBitForBit) {
  const slurry::parallel::ThreadLimit limit(2);
  for (const double h : {0.004, 0.0037}) {
    Vertices v;
    Triangles t;
    liquid(h, v, t);
    ASSERT_GT(t.size(), 1000u);
    expect_same(mesh_band(v, t, h, 3), mesh_band(v, t, h, 3, /*exhaustive=*/true), "a liquid's surface");
    Vertices va;
    Triangles ta;
    assorted(h, va, ta);
    expect_same(mesh_band(va, ta, h, 3), mesh_band(va, ta, h, 3, /*exhaustive=*/true), "assorted triangles");
    expect_same(mesh_band(va, ta, h, 5), mesh_band(va, ta, h, 5, /*exhaustive=*/true), "assorted triangles, width 5");
  }
}

TEST(TriangleDistance, RowIsThePointByPoint) {
#if defined(__AVX2__) && defined(__FMA__)
  using slurry::io::detail::Tri;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-2.0f, 2.0f);
  std::size_t compared = 0, regions[8] = {};
  for (int n = 0; n < 40000; ++n) {
    Tri t{};
    for (int d = 0; d < 3; ++d) t.a[d] = u(rng), t.b[d] = u(rng), t.c[d] = u(rng);
    switch (n % 10) {  // degenerate ones: a repeated vertex, a sliver, a point
      case 0: std::copy(t.a, t.a + 3, t.b); break;
      case 1: for (int d = 0; d < 3; ++d) t.c[d] = t.a[d] + 0.5f * (t.b[d] - t.a[d]); break;
      case 2: std::copy(t.a, t.a + 3, t.b), std::copy(t.a, t.a + 3, t.c); break;
      case 3:  // whole coordinates: exact products, ties and zero areas
        for (int d = 0; d < 3; ++d) t.a[d] = std::round(t.a[d]), t.b[d] = std::round(t.b[d]), t.c[d] = std::round(t.c[d]);
        break;
      default: break;
    }
    const float px = std::round(u(rng) * 2), py = std::round(u(rng) * 2);
    const std::int32_t z0 = std::int32_t(std::round(u(rng) * 3)) - 4;
    float row[8];
    _mm256_storeu_ps(row, slurry::io::detail::distance2_row(t, px, py, z0));
    for (int l = 0; l < 8; ++l) {
      const float p[3] = {px, py, float(z0 + l)};
      const float e = slurry::io::detail::distance2(t, p);
      ASSERT_EQ(std::memcmp(&row[l], &e, sizeof(float)), 0) << n << " lane " << l << ": " << row[l] << " vs " << e;
      ++compared;
      // Which region gave it: a vertex (its squared distance), else an edge or the face.
      const float ap[3] = {p[0] - t.a[0], p[1] - t.a[1], p[2] - t.a[2]};
      const float bp[3] = {p[0] - t.b[0], p[1] - t.b[1], p[2] - t.b[2]};
      const float cp[3] = {p[0] - t.c[0], p[1] - t.c[1], p[2] - t.c[2]};
      const auto sq = [](const float* v) { return v[0] * v[0] + v[1] * v[1] + v[2] * v[2]; };
      const float nearest = std::min({sq(ap), sq(bp), sq(cp)});
      regions[e < nearest * (1 - 1e-5f) ? (n % 10 < 4 ? 1 : 2) : 0] += 1;
    }
  }
  EXPECT_EQ(compared, 320000u);
  // Vertices, edges of degenerate (or whole-coordinate) triangles, and edges or faces of the
  // others all occur.
  EXPECT_GT(regions[0], compared / 20);
  EXPECT_GT(regions[1], compared / 100);
  EXPECT_GT(regions[2], compared / 20);
#else
  GTEST_SKIP() << "built without AVX2 and FMA: distance2_row is not compiled";
#endif
}

}  // namespace
