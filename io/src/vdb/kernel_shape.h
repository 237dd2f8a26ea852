#pragma once
// The anisotropic kernels of the particles whose neighbourhood needs no clamp (anisotropic.cpp,
// after Yu & Turk 2013), several particles at a time: from each particle's neighbour sums, its
// smoothed centre, its covariance C, the bounds that decide whether a clamp could apply, and then
// the Cholesky factor of (s_bulk / H^2) C^-1, which maps an offset to the unit ball. Every
// rounding is spelled out (kernel_shape.cpp), so that a vector of particles gives what one
// particle at a time gives, bit for bit.
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace slurry::io::detail {

/// A kernel W(x) = weight P(|map (x - centre)|), P(q) = (1 - q^2)^3 on q < 1.
struct Kernel {
  std::array<float, 3> centre;
  std::array<float, 9> map;  ///< row-major A^-1 V^T: world offset to the unit ball
  float weight;              ///< V K / (a_1 a_2 a_3)
  float reach;               ///< the longest axis (m), or a bound above it (the Cholesky path)
};

/// What shape_kernels computes with.
struct ShapeConstants {
  double smoothing = 0.5;     ///< lambda of the centre's smoothing
  int min_neighbours = 6;     ///< fewer neighbours: not shaped here (a round kernel)
  double max_stretch = 4.0;   ///< k_r
  double s_bulk = 0;          ///< the covariance of a full neighbourhood, 0.15 R^2 (m^2)
  double support = 0;         ///< H, the kernel radius in the bulk (m)
  double volume = 0;          ///< V, a particle's volume (m^3)
  double normalisation = 0;   ///< K, the kernel's integral factor
};

/// The neighbour sums of a run of particles, by quantity, filled by the caller: for particle p,
/// position x, neighbour offsets d_j = x_j - x with weights w_j (itself included), W = sum w_j,
/// m_k = sum w_j d_jk, s = sum w_j d_j d_j^T as xx, yy, zz, xy, xz, yz; its neighbours (itself not
/// counted) and where its kernel goes.
struct NeighbourSums {
  std::vector<double> W, m[3], s[6];
  std::vector<float> x[3];
  std::vector<std::int32_t> neighbours;
  std::vector<std::uint32_t> index;
  /// Set by shape_kernels: the mean offset m / W, and whether the kernel was shaped (0: the
  /// caller shapes it, by the eigendecomposition or as a round kernel).
  std::vector<double> mean[3];
  std::vector<std::uint8_t> shaped;
  std::size_t size() const { return W.size(); }
  void resize(std::size_t n);
};

/// For each particle p of `sums`: the mean offset, the kernel's centre x + lambda mean (written
/// to kernels[index[p]] for every particle), and, when p has at least min_neighbours neighbours
/// and its covariance C = s / W - mean mean^T satisfies
///   det C > 0, min(|C|_F, max row sum of |C|) <= k_r^2 / |C^-1|_F and <= k_r^2 s_bulk
/// (bounds of the eigenvalues: s_3 >= 1 / |C^-1|_F, s_1 <= |C|_F and s_1 <= the largest
/// Gershgorin row sum; so every s_k lies within [s_1 / k_r^2, k_r^2 s_bulk], neither clamp
/// applies, and the kernel's quadratic form V A^-2 V^T is (s_bulk / H^2) C^-1, with no
/// eigendecomposition) and that form has a Cholesky factor L:
/// map = L^T, weight = V K / (H^3 sqrt(det C / s_bulk^3)), reach = H sqrt(min(...) / s_bulk),
/// and shaped[p] = 1. The roundings are those of Eigen 3.4's 3 x 3 inverse, Frobenius norms and
/// LLT as g++ 12 compiles them with FMA; kernel_shape.cpp lists them.
void shape_kernels(NeighbourSums& sums, const ShapeConstants& constants, Kernel* kernels);

/// shape_kernels one particle at a time (the definition; shape_kernels must equal it bit for bit).
void shape_kernels_scalar(NeighbourSums& sums, const ShapeConstants& constants, Kernel* kernels);

}  // namespace slurry::io::detail
