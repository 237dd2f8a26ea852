#pragma once
// The squared distance from a point to a triangle (the narrow band of mesh_band.cpp), one point at
// a time and for a row of 8 points along z in one vector (AVX2 + FMA), bit for bit the same: the
// closest point by the Voronoi regions of the triangle's vertices, edges and face (Ericson,
// Real-Time Collision Detection, 2005, 5.1.5), in index space (voxel units), in float. The
// roundings are spelled out as fused operations: a dot product u.v is fma(u2, v2, fma(u0, v0,
// u1 v1)), a point on an edge p - t e is fma(-t, e, p) per axis (fused, lanes.h: without FMA
// hardware, rounded twice).
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif
#include <cmath>
#include <cstdint>

#include "vdb/lanes.h"

namespace slurry::io::detail {

/// A triangle in index space.
struct Tri {
  float a[3], b[3], c[3];
  float box_lo[3], box_hi[3];  ///< the bounding box
  std::int32_t lo[3], hi[3];   ///< voxels within one voxel of the bounding box
  float slack;                 ///< the bound's absolute margin (mesh_band.cpp)
};

/// u.v with u2 v2 and u0 v0 fused.
inline float dot3(float u0, float u1, float u2, float v0, float v1, float v2) {
  return fused(u2, v2, fused(u0, v0, u1 * v1));
}

/// The squared distance from p to the triangle (the definition; distance2_row must equal it bit
/// for bit).
inline float distance2(const Tri& t, const float p[3]) {
  float ab[3], ac[3], ap[3], bp[3], cp[3];
  for (int d = 0; d < 3; ++d) {
    ab[d] = t.b[d] - t.a[d], ac[d] = t.c[d] - t.a[d];
    ap[d] = p[d] - t.a[d], bp[d] = p[d] - t.b[d], cp[d] = p[d] - t.c[d];
  }
  const auto dot = [](const float* u, const float* v) { return dot3(u[0], u[1], u[2], v[0], v[1], v[2]); };
  // |p - s e|^2 for the point p - s e of an edge e from p's offset to its start.
  const auto along = [](const float* p, float s, const float* e) {
    const float x = fused(-s, e[0], p[0]), y = fused(-s, e[1], p[1]), z = fused(-s, e[2], p[2]);
    return dot3(x, y, z, x, y, z);
  };
  const float d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return dot(ap, ap);
  const float d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return dot(bp, bp);
  const float vc = fused(d1, d4, -(d3 * d2));
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return along(ap, d1 / (d1 - d3), ab);
  const float d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return dot(cp, cp);
  const float vb = fused(d5, d2, -(d1 * d6));
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return along(ap, d2 / (d2 - d6), ac);
  const float va = fused(d3, d6, -(d5 * d4));
  if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
    const float bc[3] = {t.c[0] - t.b[0], t.c[1] - t.b[1], t.c[2] - t.b[2]};
    return along(bp, (d4 - d3) / ((d4 - d3) + (d5 - d6)), bc);
  }
  const float sum = va + vb + vc;
  if (!(sum > 0)) {  // degenerate: the nearest vertex
    const float a2 = dot(ap, ap), b2 = dot(bp, bp), c2 = dot(cp, cp);
    const float m = b2 < a2 ? b2 : a2;
    return c2 < m ? c2 : m;
  }
  const float v = vb / sum, w = vc / sum;
  const float x = fused(-ac[0], w, fused(-ab[0], v, ap[0]));
  const float y = fused(-ac[1], w, fused(-ab[1], v, ap[1]));
  const float z = fused(-ac[2], w, fused(-ab[2], v, ap[2]));
  return dot3(x, y, z, x, y, z);
}

#if defined(__AVX2__) && defined(__FMA__)
/// distance2 for the 8 points (px, py, z0 + l), l = 0..7, one lane each: every region's
/// distance computed, then the one distance2's tests choose, in their order.
inline __m256 distance2_row(const Tri& t, float px, float py, std::int32_t z0) {
  const float ab[3] = {t.b[0] - t.a[0], t.b[1] - t.a[1], t.b[2] - t.a[2]};
  const float ac[3] = {t.c[0] - t.a[0], t.c[1] - t.a[1], t.c[2] - t.a[2]};
  const float bc[3] = {t.c[0] - t.b[0], t.c[1] - t.b[1], t.c[2] - t.b[2]};
  // The x and y parts of each offset and dot product are the row's, the same in every lane.
  const float ap0 = px - t.a[0], ap1 = py - t.a[1], bp0 = px - t.b[0], bp1 = py - t.b[1], cp0 = px - t.c[0],
              cp1 = py - t.c[1];
  const __m256 z = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(z0), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7)));
  const __m256 ap2 = _mm256_sub_ps(z, _mm256_set1_ps(t.a[2])), bp2 = _mm256_sub_ps(z, _mm256_set1_ps(t.b[2])),
               cp2 = _mm256_sub_ps(z, _mm256_set1_ps(t.c[2]));
  const auto dot = [](float u0, float u1, float u2, float v0, float v1, __m256 v2) {
    return _mm256_fmadd_ps(_mm256_set1_ps(u2), v2, _mm256_set1_ps(fused(u0, v0, u1 * v1)));
  };
  const auto norm2 = [](float x, float y, __m256 z2) {
    return _mm256_fmadd_ps(z2, z2, _mm256_set1_ps(fused(x, x, y * y)));
  };
  const auto fnmadd = [](__m256 a, __m256 b, __m256 c) { return _mm256_fnmadd_ps(a, b, c); };
  const auto set = [](float a) { return _mm256_set1_ps(a); };
  // |p - s e|^2 (x and y broadcast).
  const auto along = [&](float p0, float p1, __m256 p2, __m256 s, const float* e) {
    const __m256 x = fnmadd(s, set(e[0]), set(p0)), y = fnmadd(s, set(e[1]), set(p1)), zz = fnmadd(s, set(e[2]), p2);
    return _mm256_fmadd_ps(zz, zz, _mm256_fmadd_ps(x, x, _mm256_mul_ps(y, y)));
  };
  const __m256 zero = _mm256_setzero_ps();
  const auto le = [](__m256 a, __m256 b) { return _mm256_cmp_ps(a, b, _CMP_LE_OQ); };
  const auto ge = [](__m256 a, __m256 b) { return _mm256_cmp_ps(a, b, _CMP_GE_OQ); };
  const auto both = [](__m256 a, __m256 b) { return _mm256_and_ps(a, b); };
  const __m256 d1 = dot(ab[0], ab[1], ab[2], ap0, ap1, ap2), d2 = dot(ac[0], ac[1], ac[2], ap0, ap1, ap2);
  const __m256 d3 = dot(ab[0], ab[1], ab[2], bp0, bp1, bp2), d4 = dot(ac[0], ac[1], ac[2], bp0, bp1, bp2);
  const __m256 d5 = dot(ab[0], ab[1], ab[2], cp0, cp1, cp2), d6 = dot(ac[0], ac[1], ac[2], cp0, cp1, cp2);
  const __m256 vc = _mm256_fmsub_ps(d1, d4, _mm256_mul_ps(d3, d2));
  const __m256 vb = _mm256_fmsub_ps(d5, d2, _mm256_mul_ps(d1, d6));
  const __m256 va = _mm256_fmsub_ps(d3, d6, _mm256_mul_ps(d5, d4));
  const __m256 a2 = norm2(ap0, ap1, ap2), b2 = norm2(bp0, bp1, bp2), c2 = norm2(cp0, cp1, cp2);
  const __m256 e43 = _mm256_sub_ps(d4, d3), e56 = _mm256_sub_ps(d5, d6);
  const __m256 sum = _mm256_add_ps(_mm256_add_ps(va, vb), vc);
  // The face, then each earlier test's region over it, the first test last.
  const __m256 v = _mm256_div_ps(vb, sum), w = _mm256_div_ps(vc, sum);
  const __m256 fx = fnmadd(set(ac[0]), w, fnmadd(set(ab[0]), v, set(ap0)));
  const __m256 fy = fnmadd(set(ac[1]), w, fnmadd(set(ab[1]), v, set(ap1)));
  const __m256 fz = fnmadd(set(ac[2]), w, fnmadd(set(ab[2]), v, ap2));
  __m256 r = _mm256_fmadd_ps(fz, fz, _mm256_fmadd_ps(fx, fx, _mm256_mul_ps(fy, fy)));
  r = _mm256_blendv_ps(r, _mm256_min_ps(c2, _mm256_min_ps(b2, a2)), _mm256_cmp_ps(sum, zero, _CMP_NGT_UQ));
  r = _mm256_blendv_ps(r, along(bp0, bp1, bp2, _mm256_div_ps(e43, _mm256_add_ps(e43, e56)), bc),
                       both(le(va, zero), both(ge(e43, zero), ge(e56, zero))));
  r = _mm256_blendv_ps(r, along(ap0, ap1, ap2, _mm256_div_ps(d2, _mm256_sub_ps(d2, d6)), ac),
                       both(le(vb, zero), both(ge(d2, zero), le(d6, zero))));
  r = _mm256_blendv_ps(r, c2, both(ge(d6, zero), le(d5, d6)));
  r = _mm256_blendv_ps(r, along(ap0, ap1, ap2, _mm256_div_ps(d1, _mm256_sub_ps(d1, d3)), ab),
                       both(le(vc, zero), both(ge(d1, zero), le(d3, zero))));
  r = _mm256_blendv_ps(r, b2, both(ge(d3, zero), le(d4, d3)));
  return _mm256_blendv_ps(r, a2, both(le(d1, zero), le(d2, zero)));
}
#endif

}  // namespace slurry::io::detail
