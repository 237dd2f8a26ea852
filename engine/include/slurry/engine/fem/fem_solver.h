#pragma once
/// \file fem_solver.h
/// A scene (solver.type "fem") simulated as Lagrangian co-rotated linear finite elements
/// (corotated_fem.h): each body is a tetrahedral (3D) or triangle (2D) mesh, read from a TetGen
/// file (`bodies[].mesh`, relative to the scene file) or meshed from its box with spacing
/// domain.dx. One substep is
///
///   forces          f_i = sum_e R sigma b_i (+ Rayleigh damping)       (co-rotated linear)
///   update          symplectic Euler, or linearly implicit Euler on the warped stiffness
///   boundaries      walls (the domain faces) and colliders act on vertex velocities at the
///                   predicted position x + dt v, as the MPM grid update does on nodes;
///                   a vertex inside a sticky collider (or beyond a sticky wall) is pinned
///   check_health    non-finite state -> SimulationError naming the step, time, vertex, material
///
/// The substep is solver.max_dt for the implicit integrator; for the explicit one also at most
/// elastic_cfl 2 / omega_max (omega_max bounded element by element from the rest stiffness and
/// lumped mass, reduced for damping; CorotatedFem::explicit_dt). On a regular mesh 2 / omega_max
/// is about 0.5 to 0.65 h_min / c (h_min the shortest rest edge, c the P-wave speed). The particle count of Solver is the vertex count; frames carry a "vertex"
/// element (position, velocity, material, J = volume-weighted mean det F of the elements around
/// the vertex) and a "face" element with the list property "vertex_indices": the outward
/// boundary triangles in 3D, every triangle in 2D.
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "slurry/engine/geometry/colliders.h"
#include "slurry/engine/fem/corotated_fem.h"
#include "slurry/engine/solver.h"
#include "slurry/engine/substeps.h"

namespace slurry {

template <class T, int Dim>
class FemSolver final : public Solver {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Fem = fem::CorotatedFem<T, Dim>;

  /// Validates the scene, reads or builds the body meshes. Throws SceneError or IoError.
  explicit FemSolver(const Scene& scene);

  /// The substep the integrator allows (not clipped to a frame boundary).
  T stable_dt() const;
  /// One substep of length dt. Throws SimulationError if the state becomes unhealthy.
  void step(T dt);

  double time() const override { return time_; }
  std::int64_t steps() const override { return steps_; }
  std::size_t particle_count() const override { return fem_->vertex_count(); }
  std::size_t bytes() const override;
  std::int64_t advance_to(double t_end) override;
  Frame frame(const std::vector<std::string>& attributes) const override;

  Fem& fem() { return *fem_; }
  const Fem& fem() const { return *fem_; }
  const Scene& scene() const { return scene_; }
  /// The surface written to each frame's "face" element.
  const std::vector<std::array<int, 3>>& faces() const { return faces_; }
  /// The scene material of each vertex.
  const std::vector<std::uint16_t>& vertex_material() const { return vertex_material_; }
  /// Iterations of the last implicit solve (0 for explicit steps).
  int last_solver_iterations() const { return last_iterations_; }
  /// "implicit PCG <iterations> iterations" of the last substep; empty for explicit steps.
  std::string solver_status() const override;
  /// Mass from the lumped vertex masses; volume of the deformed elements.
  RunStats take_stats() override;
  /// The mesh vertices: position, velocity, material; the vertex index is the id.
  ParticleStorage particle_storage() const override;
  using Solver::save_state;
  void save_state(const StateSink& sink) const override;
  void load_state(std::string_view in, const std::string& what) override;

 private:
  struct Boundary;
  [[noreturn]] void diagnose(T dt) const;

  Scene scene_;
  std::unique_ptr<Fem> fem_;
  std::vector<Collider<T, Dim>> colliders_;
  std::vector<std::uint16_t> vertex_material_;
  std::vector<std::array<int, 3>> faces_;
  Vec gravity_, lo_, hi_;
  T explicit_dt_ = 0;
  T cfl_reached_ = 0;  // largest vertex speed dt / dx since the last take_stats()
  double time_ = 0;
  std::int64_t steps_ = 0;
  int last_iterations_ = 0;
};

extern template class FemSolver<float, 2>;
extern template class FemSolver<float, 3>;
extern template class FemSolver<double, 2>;
extern template class FemSolver<double, 3>;

}  // namespace slurry
