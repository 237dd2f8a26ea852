// The queued deformation update of G2P; see deformation_lanes.h.
#include "mpm/deformation_lanes.h"

#include <algorithm>

#include "mpm/lanes_io.h"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

namespace slurry::detail {

#if defined(__AVX2__) && defined(__FMA__)
void deformation_update_lanes(float dt, Eigen::Matrix3f* F, const std::int64_t* ids, const Eigen::Matrix3f* G,
                              int n) {
  constexpr int W = 8;
  const __m256 vdt = _mm256_set1_ps(dt), one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps();
  for (int j0 = 0; j0 < n; j0 += W) {
    const int count = std::min(W, n - j0);
    // Spare lanes of a short batch repeat its first particle; their results are dropped.
    float* fp[W];
    const float* gp[W];
    for (int l = 0; l < W; ++l) {
      const int j = j0 + (l < count ? l : 0);
      fp[l] = F[ids[j]].data();
      gp[l] = G[j].data();
    }
    // In registers (lanes_io.h): a transpose through memory stalled on store-to-load forwarding.
    __m256 f[9], g[9];
    load8_3x3(fp, f);
    load8_3x3(gp, g);
    __m256 a[9], r[9];
    for (int e = 0; e < 9; ++e) a[e] = _mm256_fmadd_ps(vdt, g[e], e % 4 == 0 ? one : zero);  // diagonal: 0, 4, 8
    // Entry (i, j) is e = i + 3 j. The inner pair's order of deformation_lanes.h: entry (2, 2)
    // multiplies k = 1 first, the others k = 2.
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const int first = inner_first(i, j), second = 3 - first;
        r[i + 3 * j] = _mm256_fmadd_ps(a[i], f[3 * j],
                                       _mm256_fmadd_ps(a[i + 3 * second], f[second + 3 * j],
                                                       _mm256_mul_ps(a[i + 3 * first], f[first + 3 * j])));
      }
    store8_3x3(r, fp, count);
  }
}
#endif

}  // namespace slurry::detail
