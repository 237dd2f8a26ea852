#pragma once
// Sums over many candidates in kLanes partial sums (candidate q in lane q mod kLanes, written as
// a loop of whole vectors that compilers vectorize), then the lanes added as a tree in double:
// the same additions on any machine, whatever its vector width. Used by the anisotropic field's
// neighbour sums (anisotropic.cpp).
#include <cstddef>

namespace slurry::io::detail {

/// Lanes of the partial sums: a multiple of the widest vector's float lanes (16).
constexpr std::size_t kLanes = 16;
/// A padding coordinate for the candidates: beyond any neighbourhood, its square still finite.
constexpr float kFar = 1e15f;

/// The sum of kLanes lanes in double, as a tree of halving strides.
template <class T>
double lane_total(const T (&lanes)[kLanes]) {
  double s[kLanes];
  for (std::size_t l = 0; l < kLanes; ++l) s[l] = double(lanes[l]);
  for (std::size_t w = kLanes / 2; w > 0; w /= 2)
    for (std::size_t l = 0; l < w; ++l) s[l] += s[l + w];
  return s[0];
}

}  // namespace slurry::io::detail
