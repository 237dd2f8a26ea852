#pragma once
/// \file sand_lanes.h
/// The 3D sand phase of P2G (MpmSolver::project_and_stress) over SIMD lanes: for the particles
/// order[begin, end) of one bin, the Drucker-Prager return mapping of Klar et al. 2016 and the
/// Kirchhoff stress from its own factorisation (the eigenvectors of Fe Fe^T, or the SVD where
/// those are not accurate), through the batched DruckerPrager::project_with_stress
/// (plasticity.h, svd_lanes.h), W = lanes::kWidth<T> particles at a time.
///
/// It has a translation unit of its own (sand_lanes.cpp): instantiated inside
/// simulation_3f.cpp, the batched code changed GCC's inlining elsewhere in that unit, and with
/// it the last bits of a scene without sand (stiff_bar_implicit_3d).
#include <Eigen/Core>

#include <cstddef>
#include <cstdint>

#include "slurry/constitutive/plasticity.h"

namespace slurry::detail {

/// For i in [begin, end), p = order[i]: projects F[p] and updates plastic[p], and sets
/// K[i - begin] = -dt vol0[p & vol0_mask] tau (the rest volume stored once or per particle, as
/// ScalarChannel stores it). A short last batch repeats its first particle in the spare lanes and
/// drops their results: lanes do not interact, so a particle's result does not depend on the
/// batch it falls in. Returns how many particles yielded.
template <class T>
std::int64_t project_and_stress_lanes(const constitutive::DruckerPrager<T>& dp, T mu, T lambda, T dt,
                                      const std::uint32_t* order, std::uint32_t begin, std::uint32_t end,
                                      Eigen::Matrix<T, 3, 3>* F, T* plastic, const T* vol0, std::size_t vol0_mask,
                                      Eigen::Matrix<T, 3, 3>* K);

extern template std::int64_t project_and_stress_lanes<float>(const constitutive::DruckerPrager<float>&, float, float,
                                                             float, const std::uint32_t*, std::uint32_t, std::uint32_t,
                                                             Eigen::Matrix3f*, float*, const float*, std::size_t,
                                                             Eigen::Matrix3f*);
extern template std::int64_t project_and_stress_lanes<double>(const constitutive::DruckerPrager<double>&, double,
                                                              double, double, const std::uint32_t*, std::uint32_t,
                                                              std::uint32_t, Eigen::Matrix3d*, double*, const double*,
                                                              std::size_t, Eigen::Matrix3d*);

}  // namespace slurry::detail
