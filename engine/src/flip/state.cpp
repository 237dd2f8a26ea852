// FlipSolver's checkpoints: the state written and read back (save_state, load_state), whole or
// as one process's part of a split run (save_own_state, load_state_parts). Compiled apart from
// the solver's phases (flip_solver_impl.h) so that these functions' code does not change how the
// compiler lays out and contracts the phases' arithmetic.
#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <string_view>
#include <type_traits>

#include "flip/split.h"
#include "state_io.h"
#include "slurry/engine/flip/flip_solver.h"
#include "slurry/transfer/lattice.h"

namespace slurry::flip {

template <class T, int Dim>
void FlipSolver<T, Dim>::save_state(const StateSink& out) const {
  // Carried over between substeps: the particles in their storage order (with the next id),
  // the emitters' generators and carried fractions, the pressure (the warm start of the next
  // projection), and the face velocities, validity, labels and level set of the last substep.
  // Face weights and solid velocities are rebuilt from the colliders at the next substep;
  // sorting, transfer weights and solver work vectors are scratch.
  if (split_) {
    // The whole state, gathered on rank 0 (which writes it) in one process's layout: particles
    // in ascending id, the grid fields of every box in their places. It resumes on any number
    // of processes.
    auto& S = *split_;
    FlipParticles<T, Dim> all = gather_particles();
    Grid whole;
    whole.res = S.res;
    whole.dx = S.dx;
    whole.origin = S.origin;
    for (int d = 0; d < Dim; ++d) {
      whole.u[std::size_t(d)] = S.gather(grid_.u[std::size_t(d)], d);
      whole.valid[std::size_t(d)] = S.gather(grid_.valid[std::size_t(d)], d);
    }
    whole.label = S.gather(grid_.label, -1);
    whole.phi = S.gather(grid_.phi, -1);
    whole.pressure = S.gather(grid_.pressure, -1);
    WhitewaterParticles<T, Dim> ww;
    double counters[2] = {0, 0};
    if (whitewater_) {
      ww = gather_whitewater();
      counters[0] = double(whitewater_->generated()), counters[1] = double(whitewater_->removed());
      S.comm->sum(counters, 2);
    }
    if (S.comm->rank() == 0)
      write_state(out, all, whole, nullptr, whitewater_ ? &ww : nullptr, std::int64_t(counters[0]), std::int64_t(counters[1]));
    return;
  }
  write_state(out, particles_, grid_);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::write_state(const StateSink& out, const FlipParticles<T, Dim>& P, const Grid& grid,
                                     const StatePart* part, const WhitewaterParticles<T, Dim>* whitewater,
                                     std::int64_t generated, std::int64_t removed) const {
  slurry::detail::StateWriter w(out);
  slurry::detail::write_layout<T, Dim>(w, slurry::detail::kTagFlip);
  if (part) {
    w.tag(slurry::detail::kTagPart);
    w.pod(std::int32_t(part->rank));
    w.pod(std::int32_t(part->ranks));
    for (int d = 0; d < Dim; ++d) w.pod(std::int32_t(part->lo[d])), w.pod(std::int32_t(part->hi[d]));
  }
  // A part holds the fields over its box only (the window's entries there, in the box's order).
  const auto field = [&](const auto& v, int axis) {
    if (!part) return w.vec(v);
    std::remove_cv_t<std::remove_reference_t<decltype(v)>> box;
    split_->for_runs(axis, part->lo, part->hi, [&](std::int64_t i, int n) { box.insert(box.end(), v.begin() + i, v.begin() + i + n); });
    w.vec(box);
  };
  w.pod(std::uint8_t(P.affine));
  w.pod(std::uint8_t(P.has_material));
  w.vec(P.x);
  w.vec(P.v);
  for (int d = 0; d < Dim; ++d) w.vec(P.c[std::size_t(d)]);
  w.vec(P.material);
  w.vec(P.id);
  w.pod(P.next_id);
  for (int d = 0; d < Dim; ++d) {
    field(grid.u[std::size_t(d)], d);
    field(grid.valid[std::size_t(d)], d);
  }
  field(grid.label, -1);
  field(grid.phi, -1);
  field(grid.pressure, -1);
  w.pod(std::uint64_t(emitters_.size()));
  for (const auto& e : emitters_) {
    w.pod(e.carry);
    w.pod(e.emitted);
    w.rng(e.rng);
  }
  w.pod(max_speed_);
  w.pod(cfl_reached_);
  w.pod(time_);
  w.pod(steps_);
  w.pod(reseed_added_);
  w.pod(reseed_removed_);
  const auto& lp = last_projection_;
  w.pod(lp.iterations);
  w.pod(lp.relative_residual);
  w.pod(std::uint8_t(lp.converged));
  w.pod(lp.max_divergence);
  w.pod(lp.unknowns);
  if (whitewater_) {  // only in the state of a scene with whitewater: others keep their layout
    const auto& W = whitewater ? *whitewater : whitewater_->particles();
    w.vec(W.x);
    w.vec(W.v);
    w.vec(W.life);
    w.vec(W.id);
    w.vec(W.type);
    w.pod(W.next_id);
    w.pod(whitewater ? generated : whitewater_->generated());
    w.pod(whitewater ? removed : whitewater_->removed());
  }
  w.tag(slurry::detail::kTagEnd);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::load_state(std::string_view in, const std::string& what) {
  if (!split_) {
    read_state(in, what, particles_, grid_);
    return;
  }
  // Every rank reads the whole state and keeps its own particles and its window of the fields.
  auto& S = *split_;
  FlipParticles<T, Dim> all;
  all.affine = particles_.affine;
  all.has_material = particles_.has_material;
  Grid whole;
  whole.res = S.res;
  whole.dx = S.dx;
  whole.origin = S.origin;
  read_state(in, what, all, whole);
  const int me = S.comm->rank();
  std::size_t n = 0;
  for (std::size_t p = 0; p < all.size(); ++p)
    if (S.owner(all.x[p]) == me) all.move(n++, p);
  all.truncate(n);
  particles_ = std::move(all);
  S.own = particles_.size();
  double total = double(particles_.size());
  S.comm->sum(&total, 1);
  S.total = std::uint64_t(total);
  for (int d = 0; d < Dim; ++d) {
    S.crop(whole.u[std::size_t(d)], grid_.u[std::size_t(d)], d);
    S.crop(whole.valid[std::size_t(d)], grid_.valid[std::size_t(d)], d);
  }
  S.crop(whole.label, grid_.label, -1);
  S.crop(whole.phi, grid_.phi, -1);
  S.crop(whole.pressure, grid_.pressure, -1);
  if (whitewater_) {  // the secondary particles in this rank's box; rank 0 keeps the counters
    auto& W = whitewater_->particles();
    std::size_t k = 0;
    for (std::size_t i = 0; i < W.size(); ++i)
      if (S.owner(W.x[i]) == me) W.move(k++, i);
    W.resize(k);
    if (me != 0) whitewater_->generated() = 0, whitewater_->removed() = 0;
  }
}

template <class T, int Dim>
void FlipSolver<T, Dim>::read_state(std::string_view in, const std::string& what, FlipParticles<T, Dim>& P, Grid& grid,
                                    StatePart* part) {
  slurry::detail::StateReader r(in, what);
  slurry::detail::read_layout<T, Dim>(r, slurry::detail::kTagFlip, "FLIP");
  // The fields' sizes: the grid's, or a part's box's (grid.res is the domain's).
  IVec cells = grid.res;
  if (part) {
    r.tag(slurry::detail::kTagPart, "part");
    part->rank = r.get<std::int32_t>();
    part->ranks = r.get<std::int32_t>();
    for (int d = 0; d < Dim; ++d) {
      part->lo[d] = r.get<std::int32_t>(), part->hi[d] = r.get<std::int32_t>();
      if (!(0 <= part->lo[d] && part->lo[d] < part->hi[d] && part->hi[d] <= grid.res[d]))
        r.fail("its box of cells is not inside this scene's grid");
    }
    cells = part->hi - part->lo;
  }
  const auto faces = [&](int d) {
    IVec n = cells;
    if (!part || part->hi[d] == grid.res[d]) n[d] += 1;
    std::int64_t k = 1;
    for (int a = 0; a < Dim; ++a) k *= n[a];
    return k;
  };
  if (r.get<std::uint8_t>() != std::uint8_t(P.affine) || r.get<std::uint8_t>() != std::uint8_t(P.has_material))
    r.fail("its particles carry other channels (APIC vectors, material) than this scene's transfer and materials need");
  r.vec(P.x, -1, "x");
  const auto n = std::int64_t(P.x.size());
  r.vec(P.v, n, "v");
  for (int d = 0; d < Dim; ++d) r.vec(P.c[std::size_t(d)], P.affine ? n : 0, "c");
  r.vec(P.material, P.has_material ? n : 0, "material");
  r.vec(P.id, n, "id");
  r.pod(P.next_id);
  for (const auto k : P.material)
    if (k >= scene_.materials.size()) r.fail("a particle's material " + std::to_string(k) + " is not one of this scene's");
  slurry::detail::require_inside(r, P.x, grid.origin, Vec(grid.origin + grid.res.template cast<T>() * grid.dx));
  slurry::detail::require_finite(r, P.v, "the velocity");
  for (int d = 0; d < Dim; ++d) slurry::detail::require_finite(r, P.c[std::size_t(d)], "the affine vector");
  slurry::detail::require_unique_ids(r, P.id, P.next_id);
  for (int d = 0; d < Dim; ++d) {
    r.vec(grid.u[std::size_t(d)], faces(d), "u");
    r.vec(grid.valid[std::size_t(d)], faces(d), "valid");
  }
  std::int64_t count = 1;
  for (int d = 0; d < Dim; ++d) count *= cells[d];
  r.vec(grid.label, count, "label");
  r.vec(grid.phi, count, "phi");
  r.vec(grid.pressure, count, "pressure");
  if (r.get<std::uint64_t>() != emitters_.size()) r.fail("it has another number of emitters");
  for (auto& e : emitters_) {
    r.pod(e.carry);
    r.pod(e.emitted);
    r.rng(e.rng);
  }
  r.pod(max_speed_);
  r.pod(cfl_reached_);
  r.pod(time_);
  if (!(time_ >= 0 && std::isfinite(time_))) r.fail("its time is not a finite value >= 0");
  r.pod(steps_);
  r.pod(reseed_added_);
  r.pod(reseed_removed_);
  auto& lp = last_projection_;
  r.pod(lp.iterations);
  r.pod(lp.relative_residual);
  lp.converged = r.get<std::uint8_t>() != 0;
  r.pod(lp.max_divergence);
  r.pod(lp.unknowns);
  if (whitewater_) {
    auto& W = whitewater_->particles();
    r.vec(W.x, -1, "whitewater x");
    const auto m = std::int64_t(W.x.size());
    r.vec(W.v, m, "whitewater v");
    r.vec(W.life, m, "whitewater life");
    r.vec(W.id, m, "whitewater id");
    r.vec(W.type, m, "whitewater type");
    r.pod(W.next_id);
    r.pod(whitewater_->generated());
    r.pod(whitewater_->removed());
    slurry::detail::require_finite(r, W.v, "the whitewater velocity");
    for (const auto k : W.type)
      if (k > std::uint8_t(WhitewaterType::Bubble)) r.fail("a whitewater particle's type " + std::to_string(k) + " is not 0, 1 or 2");
  }
  r.tag(slurry::detail::kTagEnd, "end");
  r.finish();
  faces_ready_ = false;  // face weights and solid velocities are rebuilt by the next substep
}

template <class T, int Dim>
void FlipSolver<T, Dim>::save_own_state(const StateSink& out) const {
  if (!split_) return save_state(out);
  const auto& S = *split_;
  StatePart part;
  part.rank = S.comm->rank(), part.ranks = S.comm->size(), part.lo = S.lo, part.hi = S.hi;
  write_state(out, particles_, grid_, &part);
}

template <class T, int Dim>
void FlipSolver<T, Dim>::load_state_parts(int parts, const std::function<std::string(int)>& part, const std::string& what) {
  // Each part is read whole, one at a time; this process keeps the particles it owns (all of
  // them in one process) and the parts' fields where they meet its window (the whole grid).
  if (parts < 1) throw IoError(what + ": a checkpoint of no parts");
  const IVec res = split_ ? split_->res : grid_.res;
  const IVec wlo = split_ ? split_->wlo : IVec::Zero(), wres = split_ ? IVec(split_->whi - split_->wlo) : grid_.res;
  const int me = split_ ? split_->comm->rank() : 0;
  std::string mine, mine_whitewater;  // the kept particles, packed
  std::uint64_t total = 0;
  std::uint32_t next_id = 0, next_whitewater_id = 0;
  std::int64_t generated = 0, removed = 0;
  for (int i = 0; i < parts; ++i) {
    const std::string name = what + " (part " + std::to_string(i) + ")";
    FlipParticles<T, Dim> Q;
    Q.affine = particles_.affine, Q.has_material = particles_.has_material;
    Grid box;
    box.res = res, box.dx = grid_.dx, box.origin = grid_.origin;
    StatePart info;
    read_state(part(i), name, Q, box, &info);
    if (info.rank != i || info.ranks != parts)
      throw IoError(name + ": it says part " + std::to_string(info.rank) + " of " + std::to_string(info.ranks) +
                    "; expected part " + std::to_string(i) + " of " + std::to_string(parts) +
                    " (the files checkpoint_NNNN.rank0.slc to rank" + std::to_string(parts - 1) + ")");
    total += Q.size();
    next_id = std::max(next_id, Q.next_id);
    for (std::size_t p = 0; p < Q.size(); ++p)
      if (!split_ || split_->owner(Q.x[p]) == me) detail::pack_particle(Q, p, mine);
    if (whitewater_) {  // read into whitewater_ by read_state: this part's secondary particles and counters
      const auto& W = whitewater_->particles();
      for (std::size_t p = 0; p < W.size(); ++p)
        if (!split_ || split_->owner(W.x[p]) == me) detail::pack_whitewater(W, p, mine_whitewater);
      next_whitewater_id = std::max(next_whitewater_id, W.next_id);
      generated += whitewater_->generated(), removed += whitewater_->removed();
    }
    const auto paste = [&](const auto& from, auto& to, int axis) {
      IVec n = info.hi - info.lo, window = wres;
      if (axis >= 0) window[axis] += 1, n[axis] += info.hi[axis] == res[axis] ? 1 : 0;
      std::int64_t count = 1;
      for (int d = 0; d < Dim; ++d) count *= n[d];
      for (std::int64_t k = 0; k < count; ++k) {
        const IVec at = IVec(transfer::lattice_coord<Dim>(k, n) + info.lo - wlo);
        if ((at.array() >= 0).all() && (at.array() < window.array()).all())
          to[std::size_t(transfer::lattice_index<Dim>(at, window))] = from[std::size_t(k)];
      }
    };
    for (int d = 0; d < Dim; ++d) {
      paste(box.u[std::size_t(d)], grid_.u[std::size_t(d)], d);
      paste(box.valid[std::size_t(d)], grid_.valid[std::size_t(d)], d);
    }
    paste(box.label, grid_.label, -1);
    paste(box.phi, grid_.phi, -1);
    paste(box.pressure, grid_.pressure, -1);
  }
  FlipParticles<T, Dim> P;
  P.affine = particles_.affine, P.has_material = particles_.has_material;
  detail::unpack_particles(mine, P);
  P.next_id = next_id;
  particles_ = std::move(P);
  if (split_) split_->own = particles_.size(), split_->total = total;
  if (whitewater_) {
    WhitewaterParticles<T, Dim> W;
    detail::unpack_whitewater(mine_whitewater, W);
    detail::sort_whitewater(W);
    W.next_id = next_whitewater_id;
    whitewater_->particles() = std::move(W);
    whitewater_->generated() = me == 0 ? generated : 0;
    whitewater_->removed() = me == 0 ? removed : 0;
  }
}

#define SLURRY_FLIP_STATE(T, Dim)                                                                      \
  template void FlipSolver<T, Dim>::save_state(const StateSink&) const;                                \
  template void FlipSolver<T, Dim>::load_state(std::string_view, const std::string&);                  \
  template void FlipSolver<T, Dim>::save_own_state(const StateSink&) const;                            \
  template void FlipSolver<T, Dim>::load_state_parts(int, const std::function<std::string(int)>&,     \
                                                     const std::string&);              \
  template void FlipSolver<T, Dim>::write_state(const StateSink&, const FlipParticles<T, Dim>&,      \
                                                const Grid&, const StatePart*,                       \
                                                const WhitewaterParticles<T, Dim>*, std::int64_t,    \
                                                std::int64_t) const;                                 \
  template void FlipSolver<T, Dim>::read_state(std::string_view, const std::string&,                 \
                                               FlipParticles<T, Dim>&, Grid&, StatePart*);
SLURRY_FLIP_STATE(float, 2)
SLURRY_FLIP_STATE(float, 3)
SLURRY_FLIP_STATE(double, 2)
SLURRY_FLIP_STATE(double, 3)
#undef SLURRY_FLIP_STATE

}  // namespace slurry::flip
