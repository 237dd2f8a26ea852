#pragma once
/// \file seeding.h
/// Where FLIP particles come from and how their density is kept in bounds:
///  - seed_body: a body's shape filled on a regular (or seeded jittered) lattice of spacing
///    dx / ppc^(1/Dim), exactly as the MPM solver seeds bodies;
///  - Emitter: a box or sphere inflow region kept filled at ppc particles per cell (seeded
///    std::mt19937_64 positions), at most rate * dt * ppc / dx^Dim new particles per substep;
///  - reseed: after advection, cells deep in the liquid (every face neighbour holds particles,
///    is solid or is outside the domain) with fewer than min_per_cell particles get new ones at
///    random positions with the grid's velocity, and cells with more than max_per_cell lose the
///    surplus (the highest-index ones). New positions come from a counter-based generator keyed
///    by (seed, step, cell), so reseeding is parallel and reproducible for any thread count.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/flip/cell_sort.h"
#include "slurry/engine/flip/flip_particles.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/split_window.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// Uniform double in [0, 1) from 64 random bits (bit-for-bit portable).
inline double to_unit(std::uint64_t bits) { return double(bits >> 11) * 0x1.0p-53; }

/// SplitMix64 (Steele, Lea & Flood 2014): a counter-based generator step.
inline std::uint64_t splitmix64(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// Positions filling a body's shape (box, sphere, cylinder) at spacing dx / ppc^(1/Dim).
template <class T, int Dim>
std::vector<Eigen::Matrix<T, Dim, 1>> seed_body(const BodyParams& b, double dx) {
  using DVec = Eigen::Matrix<double, Dim, 1>;
  DVec lo, hi;
  const DVec c = b.center.head<Dim>();
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
  const double h_target = dx / std::pow(b.particles_per_cell, 1.0 / Dim);
  Eigen::Matrix<int, Dim, 1> n;
  DVec h;
  for (int d = 0; d < Dim; ++d) {
    n[d] = std::max(1, int(std::lround((hi[d] - lo[d]) / h_target)));
    h[d] = (hi[d] - lo[d]) / n[d];
  }
  std::mt19937_64 rng(b.seed);
  std::vector<Eigen::Matrix<T, Dim, 1>> out;
  const std::int64_t total = std::int64_t(n.template cast<std::int64_t>().prod());
  Eigen::Matrix<int, Dim, 1> i;
  for (std::int64_t k = 0; k < total; ++k) {
    std::int64_t r = k;
    for (int d = Dim - 1; d >= 0; --d) i[d] = int(r % n[d]), r /= n[d];
    DVec x;
    for (int d = 0; d < Dim; ++d) {
      const double u = b.sampling == Sampling::Jittered ? to_unit(rng()) : 0.5;
      x[d] = lo[d] + (i[d] + u) * h[d];
    }
    bool inside = true;
    if (b.shape == Shape::Sphere) {
      inside = (x - c).squaredNorm() <= b.radius * b.radius;
    } else if (b.shape == Shape::Cylinder) {
      DVec r2 = x - c;
      r2[b.axis] = 0;
      inside = r2.squaredNorm() <= b.radius * b.radius;
    }
    if (inside) out.push_back(x.template cast<T>());
  }
  return out;
}

/// A liquid source (scene `emitters[]`): an inflow region kept full of liquid moving at
/// `velocity`. Each substep every cell whose centre lies in the shape is topped up to
/// particles_per_cell with particles at seeded random positions in the cell (inside the shape),
/// and particles inside the shape take the emitter's velocity. The particles added per substep
/// are capped by rate * dt * ppc / dx^Dim (fractional parts carried over), so the emitted volume
/// is min(rate, what the region lets out) per second, to within one particle.
template <class T, int Dim>
struct Emitter {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  EmitterParams params;
  std::uint16_t material = 0;
  double carry = 0;  ///< fractional particle owed from earlier substeps
  std::int64_t emitted = 0;
  std::mt19937_64 rng;
  std::vector<std::int32_t> counts;  // particles per cell of the emitter's cell box

  Emitter(const EmitterParams& p, std::uint16_t mat) : params(p), material(mat), rng(p.seed) {}

  /// Largest number of particles allowed for the substep [t, t + dt] (the part inside
  /// [start, end]).
  std::int64_t allowance(double t, double dt, double dx) {
    const double a = std::max(t, params.start), b = std::min(t + dt, params.end);
    if (!(b > a)) return 0;
    const double exact = params.rate * (b - a) * params.particles_per_cell / std::pow(dx, Dim) + carry;
    const double whole = std::floor(exact);
    carry = exact - whole;
    return std::int64_t(whole);
  }

  bool inside(const Vec& x) const {
    const Eigen::Matrix<double, Dim, 1> y = x.template cast<double>();
    if (params.shape == Shape::Sphere) return (y - params.center.head<Dim>()).squaredNorm() <= params.radius * params.radius;
    return (y.array() >= params.min.head<Dim>().array()).all() && (y.array() <= params.max.head<Dim>().array()).all();
  }

  /// Tops up the emitter's cells for the substep [t, t + dt]; returns the particles added. `g`
  /// gives the domain's cells (only its res, dx and origin are read). `sum`, if given, adds the
  /// counts of particles per emitter cell over the processes of a split run (every process then
  /// draws and adds the same particles, and keeps those it owns).
  std::int64_t emit(FlipParticles<T, Dim>& P, const MacGrid<T, Dim>& g, double t, double dt,
                    const std::function<void(std::vector<std::int32_t>&)>& sum = {}) {
    std::int64_t budget = allowance(t, dt, double(g.dx));
    const bool active = t + dt > params.start && t < params.end;
    if (!active) return 0;
    const Vec v = params.velocity.head<Dim>().template cast<T>();
    // The box of cells the shape touches.
    Eigen::Matrix<double, Dim, 1> lo, hi;
    if (params.shape == Shape::Sphere) {
      lo = params.center.head<Dim>().array() - params.radius;
      hi = params.center.head<Dim>().array() + params.radius;
    } else {
      lo = params.min.head<Dim>();
      hi = params.max.head<Dim>();
    }
    IVec c0, n;
    std::int64_t cells = 1;
    for (int d = 0; d < Dim; ++d) {
      c0[d] = std::clamp(int(std::floor((lo[d] - g.origin[d]) / g.dx)), 0, g.res[d] - 1);
      const int c1 = std::clamp(int(std::floor((hi[d] - g.origin[d]) / g.dx)), 0, g.res[d] - 1);
      n[d] = c1 - c0[d] + 1;
      cells *= n[d];
    }
    auto local = [&](const Vec& x, std::int64_t& k) {
      k = 0;
      for (int d = 0; d < Dim; ++d) {
        const int i = int(std::floor((x[d] - g.origin[d]) / g.dx)) - c0[d];
        if (i < 0 || i >= n[d]) return false;
        k = k * n[d] + i;
      }
      return true;
    };
    counts.assign(std::size_t(cells), 0);
    for (std::size_t p = 0; p < P.size(); ++p) {
      std::int64_t k;
      if (local(P.x[p], k)) ++counts[std::size_t(k)];
      if (inside(P.x[p])) P.v[p] = v;
    }
    if (sum) sum(counts);
    const int target = int(std::lround(params.particles_per_cell));
    std::int64_t added = 0;
    for (std::int64_t k = 0; k < cells && budget > 0; ++k) {
      IVec i;
      std::int64_t r = k;
      for (int d = Dim - 1; d >= 0; --d) i[d] = int(r % n[d]) + c0[d], r /= n[d];
      if (!inside(g.cell_center(i))) continue;
      for (int q = counts[std::size_t(k)]; q < target && budget > 0; ++q) {
        // A random point of the cell inside the shape (a few tries; the centre is inside).
        Vec x = g.cell_center(i);
        for (int attempt = 0; attempt < 8; ++attempt) {
          Vec y;
          for (int d = 0; d < Dim; ++d) y[d] = g.origin[d] + (T(i[d]) + T(0.001 + 0.998 * to_unit(rng()))) * g.dx;
          if (inside(y)) {
            x = y;
            break;
          }
        }
        P.push_back(x, v, material);
        --budget;
        ++added;
      }
    }
    // What the region could not take is not owed later.
    if (budget > 0) carry = 0;
    emitted += added;
    return added;
  }
};

struct ReseedCounts {
  std::int64_t added = 0, removed = 0;
};

/// Reseeding scratch kept between steps.
template <class T, int Dim>
struct Reseeder {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  CellSort<T, Dim> sort;
  std::vector<std::int32_t> seen;
  std::vector<std::int64_t> need;  // particles to add per cell, then their prefix sums
  std::vector<std::uint16_t> cell_material;
  std::vector<std::uint8_t> hole;
  std::vector<std::uint32_t> first_id;  // a split run's: each reseeded cell's first new id

  /// Where the grid lies in the domain's when a run is split over processes (split_window.h;
  /// the grid is one process's window, its particles those of its own cells), with the particles
  /// per cell of the window: its own cells' and, from their owners, those of the 2 cells around
  /// its box.
  struct Window : SplitWindow<Dim> {
    const std::vector<double>* counts = nullptr;
  };

  /// `init(x, v, c)` sets the velocity (and APIC affine vectors, c may be null) of a new particle
  /// at x from the grid. Cells labelled Solid in `g` count as full neighbours. `w`: a split
  /// run's window (Window); every process calls run() alike.
  template <class InitFn>
  ReseedCounts run(FlipParticles<T, Dim>& P, const MacGrid<T, Dim>& g, int min_per_cell, int max_per_cell,
                   std::uint64_t seed, std::int64_t step, InitFn&& init, const Window* w = nullptr) {
    ReseedCounts out;
    sort.build(P.x, g.origin, g.dx, g.res, false, g.offset);
    const std::int64_t cells = g.num_cells();
    const auto& start = sort.start;
    // Whether a cell's particles are empty (the window's counts in a split run: its ring's come
    // from their owners).
    const auto empty = [&](std::int64_t k) { return w ? (*w->counts)[std::size_t(k)] == 0 : start[k + 1] == start[k]; };
    // Remove the surplus of over-full cells (serial and stable: the highest indices go).
    bool crowded = false;
    for (std::int64_t k = 0; k < cells && !crowded && max_per_cell > 0; ++k) crowded = sort.count(k) > max_per_cell;
    if (crowded) {
      seen.assign(std::size_t(cells), 0);
      std::size_t w = 0;
      for (std::size_t p = 0; p < P.size(); ++p) {
        if (++seen[std::size_t(sort.key[p])] > max_per_cell) continue;
        if (w != p) P.move(w, p);
        ++w;
      }
      out.removed = std::int64_t(P.size() - w);
      P.truncate(w);
      sort.build(P.x, g.origin, g.dx, g.res, false);
    }
    if (min_per_cell <= 0) return out;
    // Starving interior cells: every face neighbour holds particles, is solid, is outside the
    // domain, or is an empty hole that this pass fills (so no cell is left starving next to a
    // hole that becomes full).
    auto enclosed = [&](std::int64_t k, bool holes_count_as_full) {
      return !g.any_face_neighbour(k, [&](std::int64_t kj) {
        return empty(kj) && g.label[kj] != MacGrid<T, Dim>::Solid && !(holes_count_as_full && hole[kj]);
      });
    };
    hole.resize(std::size_t(cells));
    parallel::parallel_for(0, cells, [&](std::int64_t k) {
      hole[k] = empty(k) && g.label[k] != MacGrid<T, Dim>::Solid && enclosed(k, false);
    });
    need.assign(std::size_t(cells + 1), 0);
    parallel::parallel_for(0, cells, [&](std::int64_t k) {
      if (w && !w->owns(g.cell_coord(k))) return;
      const std::int64_t n = sort.count(k);
      if (n >= min_per_cell || g.label[k] == MacGrid<T, Dim>::Solid) return;
      if (hole[k] || enclosed(k, true)) need[k + 1] = min_per_cell - n;
    });
    std::uint32_t next_id = 0;
    if (w)  // the ids over every process's cells (first_id: each cell's first)
      next_id = number_new_particles(
          g, *w, [&](std::int64_t k) { return std::uint32_t(need[k + 1]); }, first_id);
    for (std::int64_t k = 0; k < cells; ++k) need[k + 1] += need[k];
    const std::int64_t added = need[cells];
    if (w) P.next_id = next_id - std::uint32_t(added);  // push_back below counts up to next_id
    if (added == 0) return out;
    if (P.has_material) {  // the material of a new particle: that of the last one found in its cell
      cell_material.assign(std::size_t(cells), 0);
      for (std::size_t p = 0; p < P.size(); ++p) cell_material[std::size_t(sort.key[p])] = P.material[p];
    }
    const std::size_t n0 = P.size();
    for (std::int64_t a = 0; a < added; ++a) P.push_back(Vec::Zero(), Vec::Zero(), 0);
    parallel::parallel_for(0, cells, [&](std::int64_t k) {
      if (need[k + 1] == need[k]) return;
      const IVec i = g.cell_coord(k);
      std::uint64_t state = seed ^ (std::uint64_t(step) * 0xD1B54A32D192ED03ull) ^
                            (domain_cell(g, k, w) * 0x8CB92BA72F3D8DD7ull);
      const std::uint16_t mat = P.has_material ? cell_material[k] : 0;
      for (std::int64_t q = need[k]; q < need[k + 1]; ++q) {
        Vec x;
        // Kept off the cell's faces, so rounding never puts the particle in a neighbour.
        for (int d = 0; d < Dim; ++d)
          x[d] = g.origin[d] + (T(i[d] + g.offset[d]) + T(0.001 + 0.998 * to_unit(splitmix64(state)))) * g.dx;
        const std::size_t p = n0 + std::size_t(q);
        P.x[p] = x;
        if (w) P.id[p] = first_id[std::size_t(k)] + std::uint32_t(q - need[k]);
        if (P.has_material) P.material[p] = mat;
        Vec c[Dim];
        init(x, P.v[p], P.affine ? c : nullptr);
        if (P.affine)
          for (int d = 0; d < Dim; ++d) P.c[d][p] = c[d];
      }
    });
    out.added = added;
    return out;
  }

};

}  // namespace slurry::flip
