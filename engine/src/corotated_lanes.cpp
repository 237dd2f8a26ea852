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
  if constexpr (Dim == 2 && std::is_same_v<T, float> && W % 4 == 0) {
    // 2D float: a 2x2 F is one 4-float vector (column-major: f00, f10, f01, f11), so four
    // particles are one 4x4 transpose into the lanes, and four K's one transpose back and four
    // stores (K is contiguous in i). The arithmetic is the generic loop's, lane for lane.
    for (auto i0 = begin; i0 < end; i0 += W) {
      const int count = int(std::min<std::uint32_t>(W, end - i0));
      for (int g = 0; g < W; g += 4) {
        __m128 r[4];
        for (int k = 0; k < 4; ++k) {
          const auto i = i0 + (g + k < count ? g + k : 0);
          r[k] = _mm_loadu_ps(F[order[i]].data());
        }
        _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
        _mm_storeu_ps(Fl.a[0][0].data() + g, r[0]);
        _mm_storeu_ps(Fl.a[1][0].data() + g, r[1]);
        _mm_storeu_ps(Fl.a[0][1].data() + g, r[2]);
        _mm_storeu_ps(Fl.a[1][1].data() + g, r[3]);
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
        __m128 r[4] = {_mm_mul_ps(sc, _mm_loadu_ps(tau.a[0][0].data() + g)),
                       _mm_mul_ps(sc, _mm_loadu_ps(tau.a[1][0].data() + g)),
                       _mm_mul_ps(sc, _mm_loadu_ps(tau.a[0][1].data() + g)),
                       _mm_mul_ps(sc, _mm_loadu_ps(tau.a[1][1].data() + g))};
        _MM_TRANSPOSE4_PS(r[0], r[1], r[2], r[3]);
        for (int k = 0; k < 4 && g + k < count; ++k)
          _mm_storeu_ps(K[i0 + g + k - begin].data(), r[k]);
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
