#pragma once
/// \file solver.h
/// The solver-independent face of a simulation (MPM, FLIP or FEM), for the run loop, the CLI
/// and programs that embed the engine: make_solver (or make_simulation, run/run.h, which also
/// reads the scene's mesh files) builds the solver a scene asks for; Solver steps it, hands out
/// its frames (frame.h) and shows its particles without copying them.
///
/// ParticleView<T, Dim> is a typed, read-only view of the current particles (FEM: the mesh
/// vertices) in a stable order, ascending persistent id, whatever order the solver stores them
/// in (the MPM solver re-sorts its particles by grid block every few substeps; FLIP sorts them by
/// cell). Channels are read in place; the view holds only the permutation from id order to
/// storage (4 bytes per particle, none when the storage is already in id order). A view is valid
/// until the simulation takes its next substep.
///
/// This header includes the scene, frame and statistics types only: no grid, transfer or
/// threading-backend header (those stay behind the solver classes of mpm/mpm_solver.h,
/// flip/flip_solver.h and fem/fem_solver.h).
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "slurry/engine/communicator.h"
#include "slurry/engine/errors.h"
#include "slurry/engine/frame.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/engine/stats.h"

namespace slurry {

/// Where a solver keeps its particle channels, type-erased (ParticleView is the typed face).
/// Arrays are in storage order and hold `count` entries; a null optional channel is not stored.
struct ParticleStorage {
  Precision precision = Precision::Float;
  int dimension = 3;
  std::size_t count = 0;
  const void* x = nullptr;                  ///< Eigen::Matrix<T, Dim, 1>[count], position (m)
  const void* v = nullptr;                  ///< Eigen::Matrix<T, Dim, 1>[count], velocity (m/s)
  const std::uint32_t* id = nullptr;        ///< persistent id; null: the storage index is the id
  const std::uint16_t* material = nullptr;  ///< scene material index; null: every particle is material 0
  const void* F = nullptr;        ///< Eigen::Matrix<T, Dim, Dim>[count], MPM solids' elastic deformation gradient
  const void* J = nullptr;        ///< T[count], MPM fluids' volume ratio
  const void* plastic = nullptr;  ///< T[count], MPM plastic state (snow Jp, accumulated plastic strain)
};

template <class T, int Dim>
class ParticleView {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;

  ParticleView(const ParticleStorage& s, std::vector<std::uint32_t> by_id)
      : s_(s), by_id_(std::move(by_id)) {}

  std::size_t size() const { return s_.count; }
  /// Storage index of the particle with the i-th smallest id.
  std::size_t slot(std::size_t i) const { return by_id_.empty() ? i : by_id_[i]; }
  /// Persistent id of the i-th particle (ascending in i).
  std::uint32_t id(std::size_t i) const { return s_.id ? s_.id[slot(i)] : std::uint32_t(i); }
  const Vec& position(std::size_t i) const { return positions()[slot(i)]; }
  const Vec& velocity(std::size_t i) const { return velocities()[slot(i)]; }
  std::uint16_t material(std::size_t i) const { return s_.material ? s_.material[slot(i)] : std::uint16_t(0); }

  /// The channels in storage order, for copy-free bulk reads (index them with slot(i)). The
  /// optional ones return null when the scene does not store them (particles.h, `Channels`).
  const Vec* positions() const { return static_cast<const Vec*>(s_.x); }
  const Vec* velocities() const { return static_cast<const Vec*>(s_.v); }
  const std::uint32_t* ids() const { return s_.id; }
  const std::uint16_t* materials() const { return s_.material; }
  const Mat* F() const { return static_cast<const Mat*>(s_.F); }
  const T* J() const { return static_cast<const T*>(s_.J); }
  const T* plastic() const { return static_cast<const T*>(s_.plastic); }

 private:
  ParticleStorage s_;
  std::vector<std::uint32_t> by_id_;
};

/// Dimension- and precision-independent face of a simulation, for the run loop and the CLI.
class Solver {
 public:
  virtual ~Solver() = default;
  /// Simulated time (s).
  virtual double time() const = 0;
  /// Substeps taken so far.
  virtual std::int64_t steps() const = 0;
  virtual std::size_t particle_count() const = 0;
  /// Bytes held by particles and grid.
  virtual std::size_t bytes() const = 0;
  /// Takes substeps until time() reaches t_end exactly; returns how many it took.
  virtual std::int64_t advance_to(double t_end) = 0;
  /// The particles' current state as a frame (frame.h): a table "vertex" with the columns of the
  /// named attributes (position, velocity, material, J, plastic; FLIP: id), owned.
  virtual Frame frame(const std::vector<std::string>& attributes) const = 0;
  /// The particles this process holds, as a frame of their own (output.per_rank): in a run
  /// split over MPI processes, this process's particles in ascending id, with an "id" column
  /// whether asked for or not, and the comment "slurry part R of N id=requested|added" after the
  /// frame's own comment (merge_rank_frames() in run.h joins the parts). Not collective. A run
  /// that is not split returns frame(attributes).
  virtual Frame own_frame(const std::vector<std::string>& attributes) const { return frame(attributes); }
  /// frame(attributes) for writing at once: the same table, but columns may be borrowed from the
  /// particle arrays (ColumnRef) instead of copied, so the frame is valid only until the
  /// simulation next changes. The run loop writes frames through it (the FLIP solver's frame
  /// then costs no copy of the particles: 21 MB on the 3D dam break). Collective where frame()
  /// is.
  virtual Frame frame_view(const std::vector<std::string>& attributes) const { return frame(attributes); }
  /// Secondary particles kept beside the particles (FLIP whitewater, solver.whitewater) as a
  /// frame of their own: a table "vertex" with x, y(, z), vx, vy(, vz), `type` (uchar: 0 spray,
  /// 1 foam, 2 bubble) and `id` (uint), columns borrowed as frame_view's; a frame without tables
  /// when the scene has none. The run loop writes it as whitewater_NNNN.ply.
  virtual Frame whitewater_frame_view() const { return {}; }
  /// One line on the last substep's linear solve (iterations, relative residual), for the CLI's
  /// per-frame log; empty for solvers without one (explicit MPM and FEM).
  virtual std::string solver_status() const { return {}; }
  /// Conservation and sanity figures of the current state (stats.h). The per-frame figures
  /// (projected, cfl) cover the substeps since the previous call, which resets them.
  virtual RunStats take_stats() = 0;
  /// Where the particle channels are now (valid until the next substep).
  virtual ParticleStorage particle_storage() const = 0;

  /// Receives a state's bytes in order, piece by piece (a whole particle channel at a time).
  using StateSink = std::function<void(const char* data, std::size_t size)>;
  /// Hands the state that determines every later substep to `sink` (binary, this machine's
  /// byte order): particles with every channel in their storage order, time, step counter,
  /// emitter random generators and carried-over grid fields. A simulation built from the same
  /// scene and given this state by load_state() takes bit-identical substeps from there on.
  /// Checkpoints stream it to their file without holding a copy. Collective in a split run.
  virtual void save_state(const StateSink& sink) const = 0;
  /// The same state appended to `out`.
  void save_state(std::string& out) const {
    save_state(StateSink([&out](const char* data, std::size_t size) { out.append(data, size); }));
  }
  /// Replaces the state by one save_state() wrote (the simulation must have been built from
  /// the same scene). Throws IoError naming `what` if the bytes are truncated or do not fit
  /// this simulation (another solver, dimension, precision or particle layout).
  virtual void load_state(std::string_view in, const std::string& what) = 0;
  /// As save_state(), with only this process's particles in a run split over processes (a part
  /// of the state, for per-process checkpoints: output.per_rank). Not collective. A run that is
  /// not split hands save_state().
  virtual void save_own_state(const StateSink& sink) const { save_state(sink); }
  /// Replaces the state by the `parts` parts save_own_state() wrote on the processes of a split
  /// run, `part(i)` returning part i's bytes (it may be asked for each more than once): any
  /// number of processes, one included, loads them, each keeping its own particles. Throws
  /// IoError naming `what` as load_state(). The solvers that never run split take one part only.
  virtual void load_state_parts(int parts, const std::function<std::string(int)>& part, const std::string& what);

  /// Scales every later substep: dt = scale x the stable substep (on_instability "retry"
  /// halves it; 1 restores the automatic step). In (0, 1].
  void set_dt_scale(double scale) { dt_scale_ = scale; }
  double dt_scale() const { return dt_scale_; }

  /// The current particles in ascending id order, typed as the scene's precision and dimension
  /// (float or double, 2 or 3). Throws std::invalid_argument for another T or Dim.
  template <class T, int Dim>
  ParticleView<T, Dim> particles_view() const {
    const ParticleStorage s = particle_storage();
    constexpr Precision p = sizeof(T) == sizeof(double) ? Precision::Double : Precision::Float;
    if (s.precision != p || s.dimension != Dim)
      throw std::invalid_argument(std::string("particles_view<") + (p == Precision::Double ? "double" : "float") + ", " +
                                  std::to_string(Dim) + ">: the simulation is " +
                                  (s.precision == Precision::Double ? "double" : "float") + " in " +
                                  std::to_string(s.dimension) + "D (solver.precision, solver.dimension)");
    return ParticleView<T, Dim>(s, id_order(s.id, s.count));
  }

 protected:
  double dt_scale_ = 1;
  /// The storage index of each particle in ascending-id order; empty when the storage already is
  /// in that order (or has no ids).
  static std::vector<std::uint32_t> id_order(const std::uint32_t* ids, std::size_t n);
};

/// Builds the solver a scene asks for (its solver, dimension and precision). Validates the scene
/// and checks its resources. A scene that names mesh files must have them read into
/// Scene::files (io::read_scene_files; make_simulation in run/run.h does it), else SceneError.
/// With a communicator of more than one rank (every rank calls this with the same scene), the
/// explicit MPM solver and the FLIP solver split the domain over the ranks (mpm/mpm_solver.h,
/// flip/flip_solver.h); FEM runs in one process only and is refused with SceneError.
std::unique_ptr<Solver> make_solver(const Scene& scene, Communicator* communicator = nullptr);

}  // namespace slurry
