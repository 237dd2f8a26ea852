#pragma once
/// \file deformation_lanes.h
/// G2P's update of a solid's deformation gradient, F <- (I + dt grad v) F (the MLS-MPM update of
/// Hu et al. 2018, eq. 17, with grad v = C), as the state functor that gather_particles calls:
/// one particle at a time, or, where the gather queues its updates (3D float MLS on AVX2 with
/// FMA), a queue of particles at once, 8 in AVX2 lanes, in a translation unit of its own
/// (deformation_lanes.cpp, as sand_lanes.cpp).
///
/// Where it runs in lanes (float, 3D, FMA), both forms spell their roundings out, so that they
/// agree bitwise whatever the compiler does (tests/mpm/parallel_test.cpp compares them): each
/// entry of A = I + dt G is one fused multiply-add, fma(dt, g_ik, delta_ik), and each entry of
/// A F is a_0 b_0 + (a_1 b_1 + a_2 b_2) with each product fused into the add that takes it,
///   entries (i, j) != (2, 2): fma(A_i0, F_0j, fma(A_i1, F_1j, A_i2 F_2j)),
///   entry (2, 2):             fma(A_20, F_02, fma(A_22, F_22, A_21 F_12)).
/// That is how GCC 12 compiled Eigen's A = I + dt G, A F before (read from its code: its SLP
/// vectoriser took entries 0-7 in one 8-wide vector and the last alone, with the inner pair's
/// operands in the other order), so frames are bitwise those of earlier builds. Elsewhere (2D,
/// double, no FMA) MpmSolver keeps the Eigen expression in a lambda, as GCC compiles it.
#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <type_traits>

namespace slurry::detail {

/// F[ids[j]] <- (I + dt G[j]) F[ids[j]] for j < n, with the roundings of the file comment.
/// Defined only for AVX2 with FMA (SolidStateUpdate::kBatched), the only builds that call it.
void deformation_update_lanes(float dt, Eigen::Matrix3f* F, const std::int64_t* ids, const Eigen::Matrix3f* G, int n);

/// Which product of entry (i, j)'s inner pair is rounded on its own (the file comment): k = 1
/// for entry (2, 2), k = 2 for the others. Both forms take it from here.
constexpr int inner_first(int i, int j) { return i == 2 && j == 2 ? 1 : 2; }

/// Whether the build has the lanes (AVX2 with FMA).
inline constexpr bool kDeformationLanes =
#if defined(__AVX2__) && defined(__FMA__)
    true;
#else
    false;
#endif

/// The solid state update of G2P: F[p] <- (I + dt gv) F[p].
template <class T, int Dim>
struct SolidStateUpdate {
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  Mat* F;
  T dt;
  /// Whether batch() runs in lanes; gather_particles calls it for its queued updates when so.
  /// (Written in terms of T and Dim in every build, so that the members' static_asserts are
  /// checked only where a member is used: a plain `false` failed them in the portable build.)
  static constexpr bool kBatched = std::is_same_v<T, float> && Dim == 3 && kDeformationLanes;

  // Used only where kBatched (MpmSolver keeps its lambda elsewhere): the members below exist
  // for float 3D with FMA.
  void operator()(std::int64_t p, const Mat& gv) const {
    static_assert(kBatched, "SolidStateUpdate is the float 3D FMA update");
    Mat A, R;
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) A(i, k) = std::fma(dt, gv(i, k), T(i == k));
    const Mat& f = F[p];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const int first = inner_first(i, j), second = 3 - first;
        R(i, j) = std::fma(A(i, 0), f(0, j), std::fma(A(i, second), f(second, j), A(i, first) * f(first, j)));
      }
    F[p] = R;
  }
  /// The update of particles ids[0, n) with gradients gv[0, n).
  void batch(const std::int64_t* ids, const Mat* gv, int n) const {
    static_assert(kBatched, "SolidStateUpdate is the float 3D FMA update");
    deformation_update_lanes(dt, F, ids, gv, n);
  }
};

}  // namespace slurry::detail
