// The kernels of kernel_shape.h, one particle at a time or four in a vector of doubles (AVX2).
// This file is compiled without contraction (-ffp-contract=off): a product is fused into a sum
// only where a fused operation says so (without FMA hardware, the one-particle form rounds those
// twice), and the roundings below are those of Eigen 3.4's 3 x 3 inverse (cofactors), Frobenius
// norms (pairs of entries, then their sum) and unblocked LLT as g++ 12 compiles them with FMA (its
// contraction included), so that the kernels are the ones those routines give.
#include "vdb/kernel_shape.h"

#include <cmath>

#include "vdb/lanes.h"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

namespace slurry::io::detail {

void NeighbourSums::resize(std::size_t n) {
  W.resize(n);
  for (auto& v : m) v.resize(n);
  for (auto& v : s) v.resize(n);
  for (auto& v : x) v.resize(n);
  neighbours.resize(n);
  index.resize(n);
  for (auto& v : mean) v.resize(n);
  shaped.resize(n);
}

namespace {

/// One particle: doubles and bools.
struct One {
  using D = double;
  using M = bool;
  static constexpr std::size_t kWidth = 1;
  static D set(double a) { return a; }
  static D load(const double* p) { return *p; }
  static D load(const float* p) { return double(*p); }
  static D load(const std::int32_t* p) { return double(*p); }
  static void store(double* p, D a) { *p = a; }
  static D fma(D a, D b, D c) { return fused(a, b, c); }
  static D sqrt(D a) { return std::sqrt(a); }
  static D abs(D a) { return std::fabs(a); }
  static D lesser(D a, D b) { return a < b ? a : b; }   ///< a when a < b, else b
  static D greater(D a, D b) { return a > b ? a : b; }  ///< a when a > b, else b
  static M gt(D a, D b) { return a > b; }               ///< false when either is NaN
  static M ge(D a, D b) { return a >= b; }
  static M le(D a, D b) { return a <= b; }
  static M not_le(D a, D b) { return !(a <= b); }  ///< true when either is NaN
  static M both(M a, M b) { return a && b; }
  static unsigned bits(M a) { return a ? 1u : 0u; }
};

#if defined(__AVX2__) && defined(__FMA__)
/// Four particles: a vector of doubles each, the masks as vectors of all-ones lanes.
struct Four {
  using D = __m256d;
  using M = __m256d;
  static constexpr std::size_t kWidth = 4;
  static D set(double a) { return _mm256_set1_pd(a); }
  static D load(const double* p) { return _mm256_loadu_pd(p); }
  static D load(const float* p) { return _mm256_cvtps_pd(_mm_loadu_ps(p)); }
  static D load(const std::int32_t* p) {
    return _mm256_cvtepi32_pd(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  }
  static void store(double* p, D a) { _mm256_storeu_pd(p, a); }
  static D fma(D a, D b, D c) { return _mm256_fmadd_pd(a, b, c); }
  static D sqrt(D a) { return _mm256_sqrt_pd(a); }
  static D abs(D a) { return _mm256_andnot_pd(_mm256_set1_pd(-0.0), a); }
  static D lesser(D a, D b) { return _mm256_min_pd(a, b); }   // a < b ? a : b, lane by lane
  static D greater(D a, D b) { return _mm256_max_pd(a, b); }  // a > b ? a : b
  static M gt(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_GT_OQ); }
  static M ge(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_GE_OQ); }
  static M le(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_LE_OQ); }
  static M not_le(D a, D b) { return _mm256_cmp_pd(a, b, _CMP_NLE_UQ); }
  static M both(M a, M b) { return _mm256_and_pd(a, b); }
  static unsigned bits(M a) { return unsigned(_mm256_movemask_pd(a)); }
};
#endif

/// Particles [p, p + L::kWidth) of `sums`.
template <class L>
void shape(NeighbourSums& sums, std::size_t p, const ShapeConstants& k, Kernel* kernels) {
  using D = typename L::D;
  using M = typename L::M;
  constexpr std::size_t w = L::kWidth;
  const D W = L::load(&sums.W[p]);
  D mean[3];
  for (int a = 0; a < 3; ++a) {
    mean[a] = L::load(&sums.m[a][p]) / W;
    L::store(&sums.mean[a][p], mean[a]);
  }
  double centre[3][w];
  for (int a = 0; a < 3; ++a) L::store(centre[a], L::fma(L::set(k.smoothing), mean[a], L::load(&sums.x[a][p])));
  for (std::size_t l = 0; l < w; ++l)
    for (int a = 0; a < 3; ++a) kernels[sums.index[p + l]].centre[std::size_t(a)] = float(centre[a][l]);

  // The covariance: c_ab = s_ab / W - mean_a mean_b, the product fused.
  const D c00 = L::fma(-mean[0], mean[0], L::load(&sums.s[0][p]) / W);
  const D c11 = L::fma(-mean[1], mean[1], L::load(&sums.s[1][p]) / W);
  const D c22 = L::fma(-mean[2], mean[2], L::load(&sums.s[2][p]) / W);
  const D c01 = L::fma(-mean[0], mean[1], L::load(&sums.s[3][p]) / W);
  const D c02 = L::fma(-mean[0], mean[2], L::load(&sums.s[4][p]) / W);
  const D c12 = L::fma(-mean[1], mean[2], L::load(&sums.s[5][p]) / W);
  // Cofactors (one product rounded, the other fused), the determinant by the first column.
  const D f00 = L::fma(c11, c22, -(c12 * c12));
  const D f10 = L::fma(c12, c02, -(c22 * c01));
  const D f20 = L::fma(c01, c12, -(c11 * c02));
  const D f11 = L::fma(-c02, c02, c00 * c22);
  const D f12 = L::fma(-c12, c00, c02 * c01);
  const D f22 = L::fma(-c01, c01, c00 * c11);
  const D det = L::fma(f20, c02, f00 * c00 + f10 * c01);
  // The largest eigenvalue's bounds: the largest row sum of |C| (a + (b + c) per row), and |C|_F
  // with the entries in column order paired (0 4 2 6 | 1 5 3 7, each pair's second square fused)
  // and the last one fused at the end.
  const D a00 = L::abs(c00), a11 = L::abs(c11), a22 = L::abs(c22), a01 = L::abs(c01), a02 = L::abs(c02),
          a12 = L::abs(c12);
  D rows = L::greater(a00 + (a01 + a02), L::set(0.0));
  rows = L::greater(a01 + (a11 + a12), rows);
  rows = L::greater(a02 + (a12 + a22), rows);
  const auto frobenius = [](D e0, D e1, D e2, D e3, D e4, D e5, D e6, D e7, D e8) {
    const D low = L::fma(e6, e6, e4 * e4) + L::fma(e2, e2, e0 * e0);
    const D high = L::fma(e7, e7, e5 * e5) + L::fma(e3, e3, e1 * e1);
    return L::sqrt(L::fma(e8, e8, low + high));
  };
  const D largest = L::lesser(rows, frobenius(c00, c01, c02, c01, c11, c12, c02, c12, c22));
  // The inverse (column order: f00 f10 f20 | f10 f11 f12 | f20 f12 f22, times 1 / det).
  const D invdet = L::set(1.0) / det;
  const D i00 = f00 * invdet, i10 = f10 * invdet, i20 = f20 * invdet, i11 = f11 * invdet, i12 = f12 * invdet,
          i22 = f22 * invdet;
  const D kr2 = L::set(k.max_stretch * k.max_stretch);
  M ok = L::ge(L::load(&sums.neighbours[p]), L::set(double(k.min_neighbours)));
  ok = L::both(ok, L::gt(det, L::set(0.0)));
  ok = L::both(ok, L::le(largest, kr2 / frobenius(i00, i10, i20, i10, i11, i12, i20, i12, i22)));
  ok = L::both(ok, L::le(largest, kr2 * L::set(k.s_bulk)));
  // The Cholesky factor of the form (s_bulk / H^2) C^-1 (its lower triangle), column by column.
  const D scale = L::set(k.s_bulk / (k.support * k.support));
  const D g00 = scale * i00, g10 = scale * i10, g20 = scale * i20, g11 = scale * i11, g21 = scale * i12,
          g22 = scale * i22;
  ok = L::both(ok, L::not_le(g00, L::set(0.0)));
  const D l00 = L::sqrt(g00);
  const D l10 = g10 / l00, l20 = g20 / l00;
  const D x1 = g11 - l10 * l10;
  ok = L::both(ok, L::not_le(x1, L::set(0.0)));
  const D l11 = L::sqrt(x1);
  const D l21 = (g21 - l20 * l10) / l11;
  const D x2 = g22 - L::fma(l21, l21, l20 * l20);
  ok = L::both(ok, L::not_le(x2, L::set(0.0)));
  const D l22 = L::sqrt(x2);
  const double H = k.support, s_bulk = k.s_bulk;
  const D weight = L::set(k.volume * k.normalisation) / (L::set(H * H * H) * L::sqrt(det / L::set(s_bulk * s_bulk * s_bulk)));
  const D reach = L::set(H) * L::sqrt(largest / L::set(s_bulk));
  const unsigned shaped = L::bits(ok);
  double out[8][w];
  L::store(out[0], l00), L::store(out[1], l10), L::store(out[2], l20), L::store(out[3], l11);
  L::store(out[4], l21), L::store(out[5], l22), L::store(out[6], weight), L::store(out[7], reach);
  for (std::size_t l = 0; l < w; ++l) {
    sums.shaped[p + l] = std::uint8_t((shaped >> l) & 1u);
    if (!sums.shaped[p + l]) continue;
    Kernel& ker = kernels[sums.index[p + l]];
    // map = L^T, row-major.
    ker.map = {float(out[0][l]), float(out[1][l]), float(out[2][l]), 0.0f, float(out[3][l]), float(out[4][l]),
               0.0f, 0.0f, float(out[5][l])};
    ker.weight = float(out[6][l]);
    ker.reach = float(out[7][l]);
  }
}

}  // namespace

void shape_kernels_scalar(NeighbourSums& sums, const ShapeConstants& constants, Kernel* kernels) {
  for (std::size_t p = 0; p < sums.size(); ++p) shape<One>(sums, p, constants, kernels);
}

void shape_kernels(NeighbourSums& sums, const ShapeConstants& constants, Kernel* kernels) {
  std::size_t p = 0;
#if defined(__AVX2__) && defined(__FMA__)
  for (; p + Four::kWidth <= sums.size(); p += Four::kWidth) shape<Four>(sums, p, constants, kernels);
#endif
  for (; p < sums.size(); ++p) shape<One>(sums, p, constants, kernels);
}

}  // namespace slurry::io::detail
