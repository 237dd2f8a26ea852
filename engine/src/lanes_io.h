#pragma once
/// \file lanes_io.h
/// Particles' Dim x Dim matrices into the lanes of a lanes::Mat2 / lanes::Mat3 (entry (i, j) of
/// W matrices in a[i][j]) and back, for the batched stress of P2G (corotated_lanes.cpp,
/// sand_lanes.cpp). In float, four matrices at a time: one 4x4 transpose per 4 entries
/// (column-major, entry e is (e % Dim, e / Dim)), the ninth entry of a 3x3 gathered by itself.
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
