// The batched fixed corotated stress of P2G; see corotated_lanes.h.
#include "corotated_lanes.h"

#include <algorithm>

#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fixed_corotated_lanes.h"

namespace slurry::detail {

template <class T>
void fixed_corotated_stress_lanes(T mu, T lambda, const T* factor, T dt, const std::uint32_t* order,
                                  std::uint32_t begin, std::uint32_t end,
                                  const Eigen::Matrix<T, 3, 3>* F, const T* vol0,
                                  std::size_t vol0_mask, Eigen::Matrix<T, 3, 3>* K) {
  namespace lanes = constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  lanes::Mat3<T, W> Fl, tau;
  lanes::Lane<T, W> mul, lambdal;
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
      const Eigen::Matrix<T, 3, 3> t =
          scalar.bits[l] != T(0)
              ? constitutive::FixedCorotated<T, 3>{mul[l], lambdal[l]}.kirchhoff(F[p])
              : tau.get(l);
      K[i0 + l - begin] = (-dt * vol0[p & vol0_mask]) * t;
    }
  }
}

template void fixed_corotated_stress_lanes<float>(float, float, const float*, float,
                                                  const std::uint32_t*, std::uint32_t,
                                                  std::uint32_t, const Eigen::Matrix3f*,
                                                  const float*, std::size_t, Eigen::Matrix3f*);
template void fixed_corotated_stress_lanes<double>(double, double, const double*, double,
                                                   const std::uint32_t*, std::uint32_t,
                                                   std::uint32_t, const Eigen::Matrix3d*,
                                                   const double*, std::size_t, Eigen::Matrix3d*);

}  // namespace slurry::detail
