#pragma once
/// \file stats.h
/// Conservation and sanity figures of a run, taken after every frame: what a user checks to
/// know how far to trust a result. run_scene writes them to `stats.csv` beside the frames (one
/// row per frame) and warns, naming the frame, when one drifts beyond the scene's tolerances
/// (`output.mass_drift`, `output.volume_drift`, `output.energy_growth`).
///
/// Definitions (SI units; sums over particles p, or FEM nodes, with masses m_p):
///   mass               sum m_p (FLIP: rho V_particle per particle)
///   momentum           sum m_p v_p
///   angular_momentum   sum m_p x_p x v_p about the origin (2D: the z component)
///   kinetic            sum m_p |v_p|^2 / 2
///   potential          -sum m_p g . x_p (zero where x . g = 0)
///   elastic            sum V_p^0 psi(F_p) (MPM solids, FEM elements; 0 for liquids)
///   surface            sigma x the free surface's area (length in 2D): FLIP with surface
///                      tension (SurfaceTension::area); 0 otherwise
///   volume             MPM: sum V_p^0 J_p; FLIP: the particle count x dx^Dim / the mean
///                      particle count of the interior cells (those whose 3^Dim neighbourhood all
///                      holds particles), or x the seeding volume where there is no such cell;
///                      FEM: deformed element volume
///   max_fluid_J_error  largest |J_p - 1| of weakly compressible MPM fluid particles
///   projected          plastic return mappings that changed F during the frame (MPM)
///   cfl                largest particle displacement in one substep during the frame, in cells
#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace slurry {

struct RunStats {
  int frame = 0;
  double time = 0;
  std::int64_t substeps = 0;  ///< substeps taken for this frame
  std::size_t particles = 0;
  double mass = 0;
  Eigen::Vector3d momentum{0, 0, 0};
  Eigen::Vector3d angular_momentum{0, 0, 0};
  double kinetic = 0;
  double potential = 0;
  double elastic = 0;
  double surface = 0;
  double volume = 0;
  double max_fluid_J_error = 0;
  std::int64_t projected = 0;
  double cfl = 0;
  /// output.error_estimate (run/error_estimate.h): estimated error of energy() (J) and the
  /// largest estimated error of a material's centroid (m); NaN without the estimate.
  double error_energy = std::numeric_limits<double>::quiet_NaN();
  double error_centroid = std::numeric_limits<double>::quiet_NaN();

  /// kinetic + potential + elastic + surface.
  double energy() const { return kinetic + potential + elastic + surface; }
};

/// Tolerances of the drift warnings (the scene's output block).
struct DriftTolerances {
  double mass = 1e-4;    ///< relative change of the total mass
  double volume = 0.1;   ///< relative change of the volume
  /// Growth of kinetic + potential + elastic + surface energy beyond its starting value,
  /// relative to the initial kinetic and surface energy plus the largest potential energy drop
  /// the domain allows (m g H). Dissipation (a decrease) is never reported.
  double energy = 0.05;
  /// Energy is not checked when emitters or moving colliders add energy (their work is not
  /// tracked).
  bool check_energy = true;
};

/// The drift warnings of `now` against the first frame's figures `first`: one line per
/// quantity beyond its tolerance, naming the frame, the figure and the tolerance. `energy_scale`
/// is the denominator of the energy test (J).
std::vector<std::string> drift_warnings(const RunStats& first, const RunStats& now, const DriftTolerances& tol,
                                        double energy_scale);

/// Accumulates the particle sums of RunStats over arrays of positions, velocities and masses
/// (Dim 2 or 3; m may be null with `uniform_mass` given instead).
template <class Vec, class T>
void add_particle_sums(RunStats& s, const std::vector<Vec>& x, const std::vector<Vec>& v, const T* m,
                       double uniform_mass, const Eigen::Vector3d& gravity) {
  constexpr int Dim = Vec::RowsAtCompileTime;
  for (std::size_t p = 0; p < x.size(); ++p) {
    const double mp = m ? double(m[p]) : uniform_mass;
    Eigen::Vector3d xp = Eigen::Vector3d::Zero(), vp = Eigen::Vector3d::Zero();
    for (int d = 0; d < Dim; ++d) xp[d] = double(x[p][d]), vp[d] = double(v[p][d]);
    s.mass += mp;
    s.momentum += mp * vp;
    // x x v written out: Eigen's cross() lives in <Eigen/Geometry>, which this header avoids.
    s.angular_momentum += mp * Eigen::Vector3d(xp[1] * vp[2] - xp[2] * vp[1], xp[2] * vp[0] - xp[0] * vp[2],
                                               xp[0] * vp[1] - xp[1] * vp[0]);
    s.kinetic += 0.5 * mp * vp.squaredNorm();
    s.potential -= mp * gravity.head<Dim>().dot(xp.head<Dim>());
  }
}

}  // namespace slurry
