#pragma once
/// \file lanes_io.h
/// Particles' Dim x Dim matrices into the lanes of a lanes::Mat2 / lanes::Mat3 (entry (i, j) of
/// W matrices in a[i][j]) and back, for the batched stress of P2G (corotated_lanes.cpp,
/// sand_lanes.cpp). In float, four matrices at a time: one 4x4 transpose per 4 entries
/// (column-major, entry e is (e % Dim, e / Dim)), the ninth entry of a 3x3 gathered by itself.
/// Also load8_3x3 and store8_3x3, eight 3x3 float matrices to and from registers by 8x8
/// transposes, for G2P's queued deformation update (deformation_lanes.cpp). Used for the
/// stress's lanes too (one 16-lane store per entry), they measured no faster: those loads wait
/// on memory, not on forwarding.
/// Copied one scalar at a time, a batch's lanes were read back as vectors before the scalar
/// stores had landed (store-to-load forwarding stalls: a third of the 3D stress time). The values
/// are the same either way.
#include <Eigen/Core>

#include <type_traits>
#include <utility>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

namespace slurry::detail {

/// The scalar and width of a lanes matrix, and whether its float transposes apply.
template <class MatL>
struct LanesOf {
  using Lane = std::decay_t<decltype(std::declval<MatL&>().a[0][0])>;
  using T = typename Lane::Scalar;
  static constexpr int W = Lane::RowsAtCompileTime;
  static constexpr bool transposed = std::is_same_v<T, float> && W % 4 == 0;
};
/// The lanes of column-major entry e of a Dim x Dim matrix: (e % Dim, e / Dim).
template <int Dim, class MatL>
inline auto* entry_lanes(MatL& L, int e) {
  return L.a[e % Dim][e / Dim].data();
}

#if defined(__AVX__)
/// r[k] <- column k of the 8x8 matrix whose rows are r[0..7].
inline void transpose8(__m256* r) {
  const __m256 t0 = _mm256_unpacklo_ps(r[0], r[1]), t1 = _mm256_unpackhi_ps(r[0], r[1]);
  const __m256 t2 = _mm256_unpacklo_ps(r[2], r[3]), t3 = _mm256_unpackhi_ps(r[2], r[3]);
  const __m256 t4 = _mm256_unpacklo_ps(r[4], r[5]), t5 = _mm256_unpackhi_ps(r[4], r[5]);
  const __m256 t6 = _mm256_unpacklo_ps(r[6], r[7]), t7 = _mm256_unpackhi_ps(r[6], r[7]);
  const __m256 s0 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 s1 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 s2 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 s3 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 s4 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 s5 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 s6 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 s7 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(3, 2, 3, 2));
  r[0] = _mm256_permute2f128_ps(s0, s4, 0x20);
  r[1] = _mm256_permute2f128_ps(s1, s5, 0x20);
  r[2] = _mm256_permute2f128_ps(s2, s6, 0x20);
  r[3] = _mm256_permute2f128_ps(s3, s7, 0x20);
  r[4] = _mm256_permute2f128_ps(s0, s4, 0x31);
  r[5] = _mm256_permute2f128_ps(s1, s5, 0x31);
  r[6] = _mm256_permute2f128_ps(s2, s6, 0x31);
  r[7] = _mm256_permute2f128_ps(s3, s7, 0x31);
}
/// e[k] <- entry k (column-major) of the 3x3 float matrices m[0..7], in registers: entries 0-7
/// by one 8x8 transpose of 32-byte loads (within each 36-byte matrix), entry 8 gathered.
inline void load8_3x3(const float* const* m, __m256* e) {
  for (int k = 0; k < 8; ++k) e[k] = _mm256_loadu_ps(m[k]);
  transpose8(e);
  e[8] = _mm256_setr_ps(m[0][8], m[1][8], m[2][8], m[3][8], m[4][8], m[5][8], m[6][8], m[7][8]);
}
/// The inverse of load8_3x3 for the first count matrices (e is overwritten).
inline void store8_3x3(__m256* e, float* const* m, int count) {
  alignas(32) float last[8];
  _mm256_store_ps(last, e[8]);
  transpose8(e);
  for (int k = 0; k < count; ++k) {
    _mm256_storeu_ps(m[k], e[k]);
    m[k][8] = last[k];
  }
}
#endif

/// Lane k of L <- *src(k), k < W (src(k) a pointer to a Dim x Dim matrix).
template <int Dim, class MatL, class Src>
inline void load_lanes(MatL& L, Src&& src) {
  constexpr int W = LanesOf<MatL>::W;
#if defined(__SSE2__)
  if constexpr (LanesOf<MatL>::transposed) {
    constexpr int E = Dim * Dim;
    for (int g = 0; g < W; g += 4) {
      const float* f[4];
      for (int k = 0; k < 4; ++k) f[k] = src(g + k)->data();
      for (int q = 0; q < E / 4; ++q) {
        __m128 r[4];
        for (int k = 0; k < 4; ++k) r[k] = _mm_loadu_ps(f[k] + 4 * q);
        _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
        for (int e = 0; e < 4; ++e) _mm_storeu_ps(entry_lanes<Dim>(L, 4 * q + e) + g, r[e]);
      }
      if constexpr (E % 4 == 1)
        _mm_storeu_ps(entry_lanes<Dim>(L, E - 1) + g, _mm_setr_ps(f[0][E - 1], f[1][E - 1], f[2][E - 1], f[3][E - 1]));
    }
    return;
  }
#endif
  for (int k = 0; k < W; ++k) L.put(k, *src(k));
}

/// *dst(k) <- scale[k] * (lane k of L), or lane k itself when scale is null, for k < count.
template <int Dim, class MatL, class Dst>
inline void store_lanes(const MatL& L, const typename LanesOf<MatL>::T* scale, int count, Dst&& dst) {
#if defined(__SSE2__)
  if constexpr (LanesOf<MatL>::transposed) {
    constexpr int E = Dim * Dim;
    auto lane = [&](int e, int g) {
      const __m128 v = _mm_loadu_ps(entry_lanes<Dim>(L, e) + g);
      return scale ? _mm_mul_ps(_mm_loadu_ps(scale + g), v) : v;
    };
    for (int g = 0; g < count; g += 4) {
      float* d[4];
      for (int k = 0; k < 4 && g + k < count; ++k) d[k] = dst(g + k)->data();
      for (int q = 0; q < E / 4; ++q) {
        __m128 r[4];
        for (int e = 0; e < 4; ++e) r[e] = lane(4 * q + e, g);
        _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
        for (int k = 0; k < 4 && g + k < count; ++k) _mm_storeu_ps(d[k] + 4 * q, r[k]);
      }
      if constexpr (E % 4 == 1) {
        alignas(16) float last[4];
        _mm_store_ps(last, lane(E - 1, g));
        for (int k = 0; k < 4 && g + k < count; ++k) d[k][E - 1] = last[k];
      }
    }
    return;
  }
#endif
  for (int k = 0; k < count; ++k) {
    if (scale)
      *dst(k) = scale[k] * L.get(k);
    else
      *dst(k) = L.get(k);
  }
}

}  // namespace slurry::detail
