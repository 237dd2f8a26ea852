// The batched fixed corotated stress of P2G; see corotated_lanes.h.
#include "corotated_lanes.h"

#include <algorithm>
#include <type_traits>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fixed_corotated_lanes.h"

namespace slurry::detail {

template <class T, int Dim>
void fixed_corotated_stress_lanes(T mu, T lambda, const T* factor, T dt, const std::uint32_t* order,
                                  std::uint32_t begin, std::uint32_t end,
                                  const Eigen::Matrix<T, Dim, Dim>* F, const T* vol0,
                                  std::size_t vol0_mask, Eigen::Matrix<T, Dim, Dim>* K) {
  namespace lanes = constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  using MatL = std::conditional_t<Dim == 3, lanes::Mat3<T, W>, lanes::Mat2<T, W>>;
  MatL Fl, tau;
  lanes::Lane<T, W> mul, lambdal;
#if defined(__SSE2__)
  if constexpr (std::is_same_v<T, float> && W % 4 == 0) {
    // Float: four particles at a time, one 4x4 transpose per 4 entries of their matrices
    // (column-major, entry e is (e % Dim, e / Dim)) into the lanes, and back for K, which is
    // contiguous in i; the ninth entry of a 3x3 is gathered by itself. Copied one scalar at a
    // time, each batch's lanes were read back as vectors before the stores had landed (a third of
    // the 3D stress time). The arithmetic is the generic loop's, lane for lane.
    constexpr int E = Dim * Dim, E4 = E / 4;
    auto lane = [](MatL& m, int e) { return m.a[e % Dim][e / Dim].data(); };
    for (auto i0 = begin; i0 < end; i0 += W) {
      const int count = int(std::min<std::uint32_t>(W, end - i0));
      for (int g = 0; g < W; g += 4) {
        const float* f[4];
        for (int k = 0; k < 4; ++k) f[k] = F[order[i0 + (g + k < count ? g + k : 0)]].data();
        for (int q = 0; q < E4; ++q) {
          __m128 r[4];
          for (int k = 0; k < 4; ++k) r[k] = _mm_loadu_ps(f[k] + 4 * q);
          _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
          for (int e = 0; e < 4; ++e) _mm_storeu_ps(lane(Fl, 4 * q + e) + g, r[e]);
        }
        if constexpr (E % 4 == 1) _mm_storeu_ps(lane(Fl, E - 1) + g, _mm_setr_ps(f[0][E - 1], f[1][E - 1], f[2][E - 1], f[3][E - 1]));
      }
      lanes::Lane<T, W> scale;
      for (int l = 0; l < W; ++l) {
        const auto i = i0 + (l < count ? l : 0);
        mul[l] = factor ? mu * factor[i - begin] : mu;
        lambdal[l] = factor ? lambda * factor[i - begin] : lambda;
        scale[l] = -dt * vol0[order[i] & vol0_mask];
      }
      const auto scalar = lanes::fixed_corotated_kirchhoff(Fl, mul, lambdal, tau);
      for (int g = 0; g < count; g += 4) {
        const __m128 sc = _mm_loadu_ps(scale.data() + g);
        for (int q = 0; q < E4; ++q) {
          __m128 r[4];
          for (int e = 0; e < 4; ++e) r[e] = _mm_mul_ps(sc, _mm_loadu_ps(lane(tau, 4 * q + e) + g));
          _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
          for (int k = 0; k < 4 && g + k < count; ++k) _mm_storeu_ps(K[i0 + g + k - begin].data() + 4 * q, r[k]);
        }
        if constexpr (E % 4 == 1) {
          alignas(16) float last[4];
          _mm_store_ps(last, _mm_mul_ps(sc, _mm_loadu_ps(lane(tau, E - 1) + g)));
          for (int k = 0; k < 4 && g + k < count; ++k) K[i0 + g + k - begin].data()[E - 1] = last[k];
        }
      }
      for (int l = 0; l < count; ++l)
        if (scalar.bits[l] != T(0)) {
          const auto p = order[i0 + l];
          K[i0 + l - begin] =
              (-dt * vol0[p & vol0_mask]) *
              constitutive::FixedCorotated<T, Dim>{mul[l], lambdal[l]}.kirchhoff(F[p]);
        }
    }
    return;
  }
#endif
  for (auto i0 = begin; i0 < end; i0 += W) {
    const int count = int(std::min<std::uint32_t>(W, end - i0));
    for (int l = 0; l < W; ++l) {
      const auto i = i0 + (l < count ? l : 0);
      Fl.put(l, F[order[i]]);
      mul[l] = factor ? mu * factor[i - begin] : mu;
      lambdal[l] = factor ? lambda * factor[i - begin] : lambda;
    }
    const auto scalar = lanes::fixed_corotated_kirchhoff(Fl, mul, lambdal, tau);
    for (int l = 0; l < count; ++l) {
      const auto p = order[i0 + l];
      const Eigen::Matrix<T, Dim, Dim> t =
          scalar.bits[l] != T(0)
              ? constitutive::FixedCorotated<T, Dim>{mul[l], lambdal[l]}.kirchhoff(F[p])
              : tau.get(l);
      K[i0 + l - begin] = (-dt * vol0[p & vol0_mask]) * t;
    }
  }
}

SLURRY_COROTATED_LANES_FOR_EACH(SLURRY_COROTATED_LANES_INSTANCE)

}  // namespace slurry::detail
