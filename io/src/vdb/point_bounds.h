#pragma once
// The smallest and largest coordinates of a point set per axis, per chunk of points in parallel,
// then over the chunks (min and max are exact, so the result is a serial loop's).
#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <vector>

#include "slurry/transfer/parallel.h"

namespace slurry::io::detail {

struct PointBounds {
  std::array<float, 3> lo{}, hi{};
};

/// Bounds of `pos`, a vector of std::array<float, 3> (lo > hi on every axis when it is empty).
template <class Points>
PointBounds point_bounds(const Points& pos) {
  constexpr std::size_t kChunk = std::size_t(1) << 16;
  const std::size_t chunks = (pos.size() + kChunk - 1) / kChunk;
  constexpr float kInf = std::numeric_limits<float>::infinity();
  std::vector<PointBounds> part(chunks);
  slurry::parallel::parallel_tasks(0, std::int64_t(chunks), [&](std::int64_t c) {
    PointBounds b{{kInf, kInf, kInf}, {-kInf, -kInf, -kInf}};
    for (std::size_t i = std::size_t(c) * kChunk; i < std::min(pos.size(), std::size_t(c + 1) * kChunk); ++i)
      for (int d = 0; d < 3; ++d) b.lo[d] = std::min(b.lo[d], pos[i][d]), b.hi[d] = std::max(b.hi[d], pos[i][d]);
    part[std::size_t(c)] = b;
  });
  PointBounds out{{kInf, kInf, kInf}, {-kInf, -kInf, -kInf}};
  for (const PointBounds& b : part)
    for (int d = 0; d < 3; ++d) out.lo[d] = std::min(out.lo[d], b.lo[d]), out.hi[d] = std::max(out.hi[d], b.hi[d]);
  return out;
}

}  // namespace slurry::io::detail
