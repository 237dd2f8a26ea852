#pragma once
/// \file pressure_multigrid.h
/// Geometric multigrid preconditioner for the FLIP pressure PCG (McAdams, Sifakis & Teran 2010,
/// "A parallel multigrid Poisson solver for fluids simulation on large grids"): z = M^-1 r is
/// one V-cycle on A z = r from z = 0.
///
/// Hierarchy: level 0 is the assembled fine system (diagonal with the ghost-fluid terms, face
/// weights; copied to the scalar type S, float by default: the preconditioner may be inexact,
/// the outer PCG stays in double). Level l + 1 has ceil(n / 2) cells per axis; cell I has the
/// children 2I + {0, 1}^Dim.
/// - Labels: a coarse cell is air if any child is air, else fluid if any child is fluid, else
///   solid. (The rule "fluid if any child is fluid" loses the free surface where it runs
///   inside a coarse cell next to a wall: measured on a 32^3 box with one air layer at the
///   domain edge, the V-cycle then amplified the residual 4.6x per cycle and PCG took 63
///   iterations against 26 for MIC(0). With air dominant and the coarse ghost fluid below it
///   contracts by ~0.4 per cycle.)
/// - Level set: a coarse cell's phi is the mean over its non-solid children (exact at the
///   coarse centre for a linear phi).
/// - Faces: a coarse face's weight is the mean open weight of the fine faces it covers.
/// - Operator: the re-discretised Laplacian with these weights, Neumann at solids, Dirichlet
///   p = 0 at air with the ghost-fluid fraction theta = phi_c / (phi_c - phi_air) of the coarse
///   level set (Gibou et al. 2002, as on the fine level), scaled by 1/4 per level: with R
///   averaging and P interpolating, R A_h P ~ -h^2 lap = (1/4) (-(2h)^2 lap).
/// The hierarchy stops at the first level with every axis <= kCoarsest cells, or above a
/// level that would have no free-surface coupling left while the finer one has.
///
/// Transfers (cell centred, McAdams et al. 2010): prolongation P is trilinear (per axis the
/// fine cell takes 3/4 of its parent and 1/4 of the parent's neighbour on its side), with the
/// weights of solid parents dropped and the rest renormalised (P 1 = 1 next to walls:
/// Neumann; air parents keep their weight with value 0: Dirichlet); restriction
/// R = 2^-Dim P^T (per axis (1, 3, 3, 1) / 8 over fine cells 2I - 1 .. 2I + 2 in the interior).
/// Values outside the unknowns are zero on every level (masked R and P).
///
/// Smoothing: red-black Gauss-Seidel, `smoothing` sweeps red-then-black before the coarse
/// correction and the same number black-then-red after it; `boundary_smoothing` extra sweeps
/// on the boundary band (unknowns with an open face to air or a partly open face: where the
/// coarse levels approximate the fine operator worst) after the interior pre-sweeps and,
/// mirrored, before the interior post-sweeps (McAdams et al. boundary smoothing). The coarsest
/// level gets kCoarseSweeps symmetric sweeps. With post-smoothing the adjoint of
/// pre-smoothing and R proportional to P^T, M^-1 is symmetric and positive definite, so PCG
/// stays valid (every sweep count is fixed: M is linear).
///
/// Parallel and deterministic: each half-sweep updates one colour from the other, transfers
/// write one cell each, so the result does not depend on the thread count; levels below
/// kParallelCells cells run serially (a parallel region costs more than their work).
/// Memory (S = float): 13 floats and a byte per (padded) fine cell for level 0, ~1/7 of that
/// more for the coarser levels: ~61 bytes per fine cell.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// Where PressureSolver keeps the values of cell row `row` (cells k along the last axis) in its
/// packed vectors: at base[row] + k for k in [lo[row], hi[row]); every other cell of the row is
/// not stored and reads as zero.
struct PackedRows {
  const std::int64_t* base = nullptr;
  const int* lo = nullptr;
  const int* hi = nullptr;
};

template <int Dim, class S = float>
class MultigridPreconditioner {
 public:
  using IVec = Eigen::Matrix<int, Dim, 1>;
  enum Kind : std::uint8_t { kAir = 0, kFluid = 1, kSolid = 2 };

  static constexpr std::int64_t kParallelCells = 32768;  ///< smaller levels run serially
  static constexpr int kCoarsest = 8;      ///< stop coarsening when every axis has <= this many cells
  static constexpr int kCoarseSweeps = 12;  ///< symmetric RB-GS sweeps on the coarsest level (each way)
  static constexpr std::int64_t kRowGrain = 16;  ///< rows per chunk of the fixed-order dot product
  static constexpr S kCoarseThetaMin = S(0.05);  ///< ghost-fluid clamps on the coarse levels
  static constexpr S kCoarseThetaMax = S(4);

  /// Sets up level 0 from the fine system and coarsens it. diag and plus[d] = A(c, c + e_d)
  /// are PressureSolver's packed vectors (laid out by `rows`, zero outside the unknowns); kind
  /// (kFluid exactly for the unknowns) and phi are row-major over `res` (last axis fastest), and
  /// open holds the open weight of every axis-d face in MacGrid face layout (res + e_d faces per
  /// axis). Allocates only when res changes.
  template <class T, class P>
  void build(const IVec& res, const PackedRows& rows, const double* diag, const std::array<const P*, Dim>& plus,
             const std::uint8_t* kind, const std::array<const T*, Dim>& open, const T* phi) {
    if (levels_.empty() || levels_[0].n != res) {
      levels_.clear();
      IVec n = res;
      while (true) {
        levels_.emplace_back();
        levels_.back().layout(n);
        if (n.maxCoeff() <= kCoarsest) break;
        for (int a = 0; a < Dim; ++a) n[a] = (n[a] + 1) / 2;
      }
    }
    fill_level0(rows, diag, plus, kind, open, phi);
    S scale = 1;  // level l's stencil carries 4^-l (see the file comment)
    active_ = 1;
    for (std::size_t l = 1; l < levels_.size(); ++l) {
      coarsen(levels_[l - 1], levels_[l], scale *= S(0.25));
      // A level that lost the last free-surface coupling of the finer one would be singular
      // (its constant mode grows with every coarse sweep): stop above it.
      if (levels_[l - 1].dirichlet > 0 && levels_[l].dirichlet == 0) break;
      active_ = int(l) + 1;
    }
  }

  /// Levels in use for the current system (the hierarchy stops early when a coarse level would
  /// lose the free surface).
  int levels() const { return active_; }
  /// Unknowns on level l (fine: l = 0).
  std::int64_t unknowns(int l) const { return levels_[std::size_t(l)].unknowns; }
  /// Boundary-band cells on level l.
  std::int64_t band_cells(int l) const { return std::int64_t(levels_[std::size_t(l)].band.size()); }

  /// Bytes held by every level's arrays (capacity).
  std::size_t bytes() const {
    std::size_t b = 0;
    const auto add = [&](const auto& v) { b += v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type); };
    for (const Level& L : levels_) {
      add(L.diag), add(L.inv_diag), add(L.x), add(L.b), add(L.r), add(L.pscale), add(L.phi);
      for (int d = 0; d < Dim; ++d) add(L.plus[std::size_t(d)]), add(L.weight[std::size_t(d)]);
      add(L.kind), add(L.row_base), add(L.parity), add(L.lo), add(L.hi), add(L.band);
      add(L.band_colour[0]), add(L.band_colour[1]);
    }
    return b;
  }

  /// z = M^-1 r (one V-cycle from zero) over the unknowns; r and z are PressureSolver's packed
  /// vectors laid out by `rows` (z is written on the unknowns' row spans only). Returns r . z,
  /// summed in fixed row chunks.
  double apply(const PackedRows& rows, const double* r, double* z, int smoothing, int boundary_smoothing) {
    const int last = active_ - 1;
    Level& f = levels_[0];
    rows_for(f, [&](std::int64_t row) {  // b = r; x = 0, then the first red half-sweep
      const std::int64_t base = f.row_base[std::size_t(row)];
      const std::int64_t c0 = rows.base[row];
      const int p = f.parity[std::size_t(row)];
      for (int k = f.lo[std::size_t(row)]; k < f.hi[std::size_t(row)]; ++k) {
        const std::int64_t c = base + k;
        const S bv = S(r[c0 + k]);
        f.b[std::size_t(c)] = bv;
        f.x[std::size_t(c)] = ((p + k) & 1) ? S(0) : f.inv_diag[std::size_t(c)] * bv;
      }
    });
    for (int l = 0; l < last; ++l) {
      Level& L = levels_[std::size_t(l)];
      // Pre-smoothing: (R B)^smoothing, then (band R, band B)^boundary_smoothing; the first R
      // was fused into the set-up above or into restrict_to().
      smooth(L, smoothing, boundary_smoothing, true);
      // Black residuals vanish after a black half-sweep, unless band sweeps came after it.
      residual(L, boundary_smoothing == 0);
      restrict_to(L, levels_[std::size_t(l + 1)]);
    }
    {
      Level& C = levels_[std::size_t(last)];
      sweep(C, 1);
      for (int s = 1; s < kCoarseSweeps; ++s) sweep(C, 0), sweep(C, 1);
      for (int s = 0; s < kCoarseSweeps; ++s) sweep(C, 1), sweep(C, 0);
    }
    for (int l = last - 1; l >= 0; --l) {
      Level& L = levels_[std::size_t(l)];
      prolong_add(levels_[std::size_t(l + 1)], L);
      smooth(L, smoothing, boundary_smoothing, false);
    }
    return parallel::parallel_sum<double>(0, f.rows, kRowGrain, [&](std::int64_t lo, std::int64_t hi) {
      double s = 0;
      for (std::int64_t row = lo; row < hi; ++row) {
        const std::int64_t base = f.row_base[std::size_t(row)];
        const std::int64_t c0 = rows.base[row];
        for (int k = f.lo[std::size_t(row)]; k < f.hi[std::size_t(row)]; ++k) {
          const double zv = double(f.x[std::size_t(base + k)]);
          z[c0 + k] = zv;
          s += r[c0 + k] * zv;
        }
      }
      return s;
    });
  }

 private:
  /// One level on a grid padded by one ghost cell below and two above per axis (the
  /// restriction stencil reaches fine cell 2I + 2 = n + 1); ghosts hold zeros and kSolid.
  struct Level {
    IVec n = IVec::Zero();
    std::array<std::int64_t, Dim> stride{};
    std::int64_t size = 0, rows = 0, unknowns = 0;
    std::int64_t dirichlet = 0;  ///< unknowns with an open face to an air cell
    bool parallel = false;
    std::vector<S> diag, inv_diag, x, b, r;
    std::vector<S> pscale;
    std::vector<S> phi;     ///< liquid level set (mean over the non-solid children)  ///< 1 / (sum of the trilinear weights of the non-solid parents)
    std::array<std::vector<S>, Dim> plus;    ///< A(c, c + e_d), stored at c
    std::array<std::vector<S>, Dim> weight;  ///< open weight of the face between c - e_d and c
    std::vector<std::uint8_t> kind;
    std::vector<std::int64_t> row_base;  ///< padded index of cell k = 0 of each row
    std::vector<std::uint8_t> parity;    ///< colour of cell k = 0 of each row
    std::vector<int> lo, hi;             ///< unknowns of each row lie in [lo, hi)
    std::vector<std::int64_t> band;      ///< boundary-band cells (padded index), row-major order
    std::array<std::vector<std::int64_t>, 2> band_colour;  ///< band split by colour

    void layout(const IVec& cells) {
      n = cells;
      std::int64_t s = 1;
      for (int a = Dim - 1; a >= 0; --a) stride[a] = s, s *= n[a] + 3;
      size = s;
      rows = 1;
      for (int a = 0; a < Dim - 1; ++a) rows *= n[a];
      parallel = rows * n[Dim - 1] >= kParallelCells;
      row_base.resize(std::size_t(rows));
      parity.resize(std::size_t(rows));
      for (std::int64_t row = 0; row < rows; ++row) {
        const IVec i = row_coord(row);
        row_base[std::size_t(row)] = index(i);
        parity[std::size_t(row)] = std::uint8_t(i.sum() & 1);
      }
    }
    IVec row_coord(std::int64_t row) const {
      IVec i = IVec::Zero();
      for (int a = Dim - 2; a >= 0; --a) i[a] = int(row % n[a]), row /= n[a];
      return i;
    }
    /// Padded index of cell i (each coordinate may be -1 .. n + 1).
    std::int64_t index(const IVec& i) const {
      std::int64_t c = 0;
      for (int a = 0; a < Dim; ++a) c += std::int64_t(i[a] + 1) * stride[a];
      return c;
    }
  };

  template <class Fn>
  static void rows_for(const Level& L, Fn&& fn) {
    if (L.parallel) {
      parallel::parallel_for(0, L.rows, fn);
    } else {
      for (std::int64_t row = 0; row < L.rows; ++row) fn(row);
    }
  }

  static void clear(Level& L) {
    const std::size_t n = std::size_t(L.size);
    for (auto* v : {&L.diag, &L.inv_diag, &L.x, &L.b, &L.r, &L.pscale, &L.phi}) v->assign(n, S(0));
    for (int d = 0; d < Dim; ++d) L.plus[d].assign(n, S(0)), L.weight[d].assign(n, S(0));
    L.kind.assign(n, kSolid);
  }

  template <class T, class P>
  void fill_level0(const PackedRows& rows, const double* diag, const std::array<const P*, Dim>& plus,
                   const std::uint8_t* kind, const std::array<const T*, Dim>& open, const T* phi) {
    Level& L = levels_[0];
    clear(L);
    const int nz = L.n[Dim - 1];
    rows_for(L, [&](std::int64_t row) {
      const std::int64_t base = L.row_base[std::size_t(row)], c0 = row * nz;
      const std::int64_t at = rows.base[row];
      const int lo = rows.lo[row], hi = rows.hi[row];
      for (int k = 0; k < nz; ++k) {
        const std::size_t c = std::size_t(base + k);
        const bool stored = k >= lo && k < hi;  // cells outside the solver's rows are zero
        const double dg = stored ? diag[at + k] : 0.0;
        L.diag[c] = S(dg);
        L.inv_diag[c] = dg > 0 ? S(1.0 / dg) : S(0);
        L.kind[c] = kind[c0 + k];
        // Without a level set: the surface at the air cell centre (theta = 1).
        L.phi[c] = phi ? S(phi[c0 + k]) : L.kind[c] == kFluid ? S(-1) : S(1);
        for (int d = 0; d < Dim; ++d) L.plus[d][c] = stored ? S(plus[d][at + k]) : S(0);
      }
    });
    // Open weights of the interior faces below each cell (boundary faces are walls: 0).
    for (int d = 0; d < Dim; ++d) {
      IVec fr = L.n;
      fr[d] += 1;
      std::array<std::int64_t, Dim> fs{};
      std::int64_t s = 1;
      for (int a = Dim - 1; a >= 0; --a) fs[a] = s, s *= fr[a];
      rows_for(L, [&](std::int64_t row) {
        IVec i = L.row_coord(row);
        std::int64_t f = 0;
        for (int a = 0; a < Dim; ++a) f += std::int64_t(i[a]) * fs[a];
        const std::int64_t base = L.row_base[std::size_t(row)];
        for (int k = 0; k < nz; ++k) {
          i[Dim - 1] = k;
          if (i[d] == 0) continue;
          L.weight[d][std::size_t(base + k)] = S(open[d][f + k]);
        }
      });
    }
    finish(L);
  }

  /// Labels, face weights and operator of C from F; `scale` multiplies the coarse stencil.
  void coarsen(Level& F, Level& C, S scale) {
    clear(C);
    const int nz = C.n[Dim - 1];
    const int children = 1 << Dim;
    rows_for(C, [&](std::int64_t row) {
      IVec I = C.row_coord(row);
      const std::int64_t base = C.row_base[std::size_t(row)];
      for (int k = 0; k < nz; ++k) {
        I[Dim - 1] = k;
        bool fluid = false, air = false;
        S phi_sum = 0;
        int phi_count = 0;
        for (int ch = 0; ch < children; ++ch) {
          IVec i = 2 * I;
          for (int a = 0; a < Dim; ++a) i[a] += (ch >> a) & 1;
          const std::size_t f = std::size_t(F.index(i));
          const auto kf = F.kind[f];  // ghost children read kSolid
          fluid |= kf == kFluid, air |= kf == kAir;
          if (kf != kSolid) phi_sum += F.phi[f], ++phi_count;
        }
        const std::size_t c = std::size_t(base + k);
        C.phi[c] = phi_count ? phi_sum / S(phi_count) : S(0);
        // Air if any child is air, else fluid if any child is fluid, else solid: every level
        // keeps a free surface where the fine one has it (see the file comment).
        C.kind[c] = air ? kAir : fluid ? kFluid : kSolid;
        for (int d = 0; d < Dim; ++d) {
          if (I[d] == 0) continue;  // domain wall
          // Fine faces at 2 I_d along d, 2 I_a + {0, 1} along the others (inside the grid).
          S sum = 0;
          int count = 0;
          for (int ch = 0; ch < children; ++ch) {
            if ((ch >> d) & 1) continue;
            IVec i = 2 * I;
            bool inside = true;
            for (int a = 0; a < Dim; ++a) {
              if (a == d) continue;
              i[a] += (ch >> a) & 1;
              inside &= i[a] < F.n[a];
            }
            if (!inside) continue;
            sum += F.weight[d][std::size_t(F.index(i))];
            ++count;
          }
          C.weight[d][c] = count ? sum / S(count) : S(0);
        }
      }
    });
    rows_for(C, [&](std::int64_t row) {
      const std::int64_t base = C.row_base[std::size_t(row)];
      for (int k = 0; k < nz; ++k) {
        const std::int64_t c = base + k;
        if (C.kind[std::size_t(c)] != kFluid) continue;
        S diag = 0;
        for (int d = 0; d < Dim; ++d) {
          for (int side = 0; side < 2; ++side) {
            const std::int64_t nb = side ? c + C.stride[d] : c - C.stride[d];
            const S w = scale * C.weight[d][std::size_t(side ? nb : c)];
            const auto kn = C.kind[std::size_t(nb)];
            if (w <= 0 || kn == kSolid) continue;
            if (kn == kAir) {
              diag += w / theta(C.phi[std::size_t(c)], C.phi[std::size_t(nb)]);
              continue;
            }
            diag += w;
            if (side) C.plus[d][std::size_t(c)] = -w;
          }
        }
        C.diag[std::size_t(c)] = diag;
        C.inv_diag[std::size_t(c)] = diag > 0 ? S(1) / diag : S(0);
      }
    });
    // A fluid cell without an open face is no unknown: label it solid for the next level.
    rows_for(C, [&](std::int64_t row) {
      const std::int64_t base = C.row_base[std::size_t(row)];
      for (int k = 0; k < nz; ++k)
        if (C.kind[std::size_t(base + k)] == kFluid && !(C.diag[std::size_t(base + k)] > 0))
          C.kind[std::size_t(base + k)] = kSolid;
    });
    finish(C);
    // Prolongation weights renormalised over the parents that are not solid: P 1 = 1 next to
    // walls and colliders (Neumann), while air parents keep their weight with value 0
    // (Dirichlet). Without this, P drops to 3/4 at a wall and R A P exceeds the re-discretised
    // coarse operator there: the coarse correction overshoots (measured: eigenvalues of M A up
    // to 2 on a 16^3 tank).
    constexpr int kCorners = 1 << Dim;
    rows_for(F, [&](std::int64_t row) {
      const IVec i = F.row_coord(row);
      const std::int64_t base = F.row_base[std::size_t(row)];
      for (int k = F.lo[std::size_t(row)]; k < F.hi[std::size_t(row)]; ++k) {
        const std::int64_t c = base + k;
        if (F.inv_diag[std::size_t(c)] == S(0)) continue;
        S norm = 0;
        for (int t = 0; t < kCorners; ++t) {
          IVec I;
          S w = 1;
          for (int a = 0; a < Dim; ++a) {
            const int ia = a == Dim - 1 ? k : i[a];
            const bool other = (t >> a) & 1;
            I[a] = (ia >> 1) + (other ? ((ia & 1) ? 1 : -1) : 0);
            w *= other ? S(0.25) : S(0.75);
          }
          if (C.kind[std::size_t(C.index(I))] != kSolid) norm += w;
        }
        F.pscale[std::size_t(c)] = norm > 0 ? S(1) / norm : S(0);
      }
    });
  }

  /// Coarse ghost-fluid fraction between a fluid cell (level set phi_c) and an air neighbour
  /// (phi_a): theta = phi_c / (phi_c - phi_a) as on the fine level, in [kCoarseThetaMin, 1]
  /// when phi changes sign, up to kCoarseThetaMax when the air cell (air because one child is)
  /// has its centre inside the liquid. Without it the coarse Dirichlet condition sits at the
  /// air cell centre, up to a coarse cell away from the fine surface, and the coarse
  /// correction is off by the corresponding factor (measured: eigenvalues of M A up to 2.7
  /// instead of 1.01 on a 12^3 tank with two levels).
  static S theta(S phi_c, S phi_a) {
    if (!(phi_a > phi_c)) return S(1);  // level set not increasing outwards: plain Dirichlet
    // A mixed air cell whose centre is still inside the liquid: the surface lies beyond it.
    if (phi_a < 0) return std::min(phi_c / (phi_c - phi_a), kCoarseThetaMax);
    const S t = phi_c < 0 ? phi_c / (phi_c - phi_a) : S(0);
    return std::clamp(t, kCoarseThetaMin, S(1));
  }

  /// Row spans, unknown count and boundary band of a filled level.
  static void finish(Level& L) {
    const int nz = L.n[Dim - 1];
    L.lo.assign(std::size_t(L.rows), 0);
    L.hi.assign(std::size_t(L.rows), 0);
    rows_for(L, [&](std::int64_t row) {
      const std::int64_t base = L.row_base[std::size_t(row)];
      int lo = nz, hi = 0;
      for (int k = 0; k < nz; ++k)
        if (L.diag[std::size_t(base + k)] > 0) lo = std::min(lo, k), hi = k + 1;
      L.lo[std::size_t(row)] = lo < hi ? lo : 0;
      L.hi[std::size_t(row)] = lo < hi ? hi : 0;
    });
    // Serial, in row-major order: the band lists do not depend on the thread count. The band is
    // a subset of the unknowns, so the lists are reserved for the last build's unknowns plus a
    // quarter: a moving liquid of about constant volume then never grows them inside a step.
    const std::size_t need = std::size_t(L.unknowns), bound = need + need / 4;
    if (L.band.capacity() < need) L.band.reserve(bound);
    for (auto& bc : L.band_colour)
      if (bc.capacity() < need) bc.reserve(bound);
    L.unknowns = 0;
    L.dirichlet = 0;
    L.band.clear();
    for (auto& bc : L.band_colour) bc.clear();
    for (std::int64_t row = 0; row < L.rows; ++row) {
      const std::int64_t base = L.row_base[std::size_t(row)];
      for (int k = L.lo[std::size_t(row)]; k < L.hi[std::size_t(row)]; ++k) {
        const std::int64_t c = base + k;
        if (!(L.diag[std::size_t(c)] > 0)) continue;
        ++L.unknowns;
        bool boundary = false, air = false;
        for (int d = 0; d < Dim; ++d) {
          const std::int64_t up = c + L.stride[d], down = c - L.stride[d];
          const S wd = L.weight[d][std::size_t(c)], wu = L.weight[d][std::size_t(up)];
          air |= (wd > 0 && L.kind[std::size_t(down)] == kAir) || (wu > 0 && L.kind[std::size_t(up)] == kAir);
          boundary |= (wd > 0 && wd < S(1)) || (wu > 0 && wu < S(1));
        }
        L.dirichlet += air;
        boundary |= air;
        if (!boundary) continue;
        L.band.push_back(c);
        L.band_colour[std::size_t((L.parity[std::size_t(row)] + k) & 1)].push_back(c);
      }
    }
  }

  /// x_c = (b_c - sum_nb A_c,nb x_nb) / A_cc at padded cell c.
  static S relax(const Level& L, std::int64_t c) { return L.inv_diag[std::size_t(c)] * relax_sum(L, c); }

  /// b_c - sum_nb A_c,nb x_nb (the numerator of relax()).
  static S relax_sum(const Level& L, std::int64_t c) {
    S s = L.b[std::size_t(c)];
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t st = L.stride[d];
      s -= L.plus[d][std::size_t(c)] * L.x[std::size_t(c + st)] + L.plus[d][std::size_t(c - st)] * L.x[std::size_t(c - st)];
    }
    return s;
  }

  /// Gauss-Seidel half-sweep over the cells of one colour (0 = red: even coordinate sum).
  static void sweep(Level& L, int colour) {
    rows_for(L, [&](std::int64_t row) {
      const std::int64_t base = L.row_base[std::size_t(row)];
      const int lo = L.lo[std::size_t(row)], hi = L.hi[std::size_t(row)];
      for (int k = lo + ((colour ^ L.parity[std::size_t(row)] ^ lo) & 1); k < hi; k += 2)
        L.x[std::size_t(base + k)] = relax(L, base + k);
    });
  }

  /// Half-sweep of one colour over the boundary band only.
  static void band_sweep(Level& L, int colour) {
    const auto& cells = L.band_colour[std::size_t(colour)];
    const std::int64_t n = std::int64_t(cells.size());
    const auto one = [&](std::int64_t t) { L.x[std::size_t(cells[std::size_t(t)])] = relax(L, cells[std::size_t(t)]); };
    if (L.parallel && n >= 4096) {
      parallel::parallel_for(0, n, one);
    } else {
      for (std::int64_t t = 0; t < n; ++t) one(t);
    }
  }

  /// Pre-smoothing (forward; the first red half-sweep already done by the caller) or
  /// post-smoothing (backward: the exact reverse sequence).
  static void smooth(Level& L, int sweeps, int band_sweeps, bool forward) {
    if (forward) {
      sweep(L, 1);
      for (int s = 1; s < sweeps; ++s) sweep(L, 0), sweep(L, 1);
      for (int s = 0; s < band_sweeps; ++s) band_sweep(L, 0), band_sweep(L, 1);
    } else {
      for (int s = 0; s < band_sweeps; ++s) band_sweep(L, 1), band_sweep(L, 0);
      for (int s = 0; s < sweeps; ++s) sweep(L, 1), sweep(L, 0);
    }
  }

  /// r = pscale (b - A x); with red_only on red cells and 0 on black ones (exact right after a
  /// black half-sweep). The factor pscale makes R = 2^-Dim P^T with P's renormalised weights.
  static void residual(Level& L, bool red_only) {
    rows_for(L, [&](std::int64_t row) {
      const std::int64_t base = L.row_base[std::size_t(row)];
      const int p = L.parity[std::size_t(row)];
      for (int k = L.lo[std::size_t(row)]; k < L.hi[std::size_t(row)]; ++k) {
        const std::int64_t c = base + k;
        if (red_only && ((p + k) & 1)) {
          L.r[std::size_t(c)] = S(0);
          continue;
        }
        L.r[std::size_t(c)] = L.pscale[std::size_t(c)] * (relax_sum(L, c) - L.diag[std::size_t(c)] * L.x[std::size_t(c)]);
      }
    });
  }


  /// C.b = R F.r on C's unknowns (0 elsewhere), then C.x = 0 and C's first red half-sweep.
  static void restrict_to(const Level& F, Level& C) {
    constexpr int kRowsPer = Dim == 3 ? 16 : 4;
    static constexpr S wt[4] = {S(1) / 8, S(3) / 8, S(3) / 8, S(1) / 8};
    rows_for(C, [&](std::int64_t row) {
      const int lo = C.lo[std::size_t(row)], hi = C.hi[std::size_t(row)];
      if (lo >= hi) return;
      const IVec I = C.row_coord(row);
      std::array<std::int64_t, kRowsPer> fbase{};
      std::array<S, kRowsPer> fw{};
      for (int t = 0; t < kRowsPer; ++t) {
        IVec i = IVec::Zero();
        S w = S(1) / 8;  // the (1, 3, 3, 1) / 8 weights along the row axis are applied below
        int u = t;
        for (int a = 0; a < Dim - 1; ++a) {
          const int o = u % 4;
          u /= 4;
          i[a] = 2 * I[a] - 1 + o;
          w *= wt[o];
        }
        fbase[std::size_t(t)] = F.index(i);
        fw[std::size_t(t)] = w;
      }
      const std::int64_t base = C.row_base[std::size_t(row)];
      const int p = C.parity[std::size_t(row)];
      for (int k = lo; k < hi; ++k) {
        const std::int64_t c = base + k;
        const S inv = C.inv_diag[std::size_t(c)];
        if (inv == S(0)) {
          C.b[std::size_t(c)] = S(0), C.x[std::size_t(c)] = S(0);
          continue;
        }
        S sum = 0;
        for (int t = 0; t < kRowsPer; ++t) {
          const S* rf = F.r.data() + fbase[std::size_t(t)] + 2 * k;
          sum += fw[std::size_t(t)] * (rf[-1] + S(3) * (rf[0] + rf[1]) + rf[2]);
        }
        C.b[std::size_t(c)] = sum;
        C.x[std::size_t(c)] = ((p + k) & 1) ? S(0) : inv * sum;
      }
    });
  }

  /// F.x += P C.x on F's unknowns.
  static void prolong_add(const Level& C, Level& F) {
    constexpr int kRowsPer = Dim == 3 ? 4 : 2;
    rows_for(F, [&](std::int64_t row) {
      const int lo = F.lo[std::size_t(row)], hi = F.hi[std::size_t(row)];
      if (lo >= hi) return;
      const IVec i = F.row_coord(row);
      std::array<std::int64_t, kRowsPer> cbase{};
      std::array<S, kRowsPer> cw{};
      for (int t = 0; t < kRowsPer; ++t) {
        IVec I = IVec::Zero();
        S w = 1;
        for (int a = 0; a < Dim - 1; ++a) {
          const bool other = (t >> a) & 1;
          I[a] = (i[a] >> 1) + (other ? ((i[a] & 1) ? 1 : -1) : 0);
          w *= other ? S(0.25) : S(0.75);
        }
        cbase[std::size_t(t)] = C.index(I);
        cw[std::size_t(t)] = w;
      }
      const std::int64_t base = F.row_base[std::size_t(row)];
      for (int k = lo; k < hi; ++k) {
        const std::int64_t c = base + k;
        if (F.inv_diag[std::size_t(c)] == S(0)) continue;
        const int k0 = k >> 1, k1 = k0 + ((k & 1) ? 1 : -1);
        S v = 0;
        for (int t = 0; t < kRowsPer; ++t) {
          const S* xc = C.x.data() + cbase[std::size_t(t)];
          v += cw[std::size_t(t)] * (S(0.75) * xc[k0] + S(0.25) * xc[k1]);
        }
        F.x[std::size_t(c)] += F.pscale[std::size_t(c)] * v;
      }
    });
  }

  std::vector<Level> levels_;
  int active_ = 0;
};

}  // namespace slurry::flip
