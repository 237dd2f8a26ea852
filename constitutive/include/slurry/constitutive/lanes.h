#pragma once
/// \file lanes.h
/// Lane arithmetic: W scalars of type T processed together, one per SIMD lane, for the batched
/// constitutive kernels (svd_lanes.h). A lane value is an Eigen::Array<T, W, 1>, so arithmetic,
/// log and exp run as Eigen packet instructions (AVX-512: one instruction per 16 floats or 8
/// doubles; SSE2: four). What Eigen 3.4 does not vectorise is added here on its packet
/// primitives:
/// - per-lane comparisons and selects (Eigen's Array::select is evaluated one coefficient at a
///   time): a Mask holds Eigen's packet comparison result, all bits set or clear in each lane;
/// - a correctly rounded square root: with EIGEN_FAST_MATH (its default) Eigen's float packet
///   sqrt is a reciprocal-square-root estimate and one Newton step, off by an ulp or two.
/// Every operation is per lane, so a lane's result never depends on the other lanes.
#include <Eigen/Core>

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <cmath>

// Eigen's packet types (__m512 and the like) carry alignment attributes that GCC drops, with a
// warning, when they are template arguments (ploadu<Packet>); Eigen silences it the same way.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"
#endif

namespace slurry::constitutive::lanes {

template <class T, int W>
using Lane = Eigen::Array<T, W, 1>;

namespace detail {

template <class T>
using Packet = typename Eigen::internal::packet_traits<T>::type;
template <class T>
constexpr int kPacketSize = Eigen::internal::unpacket_traits<Packet<T>>::size;

/// r = op(packets of a, b) over the W lanes.
template <class T, int W, class Op>
inline Lane<T, W> packetwise(const Lane<T, W>& a, const Lane<T, W>& b, Op op) {
  static_assert(W % kPacketSize<T> == 0, "the lane count must be a multiple of the packet size");
  using Eigen::internal::ploadu;
  Lane<T, W> r;
  for (int k = 0; k < W; k += kPacketSize<T>)
    Eigen::internal::pstoreu(r.data() + k, op(ploadu<Packet<T>>(a.data() + k), ploadu<Packet<T>>(b.data() + k)));
  return r;
}

// Correctly rounded packet square roots (the instruction itself), whatever EIGEN_FAST_MATH says.
#if defined(__AVX512F__)
inline __m512 exact_sqrt(__m512 x) { return _mm512_maskz_sqrt_ps(__mmask16(0xFFFF), x); }
inline __m512d exact_sqrt(__m512d x) { return _mm512_maskz_sqrt_pd(__mmask8(0xFF), x); }
#endif
#if defined(__AVX__)
inline __m256 exact_sqrt(__m256 x) { return _mm256_sqrt_ps(x); }
inline __m256d exact_sqrt(__m256d x) { return _mm256_sqrt_pd(x); }
#endif
#if defined(__SSE2__)
inline __m128 exact_sqrt(__m128 x) { return _mm_sqrt_ps(x); }
inline __m128d exact_sqrt(__m128d x) { return _mm_sqrt_pd(x); }
#endif
inline float exact_sqrt(float x) { return std::sqrt(x); }
inline double exact_sqrt(double x) { return std::sqrt(x); }

#if defined(__SSE2__) || defined(EIGEN_DONT_VECTORIZE)
constexpr bool kExactPacketSqrt = true;  // every packet type has an exact_sqrt above
#else
constexpr bool kExactPacketSqrt = false;
#endif

}  // namespace detail

/// Per-lane truth values: each lane all bits set (true) or all clear (false), stored as T.
template <class T, int W>
struct Mask {
  Lane<T, W> bits;
};

#define SLURRY_LANES_COMPARE(name, expr)                                                          \
  template <class T, int W>                                                                       \
  inline Mask<T, W> name(const Lane<T, W>& a, const Lane<T, W>& b) {                              \
    return {detail::packetwise(a, b, [](const auto& x, const auto& y) { return expr; })};         \
  }                                                                                               \
  template <class T, int W>                                                                       \
  inline Mask<T, W> name(const Lane<T, W>& a, T b) {                                              \
    return name(a, Lane<T, W>(Lane<T, W>::Constant(b)));                                          \
  }                                                                                               \
  template <class T, int W>                                                                       \
  inline Mask<T, W> name(T a, const Lane<T, W>& b) {                                              \
    return name(Lane<T, W>(Lane<T, W>::Constant(a)), b);                                          \
  }
/// a < b, a <= b, a > b, a >= b per lane; false where either is NaN, as for scalars.
SLURRY_LANES_COMPARE(lt, Eigen::internal::pcmp_lt(x, y))
SLURRY_LANES_COMPARE(le, Eigen::internal::pcmp_le(x, y))
SLURRY_LANES_COMPARE(gt, Eigen::internal::pcmp_lt(y, x))
SLURRY_LANES_COMPARE(ge, Eigen::internal::pcmp_le(y, x))
#undef SLURRY_LANES_COMPARE

template <class T, int W>
inline Mask<T, W> operator&(const Mask<T, W>& a, const Mask<T, W>& b) {
  return {detail::packetwise(a.bits, b.bits, [](const auto& x, const auto& y) { return Eigen::internal::pand(x, y); })};
}
template <class T, int W>
inline Mask<T, W> operator|(const Mask<T, W>& a, const Mask<T, W>& b) {
  return {detail::packetwise(a.bits, b.bits, [](const auto& x, const auto& y) { return Eigen::internal::por(x, y); })};
}
template <class T, int W>
inline Mask<T, W> operator~(const Mask<T, W>& a) {
  return {detail::packetwise(a.bits, a.bits, [](const auto& x, const auto&) {
    return Eigen::internal::pandnot(Eigen::internal::ptrue(x), x);
  })};
}

/// Per lane: m ? a : b.
template <class T, int W>
inline Lane<T, W> select(const Mask<T, W>& m, const Lane<T, W>& a, const Lane<T, W>& b) {
  static_assert(W % detail::kPacketSize<T> == 0, "the lane count must be a multiple of the packet size");
  using Eigen::internal::ploadu;
  using P = detail::Packet<T>;
  Lane<T, W> r;
  for (int k = 0; k < W; k += detail::kPacketSize<T>)
    Eigen::internal::pstoreu(r.data() + k, Eigen::internal::pselect(ploadu<P>(m.bits.data() + k), ploadu<P>(a.data() + k),
                                                                    ploadu<P>(b.data() + k)));
  return r;
}
template <class T, int W>
inline Lane<T, W> select(const Mask<T, W>& m, const Lane<T, W>& a, T b) {
  return select(m, a, Lane<T, W>(Lane<T, W>::Constant(b)));
}
template <class T, int W>
inline Lane<T, W> select(const Mask<T, W>& m, T a, const Lane<T, W>& b) {
  return select(m, Lane<T, W>(Lane<T, W>::Constant(a)), b);
}
template <class T, int W>
inline Lane<T, W> select(const Mask<T, W>& m, T a, T b) {
  return select(m, Lane<T, W>(Lane<T, W>::Constant(a)), Lane<T, W>(Lane<T, W>::Constant(b)));
}

/// Whether any lane is true.
template <class T, int W>
inline bool any(const Mask<T, W>& m) {
  bool r = false;
  for (int l = 0; l < W; ++l) r |= m.bits[l] != T(0);  // all bits set is a NaN: != 0
  return r;
}

/// Correctly rounded square root per lane (std::sqrt's result in every lane).
template <class T, int W>
inline Lane<T, W> sqrt(const Lane<T, W>& a) {
  using P = detail::Packet<T>;
  if constexpr (detail::kExactPacketSqrt) {
    return detail::packetwise(a, a, [](const P& x, const P&) { return detail::exact_sqrt(x); });
  } else {
    Lane<T, W> r;
    for (int l = 0; l < W; ++l) r[l] = std::sqrt(a[l]);
    return r;
  }
}

/// The lane count that fills W / (packet size) packets of T: 16 floats or 8 doubles with
/// AVX-512, and the same counts (two or four packets per operation) with narrower ISAs, so that a
/// batch's size does not depend on the instruction set.
template <class T>
constexpr int kWidth = 64 / int(sizeof(T));

/// Whether lane code beats the scalar code it batches: packets of 4 or more T (AVX2 or AVX-512,
/// or SSE2 floats). With SSE2 doubles (2 per packet) the batched 3x3 SVD measured slower than
/// svd.h's scalar one, 171 against 156 ns (benchmarks/RESULTS.md, "3x3 SVD").
template <class T>
constexpr bool kPays = detail::kPacketSize<T> >= 4;

}  // namespace slurry::constitutive::lanes

#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
