// MpmSolver<T, Dim>, part of its definition (mpm_solver_impl.h includes the parts in order).
// What the solver hands out besides substeps: the instability diagnosis, energies and run
// statistics, save_state / load_state for checkpoints, frames (frame.h) and the particle
// storage behind particle views.
#pragma once

namespace slurry {

template <class T, int Dim>
void MpmSolver<T, Dim>::diagnose(T dt) const {
  throw SimulationError(diagnosis(dt));
}

template <class T, int Dim>
std::string MpmSolver<T, Dim>::diagnosis(T dt) const {
  const auto& P = particles_;
  const T limit = std::max(T(1), T(2 * scene_.solver.cfl)) * dx_;
  std::int64_t worst = -1;
  std::string what;
  T worst_speed = -1;
  const std::int64_t n = std::int64_t(P.size());
  for (std::int64_t p = 0; p < n && what.empty(); ++p) {
    if (!P.x[p].allFinite() || !P.v[p].allFinite()) {
      worst = p, what = "has a non-finite position or velocity";
    } else if ((P.x[p].array() < x_lo_.array()).any() || (P.x[p].array() > x_hi_.array()).any()) {
      worst = p, what = "left the domain (grid plus one cell)";
    } else if (P.v[p].norm() > worst_speed) {
      worst = p, worst_speed = P.v[p].norm();
    }
  }
  if (what.empty())
    what = "moved " + detail::fmt(double(worst_speed * dt / dx_)) + " cells in one substep (speed " +
           detail::fmt(double(worst_speed)) + " m/s, dt " + detail::fmt(double(dt)) + " s; limit " +
           detail::fmt(double(limit / dx_)) + " cells): CFL violation";
  const int mat = worst >= 0 && !P.material.empty() ? int(P.material[std::size_t(worst)]) : 0;
  const std::int64_t id = worst >= 0 ? std::int64_t(P.id[std::size_t(worst)]) : -1;
  std::ostringstream msg;
  msg << scene_.source << ": simulation unstable at step " << steps_ + 1 << ", t = " << detail::fmt(time_ + double(dt))
      << " s: particle " << id << " (material \"" << scene_.materials[mat].name << "\") " << what;
  if (cg_.unconverged > 0)
    msg << " (the implicit CG solve missed solver.cg_tolerance in " << cg_.unconverged << " of " << cg_.solves
        << " substeps; try a larger solver.cg_max_iterations)";
  msg << ". No further frames are written. Try a smaller solver.cfl, solver.elastic_cfl or solver.max_dt"
      << ", or a stiffer boundary.";
  return msg.str();
}

template <class T, int Dim>
T MpmSolver<T, Dim>::kinetic_energy() const {
  const T* m = particles_.m.read_base();
  const std::size_t mask = particles_.m.read_mask();
  T e = 0;
  for (std::size_t p = 0; p < particles_.size(); ++p)
    e += T(0.5) * m[p & mask] * particles_.v[p].squaredNorm();
  return e;
}

template <class T, int Dim>
T MpmSolver<T, Dim>::elastic_energy() const {
  const auto& P = particles_;
  const T* vol0 = P.vol0.read_base();
  const std::size_t mask = P.vol0.read_mask();
  T e = 0;
  for (std::size_t p = 0; p < P.size(); ++p) {
    const auto& mat = materials_[P.material.empty() ? 0 : P.material[p]];
    if (mat.fluid) continue;
    mat.visit_elastic([&](const auto& model) { e += vol0[p & mask] * model.energy(P.F[p]); });
  }
  return e;
}

template <class T, int Dim>
RunStats MpmSolver<T, Dim>::take_stats() {
  const auto& P = particles_;
  RunStats s;
  s.time = time_;
  s.particles = P.size();
  add_particle_sums(s, P.x, P.v, P.m.per_particle(), double(P.m.value()), scene_.solver.gravity);
  s.elastic = double(elastic_energy());
  const T* vol0 = P.vol0.read_base();
  const std::size_t mask = P.vol0.read_mask();
  for (std::size_t p = 0; p < P.size(); ++p) {
    const bool fluid = detail::tracks_J(P, materials_, p);
    const double J = fluid ? double(P.J[p]) : double(P.F[p].determinant());
    s.volume += double(vol0[p & mask]) * J;
    if (fluid) s.max_fluid_J_error = std::max(s.max_fluid_J_error, std::abs(J - 1));
  }
  s.projected = projected_;
  s.cfl = double(cfl_reached_);
  projected_ = 0;
  cfl_reached_ = 0;
  if (split_) {  // the sums of every rank (in another order than one process: the last digits may differ)
    double sums[] = {s.mass, s.momentum[0], s.momentum[1], s.momentum[2], s.angular_momentum[0], s.angular_momentum[1],
                     s.angular_momentum[2], s.kinetic, s.potential, s.elastic, s.volume, double(s.particles),
                     double(s.projected)};
    split_->comm->sum(sums, int(std::size(sums)));
    s.mass = sums[0];
    s.momentum = {sums[1], sums[2], sums[3]};
    s.angular_momentum = {sums[4], sums[5], sums[6]};
    s.kinetic = sums[7], s.potential = sums[8], s.elastic = sums[9], s.volume = sums[10];
    s.particles = std::size_t(sums[11]);
    s.projected = std::int64_t(sums[12]);
    split_->comm->max(&s.max_fluid_J_error, 1);  // cfl is global already (max_speed_ is)
  }
  return s;
}

template <class T, int Dim>
void MpmSolver<T, Dim>::save_state(const StateSink& out) const {
  // A split run writes every rank's particles (on every rank): such a state resumes on any
  // number of processes, since the bins order particles by id, not by storage.
  if (split_)
    write_state(all_particles(true), out, false);
  else
    write_state(particles_, out, false);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::save_own_state(const StateSink& out) const {
  if (split_)
    write_state(particles_, out, true);
  else
    save_state(out);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::write_state(const Particles<T, Dim>& P, const StateSink& out, bool part) const {
  // Between substeps the grid, the bins and the stress are scratch (rebuilt by every substep);
  // what carries over is the particles in their storage order (the periodic re-sort depends on
  // steps_), the step and time, the speed and wave-speed limits of the next stable_dt() (snow
  // hardening raises a material's wave speed), and the counters of take_stats(). A part (one
  // process's particles of a split run) says which of how many it is; the rest it carries is
  // the same on every process.
  detail::StateWriter w(out);
  detail::write_layout<T, Dim>(w, detail::kTagMpm);
  if (part) {
    w.tag(detail::kTagPart);
    w.pod(std::int32_t(split_->comm->rank()));
    w.pod(std::int32_t(split_->comm->size()));
  }
  w.pod(P.channels);
  w.vec(P.x);
  w.vec(P.v);
  // Mass and rest volume are written per particle, also while stored once (the file format
  // predates that); load_state stores them once again when they are all equal.
  detail::write_scalar_channel(w, P.m, P.size());
  detail::write_scalar_channel(w, P.vol0, P.size());
  w.vec(P.F);
  w.vec(P.J);
  w.vec(P.C);
  w.vec(P.plastic);
  w.vec(P.material);
  w.vec(P.id);
  w.pod(time_);
  w.pod(steps_);
  w.pod(max_speed_);
  w.pod(max_wave_speed_);
  w.pod(std::uint64_t(materials_.size()));
  for (const auto& m : materials_) w.pod(m.wave_speed);
  // Particles projected since the last statistics: this process's in a part; all processes'
  // in a split run's whole state (save_state is collective there).
  double projected = double(projected_);
  if (split_ && !part) split_->comm->sum(&projected, 1);
  w.pod(std::int64_t(projected));
  w.pod(cfl_reached_);
  w.pod(cg_.last_iterations);
  w.pod(cg_.last_residual);
  w.pod(cg_.solves);
  w.pod(cg_.iterations);
  w.pod(cg_.unconverged);
  if (sleep_) {  // only scenes with solver.sleep carry it (same scene hash on resume)
    const auto& S = *sleep_;
    w.vec(S.calm);
    w.vec(S.seen);
    std::vector<std::int64_t> keys;
    for (const auto& [k, blk] : S.asleep) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    w.pod(std::uint64_t(keys.size()));
    for (const auto k : keys) {
      const auto& blk = S.asleep.at(k);
      w.pod(k);
      w.pod(blk.count);
      w.pod(blk.hardening);
    }
    w.pod(S.woken);
    w.pod(S.slept);
  }
  w.tag(detail::kTagEnd);
}

template <class T, int Dim>
void MpmSolver<T, Dim>::read_particles(detail::StateReader& r, Particles<T, Dim>& P) const {
  const Channels c = r.get<Channels>();
  if (c.F != P.channels.F || c.J != P.channels.J || c.C != P.channels.C || c.plastic != P.channels.plastic ||
      c.material != P.channels.material)
    r.fail("its particles carry other channels (F, J, C, plastic, material) than this scene's materials and transfer need");
  r.vec(P.x, -1, "x");
  const auto n = std::int64_t(P.x.size());
  r.vec(P.v, n, "v");
  detail::read_scalar_channel(r, P.m, n, "m");
  detail::read_scalar_channel(r, P.vol0, n, "vol0");
  r.vec(P.F, c.F ? n : 0, "F");
  r.vec(P.J, c.J ? n : 0, "J");
  r.vec(P.C, c.C ? n : 0, "C");
  r.vec(P.plastic, c.plastic ? n : 0, "plastic");
  r.vec(P.material, c.material ? n : 0, "material");
  r.vec(P.id, n, "id");
  for (const auto k : P.material)
    if (k >= materials_.size()) r.fail("a particle's material " + std::to_string(k) + " is not one of this scene's");
  detail::require_inside(r, P.x, x_lo_, x_hi_);
  detail::require_finite(r, P.v, "the velocity");
  for (std::int64_t p = 0; p < n; ++p)
    if (!(P.m[std::size_t(p)] > T(0) && std::isfinite(P.m[std::size_t(p)]) && P.vol0[std::size_t(p)] > T(0) &&
          std::isfinite(P.vol0[std::size_t(p)])))
      r.fail("the mass or rest volume of particle " + std::to_string(p) + " is not a finite value > 0");
  detail::require_finite(r, P.F, "F");
  detail::require_positive(r, P.J, "J");
  detail::require_finite(r, P.C, "C");
  detail::require_finite(r, P.plastic, "the plastic state");
}

template <class T, int Dim>
void MpmSolver<T, Dim>::read_scalars(detail::StateReader& r) {
  r.pod(time_);
  if (!(time_ >= 0 && std::isfinite(time_))) r.fail("its time is not a finite value >= 0");
  r.pod(steps_);
  r.pod(max_speed_);
  r.pod(max_wave_speed_);
  if (r.get<std::uint64_t>() != materials_.size()) r.fail("it has another number of materials");
  for (auto& m : materials_) r.pod(m.wave_speed);
  r.pod(projected_);
  r.pod(cfl_reached_);
  r.pod(cg_.last_iterations);
  r.pod(cg_.last_residual);
  r.pod(cg_.solves);
  r.pod(cg_.iterations);
  r.pod(cg_.unconverged);
  if (sleep_) {
    auto& S = *sleep_;
    r.vec(S.calm, std::int64_t(S.calm.size()), "sleep calm counts");
    r.vec(S.seen, std::int64_t(S.seen.size()), "sleep steps");
    S.asleep.clear();
    const auto blocks = r.get<std::uint64_t>();
    if (blocks > S.calm.size()) r.fail("it has more sleeping blocks than the grid has blocks");
    for (std::uint64_t i = 0; i < blocks; ++i) {
      const auto k = r.get<std::int64_t>();
      if (k < 0 || std::uint64_t(k) >= S.calm.size()) r.fail("a sleeping block lies outside the grid");
      typename SleepState::Block blk;
      r.pod(blk.count);
      r.pod(blk.hardening);
      S.asleep.emplace(k, std::move(blk));  // its grid contribution is scattered again (cached = false)
    }
    r.pod(S.woken);
    r.pod(S.slept);
  }
}

template <class T, int Dim>
void MpmSolver<T, Dim>::load_state(std::string_view in, const std::string& what) {
  detail::StateReader r(in, what);
  detail::read_layout<T, Dim>(r, detail::kTagMpm, "MPM");
  auto& P = particles_;
  read_particles(r, P);
  detail::require_unique_ids(r, P.id, std::uint64_t(P.size()));  // an MPM frame's row is its particle's id
  read_scalars(r);
  r.tag(detail::kTagEnd, "end");
  r.finish();
  if (split_) {
    split_->total = P.size();
    split_particles();
    if (split_->comm->rank() != 0) projected_ = 0;  // the count is every process's: rank 0 keeps it
  }
}

template <class T, int Dim>
void MpmSolver<T, Dim>::load_state_parts(int parts, const std::function<std::string(int)>& part,
                                         const std::string& what) {
  // Each part is read whole, one at a time; a split run reads every part twice: first its
  // positions, for the particle counts per block that place the box borders of this
  // run's process count, then its particles, keeping those of its own slab. No process holds more
  // than its own particles and one part.
  if (parts < 1) throw IoError(what + ": a checkpoint of no parts");
  // Opens part i (its bytes into `bytes`), checked to say "part i of `parts`", at its particles.
  auto open = [&](int i, std::string& bytes) {
    bytes = part(i);
    auto r = std::make_unique<detail::StateReader>(bytes, what + " (part " + std::to_string(i) + ")");
    detail::read_layout<T, Dim>(*r, detail::kTagMpm, "MPM");
    r->tag(detail::kTagPart, "part");
    const auto rank = r->get<std::int32_t>(), ranks = r->get<std::int32_t>();
    if (rank != i || ranks != parts)
      r->fail("it says part " + std::to_string(rank) + " of " + std::to_string(ranks) + "; expected part " +
              std::to_string(i) + " of " + std::to_string(parts) + " (the files checkpoint_NNNN.rank0.slc to rank" +
              std::to_string(parts - 1) + ")");
    return r;
  };
  if (split_) {
    std::vector<double> counts;
    for (int i = 0; i < parts; ++i) {
      std::string bytes;
      auto r = open(i, bytes);
      r->template get<Channels>();  // checked in the second pass
      std::vector<Vec> x;
      r->vec(x, -1, "x");
      detail::require_inside(*r, x, x_lo_, x_hi_);
      counts = block_counts(x, std::move(counts));
    }
    for (auto& c : split_->boxes.cuts) c.clear();
    set_borders(counts, true);
  }
  Particles<T, Dim> P = particles_.empty_like();
  std::uint64_t total = 0;
  double t0 = 0;
  std::int64_t projected = 0;
  for (int i = 0; i < parts; ++i) {
    std::string bytes;
    auto r = open(i, bytes);
    Particles<T, Dim> Q = particles_.empty_like();
    read_particles(*r, Q);
    read_scalars(*r);
    r->tag(detail::kTagEnd, "end");
    r->finish();
    if (i == 0) t0 = time_;
    if (time_ != t0) r->fail("its time " + std::to_string(time_) + " s differs from part 0's " + std::to_string(t0) + " s");
    projected += projected_;
    total += Q.size();
    for (std::size_t p = 0; p < Q.size(); ++p)
      if (!split_ || owns(Q.x[p])) P.push_back_from(Q, p);
  }
  // Ids are 0 .. total - 1, each once: this process checks its own (an MPM frame's row is its
  // particle's id).
  std::vector<bool> seen(total, false);
  for (const auto id : P.id) {
    if (id >= total || seen[id])
      throw IoError(what + ": particle id " + std::to_string(id) + (id >= total ? " is out of range" : " appears twice") +
                    " in its parts; expected the ids 0 .. " + std::to_string(total) + " - 1 once each");
    seen[id] = true;
  }
  particles_ = std::move(P);
  projected_ = !split_ || split_->comm->rank() == 0 ? projected : 0;
  if (split_) split_->total = total;
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::frame(const std::vector<std::string>& attributes) const {
  if (!split_) return frame_of(particles_, attributes);
  // Gathered on rank 0, which writes the frame; kept there for particle_storage().
  auto& gathered = split_->gathered;
  gathered = all_particles(false);
  return split_->comm->rank() == 0 ? frame_of(gathered, attributes) : Frame{};
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::own_frame(const std::vector<std::string>& attributes) const {
  if (!split_) return frame(attributes);
  // This process's particles in ascending id: row r holds the r-th smallest id it owns.
  const auto& P = particles_;
  std::vector<std::uint32_t> order(P.size()), rows(P.size());
  for (std::size_t p = 0; p < order.size(); ++p) order[p] = std::uint32_t(p);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return P.id[a] < P.id[b]; });
  for (std::size_t r = 0; r < order.size(); ++r) rows[order[r]] = std::uint32_t(r);
  const bool requested = std::find(attributes.begin(), attributes.end(), "id") != attributes.end();
  std::vector<std::string> columns = attributes;
  if (!requested) columns.push_back("id");
  Frame part = frame_of(P, columns, rows.data());
  part.comments.push_back("slurry part " + std::to_string(split_->comm->rank()) + " of " +
                          std::to_string(split_->comm->size()) + (requested ? " id=requested" : " id=added"));
  return part;
}

template <class T, int Dim>
Frame MpmSolver<T, Dim>::frame_of(const Particles<T, Dim>& P, const std::vector<std::string>& attributes,
                                         const std::uint32_t* rows) const {
  // Particles are stored in bin order; frames list them in seeding order (P.id).
  detail::VertexFrame out("", time_, scene_.source, P.size(), rows ? rows : P.id.data());
  for (const auto& a : attributes) {
    if (a == "position") {
      out.add_positions<Dim>(P.x);
    } else if (a == "velocity") {
      out.add_velocities<Dim>(P.v);
    } else if (a == "material") {
      out.add("material", [&](std::size_t p) { return P.material.empty() ? std::uint16_t(0) : P.material[p]; });
    } else if (a == "J") {
      out.add("J", [&](std::size_t p) {
        return detail::tracks_J(P, materials_, p) ? P.J[p] : T(P.F[p].determinant());
      });
    } else if (a == "plastic") {
      out.add("plastic", [&](std::size_t p) { return P.plastic.empty() ? T(0) : P.plastic[p]; });
    } else if (a == "id") {
      out.add("id", [&](std::size_t p) { return P.id[p]; });  // = the row: MPM keeps every particle
    }
  }
  return std::move(out.data());
}

template <class T, int Dim>
ParticleStorage MpmSolver<T, Dim>::particle_storage() const {
  // A split run's rank 0 shows every particle as of the last frame(); other ranks their own.
  const auto& P = split_ && split_->comm->rank() == 0 ? split_->gathered : particles_;
  ParticleStorage s;
  s.precision = std::is_same_v<T, double> ? Precision::Double : Precision::Float;
  s.dimension = Dim;
  s.count = P.size();
  s.x = P.x.data();
  s.v = P.v.data();
  s.id = P.id.data();
  if (!P.material.empty()) s.material = P.material.data();
  if (!P.F.empty()) s.F = P.F.data();
  if (!P.J.empty()) s.J = P.J.data();
  if (!P.plastic.empty()) s.plastic = P.plastic.data();
  return s;
}

}  // namespace slurry
