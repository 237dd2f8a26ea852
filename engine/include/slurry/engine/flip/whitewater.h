#pragma once
/// \file whitewater.h
/// Whitewater of the FLIP liquid: secondary spray, foam and bubble particles, after Ihmsen,
/// Akinci, Akinci & Teschner 2012, "Unified spray, foam and air bubbles for particle-based
/// fluids", The Visual Computer 28(6-8), adapted from SPH neighbourhoods to the MAC grid's cells.
/// One-way coupled: the liquid moves them, they never act on it. A phase of the FLIP substep that
/// runs only when the scene enables `solver.whitewater` (nothing is allocated otherwise).
///
/// Generation (Ihmsen sec. 4), per liquid cell i (label Fluid), from the cell-centre velocity
/// v_i (the mean of its two faces per axis) and the neighbour cells j of its 3^Dim block, with
/// the weight W(r) = 1 - r / h, h = 2 dx:
///   trapped air  I_ta = sum_j |v_ij| (1 - v^_ij . x^_ij) W(|x_ij|)   (liquid moving together;
///                v_ij = v_i - v_j, x_ij = x_i - x_j, over liquid neighbours), m/s;
///   wave crest   I_wc = sum_j (1 - n^_i . n^_j) W(|x_ij|) over surface neighbours j with
///                x^_ji . n^_i < 0 (convex only), and only where v^_i . n^_i >= 0.6 (the crest
///                moves outward); surface cells only; n^ = grad phi / |grad phi| of the depth
///                field below;
///   kinetic      E_k = |v_i|^2 / 2, J/kg (Ihmsen's 0.5 m v^2 per unit mass).
/// Each is clamped to [0, 1] by Phi(I, min, max) = (min(I, max) - min(I, min)) / (max - min)
/// (Ihmsen eq. 1), and the cell generates on average
///   n = Phi(E_k) (trapped_air_rate Phi(I_ta) + wave_crest_rate Phi(I_wc)) dt
/// particles in a substep of length dt: a rate per second, so the expected number over a frame
/// does not depend on the substep. n is rounded stochastically (floor(n), plus one with
/// probability frac(n)) with a counter-based hash (the SplitMix64 finalizer, Steele, Lea & Flood
/// 2014) of (seed, cell, step, draw): no generator state, any thread count gives the same
/// particles. A new particle lies at a uniform point of the cell moved by u h along v^_i (u
/// uniform in [0, 1]; Ihmsen place theirs along the velocity too, within their kernel's support,
/// which puts crest particles into the air), with the liquid's velocity there.
///
/// Classification (Ihmsen sec. 5 uses the neighbour count; here the liquid's signed depth phi_w,
/// which is exact enough on the grid): spray where phi_w > spray_distance dx, bubble where
/// phi_w < -bubble_depth dx, foam between. phi_w at a cell centre is the level set phi (the
/// distance to the particles' spheres, level_set.h) in air, and -(k - 1/2) dx in a liquid cell
/// k cells from the nearest air cell (breadth-first layers, up to bubble_depth + 2 cells);
/// solid cells take their smallest neighbour's value; it is interpolated trilinearly.
///
/// Motion over a substep, integrated exactly for a velocity field held at the substep's start
/// (so spray, whose air is at rest, follows the same trajectory for any substep):
///   spray   dv/dt = g - spray_drag v                         (ballistic with linear drag)
///   bubble  dv/dt = -bubble_buoyancy g + bubble_drag (u - v)  (u the liquid's velocity at x)
///   foam    carried by the liquid: x += dt u(x + dt/2 u(x)), v = that velocity (midpoint).
/// Both relaxations are v' = c (v_inf - v) with the terminal velocity v_inf; their solution
///   v(t) = v_inf + (v0 - v_inf) e^(-c t),  x(t) = x0 + v_inf t + (v0 - v_inf) (1 - e^(-c t)) / c
/// (x0 + v0 t + g t^2 / 2 when c = 0) is what move() applies.
///
/// Lifetime (Ihmsen sec. 5): each particle draws a lifetime in [lifetime_min, lifetime_max]
/// seconds at birth, which runs down only while it is foam; spray and bubbles do not age (a
/// bubble surfaces and becomes foam, spray lands and becomes foam or a bubble). Spray that leaves
/// the domain or enters a collider (it hit a wall) is removed; foam and bubbles, carried by the
/// liquid, are kept inside as the liquid's particles are (clamped to the domain, pushed out of
/// colliders): removing them there would make the count depend on the substep.
///
/// Limit: at most max_particles; beyond it the oldest are removed first. Ids count up from 0 in
/// order of birth (a cell's particles in cell order), and the arrays stay in id order (new
/// particles are appended, removal compacts in order), so the oldest are the first rows.
/// Memory: 2 Dim + 1 scalars, a 32-bit id and a type byte per particle, plus Dim + 1 scalars and
/// 6 bytes per grid cell (velocities, depth, layers, counts), kept between substeps.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "slurry/engine/flip/face_transfer.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/solids.h"
#include "slurry/engine/flip/split_window.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// A secondary particle's kind (the `type` column of whitewater frames).
enum class WhitewaterType : std::uint8_t { Spray = 0, Foam = 1, Bubble = 2 };

/// Secondary particles, structure of arrays in ascending id (birth) order.
template <class T, int Dim>
struct WhitewaterParticles {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  std::vector<Vec> x;                ///< position (m)
  std::vector<Vec> v;                ///< velocity (m/s)
  std::vector<T> life;               ///< seconds of foam left
  std::vector<std::uint32_t> id;     ///< counts up in order of birth
  std::vector<std::uint8_t> type;    ///< WhitewaterType
  std::uint32_t next_id = 0;

  std::size_t size() const { return x.size(); }
  void resize(std::size_t n) {
    x.resize(n);
    v.resize(n);
    life.resize(n);
    id.resize(n);
    type.resize(n);
  }
  void move(std::size_t to, std::size_t from) {
    x[to] = x[from];
    v[to] = v[from];
    life[to] = life[from];
    id[to] = id[from];
    type[to] = type[from];
  }
  std::size_t bytes() const {
    return (x.capacity() + v.capacity()) * sizeof(Vec) + life.capacity() * sizeof(T) + id.capacity() * 4 + type.capacity();
  }
};

namespace whitewater_detail {
/// SplitMix64's finalizer: a bijective mix of 64 bits.
inline std::uint64_t mix64(std::uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
/// Uniform in [0, 1) from the counter (seed, a, b, c).
inline double uniform(std::uint64_t seed, std::uint64_t a, std::uint64_t b, std::uint64_t c) {
  const std::uint64_t h = mix64(mix64(mix64(seed ^ mix64(a)) ^ b) ^ c);
  return double(h >> 11) * 0x1.0p-53;
}
/// Ihmsen's clamp Phi(I, lo, hi) into [0, 1].
template <class T>
T clamp_potential(T I, T lo, T hi) {
  return (std::min(I, hi) - std::min(I, lo)) / (hi - lo);
}
}  // namespace whitewater_detail

/// x(t), v(t) of v' = c (v_inf - v) from (x0, v0) over t; with c = 0, of v' = a.
/// `a` is the acceleration c v_inf (so c = 0 is the ballistic limit).
template <class Vec, class T>
void relax_exactly(Vec& x, Vec& v, const Vec& a, T c, T t) {
  if (c > T(0)) {
    const Vec v_inf = a / c;
    const T decay = -std::expm1(-c * t);  // 1 - e^(-c t), exact for small c t
    x += v_inf * t + (v - v_inf) * (decay / c);
    v = v_inf + (v - v_inf) * (T(1) - decay);
  } else {
    x += v * t + a * (T(0.5) * t * t);
    v += a * t;
  }
}

/// Counts of the secondary particles by type.
struct WhitewaterCounts {
  std::size_t spray = 0, foam = 0, bubble = 0;
  std::int64_t generated = 0, removed = 0;  ///< since the start (removed: lifetime, domain, limit)
};

template <class T, int Dim>
class Whitewater {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Grid = MacGrid<T, Dim>;

  Whitewater() = default;
  Whitewater(const WhitewaterParams& params, const Vec& gravity) : p_(params), gravity_(gravity) {}

  /// Where the grid lies in the domain's when a run is split over processes (split_window.h):
  /// new particles come only from the cells this process owns, numbered over every process's.
  /// Every process calls generate() alike.
  using Window = SplitWindow<Dim>;

  /// One substep from t to t + dt, on the grid of this substep (labels and phi of the liquid at
  /// t, face velocities after the projection): classifies the particles by the depth at t, moves
  /// them over dt as that type, ages the foam, classifies them again where they ended (so a
  /// type is never a substep late), removes the dead, generates this substep's new particles,
  /// applies the limit.
  /// `substep` is the substep's index (a counter of the hash). x_lo, x_hi: the domain's inner box.
  void step(const Grid& g, const Solids<T, Dim>& solids, double t, T dt, std::int64_t substep, const Vec& x_lo,
            const Vec& x_hi) {
    x_lo_ = x_lo;
    x_hi_ = x_hi;
    depth_field(g);
    classify(g);
    move(g, dt);
    classify(g);  // where they ended: the frame's types, and no spray counted inside the liquid
    remove(solids, T(t) + dt, T(1e-3) * g.dx);
    generate(g, dt, substep);
    limit();
  }

  /// step()'s phases one by one, for a run split over processes, which hands the particles to
  /// the processes that own their cells after move() and after generate(), and applies the
  /// limit over every process: depth and classification at t, the motion over dt, then
  /// classify() and remove() where they ended, then generate().
  void begin(const Grid& g, const Vec& x_lo, const Vec& x_hi) {
    x_lo_ = x_lo;
    x_hi_ = x_hi;
    depth_field(g);
    classify(g);
  }
  void move_particles(const Grid& g, T dt) { move(g, dt); }
  void classify_and_remove(const Grid& g, const Solids<T, Dim>& solids, double t_end) {
    classify(g);
    remove(solids, T(t_end), T(1e-3) * g.dx);
  }
  void generate_in(const Grid& g, T dt, std::int64_t substep, const Window& w) { generate(g, dt, substep, &w); }

  WhitewaterParticles<T, Dim>& particles() { return P_; }
  const WhitewaterParticles<T, Dim>& particles() const { return P_; }
  const WhitewaterParams& params() const { return p_; }
  /// The depth field phi_w of the last substep (cell centres).
  const std::vector<T>& depth() const { return phi_; }
  /// Particles generated and removed so far (writable: checkpoints restore them).
  std::int64_t& generated() { return generated_; }
  std::int64_t& removed() { return removed_; }
  WhitewaterCounts counts() const {
    WhitewaterCounts c;
    for (const auto k : P_.type)
      (k == std::uint8_t(WhitewaterType::Spray) ? c.spray : k == std::uint8_t(WhitewaterType::Foam) ? c.foam : c.bubble)++;
    c.generated = generated_;
    c.removed = removed_;
    return c;
  }
  std::size_t bytes() const {
    return P_.bytes() + phi_.capacity() * sizeof(T) + layer_.capacity() + vel_.capacity() * sizeof(Vec) +
           (count_.capacity() + first_id_.capacity()) * sizeof(std::uint32_t) + prev_.capacity();
  }

  /// phi_w interpolated (bi/trilinearly) at x, from the last depth_field().
  T depth_at(const Grid& g, const Vec& x) const {
    std::int64_t base = 0, step[Dim];
    T frac[Dim];
    for (int a = 0; a < Dim; ++a) {
      T s = (x[a] - g.origin[a]) / g.dx - T(0.5) - T(g.offset[a]);  // a window's cells (MacGrid::offset)
      s = std::clamp(s, T(0), T(g.res[a] - 1));
      int b = std::min(int(s), std::max(g.res[a] - 2, 0));
      frac[a] = g.res[a] > 1 ? s - T(b) : T(0);
      step[a] = g.res[a] > 1 ? g.cell_stride(a) : 0;
      base += std::int64_t(b) * g.cell_stride(a);
    }
    T sum = 0;
    for (int corner = 0; corner < (1 << Dim); ++corner) {
      T w = 1;
      std::int64_t k = base;
      for (int a = 0; a < Dim; ++a) {
        const bool hi = (corner >> a) & 1;
        w *= hi ? frac[a] : T(1) - frac[a];
        k += hi ? step[a] : 0;
      }
      sum += w * phi_[std::size_t(k)];
    }
    return sum;
  }

 private:
  using Flags = std::uint8_t;

  /// phi_w per cell (see the header comment) and the layer of each liquid cell (1: next to air).
  void depth_field(const Grid& g) {
    const std::int64_t cells = g.num_cells();
    const int layers = int(std::ceil(p_.bubble_depth)) + 2;
    phi_.resize(std::size_t(cells));
    layer_.assign(std::size_t(cells), std::uint8_t(0));
    std::int64_t stride[Dim];
    for (int d = 0; d < Dim; ++d) stride[d] = g.cell_stride(d);
    const std::uint8_t* label = g.label.data();
    // Layer 1: liquid cells with an air face neighbour; layer k: liquid cells next to layer k - 1.
    // Each pass reads the layers of the pass before (a copy), so that no cell reads one that
    // another thread writes.
    for (int k = 1; k <= layers; ++k) {
      if (k > 1) prev_ = layer_;
      const std::uint8_t* prev = prev_.data();
      parallel::parallel_for(0, cells, [&](std::int64_t c) {
        if (label[c] != Grid::Fluid || (k > 1 && prev[c] != 0)) return;
        const IVec i = g.cell_coord(c);
        bool next = false;
        for (int d = 0; d < Dim && !next; ++d)
          for (int s = -1; s <= 1 && !next; s += 2) {
            const int q = i[d] + s;
            if (q < 0 || q >= g.res[d]) continue;
            const std::int64_t n = c + s * stride[d];
            next = k == 1 ? label[n] == Grid::Air : prev[n] == k - 1;
          }
        if (next) layer_[std::size_t(c)] = std::uint8_t(k);
      });
    }
    const T dx = g.dx;
    // A liquid cell of layer k lies (k - 1/2) dx deep; beyond the last layer, one layer deeper.
    const auto liquid_depth = [&](std::int64_t c) {
      const int k = layer_[std::size_t(c)] ? layer_[std::size_t(c)] : layers + 1;
      return -(T(k) - T(0.5)) * dx;
    };
    parallel::parallel_for(0, cells, [&](std::int64_t c) {
      if (label[c] == Grid::Fluid) {
        phi_[std::size_t(c)] = liquid_depth(c);
      } else if (label[c] == Grid::Air) {
        phi_[std::size_t(c)] = g.phi[std::size_t(c)];
      }
    });
    // Solid cells: the smallest value among their non-solid face neighbours (liquid against a
    // wall of a collider stays liquid when interpolated), else far outside.
    parallel::parallel_for(0, cells, [&](std::int64_t c) {
      if (label[c] != Grid::Solid) return;
      const IVec i = g.cell_coord(c);
      T best = T(3) * dx;
      for (int d = 0; d < Dim; ++d)
        for (int s = -1; s <= 1; s += 2) {
          const int q = i[d] + s;
          if (q < 0 || q >= g.res[d]) continue;
          const std::int64_t n = c + s * stride[d];
          if (label[n] == Grid::Fluid) best = std::min(best, liquid_depth(n));
          else if (label[n] == Grid::Air) best = std::min(best, g.phi[std::size_t(n)]);
        }
      phi_[std::size_t(c)] = best;
    });
  }

  /// Types particles `first` .. end by the depth where they are.
  void classify(const Grid& g, std::size_t first = 0) {
    const T spray = T(p_.spray_distance) * g.dx, bubble = -T(p_.bubble_depth) * g.dx;
    auto& P = P_;
    parallel::parallel_for(std::int64_t(first), std::int64_t(P.size()), [&](std::int64_t q) {
      const T phi = depth_at(g, P.x[std::size_t(q)]);
      P.type[std::size_t(q)] = std::uint8_t(phi > spray    ? WhitewaterType::Spray
                                            : phi < bubble ? WhitewaterType::Bubble
                                                           : WhitewaterType::Foam);
    });
  }

  Vec liquid_velocity(const Grid& g, const Vec& x) const {
    Vec u;
    gather_faces_linear(g, x, nullptr, u, nullptr, nullptr);
    return u;
  }

  void move(const Grid& g, T dt) {
    auto& P = P_;
    const T spray_drag = T(p_.spray_drag), bubble_drag = T(p_.bubble_drag);
    const Vec lift = -T(p_.bubble_buoyancy) * gravity_;
    parallel::parallel_for(0, std::int64_t(P.size()), [&](std::int64_t q) {
      const std::size_t i = std::size_t(q);
      switch (WhitewaterType(P.type[i])) {
        case WhitewaterType::Spray:
          relax_exactly(P.x[i], P.v[i], Vec(gravity_), spray_drag, dt);
          break;
        case WhitewaterType::Bubble: {
          // Terminal velocity u - k_b g / c: the acceleration c u - k_b g.
          const Vec u = liquid_velocity(g, P.x[i]);
          relax_exactly(P.x[i], P.v[i], Vec(bubble_drag * u + lift), bubble_drag, dt);
          break;
        }
        case WhitewaterType::Foam: {
          const Vec u1 = liquid_velocity(g, P.x[i]);
          const Vec u2 = liquid_velocity(g, Vec(P.x[i] + T(0.5) * dt * u1));
          P.x[i] += dt * u2;
          P.v[i] = u2;
          P.life[i] -= dt;
          break;
        }
      }
    });
  }

  /// Removes dead foam and spray that left the domain box or entered a collider (it hit a wall);
  /// foam and bubbles, which move with the liquid, are kept inside as the liquid's particles are
  /// (pushed out of colliders, clamped to the box). Keeps the order.
  void remove(const Solids<T, Dim>& solids, T t, T margin) {
    auto& P = P_;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < P.size(); ++i) {
      Vec& x = P.x[i];
      bool alive = std::isfinite(double(x.sum())) && std::isfinite(double(P.v[i].sum()));
      if (alive && P.type[i] == std::uint8_t(WhitewaterType::Spray)) {
        alive = (x.array() >= x_lo_.array()).all() && (x.array() <= x_hi_.array()).all() &&
                (solids.empty() || solids.distance(x, t) >= T(0));
      } else if (alive) {
        alive = !(P.type[i] == std::uint8_t(WhitewaterType::Foam) && P.life[i] <= T(0));
        x = solids.empty() ? Vec(x.cwiseMax(x_lo_).cwiseMin(x_hi_)) : solids.push_out(x, t, x_lo_, x_hi_, margin);
      }
      if (!alive) continue;
      if (kept != i) P.move(kept, i);
      ++kept;
    }
    removed_ += std::int64_t(P.size() - kept);
    P.resize(kept);
  }

  /// The potentials' expected count per cell over dt, rounded by the hash; then the particles.
  /// `w`: the grid is a window of a split run's domain (Window).
  void generate(const Grid& g, T dt, std::int64_t substep, const Window* w = nullptr) {
    const std::int64_t cells = g.num_cells();
    const T dx = g.dx, h = T(2) * dx;
    const std::uint8_t* label = g.label.data();
    // Cell-centre velocities of the liquid cells.
    vel_.resize(std::size_t(cells));
    parallel::parallel_for(0, cells, [&](std::int64_t c) {
      if (label[c] != Grid::Fluid) return;
      const IVec i = g.cell_coord(c);
      Vec v;
      for (int d = 0; d < Dim; ++d) {
        IVec up = i;
        up[d] += 1;
        v[d] = T(0.5) * (g.u[d][std::size_t(g.face(d, i))] + g.u[d][std::size_t(g.face(d, up))]);
      }
      vel_[std::size_t(c)] = v;
    });
    const auto normal = [&](const IVec& i) {  // grad phi_w / |grad phi_w| by central differences
      Vec n;
      for (int d = 0; d < Dim; ++d) {
        IVec lo = i, hi = i;
        lo[d] = std::max(i[d] - 1, 0);
        hi[d] = std::min(i[d] + 1, g.res[d] - 1);
        n[d] = hi[d] > lo[d] ? (phi_[std::size_t(g.cell(hi))] - phi_[std::size_t(g.cell(lo))]) / T(hi[d] - lo[d]) : T(0);
      }
      const T len = n.norm();
      return len > T(0) ? Vec(n / len) : Vec(Vec::Zero());
    };
    const T ta_lo = T(p_.trapped_air_min), ta_hi = T(p_.trapped_air_max);
    const T wc_lo = T(p_.wave_crest_min), wc_hi = T(p_.wave_crest_max);
    const T ek_lo = T(p_.kinetic_energy_min), ek_hi = T(p_.kinetic_energy_max);
    const T k_ta = T(p_.trapped_air_rate), k_wc = T(p_.wave_crest_rate);
    const std::uint64_t seed = std::uint64_t(p_.seed), s = std::uint64_t(substep);
    constexpr int kNeighbours = Dim == 3 ? 27 : 9;
    count_.assign(std::size_t(cells) + 1, 0);
    parallel::parallel_for(0, cells, [&](std::int64_t c) {
      if (label[c] != Grid::Fluid) return;
      if (w && !w->owns(g.cell_coord(c))) return;
      const Vec vi = vel_[std::size_t(c)];
      const T ek = whitewater_detail::clamp_potential(T(0.5) * vi.squaredNorm(), ek_lo, ek_hi);
      if (ek <= T(0)) return;
      const IVec i = g.cell_coord(c);
      const bool surface = layer_[std::size_t(c)] == 1;
      const Vec ni = surface ? normal(i) : Vec(Vec::Zero());
      const bool crest = surface && vi.norm() > T(0) && vi.normalized().dot(ni) >= T(0.6);
      T ta = 0, wc = 0;
      for (int o = 0; o < kNeighbours; ++o) {
        IVec j = i;
        bool inside = true;
        for (int d = 0, m = o; d < Dim; ++d, m /= 3) {
          j[d] += m % 3 - 1;
          inside = inside && j[d] >= 0 && j[d] < g.res[d];
        }
        if (!inside || j == i) continue;
        const std::int64_t cj = g.cell(j);
        if (label[cj] != Grid::Fluid) continue;
        const Vec xij = (i - j).template cast<T>() * dx;  // x_i - x_j
        const T r = xij.norm(), w = T(1) - r / h;
        const Vec vij = vi - vel_[std::size_t(cj)];
        const T vn = vij.norm();
        if (vn > T(0)) ta += vn * (T(1) - vij.dot(xij) / (vn * r)) * w;
        if (crest && layer_[std::size_t(cj)] == 1 && (-xij).dot(ni) < T(0)) wc += (T(1) - ni.dot(normal(j))) * w;
      }
      const T rate = ek * (k_ta * whitewater_detail::clamp_potential(ta, ta_lo, ta_hi) +
                           k_wc * whitewater_detail::clamp_potential(wc, wc_lo, wc_hi));
      const double expected = double(rate) * double(dt);
      const double whole = std::floor(expected);
      const double u = whitewater_detail::uniform(seed, domain_cell(g, c, w), s, 0);
      count_[std::size_t(c)] = std::uint32_t(whole) + (u < expected - whole ? 1u : 0u);
    });
    // Exclusive prefix sum: each cell's first new particle.
    std::uint64_t total = 0;
    for (std::int64_t c = 0; c <= cells; ++c) {
      const std::uint32_t k = count_[std::size_t(c)];
      count_[std::size_t(c)] = std::uint32_t(total);
      total += k;
    }
    std::uint32_t next_id = P_.next_id + std::uint32_t(total);
    if (w)  // the ids over every process's cells; first_id_ holds each generating cell's first
      next_id = number_new_particles(g, *w, [&](std::int64_t c) {
        return count_[std::size_t(c) + 1] - count_[std::size_t(c)];
      }, first_id_);
    if (total == 0) {
      P_.next_id = next_id;
      return;
    }
    auto& P = P_;
    const std::size_t n0 = P.size();
    P.resize(n0 + std::size_t(total));
    const T life_lo = T(p_.lifetime_min), life_span = T(p_.lifetime_max - p_.lifetime_min);
    const std::uint32_t id0 = P.next_id;
    parallel::parallel_for(0, cells, [&](std::int64_t c) {
      const std::uint32_t first = count_[std::size_t(c)], last = count_[std::size_t(c) + 1];
      if (last == first) return;
      const IVec i = g.cell_coord(c);
      const Vec vi = vel_[std::size_t(c)];
      const T speed = vi.norm();
      const Vec dir = speed > T(0) ? Vec(vi / speed) : Vec(Vec::Zero());
      const Vec corner = g.origin + dx * IVec(i + g.offset).template cast<T>();
      const std::uint64_t kc = domain_cell(g, c, w);
      for (std::uint32_t k = first; k < last; ++k) {
        const std::size_t q = n0 + k;
        const std::uint64_t draw = std::uint64_t(k - first);
        Vec x = corner;
        for (int d = 0; d < Dim; ++d)
          x[d] += dx * T(whitewater_detail::uniform(seed, kc, s, 1 + draw * 8 + std::uint64_t(d)));
        x += dir * (h * T(whitewater_detail::uniform(seed, kc, s, 1 + draw * 8 + 4)));
        x = x.cwiseMax(x_lo_).cwiseMin(x_hi_);
        P.x[q] = x;
        P.v[q] = liquid_velocity(g, x);
        P.life[q] = life_lo + life_span * T(whitewater_detail::uniform(seed, kc, s, 1 + draw * 8 + 5));
        P.id[q] = w ? first_id_[std::size_t(c)] + (k - first) : id0 + k;
        P.type[q] = std::uint8_t(WhitewaterType::Foam);
      }
    });
    P.next_id = next_id;
    generated_ += std::int64_t(total);
    classify(g, n0);  // from the depth where they start (the frame shows it before their first move)
  }

  /// At most max_particles: the oldest (the first rows) go first.
  void limit() {
    auto& P = P_;
    const std::size_t cap = std::size_t(p_.max_particles);
    if (P.size() <= cap) return;
    const std::size_t drop = P.size() - cap;
    for (std::size_t i = 0; i < cap; ++i) P.move(i, i + drop);
    P.resize(cap);
    removed_ += std::int64_t(drop);
  }

  WhitewaterParams p_;
  Vec gravity_ = Vec::Zero(), x_lo_ = Vec::Zero(), x_hi_ = Vec::Zero();
  WhitewaterParticles<T, Dim> P_;
  std::vector<T> phi_;
  std::vector<std::uint8_t> layer_, prev_;
  std::vector<Vec> vel_;
  std::vector<std::uint32_t> count_, first_id_;
  std::int64_t generated_ = 0, removed_ = 0;
};

}  // namespace slurry::flip
