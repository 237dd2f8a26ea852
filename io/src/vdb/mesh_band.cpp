// The narrow band of distances to a triangle mesh (mesh_band.h).
#include "vdb/mesh_band.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "slurry/transfer/parallel.h"
#include "vdb/block_pairs.h"
#include "vdb/cell_starts.h"
#include "vdb/buffer.h"
#include "vdb/triangle_distance.h"

namespace slurry::io::detail {

namespace {

constexpr int B = MeshBand::kSize;
constexpr int kBits = 21;
constexpr std::int64_t kRange = std::int64_t(1) << kBits;
/// A lower bound of a squared distance (voxels^2) skips the exact one only when it exceeds the
/// best distance so far by this much relative, plus this much times (1 + s^2) absolute, s the
/// span of the voxels around the triangle: far beyond the rounding of either (distance2 rounds
/// within a few float ulps of the squares of its differences, at most s^2), so a skipped triangle
/// is never the closest or tied with it, and the band is the one every exact distance gives.
constexpr float kBoundMargin = 1e-3f;

std::int64_t floor_div(std::int64_t a, std::int64_t b) {
  return a >= 0 ? a / b : -((-a + b - 1) / b);
}

}  // namespace

MeshBand mesh_band(const std::vector<std::array<float, 3>>& vertices,
                   const std::vector<std::array<std::int32_t, 3>>& triangles, double h, int width,
                   bool exhaustive) {
  MeshBand out;
  const std::size_t nt = triangles.size();
  if (nt == 0) return out;
  if (!(h > 0) || width < 1) throw std::invalid_argument("mesh_band: expected h > 0 and width >= 1");
  const float inv_h = float(1 / h);
  UninitVector<Tri> tri(nt);
  parallel::parallel_for(0, std::int64_t(nt), [&](std::int64_t i) {
    Tri& t = tri[std::size_t(i)];
    const auto& v = triangles[std::size_t(i)];
    for (int d = 0; d < 3; ++d) {
      t.a[d] = vertices[std::size_t(v[0])][d] * inv_h;
      t.b[d] = vertices[std::size_t(v[1])][d] * inv_h;
      t.c[d] = vertices[std::size_t(v[2])][d] * inv_h;
      t.box_lo[d] = std::min({t.a[d], t.b[d], t.c[d]}), t.box_hi[d] = std::max({t.a[d], t.b[d], t.c[d]});
      t.lo[d] = std::int32_t(std::ceil(t.box_lo[d] - 1));
      t.hi[d] = std::int32_t(std::floor(t.box_hi[d] + 1));
    }
    const float span = float(std::max({t.hi[0] - t.lo[0], t.hi[1] - t.lo[1], t.hi[2] - t.lo[2]}));
    t.slack = kBoundMargin * (1 + span * span);
  });
  // The blocks the triangles seed (their voxels within one voxel of their box). The band reaches
  // `width` voxels further: at most `reach` blocks beyond a seeded one on each axis.
  const std::int64_t reach = (width + B - 1) / B;
  std::int64_t lo[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, hi[3] = {INT64_MIN, INT64_MIN, INT64_MIN};
  for (const Tri& t : tri)
    for (int d = 0; d < 3; ++d) {
      lo[d] = std::min(lo[d], floor_div(t.lo[d], B));
      hi[d] = std::max(hi[d], floor_div(t.hi[d], B));
    }
  for (int d = 0; d < 3; ++d)
    if (hi[d] - lo[d] + 2 * reach + 3 >= kRange)
      throw std::invalid_argument("mesh_band: the mesh spans more than 2^21 blocks of 8 voxels");
  // Keys for the blocks within `reach` of a seeded one and one block beyond, so that a block's
  // face neighbours always have keys.
  for (int d = 0; d < 3; ++d) lo[d] -= reach + 1;
  // Block keys x + nx (y + ny z) over that box of blocks: ordered by z, then y, then x, in as few
  // bits as the box needs (fewer sort passes).
  const std::int64_t nx = hi[0] - lo[0] + reach + 2, ny = hi[1] - lo[1] + reach + 2;
  const auto key_of = [&](std::int64_t x, std::int64_t y, std::int64_t z) { return std::uint64_t(x + nx * (y + ny * z)); };
  const auto cell_of = [&](std::uint64_t k) {
    const std::int64_t i = std::int64_t(k);
    return std::array<std::int64_t, 3>{i % nx, (i / nx) % ny, i / (nx * ny)};
  };
  // The blocks triangle i seeds: [b0, b1] per axis.
  const auto block_range = [&](std::size_t i, std::int64_t b0[3], std::int64_t b1[3]) {
    const Tri& t = tri[i];
    for (int d = 0; d < 3; ++d) b0[d] = floor_div(t.lo[d], B) - lo[d], b1[d] = floor_div(t.hi[d], B) - lo[d];
  };
  // The (seeded block, triangle) pairs, in triangle order.
  UninitVector<std::uint64_t> keys;
  UninitVector<std::uint32_t> owner;
  list_block_pairs(nt, block_range, key_of, keys, owner);
  // By block, then triangle.
  sort_pairs_by_cell(keys, owner, double(nx) * double(ny) * double(hi[2] - lo[2] + reach + 2));
  std::vector<std::uint32_t> run;  // starts of each seeded block's triangles, then keys.size()
  for (std::size_t i = 0; i < keys.size(); ++i)
    if (i == 0 || keys[i] != keys[i - 1]) run.push_back(std::uint32_t(i));
  run.push_back(std::uint32_t(keys.size()));
  // The blocks: those within `width` voxels of a seeded block's seeded voxels (every voxel the
  // band can reach), ascending; each with its triangles, the seeded block's run or none.
  const std::size_t ns = run.size() - 1;
  std::vector<std::array<std::int64_t, 6>> near(ns);  // block range per axis: lo x y z, hi x y z
  parallel::parallel_for(0, std::int64_t(ns), [&](std::int64_t r) {
    const auto c = cell_of(keys[run[std::size_t(r)]]);
    std::int64_t v0[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, v1[3] = {INT64_MIN, INT64_MIN, INT64_MIN};
    for (std::uint32_t q = run[std::size_t(r)]; q < run[std::size_t(r) + 1]; ++q)
      for (int d = 0; d < 3; ++d) {
        const std::int64_t o = (c[std::size_t(d)] + lo[d]) * B;
        v0[d] = std::min(v0[d], std::max<std::int64_t>(tri[owner[q]].lo[d], o));
        v1[d] = std::max(v1[d], std::min<std::int64_t>(tri[owner[q]].hi[d], o + B - 1));
      }
    for (int d = 0; d < 3; ++d) {
      near[std::size_t(r)][std::size_t(d)] = floor_div(v0[d] - width, B) - lo[d];
      near[std::size_t(r)][std::size_t(d) + 3] = floor_div(v1[d] + width, B) - lo[d];
    }
  });
  std::vector<std::uint64_t> block_key;
  for (const auto& b : near)
    for (std::int64_t z = b[2]; z <= b[5]; ++z)
      for (std::int64_t y = b[1]; y <= b[4]; ++y)
        for (std::int64_t x = b[0]; x <= b[3]; ++x) block_key.push_back(key_of(x, y, z));
  std::sort(block_key.begin(), block_key.end());
  block_key.erase(std::unique(block_key.begin(), block_key.end()), block_key.end());
  const std::size_t nb = block_key.size();
  std::vector<std::array<std::uint32_t, 2>> seeds(nb, {0, 0});  // [begin, end) of its triangles
  for (std::size_t b = 0, r = 0; b < nb && r < ns; ++b) {
    if (block_key[b] != keys[run[r]]) continue;
    seeds[b] = {run[r], run[r + 1]};
    ++r;
  }
  const auto origin_of = [&](std::size_t b) {
    const auto c = cell_of(block_key[b]);
    return std::array<std::int64_t, 3>{(c[0] + lo[0]) * B, (c[1] + lo[1]) * B, (c[2] + lo[2]) * B};
  };
  // Face neighbours of each block (-1: none, so no band there).
  UninitVector<std::array<std::int32_t, 6>> next(nb);
  parallel::parallel_for(0, std::int64_t(nb), [&](std::int64_t b) {
    const auto c = cell_of(block_key[std::size_t(b)]);
    for (int f = 0; f < 6; ++f) {
      std::int64_t n[3] = {c[0], c[1], c[2]};
      n[f / 2] += f % 2 ? 1 : -1;
      const std::uint64_t nk = key_of(n[0], n[1], n[2]);
      const auto it = std::lower_bound(block_key.begin(), block_key.end(), nk);
      next[std::size_t(b)][std::size_t(f)] =
          it != block_key.end() && *it == nk ? std::int32_t(it - block_key.begin()) : -1;
    }
  });
  constexpr int V = B * B * B;
  const float none = std::numeric_limits<float>::infinity();
  // Each block's task fills its own values: no serial pass over the whole band.
  UninitVector<float> dist2(nb * V);
  UninitVector<std::int32_t> closest(nb * V);
  // 1. Seeds: each triangle's exact distance to the voxels within one voxel of its box.
  parallel::parallel_tasks(0, std::int64_t(nb), [&](std::int64_t b) {
    const auto o = origin_of(std::size_t(b));
    float* d2 = dist2.data() + std::size_t(b) * V;
    std::int32_t* cl = closest.data() + std::size_t(b) * V;
    std::fill(d2, d2 + V, none);
    std::fill(cl, cl + V, -1);
    for (std::uint32_t r = seeds[std::size_t(b)][0]; r < seeds[std::size_t(b)][1]; ++r) {
      const std::uint32_t i = owner[r];
      const Tri& t = tri[i];
      std::int64_t v0[3], v1[3];
      bool empty = false;
      for (int d = 0; d < 3; ++d) {
        v0[d] = std::max<std::int64_t>(t.lo[d], o[d]);
        v1[d] = std::min<std::int64_t>(t.hi[d], o[d] + B - 1);
        empty = empty || v0[d] > v1[d];
      }
      if (empty) continue;
      // The squared distance to the triangle's bounding box is a lower bound of its distance:
      // a voxel whose bound exceeds the distance it already has, by more than distance2's
      // rounding could make up, keeps the triangle it has without this one's exact distance.
      const auto gap2 = [&](int d, std::int64_t v) {
        const float g = std::max({t.box_lo[d] - float(v), float(v) - t.box_hi[d], 0.0f});
        return g * g;
      };
#if defined(__AVX2__) && defined(__FMA__)
      // A row of the block along z at a time, its 8 voxels in one vector; those outside
      // [v0, v1] along z, or ruled out by the bound, keep what they have.
      static_assert(B == 8);
      const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
      const __m256 in_z = _mm256_castsi256_ps(
          _mm256_and_si256(_mm256_cmpgt_epi32(lane, _mm256_set1_epi32(std::int32_t(v0[2] - o[2]) - 1)),
                           _mm256_cmpgt_epi32(_mm256_set1_epi32(std::int32_t(v1[2] - o[2]) + 1), lane)));
      const __m256 z = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(std::int32_t(o[2])), lane));
      const __m256 gz = _mm256_max_ps(
          _mm256_max_ps(_mm256_sub_ps(_mm256_set1_ps(t.box_lo[2]), z), _mm256_sub_ps(z, _mm256_set1_ps(t.box_hi[2]))),
          _mm256_setzero_ps());
      const __m256 gz2 = _mm256_mul_ps(gz, gz);
      for (std::int64_t x = v0[0]; x <= v1[0]; ++x) {
        const float gx = gap2(0, x);
        for (std::int64_t y = v0[1]; y <= v1[1]; ++y) {
          const float gxy = gx + gap2(1, y);
          const std::size_t row = std::size_t(((x - o[0]) * B + (y - o[1])) * B);
          const __m256 best = _mm256_loadu_ps(d2 + row);
          __m256 live = in_z;
          if (!exhaustive) {
            const __m256 bound = _mm256_fmadd_ps(best, _mm256_set1_ps(1 + kBoundMargin), _mm256_set1_ps(t.slack));
            live = _mm256_andnot_ps(_mm256_cmp_ps(_mm256_add_ps(_mm256_set1_ps(gxy), gz2), bound, _CMP_GT_OQ), live);
          }
          if (_mm256_testz_ps(live, live)) continue;
          const __m256 e = distance2_row(t, float(x), float(y), std::int32_t(o[2]));
          const __m256 closer = _mm256_and_ps(live, _mm256_cmp_ps(e, best, _CMP_LT_OQ));  // ties keep the lower i
          _mm256_storeu_ps(d2 + row, _mm256_blendv_ps(best, e, closer));
          const __m256 who = _mm256_loadu_ps(reinterpret_cast<const float*>(cl + row));
          _mm256_storeu_ps(reinterpret_cast<float*>(cl + row),
                           _mm256_blendv_ps(who, _mm256_castsi256_ps(_mm256_set1_epi32(std::int32_t(i))), closer));
        }
      }
#else
      for (std::int64_t x = v0[0]; x <= v1[0]; ++x) {
        const float gx = gap2(0, x);
        for (std::int64_t y = v0[1]; y <= v1[1]; ++y) {
          const float gxy = gx + gap2(1, y);
          for (std::int64_t z = v0[2]; z <= v1[2]; ++z) {
            const std::size_t at = std::size_t(((x - o[0]) * B + (y - o[1])) * B + (z - o[2]));
            if (!exhaustive && gxy + gap2(2, z) > fused(d2[at], 1 + kBoundMargin, t.slack)) continue;
            const float p[3] = {float(x), float(y), float(z)};
            const float e = distance2(t, p);
            if (e < d2[at]) d2[at] = e, cl[at] = std::int32_t(i);  // ascending i: ties keep the lower
          }
        }
      }
#endif
    }
  });
  // 2. Layers: a voxel not reached takes the nearest of its face neighbours' closest triangles.
  //    Only a voxel beside one reached in the layer before can change (the others would see the
  //    same neighbours as then): each block's voxels as 8 words of 64 bits (x; bit 8 y + z),
  //    the reached ones and the newly reached ones, whose face neighbours are the next layer's
  //    candidates. A layer reads only the previous one: its results are kept aside, then stored.
  constexpr std::uint64_t kZ0 = 0x0101010101010101ull, kZ7 = kZ0 << 7;
  UninitVector<std::array<std::uint64_t, B>> reached(nb), fresh(nb), fresh_next(nb);
  parallel::parallel_for(0, std::int64_t(nb), [&](std::int64_t b) {
    const std::int32_t* cl = closest.data() + std::size_t(b) * V;
    for (int x = 0; x < B; ++x) {
      std::uint64_t word = 0;
      for (int v = 0; v < B * B; ++v) word |= std::uint64_t(cl[x * B * B + v] >= 0) << v;
      reached[std::size_t(b)][std::size_t(x)] = fresh[std::size_t(b)][std::size_t(x)] = word;
    }
  });
  UninitVector<float> dist2_next(nb * V);
  UninitVector<std::int32_t> closest_next(nb * V);
  const float reach2 = float(width) * float(width);
  for (int layer = 0; layer < width + 1; ++layer) {
    parallel::parallel_tasks(0, std::int64_t(nb), [&](std::int64_t b) {
      const auto o = origin_of(std::size_t(b));
      const auto& nbr = next[std::size_t(b)];
      const auto word = [&](int f, int x) {  // face neighbour f's word x, 0 without one
        return nbr[std::size_t(f)] < 0 ? std::uint64_t(0) : fresh[std::size_t(nbr[std::size_t(f)])][std::size_t(x)];
      };
      const auto& mine = fresh[std::size_t(b)];
      auto& out_fresh = fresh_next[std::size_t(b)];
      for (int x = 0; x < B; ++x) {
        const std::uint64_t w = mine[std::size_t(x)];
        std::uint64_t near = ((w << 1) & ~kZ0) | ((w >> 1) & ~kZ7) | (w << B) | (w >> B);
        near |= x > 0 ? mine[std::size_t(x - 1)] : word(0, B - 1);
        near |= x < B - 1 ? mine[std::size_t(x + 1)] : word(1, 0);
        near |= word(2, x) >> (B * (B - 1));  // -y neighbour's row y = 7 beside row y = 0
        near |= word(3, x) << (B * (B - 1));  // +y neighbour's row y = 0 beside row y = 7
        near |= (word(4, x) >> (B - 1)) & kZ0;
        near |= (word(5, x) << (B - 1)) & kZ7;
        std::uint64_t todo = (exhaustive ? ~std::uint64_t(0) : near) & ~reached[std::size_t(b)][std::size_t(x)], got = 0;
        for (; todo != 0; todo &= todo - 1) {
          const int bit = __builtin_ctzll(todo), y = bit / B, z = bit % B;
          const std::size_t at = std::size_t(std::size_t(b) * V + std::size_t((x * B + y) * B + z));
          std::int32_t cand[6];
          int nc = 0;
          const int q[3] = {x, y, z};
          for (int f = 0; f < 6; ++f) {
            int n[3] = {q[0], q[1], q[2]};
            n[f / 2] += f % 2 ? 1 : -1;
            std::int64_t blk = b;
            if (n[f / 2] < 0 || n[f / 2] >= B) {
              blk = nbr[std::size_t(f)];
              if (blk < 0) continue;
              n[f / 2] = (n[f / 2] + B) % B;
            }
            const std::int32_t c = closest[std::size_t(blk) * V + std::size_t((n[0] * B + n[1]) * B + n[2])];
            if (c < 0 || std::find(cand, cand + nc, c) != cand + nc) continue;
            cand[nc++] = c;
          }
          if (nc == 0) continue;
          std::sort(cand, cand + nc);
          const float p[3] = {float(o[0] + x), float(o[1] + y), float(o[2] + z)};
          float best = none;
          std::int32_t who = -1;
          for (int k = 0; k < nc; ++k)
            if (const float e = distance2(tri[std::size_t(cand[k])], p); e < best) best = e, who = cand[k];
          if (best < reach2) dist2_next[at] = best, closest_next[at] = who, got |= std::uint64_t(1) << bit;
        }
        out_fresh[std::size_t(x)] = got;
      }
    });
    parallel::parallel_tasks(0, std::int64_t(nb), [&](std::int64_t b) {
      for (int x = 0; x < B; ++x) {
        const std::uint64_t got = fresh_next[std::size_t(b)][std::size_t(x)];
        reached[std::size_t(b)][std::size_t(x)] |= got;
        for (std::uint64_t todo = got; todo != 0; todo &= todo - 1) {
          const std::size_t at = std::size_t(b) * V + std::size_t(x * B * B + __builtin_ctzll(todo));
          dist2[at] = dist2_next[at], closest[at] = closest_next[at];
        }
      }
    });
    fresh.swap(fresh_next);
  }
  // The blocks with a voxel in the band, in block order: flagged, numbered, then copied.
  std::vector<std::uint32_t> place(nb + 1, 0);
  parallel::parallel_for(0, std::int64_t(nb), [&](std::int64_t b) {
    const float* d2 = dist2.data() + std::size_t(b) * V;
    place[std::size_t(b) + 1] = std::any_of(d2, d2 + V, [&](float e) { return e < reach2; }) ? 1 : 0;
  });
  for (std::size_t b = 0; b < nb; ++b) place[b + 1] += place[b];
  out.origin.resize(place[nb]);
  out.distance.resize(std::size_t(place[nb]) * V);
  out.triangle.resize(std::size_t(place[nb]) * V);
  parallel::parallel_tasks(0, std::int64_t(nb), [&](std::int64_t b) {
    if (place[std::size_t(b) + 1] == place[std::size_t(b)]) return;
    const std::size_t to = place[std::size_t(b)];
    const auto o = origin_of(std::size_t(b));
    out.origin[to] = {std::int32_t(o[0]), std::int32_t(o[1]), std::int32_t(o[2])};
    const float* d2 = dist2.data() + std::size_t(b) * V;
    for (int v = 0; v < V; ++v) out.distance[to * V + std::size_t(v)] = std::sqrt(d2[v]);
    std::copy_n(closest.data() + std::size_t(b) * V, V, out.triangle.data() + to * V);
  });
  return out;
}

}  // namespace slurry::io::detail
