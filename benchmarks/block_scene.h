// The scene of the MPM throughput benchmarks (bench_mpm_step, bench_mpi): a block of fixed
// corotated jelly filling the middle half of the domain along each axis, moving at
// (0.3, -0.2, 0.1) m/s, 3D MLS with the quadratic kernel, 8 particles per cell in 3D (4 in 2D), so
// res^3 particles for res cells per axis (res^2 in 2D). `stretch` lengthens the domain and the
// block along x by that factor (weak scaling: the same particles per rank on `stretch` ranks).
#pragma once
#include "slurry/engine/scene/scene.h"

namespace slurry::bench {

/// The block's material (bench_mpm_step's BM_Material): fixed corotated jelly; snow (fixed
/// corotated with Stomakhin et al. 2013 plasticity, its default window and hardening); sand
/// (Hencky StVK with Drucker-Prager, friction angle 30 degrees, Klar et al. 2016).
enum class BlockMaterial { Jelly, Snow, Sand };

inline Scene block_scene(int dim, int res, bool dbl, int stretch = 1, BlockMaterial material = BlockMaterial::Jelly) {
  Scene s;
  s.source = "bench";
  s.solver.dimension = dim;
  s.solver.precision = dbl ? Precision::Double : Precision::Float;
  s.solver.transfer = TransferKind::MLS;
  s.solver.kernel = KernelKind::Quadratic;
  s.domain.min = {0, 0, 0};
  s.domain.max = {0.5 * stretch + 0.5, 1, 1};
  s.domain.dx = 1.0 / res;
  MaterialParams m;
  m.name = "jelly";
  m.model = ElasticModel::FixedCorotated;
  if (material == BlockMaterial::Snow) m.plasticity = PlasticModel::Snow;
  if (material == BlockMaterial::Sand) {
    m.model = ElasticModel::HenckyStVK;
    m.plasticity = PlasticModel::DruckerPrager;
  }
  s.materials = {m};
  BodyParams b;
  b.min = {0.25, 0.25, 0.25};
  b.max = {0.25 + 0.5 * stretch, 0.75, 0.75};
  b.material = "jelly";
  b.velocity = {0.3, -0.2, 0.1};
  b.particles_per_cell = dim == 3 ? 8 : 4;
  s.bodies = {b};
  return s;
}

}  // namespace slurry::bench
