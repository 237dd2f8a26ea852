#pragma once
/// \file pressure.h
/// Pressure projection of the FLIP liquid solver on a MacGrid: makes the face velocities
/// discretely divergence free in fluid cells, u <- u - dt/rho grad p.
/// (One header of about 1,130 lines: the packed storage, the operator, MIC(0) and its level
/// schedule all index the same row spans, and the multigrid preconditioner is pressure_multigrid.h.)
///
/// Discretisation (Bridson, "Fluid Simulation for Computer Graphics", 2nd ed., ch. 5; the finite
/// differences of the course notes, Bridson & Mueller-Fischer 2007):
///   divergence  D_c = sum_d [U(c + 1/2 e_d) - U(c - 1/2 e_d)],   U = w u + (1 - w) u_solid
///   gradient    (grad p)_f = (p_b - p_a) / dx   across face f from cell a to cell b
///   system      (A p)_c = sum_faces w_f (p_c - p_nb) = -(rho dx / dt) D_c
/// i.e. the 7-point (5-point in 2D) Laplacian scaled by dx^2, with face weights w in [0, 1]
/// (MacGrid::open_weight). Boundary conditions:
/// - Neumann at solids: the closed part (1 - w) of a face carries u_solid (Batty, Bertails &
///   Bridson 2007; Ng, Min & Gibou 2009); closed faces get u = u_solid.
/// - Dirichlet p = 0 at the free surface. With `ghost_fluid` the surface sits where phi, linearly
///   interpolated between the cell centres, crosses zero, theta = phi_c / (phi_c - phi_air), and
///   the air neighbour holds the ghost pressure p_c (theta - 1) / theta: the diagonal gains
///   w / theta (Gibou, Fedkiw, Cheng & Kang 2002; Enright, Nguyen, Gibou & Fedkiw 2003). theta is
///   clamped below at 1e-3 (at 0.01 the clamp error, ~0.01 dx |grad p|, already showed as a loss
///   of order at 256^2 in the tests). Without it p = 0 at the air cell centre (theta = 1), first order.
///   With a surface pressure (surface tension, set_surface_pressure) the surface is p = p_gamma.
///   With the surface placed inside the fluid cells (set_subcell_surface), faces with
///   theta < kSliverTheta that liquid behind their cell holds are left unprojected.
/// A fluid component without any free-surface face (a closed container) makes A singular: the
/// right-hand side is projected onto the range (its mean over the component removed) and the
/// solution's mean over the component is set to zero.
///
/// A is symmetric positive (semi)definite. It is stored in Bridson's compact form: per cell the
/// diagonal and one off-diagonal per positive axis. Like every vector of the solve it is packed:
/// only the cell rows (along the last axis) that hold unknowns are stored, each over its span
/// of unknowns [lo, hi) and one cell more at each end. A neighbour that its row does not store
/// is read from a zero row at the end of every vector: each span is cut into pieces over which
/// every neighbour row stores all or none of the neighbours. The liquid of the 150 x 100 x 75
/// dam break fills about a tenth of the tank; the full-grid vectors this replaces held 85 MB
/// there. The solve is PCG with a choice of preconditioner:
/// - None: plain CG;
/// - Jacobi: z = r / diag(A);
/// - MIC0: modified incomplete Cholesky with zero fill-in, tau = 0.97, safety sigma = 0.25
///   (Bridson 2015, Fig. 5.2-5.4). Its two triangular solves are run by level scheduling over
///   tiles of 8 x 8 cell rows (a tile depends on its -x and -y neighbour tiles; tiles on one
///   anti-diagonal run in parallel): the arithmetic is that of the serial lexicographic MIC(0).
/// - Multigrid: one geometric multigrid V-cycle (McAdams, Sifakis & Teran 2010; float levels,
///   red-black Gauss-Seidel, see pressure_multigrid.h): iterations nearly independent of the
///   resolution.
/// Every reduction sums fixed chunks in a fixed order (parallel::parallel_sum), so results are
/// bitwise identical for any thread count.
///
/// Two levels of API: `PressureSolver` keeps its buffers between steps (use one per simulation),
/// and the free function `project()` builds a temporary one.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "slurry/engine/errors.h"
#include "slurry/engine/flip/mac_grid.h"
#include "slurry/engine/flip/pressure_multigrid.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

/// Preconditioner of the pressure CG. Scene key values: "none", "jacobi", "mic0", "multigrid".
enum class Preconditioner { None, Jacobi, MIC0, Multigrid };

inline const char* to_string(Preconditioner p) {
  switch (p) {
    case Preconditioner::None: return "none";
    case Preconditioner::Jacobi: return "jacobi";
    case Preconditioner::MIC0: return "mic0";
    case Preconditioner::Multigrid: return "multigrid";
  }
  return "?";
}

/// "none" | "jacobi" | "mic0" | "multigrid"; throws SceneError naming the value otherwise.
inline Preconditioner parse_preconditioner(const std::string& name) {
  if (name == "none") return Preconditioner::None;
  if (name == "jacobi") return Preconditioner::Jacobi;
  if (name == "mic0") return Preconditioner::MIC0;
  if (name == "multigrid") return Preconditioner::Multigrid;
  throw SceneError("pressure.preconditioner = \"" + name +
                   "\"; allowed: \"none\", \"jacobi\", \"mic0\", \"multigrid\"");
}

/// Parameters of the projection; the field names are the scene keys.
struct ProjectionOptions {
  /// Multigrid by default: on the 150 x 100 x 75 dam break it needs 7 iterations where MIC(0)
  /// needs 66 and takes a quarter of the CPU time (benchmarks/RESULTS.md).
  Preconditioner preconditioner = Preconditioner::Multigrid;
  double tolerance = 1e-6;    ///< on the relative residual ||b - A p|| / ||b||, in (0, 1)
  int max_iterations = 1000;  ///< PCG iteration cap, >= 1
  double density = 1000;      ///< liquid density rho (kg/m^3), > 0
  bool ghost_fluid = true;    ///< second-order free surface (else p = 0 at air cell centres)
  /// MIC(0) parallel form: 0 = exact MIC(0), triangular solves level-scheduled over tiles of
  /// rows; k >= 1 = k independent slabs along x holding equal shares of the fluid cells (block
  /// Jacobi with MIC(0) blocks: couplings between slabs dropped from the preconditioner, one
  /// task per slab, a few synchronisations per iteration instead of one per tile diagonal).
  int mic_blocks = 0;
  /// Multigrid: red-black Gauss-Seidel sweeps before and (mirrored) after the coarse
  /// correction on every level, >= 1.
  int multigrid_smoothing = 2;
  /// Multigrid: extra red-black sweeps on the boundary band (cells with an open face to air or
  /// a partly open face) around the interior sweeps, >= 0.
  int multigrid_boundary_smoothing = 0;

  void validate() const {
    const auto fail = [](const char* key, double value, const char* allowed) {
      std::ostringstream msg;
      msg << "pressure." << key << " = " << value << "; allowed: " << allowed;
      throw SceneError(msg.str());
    };
    if (!(tolerance > 0 && tolerance < 1)) fail("tolerance", tolerance, "(0, 1)");
    if (max_iterations < 1) fail("max_iterations", max_iterations, ">= 1");
    if (mic_blocks < 0) fail("mic_blocks", mic_blocks, ">= 0");
    if (multigrid_smoothing < 1) fail("multigrid_smoothing", multigrid_smoothing, ">= 1");
    if (multigrid_boundary_smoothing < 0) fail("multigrid_boundary_smoothing", multigrid_boundary_smoothing, ">= 0");
    if (!(density > 0) || !std::isfinite(density)) fail("density", density, "> 0");
  }
};

/// What one projection did.
struct ProjectionReport {
  int iterations = 0;            ///< PCG iterations (matrix-vector products after the first)
  double relative_residual = 0;  ///< ||b - A p|| / ||b|| at return (recursively updated residual)
  bool converged = false;        ///< relative_residual <= tolerance
  /// max over fluid cells of |div u| (1/s) after the update, leaving out the cells with a face
  /// to air that the subcell surface's sliver rule left unprojected (their divergence is left to
  /// the particles' velocity there: PressureSolver::set_subcell_surface)
  double max_divergence = 0;
  std::int64_t unknowns = 0;     ///< fluid cells in the system
};

/// Assembles and solves the pressure system of a MacGrid; keeps its buffers between calls.
template <class T, int Dim>
class PressureSolver {
 public:
  using Grid = MacGrid<T, Dim>;
  using IVec = typename Grid::IVec;

  /// Rows of tiles of kTile x kTile cell rows are the unit of the MIC(0) level schedule.
  static constexpr int kTile = 8;
  /// Cell rows per chunk of the parallel vector loops and sums.
  static constexpr std::int64_t kRowGrain = 16;
  static constexpr double kThetaMin = 1e-3;  ///< ghost-fluid clamp
  static constexpr double kMicTau = 0.97;    ///< MIC(0) modification (Bridson 2015)
  static constexpr double kMicSigma = 0.25;  ///< MIC(0) safety: fall back to IC when e < sigma A_cc

  /// project()'s default target: D_c = 0.
  struct NoTarget {
    double operator()(std::int64_t, const IVec&) const { return 0.0; }
  };

  /// Builds A (scaled by dt / (rho dx^2)) from g.label, g.phi and the open face weights.
  /// Unknowns are Fluid cells with at least one open face.
  void assemble(const Grid& g, bool ghost_fluid) {
    setup_layout(g);
    ghost_fluid_ = ghost_fluid;
    // Row c of A for a Fluid cell c: the diagonal (returned), the off-diagonals to the upper
    // Fluid neighbours and whether a face opens to air. Unknowns are the cells with diag > 0.
    const auto fluid_row = [&](std::int64_t c, const IVec& i, std::array<T, Dim>& up, bool& dirichlet) {
      double diag = 0;
      dirichlet = false;
      for (int d = 0; d < Dim; ++d) {
        up[std::size_t(d)] = T(0);
        const std::int64_t lower = g.face(d, i);
        for (int side = 0; side < 2; ++side) {  // lower face (side 0) or upper face (side 1)
          const std::int64_t nb = side ? c + g.cell_stride(d) : c - g.cell_stride(d);
          const double w = double(g.open_weight(d, i[d] + side, side ? lower + face_up_[d] : lower, side ? nb : c));
          if (w <= 0) continue;
          const auto nl = g.label[std::size_t(nb)];
          if (nl == Grid::Fluid) {
            diag += w;
            if (side) up[std::size_t(d)] = T(-w);
          } else if (nl == Grid::Air) {
            diag += w / theta(g, c, nb);
            dirichlet = true;
          }
        }
      }
      return diag;
    };
    // Pass 1: each row's span of unknowns, then the packed layout.
    span_lo_.assign(std::size_t(num_rows_), 0);
    span_hi_.assign(std::size_t(num_rows_), 0);
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      IVec i = row_coord(res_, row);
      int lo = nz_, hi = 0;
      std::array<T, Dim> up{};
      bool dirichlet = false;
      for (int k = 0; k < nz_; ++k) {
        const std::int64_t c = row * nz_ + k;
        if (g.label[std::size_t(c)] != Grid::Fluid) continue;
        i[Dim - 1] = k;
        if (fluid_row(c, i, up, dirichlet) > 0) lo = std::min(lo, k), hi = k + 1;
      }
      span_lo_[std::size_t(row)] = lo < hi ? lo : 0;
      span_hi_[std::size_t(row)] = lo < hi ? hi : 0;
    });
    compute_windows();
    // Pass 2: the coefficients of the Fluid cells in the spans (every other stored entry is 0).
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      IVec i = row_coord(res_, row);
      const std::int64_t at0 = row_base(row);
      std::array<T, Dim> up{};
      bool dirichlet = false;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = row * nz_ + k;
        if (g.label[std::size_t(c)] != Grid::Fluid) continue;
        i[Dim - 1] = k;
        const std::size_t at = std::size_t(at0 + k);
        diag_[at] = fluid_row(c, i, up, dirichlet);
        for (int d = 0; d < Dim; ++d) plus_[std::size_t(d)][at] = up[std::size_t(d)];
        dirichlet_[at] = dirichlet;
      }
    });
    // An open fluid-fluid face always gives both cells a positive diagonal, so plus(d) never
    // couples an unknown to a non-unknown.
    unknowns_ = rows_sum<std::int64_t>([&](std::int64_t row) {
      std::int64_t m = 0;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) m += diag_[std::size_t(row_base(row) + k)] > 0;
      return m;
    });
    kind_ready_ = preconditioner_wanted_ == Preconditioner::Multigrid;
    if (kind_ready_) {  // the multigrid's cell kinds, level set and face weights, on the full grid
      for (int d = 0; d < Dim; ++d) {
        open_[d].resize(std::size_t(g.num_faces(d)));
        T* open = open_[d].data();
        for_each_face_row(g, d, [&](std::int64_t f0, std::int64_t c0, const IVec& fi) {
          const int n = g.res[Dim - 1] + (d == Dim - 1 ? 1 : 0);
          for (int j = 0; j < n; ++j) open[f0 + j] = g.open_weight(d, d == Dim - 1 ? j : fi[d], f0 + j, c0 + j);
        });
      }
      kind_.resize(std::size_t(num_cells_));
      phi_.resize(std::size_t(num_cells_));
      for_each_index(g.res, [&](std::int64_t c, const IVec&) {
        const auto label = g.label[std::size_t(c)];
        kind_[std::size_t(c)] = label == Grid::Air ? Multigrid::kAir : is_unknown(c) ? Multigrid::kFluid : Multigrid::kSolid;
        phi_[std::size_t(c)] = g.phi[std::size_t(c)];
      });
    }
    compute_blocks();
    find_closed_components();
    if (preconditioner_wanted_ == Preconditioner::MIC0) build_mic0();
    mic_built_ = preconditioner_wanted_ == Preconditioner::MIC0;
    if (preconditioner_wanted_ == Preconditioner::Multigrid) build_multigrid();
    multigrid_built_ = preconditioner_wanted_ == Preconditioner::Multigrid;
  }

  /// Chooses which preconditioner assemble() prepares (project() sets it from the options).
  void prepare_for(Preconditioner p, int mic_blocks = 0) {
    preconditioner_wanted_ = p;
    mic_blocks_ = mic_blocks;
  }

  /// Whether cell c (full-grid index) is an unknown of the last assembly.
  bool is_unknown(std::int64_t c) const {
    const std::int64_t at = packed(c);
    return at >= 0 && diag_[std::size_t(at)] > 0;
  }

  /// Bytes held by the solver's work arrays and the multigrid hierarchy (capacity).
  std::size_t bytes() const {
    std::size_t b = multigrid_.bytes();
    const auto add = [&](const auto& v) { b += v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type); };
    add(diag_), add(precon_), add(x_), add(r_), add(z_), add(p_);
    for (int d = 0; d < Dim; ++d) add(plus_[std::size_t(d)]), add(open_[std::size_t(d)]);
    add(dirichlet_), add(kind_), add(phi_), add(span_lo_), add(span_hi_), add(closed_cells_), add(closed_start_);
    add(win_lo_), add(win_hi_), add(base_), add(pieces_), add(piece_start_);
    add(flood_seen_), add(flood_queue_), add(block_start_), add(wave_progress_), add(tile_sums_);
    return b;
  }
  std::int64_t unknowns() const { return unknowns_; }
  /// Fluid components with no free-surface face (each makes A singular by one constant).
  int closed_components() const { return int(closed_start_.size()) - (closed_start_.empty() ? 0 : 1); }

  /// y = A x over the unknowns (full-grid vectors; zero elsewhere).
  void apply(const std::vector<double>& x, std::vector<double>& y) {
    gather(x.data(), p_.data());
    matvec(p_.data(), z_.data());
    scatter(z_.data(), y);
  }

  /// Solves A x = b by PCG. b and x are full-grid vectors (cell index); entries outside the
  /// unknowns are ignored in b and returned as 0 in x. x holds the initial guess on entry.
  ProjectionReport solve(const std::vector<double>& b, std::vector<double>& x, const ProjectionOptions& opt) {
    opt.validate();
    gather(b.data(), r_.data());
    if (std::int64_t(x.size()) == num_cells_) {
      gather(x.data(), x_.data());
    } else {
      std::fill(x_.begin(), x_.begin() + packed_size_, 0.0);
    }
    ProjectionReport rep = solve_in_place(opt);
    scatter(x_.data(), x);
    return rep;
  }

  /// Projects g's face velocities: assembles A, solves for p (warm start from g.pressure),
  /// subtracts dt/rho grad p on open faces next to fluid, sets u = u_solid on closed faces and
  /// valid = 1 exactly on the updated faces. Writes g.pressure (0 outside the fluid).
  /// `target_flux`, if given, asks for D_c = target_flux(c, i) instead of 0 at every unknown c
  /// (cell index c, coordinates i; dx times a target divergence, for the FLIP volume correction;
  /// called twice per unknown, so it must be a function of the grid); max_divergence then
  /// measures |D_c - target_flux(c, i)| / dx.
  template <class Target = NoTarget>
  ProjectionReport project(Grid& g, T dt, const ProjectionOptions& opt, const Target& target_flux = {}) {
    prepare(g, dt, opt, target_flux);
    ProjectionReport rep = solve_in_place(opt);
    finish(g, dt, opt, target_flux, rep);
    return rep;
  }

  /// project()'s first half: assembles A and the right-hand side b over the unknowns and loads
  /// the warm start from g.pressure, for solve_in_place() or for a solve elsewhere (the rows of
  /// a run split over processes, read with diagonal(), rhs() and value()).
  template <class Target = NoTarget>
  void prepare(const Grid& g, T dt, const ProjectionOptions& opt, const Target& target_flux = {}) {
    opt.validate();
    prepare_for(opt.preconditioner, opt.mic_blocks);
    assemble(g, opt.ghost_fluid);
    const double scale = opt.density * double(g.dx) / double(dt);  // b = -(rho dx / dt) D
    // b and the warm start p go straight into the solver's own vectors (b into the residual's,
    // see pcg()), over the rows' spans of unknowns only: assemble() has zeroed the rest.
    double* const b = r_.data();
    double* const p = x_.data();
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      IVec i = row_coord(g.res, row);
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        i[Dim - 1] = k;
        const std::int64_t c = row * nz_ + k, at = at0 + k;
        const bool unknown = diag_[std::size_t(at)] > 0;
        const double target = unknown ? double(target_flux(c, std::as_const(i))) : 0.0;
        b[at] = unknown ? -scale * (double(open_flux_sum(g, c, i)) - target) : 0.0;
        if (unknown && surface_pressure_) b[at] += surface_rhs(g, c, i);
        p[at] = unknown ? double(g.pressure[std::size_t(c)]) : 0.0;
      }
    });
  }

  /// project()'s second half, from the solution held by the solver (value()): writes
  /// g.pressure, updates the faces and sets rep.max_divergence, the largest over the unknowns c
  /// with counted(c) (a split run counts its own cells only).
  template <class Target = NoTarget, class Counted = NoTarget>
  void finish(Grid& g, T dt, const ProjectionOptions& opt, const Target& target_flux, ProjectionReport& rep,
              const Counted& counted = {}) {
    constexpr bool count_all = std::is_same_v<Counted, NoTarget>;
    const double* const p = x_.data();
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {  // 0 outside the spans
      T* pr = g.pressure.data() + row * nz_;
      const std::int64_t at0 = row_base(row);
      const int lo = span_lo_[std::size_t(row)], hi = span_hi_[std::size_t(row)];
      for (int k = 0; k < nz_; ++k) pr[k] = k >= lo && k < hi ? T(p[at0 + k]) : T(0);
    });
    const double coef = double(dt) / (opt.density * double(g.dx));
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t down = g.cell_stride(d);
      for_each_face_row(g, d, [&](std::int64_t f0, std::int64_t c0, const IVec& fi) {
        const int n = g.res[Dim - 1] + (d == Dim - 1 ? 1 : 0);
        // Only faces next to a row's span of unknowns can be updated: [j_lo, j_hi). Outside it
        // every face is closed (u = u_solid) or not next to an unknown (invalid), in a loop
        // without branches.
        int j_lo = n, j_hi = 0;
        const auto add_span = [&](std::int64_t row, int extra) {
          const int lo = span_lo_[std::size_t(row)], hi = span_hi_[std::size_t(row)];
          if (lo < hi) j_lo = std::min(j_lo, lo), j_hi = std::max(j_hi, hi + extra);
        };
        if (d == Dim - 1) {
          add_span(c0 / nz_, 1);  // the faces of cells lo .. hi - 1 are lo .. hi
        } else if (fi[d] > 0 && fi[d] < g.res[d]) {
          add_span(c0 / nz_, 0);
          add_span((c0 - down) / nz_, 0);
        }
        if (j_lo >= j_hi) j_lo = j_hi = n;
        // Rows of the face's upper cell b = c0 + j and lower cell a = b - down.
        const std::int64_t b_row = c0 / nz_;
        const std::int64_t a_row = d == Dim - 1 ? b_row : b_row - row_step_[std::size_t(d)];
        const int a_shift = d == Dim - 1 ? 1 : 0;
        const auto open = [&](int j) { return g.open_weight(d, d == Dim - 1 ? j : fi[d], f0 + j, c0 + j); };
        const auto rest = [&](int j0, int j1) {
          if (j0 >= j1) return;
          T* u = g.u[d].data() + f0;
          std::fill(g.valid[d].data() + f0 + j0, g.valid[d].data() + f0 + j1, std::uint8_t(0));
          // Only closed faces change (most faces are open: a store on each cost a full pass).
          for (int j = j0; j < j1; ++j)
            if (open(j) <= T(0)) u[j] = g.face_u_solid(d, f0 + j);
        };
        rest(0, j_lo);
        rest(j_hi, n);
        for (int j = j_lo; j < j_hi; ++j) {
          const std::size_t fs = std::size_t(f0 + j);
          const T w = open(j);
          if (w <= T(0)) {
            g.u[d][fs] = g.face_u_solid(d, std::int64_t(fs));
            g.valid[d][fs] = 0;
            continue;
          }
          const std::int64_t b_cell = c0 + j;  // upper cell; open faces are interior
          const std::int64_t a_cell = b_cell - down;
          const std::int64_t b_at = stored_or_zero(b_row, j), a_at = stored_or_zero(a_row, j - a_shift);
          const bool ua = diag_[std::size_t(a_at)] > 0, ub = diag_[std::size_t(b_at)] > 0;
          if (!ua && !ub) {
            g.valid[d][fs] = 0;
            continue;
          }
          double dp;
          if (ua && ub) {
            dp = p[b_at] - p[a_at];
          } else if (ua) {
            // b is air (an open face next to an unknown is fluid or air): ghost p_b.
            const double th = theta(g, a_cell, b_cell);
            if (sliver(g, th, a_cell)) {
              g.valid[d][fs] = 0;
              continue;
            }
            dp = (surface_pressure(a_cell, b_cell, th) - p[a_at]) / th;
          } else {
            const double th = theta(g, b_cell, a_cell);
            if (sliver(g, th, b_cell)) {
              g.valid[d][fs] = 0;
              continue;
            }
            dp = (p[b_at] - surface_pressure(b_cell, a_cell, th)) / th;
          }
          g.u[d][fs] = T(double(g.u[d][fs]) - coef * dp);
          g.valid[d][fs] = 1;
        }
      });
    }
    rep.max_divergence = parallel::parallel_max<double>(0, num_rows_, 0.0, [&](std::int64_t lo, std::int64_t hi) {
      double m = 0;
      for (std::int64_t row = lo; row < hi; ++row) {
        IVec i = row_coord(g.res, row);
        const std::int64_t at0 = row_base(row);
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          i[Dim - 1] = k;
          const std::int64_t c = row * nz_ + k;
          bool count = diag_[std::size_t(at0 + k)] > 0;
          if constexpr (!count_all) count = count && counted(c);
          if (count && subcell_ && dirichlet_[std::size_t(at0 + k)]) count = !has_unprojected_air_face(g, c, i);
          if (count)
            m = std::max(m, std::abs(double(open_flux_sum(g, c, i)) - double(target_flux(c, std::as_const(i)))) / double(g.dx));
        }
      }
      return m;
    });
  }

  /// After prepare(): row c of A (cell index c, an unknown) on its diagonal, and the right-hand
  /// side there; A's off-diagonal between fluid neighbours across an open face is minus the face's
  /// open weight. value(c) is the unknown's entry of the warm start, then of the solution.
  double diagonal(std::int64_t c) const { return diag_[std::size_t(packed(c))]; }
  double rhs(std::int64_t c) const { return r_[std::size_t(packed(c))]; }
  double& value(std::int64_t c) { return x_[std::size_t(packed(c))]; }
  /// Whether the unknown c has a face open to air (a Dirichlet condition: the rows of a liquid
  /// without any make A singular).
  bool touches_air(std::int64_t c) const { return dirichlet_[std::size_t(packed(c))] != 0; }

  /// sum_d U(c + 1/2 e_d) - U(c - 1/2 e_d) with U = w u + (1 - w) u_solid, w the open weight:
  /// dx times the discrete divergence of cell c.
  static T flux_sum(const Grid& g, const IVec& i) {
    T s = T(0);
    for (int d = 0; d < Dim; ++d) {
      for (int side = 0; side < 2; ++side) {
        IVec f = i;
        f[d] += side;
        const std::size_t fs = std::size_t(g.face(d, f));
        const T w = g.open_weight(d, f);
        const T flux = w * g.u[d][fs] + (T(1) - w) * g.face_u_solid(d, std::int64_t(fs));
        s += side ? flux : -flux;
      }
    }
    return s;
  }

  /// flux_sum() of cell c (coordinates i), with the face indices it has at hand.
  T open_flux_sum(const Grid& g, std::int64_t c, const IVec& i) const {
    return g.has_solid_faces() ? open_flux_sum<true>(g, c, i) : open_flux_sum<false>(g, c, i);
  }
  /// The same, for a grid with or without solid faces: one expression per case, so that the
  /// compiler's contraction of w u + (1 - w) u_solid stays what it was when every grid stored
  /// u_solid (the frames of scenes with colliders are unchanged to the bit).
  template <bool kSolidFaces>
  T open_flux_sum(const Grid& g, std::int64_t c, const IVec& i) const {
    T s = T(0);
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t lower = g.face(d, i);
      for (int side = 0; side < 2; ++side) {
        const std::size_t fs = std::size_t(side ? lower + face_up_[d] : lower);
        const T w = g.open_weight(d, i[d] + side, std::int64_t(fs), side ? c + g.cell_stride(d) : c);
        const T us = kSolidFaces ? g.u_solid[d][fs] : T(0);
        const T flux = w * g.u[d][fs] + (T(1) - w) * us;
        s += side ? flux : -flux;
      }
    }
    return s;
  }

  /// The liquid's pressure at its free surface for the next project(): `p` holds sigma kappa at
  /// the cell centres on either side of the surface (surface_tension.h), interpolated to where
  /// the surface crosses each face; null (the default) for p = 0. The ghost pressure of an air
  /// neighbour a of fluid cell c becomes p_c + (p_gamma - p_c) / theta: the diagonal is
  /// unchanged and the right-hand side gains w p_gamma / theta.
  ///
  void set_surface_pressure(const T* p) { surface_pressure_ = p; }

  /// Whether the free surface of the next project() was placed inside the fluid cells
  /// (level_set.h, place_surface_in_fluid_cells; solver.free_surface "subcell"), where theta
  /// comes down to 0.01 at a cell that the liquid barely fills. Such a face takes up its cell's
  /// divergence at a cost that theta weights (the projection's norm), but G2P hands its velocity
  /// to the particles in full: a 3D drop of 12 cells' radius oscillating for 2.2 periods ended
  /// with 50 times the kinetic energy, and with the same placement the 3D dam break's kinetic
  /// energy went from 2810 to 6740 J in one substep. So finish() then leaves a face to air with
  /// theta < kSliverTheta unprojected (invalid: the solver gives it the particles' kept velocity
  /// or an extrapolated one, as an air face) where its fluid cell c has a fluid face neighbour
  /// that is not itself beside air: the liquid behind c is then held by that neighbour's
  /// projected faces. Where every cell is a surface cell (sparse particles, spray) every face is
  /// projected, since leaving them all free let sparse particles gain kinetic energy without
  /// bound (x10 to x250 000 over 2000 substeps; FlipPhysics). Off (the default): every face is
  /// projected.
  void set_subcell_surface(bool on) { subcell_ = on; }
  static constexpr double kSliverTheta = 0.25;

  /// Free-surface fraction between fluid cell c and air cell a: theta = phi_c / (phi_c - phi_a)
  /// when phi changes sign between them, clamped to [kThetaMin, 1]; 1 without ghost fluid.
  double theta(const Grid& g, std::int64_t c, std::int64_t a) const {
    if (!ghost_fluid_) return 1.0;
    const double pc = double(g.phi[std::size_t(c)]), pa = double(g.phi[std::size_t(a)]);
    if (!(pc < 0 && pa >= 0)) return 1.0;
    return std::clamp(pc / (pc - pa), kThetaMin, 1.0);
  }

 private:
  /// Whether finish() leaves a face from fluid cell c to air with fraction th unprojected (see
  /// set_subcell_surface): a subcell surface, th < kSliverTheta, and a fluid face neighbour of c
  /// without an air face neighbour.
  bool sliver(const Grid& g, double th, std::int64_t c) const {
    if (!subcell_ || th >= kSliverTheta) return false;
    const auto is = [&](std::int64_t k, std::uint8_t l) { return g.label[std::size_t(k)] == l; };
    return g.any_face_neighbour(c, [&](std::int64_t nb) {
      return is(nb, Grid::Fluid) && !g.any_face_neighbour(nb, [&](std::int64_t a) { return is(a, Grid::Air); });
    });
  }

  /// p_gamma on the face from fluid cell c to air cell a, theta of the way from c (0 without a
  /// surface pressure).
  double surface_pressure(std::int64_t c, std::int64_t a, double th) const {
    if (!surface_pressure_) return 0.0;
    return (1.0 - th) * double(surface_pressure_[std::size_t(c)]) + th * double(surface_pressure_[std::size_t(a)]);
  }

  /// The surface pressure's share of fluid cell c's right-hand side: sum over its open faces
  /// to air of w p_gamma / theta.
  double surface_rhs(const Grid& g, std::int64_t c, const IVec& i) const {
    double s = 0;
    for_open_air_faces(g, c, i, [&](int, std::int64_t, std::int64_t nb, double w) {
      const double th = theta(g, c, nb);
      s += w * surface_pressure(c, nb, th) / th;
    });
    return s;
  }

  /// fn(d, f, a, w) for every open face f (axis d, open weight w > 0) from fluid cell c (at i) to
  /// an air cell a.
  template <class Fn>
  void for_open_air_faces(const Grid& g, std::int64_t c, const IVec& i, Fn&& fn) const {
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t lower = g.face(d, i);
      for (int side = 0; side < 2; ++side) {
        const std::int64_t nb = side ? c + g.cell_stride(d) : c - g.cell_stride(d);
        const std::int64_t f = side ? lower + face_up_[d] : lower;
        const double w = double(g.open_weight(d, i[d] + side, f, side ? nb : c));
        if (w <= 0 || g.label[std::size_t(nb)] != Grid::Air) continue;
        fn(d, f, nb, w);
      }
    }
  }

  /// Whether fluid cell c has an open face to air that finish() left unprojected (sliver()).
  bool has_unprojected_air_face(const Grid& g, std::int64_t c, const IVec& i) const {
    bool left = false;
    for_open_air_faces(g, c, i, [&](int d, std::int64_t f, std::int64_t, double) { left = left || !g.valid[d][std::size_t(f)]; });
    return left;
  }

  /// Index of the first element of row `row` of a row-major box (last axis along the row).
  static IVec row_coord(const IVec& box, std::int64_t row) {
    IVec i = IVec::Zero();
    for (int a = Dim - 2; a >= 0; --a) {
      i[a] = int(row % box[a]);
      row /= box[a];
    }
    return i;
  }

  /// fn(k, i) for every index i of the row-major box `box` (k its linear index), in parallel
  /// over rows along the last axis: one division per row, not per element.
  template <class Fn>
  static void for_each_index(const IVec& box, Fn&& fn) {
    const int nz = box[Dim - 1];
    std::int64_t rows = 1;
    for (int a = 0; a < Dim - 1; ++a) rows *= box[a];
    parallel::parallel_for(0, rows, [&](std::int64_t row) {
      IVec i = row_coord(box, row);
      for (int k = 0; k < nz; ++k) {
        i[Dim - 1] = k;
        fn(row * nz + k, i);
      }
    });
  }

  /// fn(f0, c0, fi) for every row of axis-d faces along the last axis, in parallel: f0 is the
  /// row's first face, fi its coordinates (last one 0) and c0 the index of the cell with the same
  /// coordinates, so that face f0 + j lies between cells c0 + j - cell_stride(d) and c0 + j
  /// (meaningful only for interior faces).
  template <class Fn>
  static void for_each_face_row(const Grid& g, int d, Fn&& fn) {
    const IVec fr = g.face_res(d);
    std::int64_t rows = 1;
    for (int a = 0; a < Dim - 1; ++a) rows *= fr[a];
    parallel::parallel_for(0, rows, [&](std::int64_t row) {
      const IVec fi = row_coord(fr, row);
      std::int64_t c0 = 0;
      for (int a = 0; a < Dim - 1; ++a) c0 = (c0 + fi[a]) * g.res[a + 1];
      fn(row * fr[Dim - 1], c0, fi);
    });
  }

  T* plus(int d) { return plus_[std::size_t(d)].data(); }
  const T* plus(int d) const { return plus_[std::size_t(d)].data(); }

  /// Packed index of cell k = 0 of row `row` (meaningful for the k its window stores).
  std::int64_t row_base(std::int64_t row) const { return base_[std::size_t(row)]; }

  /// Packed index of cell c (full-grid index), -1 if it is not stored.
  std::int64_t packed(std::int64_t c) const {
    if (c < 0 || c >= num_cells_) return -1;
    const std::int64_t row = c / nz_;
    return stored(row, int(c - row * nz_));
  }

  /// Packed index of cell k of row `row`, -1 if the row is outside the grid or does not store k.
  std::int64_t stored(std::int64_t row, int k) const {
    if (row < 0 || row >= num_rows_) return -1;
    const std::size_t r = std::size_t(row);
    return k >= win_lo_[r] && k < win_hi_[r] ? base_[r] + k : -1;
  }

  /// Packed index of cell k (-1 <= k <= nz_) of row `row`, or of the zero row where the row
  /// does not store k.
  std::int64_t stored_or_zero(std::int64_t row, int k) const {
    const std::size_t r = std::size_t(row);
    return k >= win_lo_[r] && k < win_hi_[r] ? base_[r] + k : zero_base_ + k;
  }

  /// A piece [k0, k1) of a row's span over which every axis neighbour row either stores the
  /// neighbours or not: up[d] and down[d] are the offsets from a cell c of the piece to c + e_d
  /// and c - e_d in the packed vectors (into the zero row for neighbours not stored).
  struct Piece {
    int k0 = 0, k1 = 0;
    std::array<std::int64_t, Dim> up{}, down{};
  };
  struct Pieces {
    const Piece* first;
    const Piece* last;
    const Piece* begin() const { return first; }
    const Piece* end() const { return last; }
  };
  /// The pieces of row `row`'s span, in increasing k.
  Pieces pieces(std::int64_t row) const {
    const Piece* p = pieces_.data();
    return Pieces{p + piece_start_[std::size_t(row)], p + piece_start_[std::size_t(row + 1)]};
  }

  /// to = from over the unknowns (full grid to packed; 0 at the other cells of the spans).
  void gather(const double* from, double* to) const {
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t at = at0 + k;
        to[at] = diag_[std::size_t(at)] > 0 ? from[row * nz_ + k] : 0.0;
      }
    });
  }

  /// to = from on the rows' spans, 0 elsewhere (packed to full grid).
  void scatter(const double* from, std::vector<double>& to) const {
    to.assign(std::size_t(num_cells_), 0.0);
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) to[std::size_t(row * nz_ + k)] = from[at0 + k];
    });
  }

  /// v.size() >= n without keeping its old contents when it has to grow (then with 1/8 to
  /// spare: the fluid's rows change every substep).
  template <class V>
  static void grow(V& v, std::int64_t n) {
    if (std::int64_t(v.size()) >= n) return;
    if (std::int64_t(v.capacity()) < n) {
      V fresh;
      fresh.reserve(std::size_t(n + n / 8));
      v.swap(fresh);
    }
    v.resize(std::size_t(n));
  }

  /// Windows (each row's span and one cell more at each end), packed offsets, the zero row
  /// and the pieces of every span; sizes the packed vectors and zeroes them.
  void compute_windows() {
    win_lo_.assign(std::size_t(num_rows_), 0);
    win_hi_.assign(std::size_t(num_rows_), 0);
    base_.resize(std::size_t(num_rows_));
    std::int64_t next = 0;
    for (std::int64_t row = 0; row < num_rows_; ++row) {
      const std::size_t r = std::size_t(row);
      const int lo = span_lo_[std::size_t(row)], hi = span_hi_[std::size_t(row)];
      if (lo < hi) win_lo_[r] = lo - 1, win_hi_[r] = hi + 1;
      base_[r] = next - win_lo_[r];
      next += win_hi_[r] - win_lo_[r];
    }
    packed_size_ = next;
    zero_base_ = next + 1;  // the zero row: cells -1 .. nz_, never written
    // Pieces: cut each span where an axis neighbour row's window starts or ends.
    piece_start_.assign(std::size_t(num_rows_ + 1), 0);
    pieces_.clear();
    {  // about one piece per row with a span: reserve twice that (a warm step allocates nothing)
      std::int64_t rows = 0;
      for (std::int64_t row = 0; row < num_rows_; ++row) rows += span_lo_[std::size_t(row)] < span_hi_[std::size_t(row)];
      if (std::int64_t(pieces_.capacity()) < rows + rows / 2) pieces_.reserve(std::size_t(2 * rows + 16));
    }
    for (std::int64_t row = 0; row < num_rows_; ++row) {
      piece_start_[std::size_t(row)] = std::int64_t(pieces_.size());
      const int lo = span_lo_[std::size_t(row)], hi = span_hi_[std::size_t(row)];
      if (lo >= hi) continue;
      std::array<int, 2 + 4 * Dim> cut{};
      int n = 0;
      cut[std::size_t(n++)] = lo;
      cut[std::size_t(n++)] = hi;
      const auto window = [&](std::int64_t q, int& wl, int& wh) {
        wl = wh = 0;
        if (q < 0 || q >= num_rows_) return;
        wl = win_lo_[std::size_t(q)], wh = win_hi_[std::size_t(q)];
      };
      // The rows beside this one along each axis d, or -1 past the grid's side: row +- row_step_[d]
      // alone would wrap a row on the last index along d into the next row of the axis before
      // (its cells are never coupled, but the sweeps would read them while another tile of the
      // wavefront writes them).
      // Entry 2 d + side: that row and its window.
      std::array<std::int64_t, 2 * (Dim - 1)> beside{};
      std::array<int, 2 * (Dim - 1)> beside_lo{}, beside_hi{};
      for (int d = 0; d < Dim - 1; ++d)
        for (int side = 0; side < 2; ++side) {
          const std::size_t e = std::size_t(2 * d + side);
          const std::int64_t step = row_step_[std::size_t(d)];
          const std::int64_t at = (row / step) % res_[d];
          beside[e] = (side ? at + 1 >= res_[d] : at == 0) ? -1 : row + (side ? step : -step);
          window(beside[e], beside_lo[e], beside_hi[e]);
          const int wl = beside_lo[e], wh = beside_hi[e];
          if (wl >= wh) continue;
          if (wl > lo && wl < hi) cut[std::size_t(n++)] = wl;
          if (wh > lo && wh < hi) cut[std::size_t(n++)] = wh;
        }
      std::sort(cut.begin(), cut.begin() + n);
      n = int(std::unique(cut.begin(), cut.begin() + n) - cut.begin());
      const std::int64_t base = row_base(row);
      for (int t = 0; t + 1 < n; ++t) {
        Piece piece;
        piece.k0 = cut[std::size_t(t)], piece.k1 = cut[std::size_t(t + 1)];
        for (int d = 0; d < Dim - 1; ++d)
          for (int side = 0; side < 2; ++side) {
            const std::size_t e = std::size_t(2 * d + side);
            const bool stored = beside_lo[e] <= piece.k0 && piece.k1 <= beside_hi[e];
            const std::int64_t offset = (stored ? base_[std::size_t(beside[e])] : zero_base_) - base;
            (side ? piece.up : piece.down)[std::size_t(d)] = offset;
          }
        piece.up[Dim - 1] = 1;
        piece.down[Dim - 1] = -1;
        pieces_.push_back(piece);
      }
    }
    piece_start_[std::size_t(num_rows_)] = std::int64_t(pieces_.size());
    const std::int64_t n = packed_size_ + nz_ + 2;
    for (auto* v : {&diag_, &precon_, &x_, &r_, &z_, &p_}) grow(*v, n);
    for (int d = 0; d < Dim; ++d) grow(plus_[std::size_t(d)], n);
    grow(dirichlet_, n);
    constexpr std::int64_t kBlock = std::int64_t(1) << 14;
    parallel::parallel_for_grain(0, (n + kBlock - 1) / kBlock, 1, [&](std::int64_t blk) {
      const std::int64_t lo = blk * kBlock, hi = std::min(n, lo + kBlock);
      for (auto* v : {&diag_, &precon_, &x_, &r_, &z_, &p_}) std::fill(v->data() + lo, v->data() + hi, 0.0);
      for (int d = 0; d < Dim; ++d) std::fill(plus_[std::size_t(d)].data() + lo, plus_[std::size_t(d)].data() + hi, T(0));
      std::fill(dirichlet_.data() + lo, dirichlet_.data() + hi, std::uint8_t(0));
    });
  }

  void setup_layout(const Grid& g) {
    res_ = g.res;
    num_cells_ = g.num_cells();
    nz_ = res_[Dim - 1];
    n0_ = res_[0];
    n1_ = Dim == 3 ? res_[1] : 1;
    num_rows_ = num_cells_ / std::max(nz_, 1);
    for (int d = 0; d < Dim; ++d) stride_[d] = g.cell_stride(d), face_up_[d] = g.face_stride(d, d);
    for (int d = 0; d < Dim - 1; ++d) row_step_[std::size_t(d)] = stride_[d] / std::max(nz_, 1);
    tiles0_ = (n0_ + kTile - 1) / kTile;
    tiles1_ = (n1_ + kTile - 1) / kTile;
  }

  /// Slab bounds along axis 0 for mic_blocks_ > 0: equal shares of the unknowns (a function of
  /// the fluid only, never of the thread count).
  void compute_blocks() {
    block_start_.assign(1, 0);
    if (mic_blocks_ <= 0) return;
    std::vector<std::int64_t> per_i(std::size_t(n0_), 0);
    for (std::int64_t row = 0; row < num_rows_; ++row)
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k)
        per_i[std::size_t(row / n1_)] += diag_[std::size_t(row_base(row) + k)] > 0;
    std::int64_t acc = 0;
    int next = 1;
    for (int i = 0; i < n0_; ++i) {
      acc += per_i[std::size_t(i)];
      if (next < mic_blocks_ && acc * mic_blocks_ >= std::int64_t(next) * unknowns_ && i + 1 < n0_) {
        block_start_.push_back(i + 1);
        while (next < mic_blocks_ && acc * mic_blocks_ >= std::int64_t(next) * unknowns_) ++next;
      }
    }
    block_start_.push_back(n0_);
  }

  /// Labels the unknowns not connected (through open fluid faces) to a free-surface face:
  /// closed_cells_ lists them grouped by component, closed_start_ the group starts.
  void find_closed_components() {
    closed_cells_.clear();
    closed_start_.clear();
    // The queues hold full-grid cell indices (a neighbour's packed index needs its row); seen
    // is packed.
    std::vector<std::uint8_t>& seen = flood_seen_;  // members: no allocation per solve
    std::vector<std::int64_t>& queue = flood_queue_;
    grow(seen, packed_size_);  // with room to spare, as the packed vectors
    std::fill(seen.begin(), seen.begin() + packed_size_, std::uint8_t(0));
    queue.clear();
    // Neighbours are found from (row, k) with stored(): a cell before the first row or wrapped
    // into another row is never coupled, as with packed().
    const auto flood = [&](std::vector<std::int64_t>& q, std::size_t head) {
      while (head < q.size()) {
        const std::int64_t c = q[head++];
        const std::int64_t row = c / nz_;  // one division per cell; the neighbours follow from (row, k)
        const int k = int(c - row * nz_);
        const std::int64_t at = base_[std::size_t(row)] + k;
        for (int d = 0; d < Dim; ++d) {
          const bool last = d == Dim - 1;
          const std::int64_t step = last ? 0 : row_step_[std::size_t(d)];
          // A coupled upper neighbour is an unknown, so its row stores it.
          if (plus(d)[at] != 0) {
            const std::int64_t up_at = last ? at + 1 : stored(row + step, k);
            if (!seen[std::size_t(up_at)]) seen[std::size_t(up_at)] = 1, q.push_back(c + stride_[d]);
          }
          const std::int64_t down_at = last ? (k > 0 ? at - 1 : -1) : stored(row - step, k);
          if (down_at >= 0 && plus(d)[down_at] != 0 && !seen[std::size_t(down_at)])
            seen[std::size_t(down_at)] = 1, q.push_back(c - stride_[d]);
        }
      }
    };
    // fn(c, packed index) for every unknown, in increasing c.
    const auto for_unknowns = [&](auto&& fn) {
      for (std::int64_t row = 0; row < num_rows_; ++row)
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t at = row_base(row) + k;
          if (diag_[std::size_t(at)] > 0) fn(row * nz_ + k, at);
        }
    };
    for_unknowns([&](std::int64_t c, std::int64_t at) {
      if (dirichlet_[std::size_t(at)]) seen[std::size_t(at)] = 1, queue.push_back(c);
    });
    flood(queue, 0);
    if (std::int64_t(queue.size()) == unknowns_) return;
    for_unknowns([&](std::int64_t c, std::int64_t at) {
      if (seen[std::size_t(at)]) return;
      closed_start_.push_back(std::int64_t(closed_cells_.size()));
      seen[std::size_t(at)] = 1;
      const std::size_t head = closed_cells_.size();
      closed_cells_.push_back(c);
      flood(closed_cells_, head);
    });
    closed_start_.push_back(std::int64_t(closed_cells_.size()));
    for (std::int64_t& c : closed_cells_) c = packed(c);  // remove_closed_means() reads packed vectors
  }

  /// v -= its mean over each closed component (serial: closed components are rare and small);
  /// v is packed.
  void remove_closed_means(double* v) const {
    for (std::size_t k = 0; k + 1 < closed_start_.size(); ++k) {
      const std::int64_t lo = closed_start_[k], hi = closed_start_[k + 1];
      double sum = 0;
      for (std::int64_t t = lo; t < hi; ++t) sum += v[closed_cells_[std::size_t(t)]];
      const double mean = sum / double(hi - lo);
      for (std::int64_t t = lo; t < hi; ++t) v[closed_cells_[std::size_t(t)]] -= mean;
    }
  }

  /// Sum of fn(row) over all cell rows, in fixed chunks (thread-count independent).
  template <class S, class Fn>
  S rows_sum(Fn&& fn) const {
    return parallel::parallel_sum<S>(0, num_rows_, kRowGrain, [&](std::int64_t lo, std::int64_t hi) {
      S s = S(0);
      for (std::int64_t row = lo; row < hi; ++row) s += fn(row);
      return s;
    });
  }

  /// Runs fn(row) over all rows in an order where rows (i-1, j) and (i, j-1) come before (i, j)
  /// (forward) or after it (backward): tiles on one anti-diagonal in parallel. Returns the sum
  /// of fn's results in a fixed order.
  template <class Fn>
  double sweep(bool forward, Fn&& fn) const {
    if (mic_blocks_ > 0) {
      // Independent slabs along axis 0: one task each, the couplings between them cut.
      const std::int64_t nb = std::int64_t(block_start_.size()) - 1;
      return parallel::parallel_sum<double>(0, nb, 1, [&](std::int64_t lo, std::int64_t hi) {
        double s = 0;
        for (std::int64_t b = lo; b < hi; ++b) {
          const int i0 = block_start_[std::size_t(b)], i1 = block_start_[std::size_t(b + 1)];
          if (forward) {
            for (int i = i0; i < i1; ++i)
              for (int j = 0; j < n1_; ++j) s += fn(std::int64_t(i) * n1_ + j, i == i0, i == i1 - 1);
          } else {
            for (int i = i1 - 1; i >= i0; --i)
              for (int j = n1_ - 1; j >= 0; --j) s += fn(std::int64_t(i) * n1_ + j, i == i0, i == i1 - 1);
          }
        }
        return s;
      });
    }
    // Tiles of kTile x kTile rows in a wavefront (parallel.h); each tile's sum is kept and the
    // sums are added anti-diagonal by anti-diagonal, tiles in ascending order within one, so the
    // result's bits do not depend on the thread count or the order the tiles ran in.
    tile_sums_.resize(std::size_t(tiles0_) * std::size_t(tiles1_));
    parallel::wavefront(tiles0_, tiles1_, !forward, wave_progress_, [&](int ti, int tj) {
      double s = 0;
      const int i0 = ti * kTile, i1 = std::min(n0_, i0 + kTile);
      const int j0 = tj * kTile, j1 = std::min(n1_, j0 + kTile);
      if (forward) {
        for (int i = i0; i < i1; ++i)
          for (int j = j0; j < j1; ++j) s += fn(std::int64_t(i) * n1_ + j, false, false);
      } else {
        for (int i = i1 - 1; i >= i0; --i)
          for (int j = j1 - 1; j >= j0; --j) s += fn(std::int64_t(i) * n1_ + j, false, false);
      }
      tile_sums_[std::size_t(ti) * std::size_t(tiles1_) + std::size_t(tj)] = s;
    });
    const int levels = tiles0_ + tiles1_ - 1;
    double total = 0;
    for (int step = 0; step < levels; ++step) {
      const int level = forward ? step : levels - 1 - step;
      const int t_lo = std::max(0, level - (tiles1_ - 1)), t_hi = std::min(tiles0_ - 1, level);
      double s = 0;
      for (int ti = t_lo; ti <= t_hi; ++ti) s += tile_sums_[std::size_t(ti) * std::size_t(tiles1_) + std::size_t(level - ti)];
      total += s;
    }
    return total;
  }

  /// MIC(0) factor: precon_c = 1 / sqrt(e_c) (Bridson 2015, Fig. 5.3, any Dim).
  void build_mic0() {
    const double* diag = diag_.data();
    double* pc = precon_.data();
    sweep(true, [&](std::int64_t row, bool cut_lo, bool cut_hi) {
      const std::int64_t at0 = row_base(row);
      for (const Piece& nb : pieces(row))
      for (int k = nb.k0; k < nb.k1; ++k) {
        const std::int64_t c = at0 + k;
        if (!(diag[c] > 0)) continue;
        double e = diag[c];
        for (int d = cut_lo ? 1 : 0; d < Dim; ++d) {
          const std::int64_t m = c + nb.down[std::size_t(d)];
          const double a = plus(d)[m] * pc[m];
          double others = 0;
          // m shares c's axis-0 index for d > 0, so its +x coupling is cut with c's.
          for (int d2 = 0; d2 < Dim; ++d2)
            if (d2 != d && !(d2 == 0 && cut_hi)) others += plus(d2)[m];
          e -= a * a + kMicTau * plus(d)[m] * others * pc[m] * pc[m];
        }
        if (e < kMicSigma * diag[c]) e = diag[c];
        pc[c] = 1.0 / std::sqrt(e);
      }
      return 0.0;
    });
  }

  /// y = A x on the unknowns; returns x . y.
  double matvec(const double* x, double* y) const {
    const double* diag = diag_.data();
    return rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      const std::int64_t at0 = row_base(row);
      for (const Piece& nb : pieces(row))
      for (int k = nb.k0; k < nb.k1; ++k) {
        const std::int64_t c = at0 + k;
        if (!(diag[c] > 0)) {
          y[c] = 0;
          continue;
        }
        double v = diag[c] * x[c];
        for (int d = 0; d < Dim; ++d) {
          const std::int64_t up = c + nb.up[std::size_t(d)], down = c + nb.down[std::size_t(d)];
          v += plus(d)[c] * x[up] + plus(d)[down] * x[down];
        }
        y[c] = v;
        s += x[c] * v;
      }
      return s;
    });
  }

  PackedRows packed_rows() const {
    return PackedRows{base_.data(), win_lo_.data(), win_hi_.data()};
  }

  /// Multigrid hierarchy from the assembled system (level 0 in float).
  void build_multigrid() {
    std::array<const T*, Dim> plus_ptr{};
    std::array<const T*, Dim> open_ptr{};
    for (int d = 0; d < Dim; ++d) plus_ptr[d] = plus(d), open_ptr[d] = open_[d].data();
    if (!kind_ready_)
      throw std::logic_error("PressureSolver: the multigrid needs prepare_for(Preconditioner::Multigrid) before assemble()");
    multigrid_.build(res_, packed_rows(), diag_.data(), plus_ptr, kind_.data(), open_ptr, ghost_fluid_ ? phi_.data() : nullptr);
  }

  /// z = M^-1 r; returns r . z.
  double precondition(const ProjectionOptions& opt, const double* r, double* z) {
    const Preconditioner kind = opt.preconditioner;
    if (kind == Preconditioner::Multigrid)
      return multigrid_.apply(packed_rows(), r, z, opt.multigrid_smoothing, opt.multigrid_boundary_smoothing);
    const double* diag = diag_.data();
    if (kind != Preconditioner::MIC0) {
      const bool jacobi = kind == Preconditioner::Jacobi;
      return rows_sum<double>([&](std::int64_t row) {
        double s = 0;
        const std::int64_t at0 = row_base(row);
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = at0 + k;
          z[c] = diag[c] > 0 ? (jacobi ? r[c] / diag[c] : r[c]) : 0.0;
          s += r[c] * z[c];
        }
        return s;
      });
    }
    // pc > 0 exactly at the unknowns (build_mic0; zero elsewhere): the sweeps test it, which
    // they read anyway, instead of the diagonal.
    // Along a row each value depends on the one before it (the last axis' coupling): that
    // chain sets the sweeps' speed. So the previous value is carried in a register (the row's
    // cells are consecutive in the packed vectors: k - 1 and k + 1 are always stored, zero
    // outside the span) and enters last, through one multiply-add, z_c = pc_c t - g_c z_prev
    // with the off-chain products t (the other axes' terms) and g_c.
    const double* pc = precon_.data();
    constexpr int kLast = Dim - 1;
    const T* plus_last = plus(kLast);
    sweep(true, [&](std::int64_t row, bool cut_lo, bool) {  // L q = r, q stored in z
      const std::int64_t at0 = row_base(row);
      for (const Piece& nb : pieces(row)) {
        double z_prev = z[at0 + nb.k0 - 1];
        for (int k = nb.k0; k < nb.k1; ++k) {
          const std::int64_t c = at0 + k;
          if (!(pc[c] > 0)) {
            z[c] = z_prev = 0;
            continue;
          }
          double t = r[c];
          for (int d = cut_lo ? 1 : 0; d < kLast; ++d) {
            const std::int64_t m = c + nb.down[std::size_t(d)];
            t -= plus(d)[m] * pc[m] * z[m];
          }
          const double g = plus_last[c - 1] * pc[c - 1] * pc[c];
          z[c] = z_prev = t * pc[c] - g * z_prev;
        }
      }
      return 0.0;
    });
    return sweep(false, [&](std::int64_t row, bool, bool cut_hi) {  // L^T z = q in place
      double s = 0;
      const std::int64_t at0 = row_base(row);
      const Pieces all = pieces(row);
      for (const Piece* nb = all.end(); nb-- != all.begin();) {
        double z_next = z[at0 + nb->k1];
        for (int k = nb->k1 - 1; k >= nb->k0; --k) {
          const std::int64_t c = at0 + k;
          if (!(pc[c] > 0)) {
            z_next = z[c];  // 0 (the forward sweep wrote it)
            continue;
          }
          double t = z[c];
          for (int d = cut_hi ? 1 : 0; d < kLast; ++d) t -= plus(d)[c] * pc[c] * z[c + nb->up[std::size_t(d)]];
          const double g = plus_last[c] * pc[c] * pc[c];
          z[c] = z_next = t * pc[c] - g * z_next;
          s += r[c] * z_next;
        }
      }
      return s;
    });
  }

  /// Solves with the right-hand side in r_ (zero off the unknowns) and the initial guess in
  /// x_ (the same): builds the preconditioner if needed, removes the closed components' means
  /// and runs pcg().
  ProjectionReport solve_in_place(const ProjectionOptions& opt) {
    if (opt.preconditioner == Preconditioner::MIC0 && (!mic_built_ || opt.mic_blocks != mic_blocks_)) {
      mic_blocks_ = opt.mic_blocks;
      compute_blocks();
      build_mic0();
      mic_built_ = true;
    }
    if (opt.preconditioner == Preconditioner::Multigrid && !multigrid_built_) {
      build_multigrid();
      multigrid_built_ = true;
    }
    remove_closed_means(r_.data());
    ProjectionReport rep = pcg(opt);
    remove_closed_means(x_.data());
    return rep;
  }

  /// PCG (Saad 2003, Alg. 9.1) on x_ with the right-hand side b in r_ (zero outside the
  /// unknowns), which becomes the residual. A p (q) and M^-1 r (z) share z_: q is dead once x
  /// and r are updated, and z once p is.
  ProjectionReport pcg(const ProjectionOptions& opt) {
    ProjectionReport rep;
    rep.unknowns = unknowns_;
    double* x = x_.data();
    double* r = r_.data();
    double* z = z_.data();
    double* p = p_.data();
    double* q = z_.data();
    const double* b = r_.data();
    const double b_norm = std::sqrt(rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) s += b[at0 + k] * b[at0 + k];
      return s;
    }));
    if (b_norm == 0) {
      std::fill(x_.begin(), x_.begin() + packed_size_, 0.0);
      rep.converged = true;
      return rep;
    }
    matvec(x, q);
    double rr = rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = at0 + k;
        r[c] = b[c] - q[c];
        s += r[c] * r[c];
      }
      return s;
    });
    rep.relative_residual = std::sqrt(rr) / b_norm;
    rep.converged = rep.relative_residual <= opt.tolerance;
    if (rep.converged) return rep;
    double rz = precondition(opt, r, z);
    copy_rows(z, p);
    while (rep.iterations < opt.max_iterations) {
      const double pq = matvec(p, q);
      if (!(pq > 0)) break;  // no descent direction left (rounding on a singular system)
      const double alpha = rz / pq;
      // x += alpha p is deferred to the pass that updates p (p is unchanged until then): one
      // pass over x, p, r and q fewer per iteration, with the same operations on every entry.
      rr = rows_sum<double>([&](std::int64_t row) {
        double s = 0;
        const std::int64_t at0 = row_base(row);
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = at0 + k;
          r[c] -= alpha * q[c];
          s += r[c] * r[c];
        }
        return s;
      });
      ++rep.iterations;
      rep.relative_residual = std::sqrt(rr) / b_norm;
      if (rep.relative_residual <= opt.tolerance) {
        rep.converged = true;
        parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
          const std::int64_t at0 = row_base(row);
          for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) x[at0 + k] += alpha * p[at0 + k];
        });
        break;
      }
      const double rz_new = precondition(opt, r, z);
      const double beta = rz_new / rz;
      rz = rz_new;
      parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
        const std::int64_t at0 = row_base(row);
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = at0 + k;
          x[c] += alpha * p[c];
          p[c] = z[c] + beta * p[c];
        }
      });
    }
    return rep;
  }

  void copy_rows(const double* from, double* to) const {
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      const std::int64_t at0 = row_base(row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) to[at0 + k] = from[at0 + k];
    });
  }

  IVec res_ = IVec::Zero();
  std::int64_t num_cells_ = 0, num_rows_ = 0, unknowns_ = 0;
  int nz_ = 0, n0_ = 0, n1_ = 0, tiles0_ = 0, tiles1_ = 0;
  mutable std::vector<int> wave_progress_;   ///< sweep(): the wavefront's per-row counters
  mutable std::vector<double> tile_sums_;    ///< sweep(): each tile's sum
  std::array<std::int64_t, Dim> stride_{};
  std::array<std::int64_t, Dim> row_step_{};  ///< rows between a cell and its +e_d neighbour (d < Dim - 1)
  bool ghost_fluid_ = true;
  const T* surface_pressure_ = nullptr;  // sigma kappa per cell, or null (set_surface_pressure)
  bool subcell_ = false;                 // the surface placed inside the fluid cells (set_subcell_surface)
  bool mic_built_ = false, multigrid_built_ = false;
  int mic_blocks_ = 0;
  std::vector<int> block_start_;
  Preconditioner preconditioner_wanted_ = ProjectionOptions().preconditioner;
  // The packed layout (see the file comment): row `row` stores cells k in its window
  // [win_lo_[row], win_hi_[row]) at base_[row] + k. The first packed_size_ entries of the packed
  // vectors are the rows' windows, the next nz_ + 2 the zero row.
  std::int64_t packed_size_ = 0;
  std::int64_t zero_base_ = 0;  ///< packed index of cell k = 0 of the zero row (after packed_size_)
  std::vector<int> win_lo_, win_hi_;
  std::vector<std::int64_t> base_;
  std::vector<Piece> pieces_;              ///< every row's pieces, row after row
  std::vector<std::int64_t> piece_start_;  ///< row's pieces are [piece_start_[row], piece_start_[row + 1])
  std::vector<double> diag_, precon_, x_, r_, z_, p_;
  /// A(c, c + e_d) = -w, stored at c in T: w is an open weight of type T, so -w is exact in T,
  /// and the products with the double vectors are those of the double value (half the bytes
  /// that the matrix-vector product and the MIC(0) sweeps read).
  std::array<std::vector<T>, Dim> plus_;
  std::vector<std::uint8_t> dirichlet_;  ///< packed: the unknown has a face open to air
  using Multigrid = MultigridPreconditioner<Dim, float>;
  /// Full grid, filled by assemble() only for the multigrid (kind_ready_).
  std::vector<std::uint8_t> kind_;  ///< Multigrid::Kind per cell: unknown (kFluid), air or solid
  std::vector<T> phi_;              ///< g.phi, for the multigrid's coarse ghost-fluid terms
  bool kind_ready_ = false;
  Multigrid multigrid_;
  /// MacGrid::open_weight per face, for the multigrid (kind_ready_). Elsewhere it is computed
  /// where it is read: a cache on every face took 13.7 MB on the 150 x 100 x 75 dam break.
  std::array<std::vector<T>, Dim> open_;
  std::array<std::int64_t, Dim> face_up_{};  ///< axis-d face index step from a cell's lower to upper face
  std::vector<int> span_lo_, span_hi_;
  std::vector<std::int64_t> closed_cells_, closed_start_;
  std::vector<std::uint8_t> flood_seen_;
  std::vector<std::int64_t> flood_queue_;
};

/// One-call projection with a temporary PressureSolver (see PressureSolver::project).
template <class T, int Dim>
ProjectionReport project(MacGrid<T, Dim>& g, T dt, const ProjectionOptions& opt) {
  PressureSolver<T, Dim> solver;
  return solver.project(g, dt, opt);
}

}  // namespace slurry::flip
