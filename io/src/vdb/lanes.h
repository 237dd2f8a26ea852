#pragma once
// Vector forms that give the plain loop's result bit for bit: the anisotropic field's partial sums
// (anisotropic.cpp), kLanes lanes added as a fixed tree; the velocity sampler's list of the
// candidates within its radius (mesh.cpp).
#ifdef __AVX512F__
#include <immintrin.h>
#endif
#include <cstddef>
#include <cstdint>

namespace slurry::io::detail {

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

/// list_below one value at a time (the definition; list_below must equal it).
inline std::size_t list_below_scalar(const double* value, std::size_t m, double limit, std::uint32_t* out,
                                     std::uint32_t first = 0) {
  std::size_t k = 0;
  for (std::size_t j = 0; j < m; ++j) {
    out[k] = first + std::uint32_t(j);
    k += value[j] < limit ? 1 : 0;
  }
  return k;
}

/// The indices j of [0, m) with value[j] < limit, ascending, in out[0, k); returns k. `out`
/// holds m + 8 entries (past k it holds anything).
inline std::size_t list_below(const double* value, std::size_t m, double limit, std::uint32_t* out) {
#if defined(__AVX512F__) && defined(__AVX512VL__)
  // Eight values a vector: their indices where below, compressed in a register and stored whole
  // (the tail is overwritten by the next); the rest one at a time.
  const __m512d below = _mm512_set1_pd(limit);
  const __m256i eight = _mm256_set1_epi32(8);
  __m256i index = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  std::size_t k = 0, j = 0;
  for (; j + 8 <= m; j += 8) {
    const __mmask8 in = _mm512_cmp_pd_mask(_mm512_loadu_pd(value + j), below, _CMP_LT_OQ);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + k), _mm256_maskz_compress_epi32(in, index));
    k += std::size_t(__builtin_popcount(unsigned(in)));
    index = _mm256_add_epi32(index, eight);
  }
  return k + list_below_scalar(value + j, m - j, limit, out + k, std::uint32_t(j));
#else
  return list_below_scalar(value, m, limit, out);
#endif
}

}  // namespace slurry::io::detail
