#pragma once
/// \file deformation_lanes.h
/// G2P's update of a solid's deformation gradient, F <- (I + dt grad v) F (the MLS-MPM update of
/// Hu et al. 2018, eq. 17, with grad v = C), as the state functor that gather_particles calls:
/// one particle at a time, or, where the gather queues its updates (3D float MLS on AVX2 with
/// FMA), a queue of particles at once, 8 in AVX2 lanes, in a translation unit of its own
/// (deformation_lanes.cpp, as sand_lanes.cpp).
///
/// The queue form gives the one-particle form's bits. That one, Eigen's A = I + dt G and A F
/// compiled by GCC with FMA contraction, rounds each entry of A once, fma(dt, g_ik, delta_ik),
/// and each entry of A F as a_0 b_0 + (a_1 b_1 + a_2 b_2), the order in which Eigen sums a
/// 3-term dot product, with each product fused into the add that takes it. Which product of the
/// inner pair is rounded on its own differs by entry, as read from GCC 12's code for the
/// one-particle form: its SLP vectoriser computes entries 0-7 (column-major) in one 8-wide
/// vector as fma(A_i0, F_0j, fma(A_i1, F_1j, A_i2 F_2j)), and entry (2, 2) alone as
/// fma(A_20, F_02, fma(A_22, F_22, A_21 F_12)). The lanes spell those operations out; tests/engine/parallel_test.cpp compares the two
/// bitwise, and the example frames (`cmp`) are unchanged.
#include <Eigen/Core>

#include <cstdint>
#include <type_traits>

namespace slurry::detail {

/// F[ids[j]] <- (I + dt G[j]) F[ids[j]] for j < n, with the roundings of SolidStateUpdate's
/// one-particle form (file comment). Defined for AVX2 with FMA; elsewhere the one-particle form
/// runs instead (SolidStateUpdate::kBatched is false).
void deformation_update_lanes(float dt, Eigen::Matrix3f* F, const std::int64_t* ids, const Eigen::Matrix3f* G, int n);

/// The solid state update of G2P: F[p] <- (I + dt gv) F[p].
template <class T, int Dim>
struct SolidStateUpdate {
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  Mat* F;
  T dt;
  /// Whether batch() runs in lanes; gather_particles calls it for its queued updates when so.
  static constexpr bool kBatched =
#if defined(__AVX2__) && defined(__FMA__)
      std::is_same_v<T, float> && Dim == 3;
#else
      false;
#endif

  void operator()(std::int64_t p, const Mat& gv) const {
    const Mat A = Mat::Identity() + dt * gv;
    F[p] = A * F[p];
  }
  /// The update of particles ids[0, n) with gradients gv[0, n).
  void batch(const std::int64_t* ids, const Mat* gv, int n) const {
    if constexpr (kBatched) deformation_update_lanes(dt, F, ids, gv, n);
  }
};

}  // namespace slurry::detail
