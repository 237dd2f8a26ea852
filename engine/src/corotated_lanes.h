#pragma once
/// \file corotated_lanes.h
/// The 3D stress of fixed corotated materials (jelly, and snow with its hardening) in P2G
/// (Simulation::compute_stress) over SIMD lanes: lanes::fixed_corotated_kirchhoff
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
template <class T>
void fixed_corotated_stress_lanes(T mu, T lambda, const T* factor, T dt, const std::uint32_t* order,
                                  std::uint32_t begin, std::uint32_t end,
                                  const Eigen::Matrix<T, 3, 3>* F, const T* vol0,
                                  std::size_t vol0_mask, Eigen::Matrix<T, 3, 3>* K);

extern template void fixed_corotated_stress_lanes<float>(float, float, const float*, float,
                                                         const std::uint32_t*, std::uint32_t,
                                                         std::uint32_t, const Eigen::Matrix3f*,
                                                         const float*, std::size_t,
                                                         Eigen::Matrix3f*);
extern template void fixed_corotated_stress_lanes<double>(double, double, const double*, double,
                                                          const std::uint32_t*, std::uint32_t,
                                                          std::uint32_t, const Eigen::Matrix3d*,
                                                          const double*, std::size_t,
                                                          Eigen::Matrix3d*);

}  // namespace slurry::detail
