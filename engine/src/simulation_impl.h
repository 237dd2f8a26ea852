// Definition of Simulation<T, Dim>; included by one translation unit per (T, Dim) so that the
// four instantiations compile in parallel.
#pragma once
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <sstream>

#include "implicit_update.h"
#include "slurry/engine/simulation.h"
#include "slurry/transfer/parallel.h"
#include "slurry/transfer/transfers.h"

namespace slurry {

namespace detail {
/// Grid padding (nodes) outside the domain on every side: enough for the cubic kernel's support
/// of a particle one cell outside the domain.
constexpr int kPad = 3;

/// Portable uniform double in [0, 1) from a 64-bit generator (std::uniform_real_distribution is
/// not specified bit-for-bit across standard libraries; frames must be reproducible).
inline double uniform01(std::mt19937_64& rng) { return double(rng() >> 11) * 0x1.0p-53; }

inline std::string fmt(double x) {
  std::ostringstream o;
  o.precision(6);
  o << x;
  return o.str();
}
}  // namespace detail

template <class T, int Dim>
Simulation<T, Dim>::Simulation(const Scene& scene) : scene_(scene) {
  scene_.validate();
  const auto& dom = scene_.domain;
  const T dx = T(dom.dx);
  Eigen::Matrix<int, Dim, 1> res;
  Vec origin;
  for (int d = 0; d < Dim; ++d) {
    const int cells = int(std::ceil((dom.max[d] - dom.min[d]) / dom.dx - 1e-9));
    res[d] = cells + 1 + 2 * detail::kPad;
    origin[d] = T(dom.min[d] - detail::kPad * dom.dx);
    x_lo_[d] = T(dom.min[d] - dom.dx);
    x_hi_[d] = T(dom.min[d] + (cells + 1) * dom.dx);
  }
  grid_.resize(origin, dx, res);
  grid_.keep_old_velocity(scene_.solver.transfer == TransferKind::FLIP);
  gravity_ = scene_.solver.gravity.head<Dim>().template cast<T>();
  for (const auto& m : scene_.materials) materials_.push_back(make_material<T, Dim>(m));
  for (const auto& c : scene_.colliders) colliders_.emplace_back(c);
  for (const auto& m : materials_) max_wave_speed_ = std::max(max_wave_speed_, m.wave_speed);
  seed_bodies();
  stress_.resize(particles_.size());
  for (const auto& v : particles_.v) max_speed_ = std::max(max_speed_, v.norm());
  if (scene_.solver.integrator == Integrator::Implicit) {
    typename ImplicitUpdate<T, Dim>::Options o;
    o.tolerance = T(scene_.solver.cg_tolerance);
    o.max_iterations = scene_.solver.cg_max_iterations;
    implicit_ = std::make_unique<ImplicitUpdate<T, Dim>>(scene_.solver.kernel, scene_.solver.transfer, o);
  }
}

template <class T, int Dim>
Simulation<T, Dim>::~Simulation() = default;

template <class T, int Dim>
void Simulation<T, Dim>::seed_bodies() {
  auto& P = particles_;
  P.channels.C = scene_.solver.transfer == TransferKind::MLS || scene_.solver.transfer == TransferKind::APIC;
  P.channels.material = scene_.materials.size() > 1;
  for (const auto& m : materials_) {
    P.channels.F = P.channels.F || !m.fluid;
    P.channels.J = P.channels.J || m.fluid;
    P.channels.plastic = P.channels.plastic || m.plastic_kind != PlasticModel::None;
  }
  // Bodies are seeded material by material, so every material owns one contiguous range.
  for (int mi = 0; mi < int(materials_.size()); ++mi) {
    const std::int64_t begin = std::int64_t(P.size());
    for (std::size_t bi = 0; bi < scene_.bodies.size(); ++bi) {
      const auto& b = scene_.bodies[bi];
      if (scene_.material_index(b.material) != mi) continue;
      const auto& mat = materials_[mi];
      Eigen::Matrix<double, Dim, 1> lo, hi;
      const Eigen::Matrix<double, Dim, 1> c = b.center.head<Dim>();
      if (b.shape == Shape::Box) {
        lo = b.min.head<Dim>();
        hi = b.max.head<Dim>();
      } else {
        lo = c.array() - b.radius;
        hi = c.array() + b.radius;
        if (b.shape == Shape::Cylinder) {
          lo[b.axis] = c[b.axis] - 0.5 * b.height;
          hi[b.axis] = c[b.axis] + 0.5 * b.height;
        }
      }
      const double h_target = scene_.domain.dx / std::pow(b.particles_per_cell, 1.0 / Dim);
      Eigen::Matrix<int, Dim, 1> n;
      Eigen::Matrix<double, Dim, 1> h;
      for (int d = 0; d < Dim; ++d) {
        n[d] = std::max(1, int(std::lround((hi[d] - lo[d]) / h_target)));
        h[d] = (hi[d] - lo[d]) / n[d];
      }
      const double vol = h.prod();
      std::mt19937_64 rng(b.seed);
      const Vec vel = b.velocity.head<Dim>().template cast<T>();
      const std::size_t before = P.size();
      Eigen::Matrix<int, Dim, 1> i = Eigen::Matrix<int, Dim, 1>::Zero();
      const std::int64_t total = std::int64_t(n.template cast<std::int64_t>().prod());
      for (std::int64_t k = 0; k < total; ++k) {
        std::int64_t r = k;
        for (int d = Dim - 1; d >= 0; --d) {
          i[d] = int(r % n[d]);
          r /= n[d];
        }
        Eigen::Matrix<double, Dim, 1> x;
        for (int d = 0; d < Dim; ++d) {
          const double u = b.sampling == Sampling::Jittered ? detail::uniform01(rng) : 0.5;
          x[d] = lo[d] + (i[d] + u) * h[d];
        }
        bool inside = true;
        if (b.shape == Shape::Sphere) {
          inside = (x - c).squaredNorm() <= b.radius * b.radius;
        } else if (b.shape == Shape::Cylinder) {
          Eigen::Matrix<double, Dim, 1> r2 = x - c;
          r2[b.axis] = 0;
          inside = r2.squaredNorm() <= b.radius * b.radius;
        }
        if (inside)
          P.push_back(x.template cast<T>(), vel, T(mat.density * vol), T(vol), std::uint16_t(mi),
                      mat.initial_plastic_state());
      }
      if (P.size() == before)
        throw SceneError(scene_.source + ": bodies[" + std::to_string(bi) +
                         "]: seeds no particles (expected a body larger than the particle spacing " +
                         detail::fmt(h_target) + ")");
    }
    ranges_.push_back({mi, begin, std::int64_t(P.size())});
  }
}

template <class T, int Dim>
std::size_t Simulation<T, Dim>::bytes() const {
  return particles_.bytes() + stress_.capacity() * sizeof(Mat) +
         grid_.size() * (sizeof(typename Grid::Node) + (grid_.keeps_old_velocity() ? sizeof(Vec) : 0)) +
         (implicit_ ? implicit_->bytes() : 0);
}

template <class T, int Dim>
T Simulation<T, Dim>::stable_dt() const {
  const T dx = grid_.dx();
  T dt = T(scene_.solver.max_dt);
  if (max_speed_ > T(0)) dt = std::min(dt, T(scene_.solver.cfl) * dx / max_speed_);
  // The linear B-spline tolerates a smaller elastic Courant number: free fall with APIC grows
  // round-off into ringing at elastic_cfl 0.5 and stays exact at 0.1 (tests/engine/physics_test),
  // so its elastic limit is scaled by a quarter.
  const T kernel_factor = scene_.solver.kernel == KernelKind::Linear ? T(0.25) : T(1);
  if (max_wave_speed_ > T(0) && !implicit_)  // the implicit update has no elastic limit
    dt = std::min(dt, kernel_factor * T(scene_.solver.elastic_cfl) * dx / max_wave_speed_);
  return dt;
}

template <class T, int Dim>
std::int64_t Simulation<T, Dim>::advance_to(double t_end) {
  std::int64_t n = 0;
  while (time_ < t_end) {
    const double remaining = t_end - time_;
    double dt = double(stable_dt());
    bool last = false;
    if (dt >= remaining * (1 - 1e-9)) {
      dt = remaining;
      last = true;
    } else if (dt > 0.5 * remaining) {
      dt = 0.5 * remaining;  // two even steps rather than one long and one tiny
    }
    step(T(dt));
    if (last) time_ = t_end;  // no drift of frame times from summing substeps
    ++n;
  }
  return n;
}

template <class T, int Dim>
void Simulation<T, Dim>::step(T dt) {
  compute_stress(dt);
  particles_to_grid();
  if (implicit_)
    update_grid_implicit(dt);
  else
    update_grid(dt);
  grid_to_particles(dt);
  return_mapping();
  time_ += double(dt);
  ++steps_;
}

template <class T, int Dim>
void Simulation<T, Dim>::compute_stress(T dt) {
  auto& P = particles_;
  for (const auto& r : ranges_) {
    const auto& mat = materials_[r.material];
    Mat* K = stress_.data();
    if (mat.fluid) {
      // tau = -J p(J) I, so K = -dt V0 tau = dt V0 J p I.
      const auto& fluid = mat.fluid_model();
      parallel::parallel_for(r.begin, r.end, [&](std::int64_t p) {
        K[p] = Mat::Identity() * (dt * P.vol0[p] * fluid.kirchhoff_pressure(P.J[p]));
      });
      continue;
    }
    mat.visit_elastic([&](const auto& model) {
      if (mat.plastic_kind == PlasticModel::Snow) {
        parallel::parallel_for(r.begin, r.end, [&](std::int64_t p) {
          const auto scaled = model.scaled(mat.hardening_factor(P.plastic[p]));
          K[p] = (-dt * P.vol0[p]) * scaled.kirchhoff(P.F[p]);
        });
      } else {
        parallel::parallel_for(r.begin, r.end, [&](std::int64_t p) {
          K[p] = (-dt * P.vol0[p]) * model.kirchhoff(P.F[p]);
        });
      }
    });
  }
}

template <class T, int Dim>
void Simulation<T, Dim>::particles_to_grid() {
  grid_.clear();
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: particles_to_grid_order<1>(); break;
    case KernelKind::Quadratic: particles_to_grid_order<2>(); break;
    case KernelKind::Cubic: particles_to_grid_order<3>(); break;
  }
}

template <class T, int Dim>
template <int Order>
void Simulation<T, Dim>::particles_to_grid_order() {
  using transfer::Scheme;
  auto& P = particles_;
  const std::int64_t n = std::int64_t(P.size());
  switch (scene_.solver.transfer) {
    case TransferKind::PIC:
    case TransferKind::FLIP:
      transfer::particles_to_grid<Order, Scheme::PIC>(grid_, P.x.data(), P.v.data(), P.m.data(), nullptr,
                                                      stress_.data(), 0, n);
      break;
    case TransferKind::APIC:
      transfer::particles_to_grid<Order, Scheme::APIC>(grid_, P.x.data(), P.v.data(), P.m.data(),
                                                       P.C.data(), stress_.data(), 0, n);
      break;
    case TransferKind::MLS:
      if constexpr (Order > 1)
        transfer::particles_to_grid<Order, Scheme::MLS>(grid_, P.x.data(), P.v.data(), P.m.data(),
                                                        P.C.data(), stress_.data(), 0, n);
      break;
  }
}

template <class T, int Dim>
void Simulation<T, Dim>::update_grid(T dt) {
  const auto& bc = scene_.boundaries;
  const int cells_lo = detail::kPad + bc.thickness;  // nodes with index < this are in the wall
  Eigen::Matrix<int, Dim, 1> cells_hi;
  for (int d = 0; d < Dim; ++d) cells_hi[d] = grid_.res()[d] - 1 - detail::kPad - bc.thickness;
  const T t = T(time_) + dt;
  const T friction = T(bc.friction);
  const bool flip = grid_.keeps_old_velocity();
  const int row_len = grid_.active_row_length();
  parallel::parallel_for(0, grid_.active_rows(), [&](std::int64_t r) {
    const std::int64_t k0 = grid_.active_row_start(r);
    Grid& g = grid_;
    auto idx = g.coord(k0);  // once per row; the last coordinate advances with k
    --idx[Dim - 1];
    for (std::int64_t k = k0; k < k0 + row_len; ++k) {
      ++idx[Dim - 1];
      auto& node = g.node(k);
      const T m = node[Dim];
      if (m <= T(0)) continue;
      Vec v = node.template head<Dim>() / m;
      if (flip) g.old_velocity(k) = v;
      v += dt * gravity_;
      for (int d = 0; d < Dim; ++d) {
        if (idx[d] < cells_lo) v = apply_condition<T, Dim>(v, Vec::Zero(), Vec::Unit(d), bc.walls, friction);
        if (idx[d] > cells_hi[d]) v = apply_condition<T, Dim>(v, Vec::Zero(), -Vec::Unit(d), bc.walls, friction);
      }
      if (!colliders_.empty()) {
        const Vec xi = g.position(idx);
        Vec n;
        for (const auto& c : colliders_)
          if (c.inside(xi, t, n)) v = apply_condition<T, Dim>(v, c.velocity, n, c.condition, c.friction);
      }
      node.template head<Dim>() = v;
    }
  });
}

template <class T, int Dim>
void Simulation<T, Dim>::update_grid_implicit(T dt) {
  GridBoundaries<T, Dim> bc;
  bc.lo = detail::kPad + scene_.boundaries.thickness;
  for (int d = 0; d < Dim; ++d) bc.hi[d] = grid_.res()[d] - 1 - detail::kPad - scene_.boundaries.thickness;
  bc.walls = scene_.boundaries.walls;
  bc.friction = T(scene_.boundaries.friction);
  bc.colliders = &colliders_;
  bc.time = T(time_) + dt;
  const auto r = implicit_->update_grid(grid_, particles_, materials_, ranges_, bc, gravity_, dt);
  cg_.last_iterations = r.iterations;
  cg_.last_residual = double(r.residual);
  ++cg_.solves;
  cg_.iterations += r.iterations;
  if (!r.converged) {
    // Not silent: counted in cg_stats(), named by diagnose() if the state then blows up, and
    // reported once on stderr.
    if (cg_.unconverged++ == 0)
      std::fprintf(stderr,
                   "slurry: warning: %s: implicit CG did not converge at step %lld (t = %g s): relative residual "
                   "%g after %d iterations (solver.cg_tolerance %g, solver.cg_max_iterations %d); further "
                   "occurrences are counted silently\n",
                   scene_.source.c_str(), (long long)(steps_ + 1), time_ + double(dt), double(r.residual),
                   r.iterations, scene_.solver.cg_tolerance, scene_.solver.cg_max_iterations);
  }
}

template <class T, int Dim>
void Simulation<T, Dim>::grid_to_particles(T dt) {
  switch (scene_.solver.kernel) {
    case KernelKind::Linear: grid_to_particles_order<1>(dt); break;
    case KernelKind::Quadratic: grid_to_particles_order<2>(dt); break;
    case KernelKind::Cubic: grid_to_particles_order<3>(dt); break;
  }
}

template <class T, int Dim>
template <int Order>
void Simulation<T, Dim>::grid_to_particles_order(T dt) {
  using transfer::Scheme;
  auto& P = particles_;
  const T flip = T(scene_.solver.flip_ratio);
  Mat* C = P.C.empty() ? nullptr : P.C.data();
  T vmax2 = 0;
  for (const auto& r : ranges_) {
    const bool fluid = materials_[r.material].fluid;
    auto run = [&](auto scheme, auto&& state) {
      constexpr Scheme S = decltype(scheme)::value;
      if constexpr (S == Scheme::MLS && Order == 1) {
        return T(0);  // rejected by Scene::validate
      } else {
        return transfer::grid_to_particles<Order, S>(grid_, P.x.data(), P.v.data(), C, dt, flip, x_lo_,
                                                     x_hi_, r.begin, r.end, state);
      }
    };
    auto with_state = [&](auto scheme) {
      if (fluid) {
        T* J = P.J.data();
        return run(scheme, [=](std::int64_t p, const Mat& gv) {
          J[p] *= (Mat::Identity() + dt * gv).determinant();
        });
      }
      Mat* F = P.F.data();
      return run(scheme, [=](std::int64_t p, const Mat& gv) {
        F[p] = (Mat::Identity() + dt * gv) * F[p];
      });
    };
    T r2 = 0;
    switch (scene_.solver.transfer) {
      case TransferKind::PIC: r2 = with_state(std::integral_constant<Scheme, Scheme::PIC>{}); break;
      case TransferKind::FLIP: r2 = with_state(std::integral_constant<Scheme, Scheme::FLIP>{}); break;
      case TransferKind::APIC: r2 = with_state(std::integral_constant<Scheme, Scheme::APIC>{}); break;
      case TransferKind::MLS: r2 = with_state(std::integral_constant<Scheme, Scheme::MLS>{}); break;
    }
    vmax2 = std::max(vmax2, r2);
  }
  max_speed_ = std::sqrt(vmax2);
  // A particle moving more than a cell in one substep (or non-finite, or outside the domain)
  // means the step was unstable: stop with a diagnosis rather than write garbage.
  const T limit = std::max(T(1), T(2 * scene_.solver.cfl)) * grid_.dx();
  if (!(max_speed_ * dt <= limit)) diagnose(dt);
}

template <class T, int Dim>
void Simulation<T, Dim>::return_mapping() {
  auto& P = particles_;
  for (std::size_t ri = 0; ri < ranges_.size(); ++ri) {
    const auto& r = ranges_[ri];
    auto& mat = materials_[r.material];
    if (mat.plastic_kind == PlasticModel::None) continue;
    parallel::parallel_for(r.begin, r.end, [&](std::int64_t p) { mat.project(P.F[p], P.plastic[p]); });
    if (mat.plastic_kind == PlasticModel::Snow) {
      // Hardening stiffens snow; the elastic time-step limit follows the stiffest particle.
      const T hmax = parallel::parallel_max<T>(r.begin, r.end, T(1), [&](std::int64_t lo, std::int64_t hi) {
        T h = T(1);
        for (std::int64_t p = lo; p < hi; ++p) h = std::max(h, mat.hardening_factor(P.plastic[p]));
        return h;
      });
      mat.wave_speed = mat.base_wave_speed * std::sqrt(hmax);
    }
  }
  max_wave_speed_ = 0;
  for (const auto& m : materials_) max_wave_speed_ = std::max(max_wave_speed_, m.wave_speed);
}

template <class T, int Dim>
void Simulation<T, Dim>::diagnose(T dt) const {
  const auto& P = particles_;
  const T limit = std::max(T(1), T(2 * scene_.solver.cfl)) * grid_.dx();
  std::int64_t worst = -1;
  std::string what;
  T worst_speed = -1;
  for (std::int64_t p = 0; p < std::int64_t(P.size()) && what.empty(); ++p) {
    if (!P.x[p].allFinite() || !P.v[p].allFinite()) {
      worst = p, what = "has a non-finite position or velocity";
    } else if ((P.x[p].array() < x_lo_.array()).any() || (P.x[p].array() > x_hi_.array()).any()) {
      worst = p, what = "left the domain (grid plus one cell)";
    } else if (P.v[p].norm() > worst_speed) {
      worst = p, worst_speed = P.v[p].norm();
    }
  }
  if (what.empty())
    what = "moved " + detail::fmt(double(worst_speed * dt / grid_.dx())) + " cells in one substep (speed " +
           detail::fmt(double(worst_speed)) + " m/s, dt " + detail::fmt(double(dt)) + " s; limit " +
           detail::fmt(double(limit / grid_.dx())) + " cells): CFL violation";
  int mat = 0;
  for (const auto& r : ranges_)
    if (worst >= r.begin && worst < r.end) mat = r.material;
  std::ostringstream msg;
  msg << scene_.source << ": simulation unstable at step " << steps_ + 1 << ", t = " << detail::fmt(time_ + double(dt))
      << " s: particle " << worst << " (material \"" << scene_.materials[mat].name << "\") " << what;
  if (cg_.unconverged > 0)
    msg << " (the implicit CG solve missed solver.cg_tolerance in " << cg_.unconverged << " of " << cg_.solves
        << " substeps; try a larger solver.cg_max_iterations)";
  msg << ". No further frames are written. Try a smaller solver.cfl, solver.elastic_cfl or solver.max_dt"
      << ", or a stiffer boundary.";
  throw SimulationError(msg.str());
}

template <class T, int Dim>
T Simulation<T, Dim>::kinetic_energy() const {
  T e = 0;
  for (std::size_t p = 0; p < particles_.size(); ++p) e += T(0.5) * particles_.m[p] * particles_.v[p].squaredNorm();
  return e;
}

template <class T, int Dim>
T Simulation<T, Dim>::elastic_energy() const {
  T e = 0;
  for (const auto& r : ranges_) {
    const auto& mat = materials_[r.material];
    if (mat.fluid) continue;
    mat.visit_elastic([&](const auto& model) {
      for (std::int64_t p = r.begin; p < r.end; ++p) e += particles_.vol0[p] * model.energy(particles_.F[p]);
    });
  }
  return e;
}

template <class T, int Dim>
io::PlyData Simulation<T, Dim>::frame(const std::vector<std::string>& attributes) const {
  const auto& P = particles_;
  const std::size_t n = P.size();
  io::PlyData data;
  data.comments.push_back("slurry frame t=" + detail::fmt(time_) + " source=" + scene_.source);
  auto& el = data.elements.emplace_back();
  el.name = "vertex";
  el.count = n;
  static const char* axes[3] = {"x", "y", "z"};
  static const char* vaxes[3] = {"vx", "vy", "vz"};
  auto column = [&](auto&& value) {
    std::vector<T> c(n);
    for (std::size_t p = 0; p < n; ++p) c[p] = value(p);
    return c;
  };
  for (const auto& a : attributes) {
    if (a == "position") {
      for (int d = 0; d < Dim; ++d) el.properties.push_back({axes[d], column([&](std::size_t p) { return P.x[p][d]; })});
    } else if (a == "velocity") {
      for (int d = 0; d < Dim; ++d) el.properties.push_back({vaxes[d], column([&](std::size_t p) { return P.v[p][d]; })});
    } else if (a == "material") {
      std::vector<std::uint16_t> m = P.material.empty() ? std::vector<std::uint16_t>(n, 0) : P.material;
      el.properties.push_back({"material", std::move(m)});
    } else if (a == "J") {
      el.properties.push_back({"J", column([&](std::size_t p) {
                                 return !P.J.empty() && (P.F.empty() || materials_[P.material.empty() ? 0 : P.material[p]].fluid)
                                            ? P.J[p]
                                            : P.F[p].determinant();
                               })});
    } else if (a == "plastic") {
      el.properties.push_back({"plastic", column([&](std::size_t p) { return P.plastic.empty() ? T(0) : P.plastic[p]; })});
    }
  }
  return data;
}

}  // namespace slurry
