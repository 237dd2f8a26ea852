#pragma once
// Vector forms that give the plain loop's result bit for bit: the anisotropic field's partial sums
// (anisotropic.cpp), kLanes lanes added as a fixed tree, and its kernels added to a row of voxels;
// the velocity sampler's squared distances to its candidates and the list of those within its
// radius (mesh.cpp).
#if defined(__AVX512F__) || (defined(__AVX2__) && defined(__FMA__))
#include <immintrin.h>
#endif
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace slurry::io::detail {

/// a b + c, rounded once where the machine has fused multiply-adds (the roundings the vector forms
/// below reproduce), else rounded twice: a build without FMA does not call a software fma in its
/// inner loops (and its results may differ from an FMA build's in the last bits).
template <class T>
inline T fused(T a, T b, T c) {
#ifdef __FMA__
  return std::fma(a, b, c);
#else
  return a * b + c;
#endif
}

/// The neighbour sums run over every candidate in kLanes partial sums (candidate q in lane
/// q mod kLanes, a loop of whole vectors that compilers vectorize), then the lanes are added as a
/// tree in double: the same additions on any machine, whatever its vector width. kLanes is a
/// multiple of the widest vector's float lanes (16).
constexpr std::size_t kLanes = 16;
/// lane_total's tree one addition at a time (the definition; lane_total must equal it bit for bit).
inline double lane_total_scalar(const float (&lanes)[kLanes]) {
  double s[kLanes];
  for (std::size_t l = 0; l < kLanes; ++l) s[l] = double(lanes[l]);
  for (std::size_t w = kLanes / 2; w > 0; w /= 2)
    for (std::size_t l = 0; l < w; ++l) s[l] += s[l + w];
  return s[0];
}

/// The sum of kLanes lanes in double, as a tree of halving strides: s[l] += s[l + w] for l < w,
/// w = 8, 4, 2, 1.
inline double lane_total(const float (&lanes)[kLanes]) {
  static_assert(kLanes == 16);
#ifdef __AVX512F__
  // The same additions, a stride per vector operation. (The zero-masked forms with every lane
  // kept: GCC 12's unmasked ones read an "undefined" vector that -Wuninitialized reports.)
  const __mmask8 all = 0xff;
  const __m512d s8 = _mm512_add_pd(_mm512_maskz_cvtps_pd(all, _mm256_loadu_ps(lanes)),
                                   _mm512_maskz_cvtps_pd(all, _mm256_loadu_ps(lanes + 8)));
  const __m256d s4 = _mm256_add_pd(_mm512_maskz_extractf64x4_pd(all, s8, 0), _mm512_maskz_extractf64x4_pd(all, s8, 1));
  const __m128d s2 = _mm_add_pd(_mm256_castpd256_pd128(s4), _mm256_extractf128_pd(s4, 1));
  return _mm_cvtsd_f64(_mm_add_sd(s2, _mm_unpackhi_pd(s2, s2)));
#else
  return lane_total_scalar(lanes);
#endif
}

/// The indices j of [0, m) with value[j] < limit, ascending, in out[0, k), one value at a time
/// without branches; returns k. `out` holds m entries.
inline std::size_t list_below(const double* value, std::size_t m, double limit, std::uint32_t* out) {
  std::size_t k = 0;
  for (std::size_t j = 0; j < m; ++j) {
    out[k] = std::uint32_t(j);
    k += value[j] < limit ? 1 : 0;
  }
  return k;
}

/// splat_row one voxel at a time (the definition; splat_row must equal it bit for bit).
inline void splat_row_scalar(float* row, std::int32_t origin, int first, int last, float centre, const float (&a)[3],
                             const float (&m)[3], float weight) {
  for (int l = first; l <= last; ++l) {
    const float dz = float(origin + l) - centre;
    const float q0 = fused(m[0], dz, a[0]), q1 = fused(m[1], dz, a[1]), q2 = fused(m[2], dz, a[2]);
    const float q = fused(q2, q2, fused(q0, q0, q1 * q1));
    if (q < 1.0f) {
      const float t = 1.0f - q;
      row[l] = fused(weight * t * t, t, row[l]);
    }
  }
}

/// A kernel added to a row of 8 voxels along z (the anisotropic field's blocks, anisotropic.cpp):
/// voxel l of [first, last] (within [0, 8)), at index z = origin + l, gets weight (1 - q)^3 where
/// q = |a + (z - centre) m|^2 < 1; the roundings spelled out: dz = float(z) - centre,
/// q_k = fma(m_k, dz, a_k), q = fma(q2, q2, fma(q0, q0, q1 q1)), row[l] = fma(weight t t, t, row[l])
/// with t = 1 - q.
inline void splat_row(float* row, std::int32_t origin, int first, int last, float centre, const float (&a)[3],
                      const float (&m)[3], float weight) {
#if defined(__AVX2__) && defined(__FMA__)
  // The 8 voxels in one vector; those outside [first, last] or the ellipsoid keep their value.
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 dz =
      _mm256_sub_ps(_mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(origin), lane)), _mm256_set1_ps(centre));
  const __m256 one = _mm256_set1_ps(1.0f);
  const __m256 q0 = _mm256_fmadd_ps(_mm256_set1_ps(m[0]), dz, _mm256_set1_ps(a[0]));
  const __m256 q1 = _mm256_fmadd_ps(_mm256_set1_ps(m[1]), dz, _mm256_set1_ps(a[1]));
  const __m256 q2 = _mm256_fmadd_ps(_mm256_set1_ps(m[2]), dz, _mm256_set1_ps(a[2]));
  const __m256 q = _mm256_fmadd_ps(q2, q2, _mm256_fmadd_ps(q0, q0, _mm256_mul_ps(q1, q1)));
  const __m256 t = _mm256_sub_ps(one, q);
  const __m256i in_range = _mm256_and_si256(_mm256_cmpgt_epi32(lane, _mm256_set1_epi32(first - 1)),
                                            _mm256_cmpgt_epi32(_mm256_set1_epi32(last + 1), lane));
  const __m256 in = _mm256_and_ps(_mm256_castsi256_ps(in_range), _mm256_cmp_ps(q, one, _CMP_LT_OQ));
  const __m256 value = _mm256_loadu_ps(row);
  const __m256 sum = _mm256_fmadd_ps(_mm256_mul_ps(_mm256_mul_ps(_mm256_set1_ps(weight), t), t), t, value);
  _mm256_storeu_ps(row, _mm256_blendv_ps(value, sum, in));
#else
  splat_row_scalar(row, origin, first, last, centre, a, m, weight);
#endif
}

/// The squared distance list_within computes: the differences in float, widened to double, squared
/// and added. The square of a float is exact in double, so the sum rounds alike whether or not a
/// compiler (or the vector form) fuses the multiplications into the additions.
inline double within_norm2(float px, float py, float pz, const float (&q)[3]) {
  const double dx = px - q[0], dy = py - q[1], dz = pz - q[2];
  return dx * dx + dy * dy + dz * dz;
}

/// list_within one candidate at a time (the definition; list_within must equal it bit for bit).
inline std::size_t list_within_scalar(const float* px, const float* py, const float* pz, std::size_t m,
                                      const float (&q)[3], double limit, double* r2, std::uint32_t* out) {
  for (std::size_t j = 0; j < m; ++j) r2[j] = within_norm2(px[j], py[j], pz[j], q);
  return list_below(r2, m, limit, out);
}

/// The squared distances r2[0, m) from q to the points (px, py, pz)[0, m) (within_norm2), and the
/// indices of those below limit, ascending, in out[0, k); returns k. `out` holds m + 8 entries.
inline std::size_t list_within(const float* px, const float* py, const float* pz, std::size_t m,
                               const float (&q)[3], double limit, double* r2, std::uint32_t* out) {
#if defined(__AVX512F__) && defined(__AVX512VL__)
  // Eight points a vector, the last one partly masked.
  const __m256 qx = _mm256_set1_ps(q[0]), qy = _mm256_set1_ps(q[1]), qz = _mm256_set1_ps(q[2]);
  const __m512d below = _mm512_set1_pd(limit);
  const __m256i eight = _mm256_set1_epi32(8);
  __m256i index = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  std::size_t k = 0;
  for (std::size_t j = 0; j < m; j += 8) {
    const __mmask8 live = m - j >= 8 ? __mmask8(0xff) : __mmask8((1u << (m - j)) - 1);
    const __m512d dx = _mm512_cvtps_pd(_mm256_sub_ps(_mm256_maskz_loadu_ps(live, px + j), qx));
    const __m512d dy = _mm512_cvtps_pd(_mm256_sub_ps(_mm256_maskz_loadu_ps(live, py + j), qy));
    const __m512d dz = _mm512_cvtps_pd(_mm256_sub_ps(_mm256_maskz_loadu_ps(live, pz + j), qz));
    const __m512d d2 = _mm512_fmadd_pd(dz, dz, _mm512_fmadd_pd(dx, dx, _mm512_mul_pd(dy, dy)));
    _mm512_mask_storeu_pd(r2 + j, live, d2);
    const __mmask8 in = _mm512_mask_cmp_pd_mask(live, d2, below, _CMP_LT_OQ);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + k), _mm256_maskz_compress_epi32(in, index));
    k += std::size_t(__builtin_popcount(unsigned(in)));
    index = _mm256_add_epi32(index, eight);
  }
  return k;
#else
  return list_within_scalar(px, py, pz, m, q, limit, r2, out);
#endif
}

}  // namespace slurry::io::detail
