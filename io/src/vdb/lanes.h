#pragma once
// The anisotropic field's partial sums (anisotropic.cpp): kLanes lanes added as a fixed tree.
#ifdef __AVX512F__
#include <immintrin.h>
#endif
#include <cstddef>

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

}  // namespace slurry::io::detail
