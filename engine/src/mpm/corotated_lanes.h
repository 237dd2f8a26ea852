#pragma once
/// \file corotated_lanes.h
/// The stress of fixed corotated materials (jelly, and snow with its hardening) in P2G
/// (MpmSolver::compute_stress) over SIMD lanes, in 2D and 3D: lanes::fixed_corotated_kirchhoff
/// (fixed_corotated_lanes.h), W = lanes::kWidth<T> particles at a time. Its own translation unit,
/// like sand_lanes.cpp.
#include <Eigen/Core>

#include <cstddef>
#include <cstdint>

namespace slurry::detail {

/// For i in [begin, end), p = order[i]: K[i - begin] = -dt vol0[p & vol0_mask] tau(F[p]) with the
/// fixed corotated model of Lame parameters (mu, lambda) h_i, h_i = factor[i - begin] (snow's
/// hardening) or 1 when factor is null. Lanes that polar_rotation would hand to the SVD are
/// computed by the scalar FixedCorotated::kirchhoff. A short last batch repeats its first particle
/// in the spare lanes and drops their results.
template <class T, int Dim>
void fixed_corotated_stress_lanes(T mu, T lambda, const T* factor, T dt, const std::uint32_t* order,
                                  std::uint32_t begin, std::uint32_t end,
                                  const Eigen::Matrix<T, Dim, Dim>* F, const T* vol0,
                                  std::size_t vol0_mask, Eigen::Matrix<T, Dim, Dim>* K);

// The instantiations: one list, declared extern here and defined in corotated_lanes.cpp.
#define SLURRY_COROTATED_LANES_FOR_EACH(X) X(float, 2) X(double, 2) X(float, 3) X(double, 3)
#define SLURRY_COROTATED_LANES_INSTANCE(T, Dim)                              \
  template void fixed_corotated_stress_lanes<T, Dim>(                        \
      T, T, const T*, T, const std::uint32_t*, std::uint32_t, std::uint32_t, \
      const Eigen::Matrix<T, Dim, Dim>*, const T*, std::size_t, Eigen::Matrix<T, Dim, Dim>*);
#define SLURRY_COROTATED_LANES_EXTERN(T, Dim) extern SLURRY_COROTATED_LANES_INSTANCE(T, Dim)
SLURRY_COROTATED_LANES_FOR_EACH(SLURRY_COROTATED_LANES_EXTERN)
#undef SLURRY_COROTATED_LANES_EXTERN

}  // namespace slurry::detail
