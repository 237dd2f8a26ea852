// FemSolver<T, Dim>: scene bodies -> one co-rotated FEM mesh, the substep loop, frames.
// Included by fem_solver_2.cpp and fem_solver_3.cpp, one dimension each.
#pragma once
#include <type_traits>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>

#include "frame_builder.h"
#include "state_io.h"
#include "slurry/engine/fem/fem_solver.h"
#include "slurry/engine/scene/scene_files.h"
#include "geometry/scene_meshes.h"

namespace slurry {

/// Walls and colliders on vertex velocities (see fem_solver.h).
template <class T, int Dim>
struct FemSolver<T, Dim>::Boundary {
  const FemSolver& sim;
  T t, dt;

  bool pin(int, const Vec& x, Vec& vb) const {
    const auto& b = sim.scene_.boundaries;
    if (b.walls == Condition::Sticky && ((x.array() <= sim.lo_.array()).any() || (x.array() >= sim.hi_.array()).any())) {
      vb.setZero();
      return true;
    }
    for (const auto& c : sim.colliders_) {
      Vec n = Vec::Zero();
      if (c.condition == Condition::Sticky && c.inside(x, t, n)) {
        vb = c.velocity_at(x, t);
        return true;
      }
    }
    return false;
  }

  void apply(int, const Vec& xp, Vec& v) const {
    const auto& b = sim.scene_.boundaries;
    const T friction = T(b.friction);
    for (int d = 0; d < Dim; ++d) {
      if (xp[d] < sim.lo_[d]) v = apply_condition<T, Dim>(v, Vec::Zero(), Vec::Unit(d), b.walls, friction);
      if (xp[d] > sim.hi_[d]) v = apply_condition<T, Dim>(v, Vec::Zero(), Vec(-Vec::Unit(d)), b.walls, friction);
    }
    for (const auto& c : sim.colliders_) {
      Vec n = Vec::Zero();
      if (c.inside(xp, t + dt, n)) v = apply_condition<T, Dim>(v, c.velocity_at(xp, t + dt), n, c.condition, c.friction);
    }
  }
};

template <class T, int Dim>
FemSolver<T, Dim>::FemSolver(const Scene& scene) : scene_(scene) {
  scene_.validate();
  if (scene_.solver.type != SolverType::FEM)
    throw SceneError(scene_.source + ": solver.type: FemSolver needs \"fem\", got \"" +
                     std::string(to_string(scene_.solver.type)) + "\"");
  if (scene_.solver.dimension != Dim)
    throw SceneError(scene_.source + ": solver.dimension: expected " + std::to_string(Dim) + ", got " +
                     std::to_string(scene_.solver.dimension));
  using VecD = Eigen::Matrix<double, Dim, 1>;
  const VecD lo = scene_.domain.min.head<Dim>(), hi = scene_.domain.max.head<Dim>();
  lo_ = lo.template cast<T>();
  hi_ = hi.template cast<T>();
  gravity_ = scene_.solver.gravity.head<Dim>().template cast<T>();
  colliders_ = detail::make_colliders<T, Dim>(scene_);

  std::vector<fem::FemMaterial<T>> materials;
  for (const auto& m : scene_.materials)
    materials.push_back(fem::FemMaterial<T>::from_young(T(m.E), T(m.nu), T(m.density), T(m.damping)));

  fem::Mesh<Dim> all;
  std::vector<int> element_material;
  std::vector<VecD> velocity;
  for (std::size_t bi = 0; bi < scene_.bodies.size(); ++bi) {
    const auto& b = scene_.bodies[bi];
    const std::string where = scene_.source + ": bodies[" + std::to_string(bi) + "]";
    fem::Mesh<Dim> m;
    if (b.mesh.empty() && b.shape == Shape::Sphere) {
      m = fem::ball_mesh<Dim>(b.center.head<Dim>(), b.radius, std::max(2, int(std::lround(2 * b.radius / scene_.domain.dx))));
    } else if (b.mesh.empty()) {
      m = fem::box_mesh<Dim>(b.min.head<Dim>(), b.max.head<Dim>(), scene_.domain.dx);
    } else {
      m = scene_tet_mesh<Dim>(scene_, b.mesh, "bodies[" + std::to_string(bi) + "]");
      for (const auto& x : m.x)
        if ((x.array() < lo.array()).any() || (x.array() > hi.array()).any()) {
          std::string p;
          for (int d = 0; d < Dim; ++d) p += (d ? ", " : "") + detail::fmt(x[d]);
          throw SceneError(where + ".mesh: the mesh has a vertex at [" + p + "], expected every vertex inside the domain");
        }
    }
    const int offset = int(all.x.size());
    const int mi = scene_.material_index(b.material);
    for (const auto& x : m.x) {
      all.x.push_back(x);
      velocity.push_back(b.velocity.head<Dim>());
      vertex_material_.push_back(std::uint16_t(mi));
    }
    for (auto el : m.elements) {
      for (int& k : el) k += offset;
      all.elements.push_back(el);
      element_material.push_back(mi);
    }
  }
  check_mesh(all, scene_.source + ": bodies");
  faces_ = fem::boundary_faces(all);
  fem_ = std::make_unique<Fem>(all, std::move(materials), std::move(element_material));
  for (std::size_t i = 0; i < velocity.size(); ++i) fem_->v[i] = velocity[i].template cast<T>();
  explicit_dt_ = fem_->explicit_dt(T(scene_.solver.elastic_cfl));
}

template <class T, int Dim>
T FemSolver<T, Dim>::stable_dt() const {
  const T max_dt = T(scene_.solver.max_dt);
  return scene_.solver.integrator == Integrator::Implicit ? max_dt : std::min(max_dt, explicit_dt_);
}

template <class T, int Dim>
std::int64_t FemSolver<T, Dim>::advance_to(double t_end) {
  return substep_to(time_, t_end, [&] { return dt_scale_ * double(stable_dt()); }, [&](double dt) { step(T(dt)); }, scene_);
}

template <class T, int Dim>
void FemSolver<T, Dim>::save_state(const StateSink& out) const {
  // The mesh, masses and rest quantities follow from the scene; positions and velocities of
  // the vertices (and time, step, counters) are the state.
  detail::StateWriter w(out);
  detail::write_layout<T, Dim>(w, detail::kTagFem);
  w.vec(fem_->x);
  w.vec(fem_->v);
  w.pod(time_);
  w.pod(steps_);
  w.pod(cfl_reached_);
  w.pod(last_iterations_);
  w.tag(detail::kTagEnd);
}

template <class T, int Dim>
void FemSolver<T, Dim>::load_state(std::string_view in, const std::string& what) {
  detail::StateReader r(in, what);
  detail::read_layout<T, Dim>(r, detail::kTagFem, "FEM");
  const auto n = std::int64_t(fem_->vertex_count());
  r.vec(fem_->x, n, "vertex positions");
  r.vec(fem_->v, n, "vertex velocities");
  detail::require_finite(r, fem_->x, "the position");
  detail::require_finite(r, fem_->v, "the velocity");
  r.pod(time_);
  if (!(time_ >= 0 && std::isfinite(time_))) r.fail("its time is not a finite value >= 0");
  r.pod(steps_);
  r.pod(cfl_reached_);
  r.pod(last_iterations_);
  r.tag(detail::kTagEnd, "end");
  r.finish();
}

template <class T, int Dim>
void FemSolver<T, Dim>::step(T dt) {
  const Boundary boundary{*this, T(time_), dt};
  if (scene_.solver.integrator == Integrator::Implicit) {
    const auto r = fem_->step_implicit(dt, gravity_, boundary);
    last_iterations_ = r.iterations;
    if (!r.converged) {
      std::ostringstream msg;
      msg << scene_.source << ": implicit FEM step " << steps_ + 1 << " at t = " << detail::fmt(time_ + double(dt))
          << ": the linear solve did not converge (relative residual " << detail::fmt(double(r.relative_residual))
          << " after " << r.iterations << " PCG iterations); try a smaller solver.max_dt";
      throw SimulationError(msg.str());
    }
  } else {
    fem_->step_symplectic(dt, gravity_, boundary);
    last_iterations_ = 0;
  }
  const auto& x = fem_->x;
  const auto& v = fem_->v;
  bool bad = false;
  T vmax2 = 0;
  for (std::size_t i = 0; i < x.size() && !bad; ++i) {
    bad = !x[i].allFinite() || !v[i].allFinite();
    vmax2 = std::max(vmax2, v[i].squaredNorm());
  }
  if (bad) diagnose(dt);
  cfl_reached_ = std::max(cfl_reached_, std::sqrt(vmax2) * dt / T(scene_.domain.dx));
  time_ += double(dt);
  ++steps_;
}

template <class T, int Dim>
void FemSolver<T, Dim>::diagnose(T dt) const {
  std::size_t i = 0;
  while (i < fem_->x.size() && fem_->x[i].allFinite() && fem_->v[i].allFinite()) ++i;
  std::ostringstream msg;
  msg << scene_.source << ": FEM simulation unstable at step " << steps_ + 1 << ", t = " << detail::fmt(time_ + double(dt))
      << ": vertex " << i << " (material \"" << scene_.materials[vertex_material_[i]].name
      << "\") has a non-finite position or velocity (dt " << detail::fmt(double(dt)) << " s, explicit limit "
      << detail::fmt(double(explicit_dt_)) << " s); reduce solver.max_dt or solver.elastic_cfl, or use solver.integrator \"implicit\"";
  throw SimulationError(msg.str());
}

template <class T, int Dim>
RunStats FemSolver<T, Dim>::take_stats() {
  const Fem& f = *fem_;
  RunStats s;
  s.time = time_;
  s.particles = f.vertex_count();
  add_particle_sums(s, f.x, f.v, f.mass().data(), 0.0, scene_.solver.gravity);
  s.elastic = double(f.energy(f.x));
  for (std::size_t e = 0; e < f.element_count(); ++e)
    s.volume += double(f.volume(e)) * double(f.deformation_gradient(e, f.x).determinant());
  s.cfl = double(cfl_reached_);
  cfl_reached_ = 0;
  return s;
}

template <class T, int Dim>
std::string FemSolver<T, Dim>::solver_status() const {
  if (last_iterations_ == 0) return {};
  return "implicit PCG " + std::to_string(last_iterations_) + " iterations";
}

template <class T, int Dim>
std::size_t FemSolver<T, Dim>::bytes() const {
  return fem_->bytes() + vertex_material_.size() * sizeof(std::uint16_t) + faces_.size() * sizeof(faces_[0]);
}

template <class T, int Dim>
Frame FemSolver<T, Dim>::frame(const std::vector<std::string>& attributes) const {
  const Fem& f = *fem_;
  const std::size_t n = f.vertex_count();
  detail::VertexFrame out("fem ", time_, scene_.source, n);
  for (const auto& a : attributes) {
    if (a == "position") {
      out.add_positions<Dim>(f.x);
    } else if (a == "velocity") {
      out.add_velocities<Dim>(f.v);
    } else if (a == "material") {
      out.add_column("material", vertex_material_);
    } else if (a == "J") {
      std::vector<T> J(n, T(0)), w(n, T(0));
      for (std::size_t e = 0; e < f.element_count(); ++e) {
        const T det = f.deformation_gradient(e, f.x).determinant();
        for (int k : f.elements()[e]) J[std::size_t(k)] += f.volume(e) * det, w[std::size_t(k)] += f.volume(e);
      }
      for (std::size_t i = 0; i < n; ++i) J[i] = w[i] > T(0) ? J[i] / w[i] : T(1);
      out.add_column("J", std::move(J));
    }
  }
  Frame data = std::move(out.data());
  auto& faces = data.tables.emplace_back();
  faces.name = "face";
  faces.count = faces_.size();
  ListColumn list{"vertex_indices", {}};
  list.data.reserve(faces_.size());
  for (const auto& t : faces_) list.data.push_back({t[0], t[1], t[2]});
  faces.lists.push_back(std::move(list));
  return data;
}

template <class T, int Dim>
ParticleStorage FemSolver<T, Dim>::particle_storage() const {
  ParticleStorage s;
  s.precision = std::is_same_v<T, double> ? Precision::Double : Precision::Float;
  s.dimension = Dim;
  s.count = fem_->vertex_count();
  s.x = fem_->x.data();
  s.v = fem_->v.data();
  s.material = vertex_material_.data();  // vertices are never re-ordered: the vertex index is the id
  return s;
}

}  // namespace slurry
