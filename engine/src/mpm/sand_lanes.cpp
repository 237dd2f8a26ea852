// The batched sand phase of P2G; see sand_lanes.h.
#include "mpm/sand_lanes.h"

#include <algorithm>

#include "mpm/lanes_io.h"

#include "slurry/constitutive/lanes.h"
#include "slurry/constitutive/svd_lanes.h"

namespace slurry::detail {

template <class T>
std::int64_t project_and_stress_lanes(const constitutive::DruckerPrager<T>& dp, T mu, T lambda, T dt,
                                      const std::uint32_t* order, std::uint32_t begin, std::uint32_t end,
                                      Eigen::Matrix<T, 3, 3>* F, T* plastic, const T* vol0, std::size_t vol0_mask,
                                      Eigen::Matrix<T, 3, 3>* K) {
  namespace lanes = constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  lanes::Mat3<T, W> Fl, tau;
  lanes::Lane<T, W> state;
  std::int64_t yielded = 0;
  lanes::Lane<T, W> scale;
  for (auto i0 = begin; i0 < end; i0 += W) {
    const int count = int(std::min<std::uint32_t>(W, end - i0));
    // Spare lanes of a short batch repeat its first particle.
    auto p = [&](int l) { return order[i0 + (l < count ? l : 0)]; };
    load_lanes<3>(Fl, [&](int l) { return &F[p(l)]; });
    for (int l = 0; l < W; ++l) {
      state[l] = plastic[p(l)];
      scale[l] = -dt * vol0[p(l) & vol0_mask];
    }
    const auto yielded_lanes = dp.project_with_stress(Fl, state, mu, lambda, tau);
    store_lanes<3>(Fl, nullptr, count, [&](int l) { return &F[p(l)]; });
    store_lanes<3>(tau, scale.data(), count, [&](int l) { return &K[i0 + l - begin]; });
    for (int l = 0; l < count; ++l) {
      plastic[p(l)] = state[l];
      yielded += yielded_lanes.bits[l] != T(0);
    }
  }
  return yielded;
}

template std::int64_t project_and_stress_lanes<float>(const constitutive::DruckerPrager<float>&, float, float, float,
                                                      const std::uint32_t*, std::uint32_t, std::uint32_t,
                                                      Eigen::Matrix3f*, float*, const float*, std::size_t,
                                                      Eigen::Matrix3f*);
template std::int64_t project_and_stress_lanes<double>(const constitutive::DruckerPrager<double>&, double, double,
                                                       double, const std::uint32_t*, std::uint32_t, std::uint32_t,
                                                       Eigen::Matrix3d*, double*, const double*, std::size_t,
                                                       Eigen::Matrix3d*);

}  // namespace slurry::detail
