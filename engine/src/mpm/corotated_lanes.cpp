// The batched fixed corotated stress of P2G; see corotated_lanes.h.
#include "mpm/corotated_lanes.h"

#include "mpm/lanes_io.h"

#include <algorithm>
#include <type_traits>

#include "slurry/constitutive/fixed_corotated.h"
#include "slurry/constitutive/fixed_corotated_lanes.h"

namespace slurry::detail {

template <class T, int Dim>
void fixed_corotated_stress_lanes(T mu, T lambda, const T* factor, T dt, const std::uint32_t* order,
                                  std::uint32_t begin, std::uint32_t end,
                                  const Eigen::Matrix<T, Dim, Dim>* F, const T* vol0,
                                  std::size_t vol0_mask, Eigen::Matrix<T, Dim, Dim>* K) {
  namespace lanes = constitutive::lanes;
  constexpr int W = lanes::kWidth<T>;
  using MatL = std::conditional_t<Dim == 3, lanes::Mat3<T, W>, lanes::Mat2<T, W>>;
  MatL Fl, tau;
  lanes::Lane<T, W> mul, lambdal;
  for (auto i0 = begin; i0 < end; i0 += W) {
    const int count = int(std::min<std::uint32_t>(W, end - i0));
    // Spare lanes of a short batch repeat its first particle.
    auto at = [&](int l) { return i0 + (l < count ? l : 0); };
    load_lanes<Dim>(Fl, [&](int l) { return &F[order[at(l)]]; });
    lanes::Lane<T, W> scale;
    for (int l = 0; l < W; ++l) {
      mul[l] = factor ? mu * factor[at(l) - begin] : mu;
      lambdal[l] = factor ? lambda * factor[at(l) - begin] : lambda;
      scale[l] = -dt * vol0[order[at(l)] & vol0_mask];
    }
    const auto scalar = lanes::fixed_corotated_kirchhoff(Fl, mul, lambdal, tau);
    store_lanes<Dim>(tau, scale.data(), count, [&](int l) { return &K[i0 + l - begin]; });
    // Lanes that polar_rotation would hand to the SVD: the scalar model.
    for (int l = 0; l < count; ++l)
      if (scalar.bits[l] != T(0))
        K[i0 + l - begin] =
            scale[l] * constitutive::FixedCorotated<T, Dim>{mul[l], lambdal[l]}.kirchhoff(F[order[i0 + l]]);
  }
}

SLURRY_COROTATED_LANES_FOR_EACH(SLURRY_COROTATED_LANES_INSTANCE)

}  // namespace slurry::detail
