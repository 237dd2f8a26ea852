#pragma once
/// \file pressure.h
/// Pressure projection of the FLIP liquid solver on a MacGrid: makes the face velocities
/// discretely divergence free in fluid cells, u <- u - dt/rho grad p.
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
/// A fluid component without any free-surface face (a closed container) makes A singular: the
/// right-hand side is projected onto the range (its mean over the component removed) and the
/// solution's mean over the component is set to zero.
///
/// A is symmetric positive (semi)definite. It is stored in Bridson's compact form on the full
/// cell grid: per cell the diagonal and one off-diagonal per positive axis, zero outside the
/// fluid. The solve is PCG with a choice of preconditioner:
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
/// Two levels of API: `PressureSolver` keeps its buffers between steps (use one per simulation:
/// a 150 x 100 x 75 grid needs ~90 MB of them), and the free function `project()` builds a
/// temporary one.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <sstream>
#include <string>
#include <type_traits>
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
  double max_divergence = 0;     ///< max over fluid cells of |div u| (1/s) after the update
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

  /// Builds A (scaled by dt / (rho dx^2)) from g.label, g.phi and the open face weights.
  /// Unknowns are Fluid cells with at least one open face.
  void assemble(const Grid& g, bool ghost_fluid) {
    setup_layout(g);
    ghost_fluid_ = ghost_fluid;
    const std::int64_t n = num_cells_;
    // Zero the buffers: entries outside the unknowns must read as 0 in dot products and as
    // finite values next to zero coefficients. Every solve writes these vectors only inside the
    // rows' spans of unknowns (and assemble() only at Fluid cells, whose nonzero entries are
    // unknowns), so once they have been zeroed whole, zeroing the last assembly's spans restores
    // them: on the dam break the spans are about a tenth of the ten full-grid vectors (90 MB)
    // that were zeroed every substep before. In parallel: std::vector::assign ran on one thread.
    {
      const std::int64_t len = n + 2 * pad_;
      std::array<double*, 7> zero{};
      int k = 0;
      for (auto* v : {&diag_, &precon_, &x_, &r_, &z_, &p_, &q_}) {
        if (std::int64_t(v->size()) != len) v->resize(std::size_t(len)), zero_all_ = true;
        zero[std::size_t(k++)] = v->data();
      }
      for (int d = 0; d < Dim; ++d)
        if (std::int64_t(plus_[d].size()) != len) plus_[d].resize(std::size_t(len)), zero_all_ = true;
      if (std::int64_t(dirichlet_.size()) != n) dirichlet_.resize(std::size_t(n)), zero_all_ = true;
      if (std::int64_t(span_lo_.size()) != num_rows_) zero_all_ = true;
      const auto clear = [&](std::int64_t lo, std::int64_t hi) {  // [lo, hi) of the padded vectors
        for (double* v : zero) std::fill(v + lo, v + hi, 0.0);
        for (int d = 0; d < Dim; ++d) std::fill(plus_[d].data() + lo, plus_[d].data() + hi, T(0));
        const std::int64_t dlo = std::clamp(lo - pad_, std::int64_t(0), n), dhi = std::clamp(hi - pad_, std::int64_t(0), n);
        std::fill(dirichlet_.data() + dlo, dirichlet_.data() + dhi, std::uint8_t(0));
      };
      if (zero_all_) {
        constexpr std::int64_t kBlock = std::int64_t(1) << 14;
        parallel::parallel_for_grain(0, (len + kBlock - 1) / kBlock, 1, [&](std::int64_t b) {
          clear(b * kBlock, std::min(len, (b + 1) * kBlock));
        });
        zero_all_ = false;
      } else {
        parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
          const std::int64_t c0 = pad_ + row * nz_;
          clear(c0 + span_lo_[std::size_t(row)], c0 + span_hi_[std::size_t(row)]);
        });
      }
    }
    kind_.resize(std::size_t(n));
    phi_.resize(std::size_t(n));
    for (int d = 0; d < Dim; ++d) {  // open weights once: the later passes only read them
      open_[d].resize(std::size_t(g.num_faces(d)));
      face_up_[d] = g.face_stride(d, d);
      // MacGrid::open_weight row by row: 0 on the domain boundary and next to a Solid cell,
      // else the weight clamped to [0, 1].
      T* open = open_[d].data();
      const T* weight = g.weight[d].data();
      const std::uint8_t* label = g.label.data();
      const std::int64_t down = g.cell_stride(d);
      for_each_face_row(g, d, [&](std::int64_t f0, std::int64_t c0, const IVec& fi) {
        const int n = g.res[Dim - 1] + (d == Dim - 1 ? 1 : 0);
        const bool row_wall = d != Dim - 1 && (fi[d] <= 0 || fi[d] >= g.res[d]);
        for (int j = 0; j < n; ++j) {
          const bool wall = row_wall || (d == Dim - 1 && (j <= 0 || j >= g.res[d]));
          open[f0 + j] = wall || label[c0 + j - down] == Grid::Solid || label[c0 + j] == Grid::Solid
                             ? T(0)
                             : std::clamp(weight[f0 + j], T(0), T(1));
        }
      });
    }
    for_each_index(g.res, [&](std::int64_t c, const IVec& i) {
      const auto label = g.label[std::size_t(c)];
      kind_[std::size_t(c)] = label == Grid::Air ? Multigrid::kAir : Multigrid::kSolid;
      phi_[std::size_t(c)] = g.phi[std::size_t(c)];
      if (label != Grid::Fluid) return;
      double diag = 0;
      bool dirichlet = false;
      for (int d = 0; d < Dim; ++d) {
        const std::int64_t lower = g.face(d, i);
        for (int side = 0; side < 2; ++side) {  // lower face (side 0) or upper face (side 1)
          const double w = double(open_[d][std::size_t(side ? lower + face_up_[d] : lower)]);
          if (w <= 0) continue;
          const std::int64_t nb = side ? c + g.cell_stride(d) : c - g.cell_stride(d);
          const auto nl = g.label[std::size_t(nb)];
          if (nl == Grid::Fluid) {
            diag += w;
            if (side) plus(d)[c] = -w;
          } else if (nl == Grid::Air) {
            diag += w / theta(g, c, nb);
            dirichlet = true;
          }
        }
      }
      diag_[std::size_t(pad_ + c)] = diag;
      dirichlet_[std::size_t(c)] = dirichlet;
      if (diag > 0) kind_[std::size_t(c)] = Multigrid::kFluid;
    });
    // An open fluid-fluid face always gives both cells a positive diagonal, so plus(d) never
    // couples an unknown to a non-unknown.
    compute_spans();
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

  bool is_unknown(std::int64_t c) const { return diag_[std::size_t(pad_ + c)] > 0; }

  /// Bytes held by the solver's work arrays and the multigrid hierarchy (capacity).
  std::size_t bytes() const {
    std::size_t b = multigrid_.bytes();
    const auto add = [&](const auto& v) { b += v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type); };
    add(diag_), add(precon_), add(x_), add(r_), add(z_), add(p_), add(q_), add(rhs_);
    for (int d = 0; d < Dim; ++d) add(plus_[std::size_t(d)]), add(open_[std::size_t(d)]);
    add(dirichlet_), add(kind_), add(phi_), add(span_lo_), add(span_hi_), add(closed_cells_), add(closed_start_);
    add(flood_seen_), add(flood_queue_), add(block_start_), add(wave_progress_), add(tile_sums_);
    return b;
  }
  std::int64_t unknowns() const { return unknowns_; }
  /// Fluid components with no free-surface face (each makes A singular by one constant).
  int closed_components() const { return int(closed_start_.size()) - (closed_start_.empty() ? 0 : 1); }

  /// y = A x over the unknowns (full-grid vectors; zero elsewhere).
  void apply(const std::vector<double>& x, std::vector<double>& y) {
    zero_all_ = true;  // p_ now holds values outside the spans
    std::copy(x.begin(), x.end(), p_.begin() + pad_);
    matvec(p_.data() + pad_, q_.data() + pad_);
    y.assign(q_.begin() + pad_, q_.begin() + pad_ + num_cells_);
  }

  /// Solves A x = b by PCG. b and x are full-grid vectors (cell index); entries outside the
  /// unknowns are ignored in b and returned as 0 in x. x holds the initial guess on entry.
  ProjectionReport solve(const std::vector<double>& b, std::vector<double>& x, const ProjectionOptions& opt) {
    opt.validate();
    rhs_.resize(std::size_t(num_cells_));  // a member: no allocation per solve
    parallel::parallel_for(0, num_cells_, [&](std::int64_t c) { rhs_[std::size_t(c)] = is_unknown(c) ? b[std::size_t(c)] : 0.0; });
    double* xs = x_.data() + pad_;
    if (std::int64_t(x.size()) == num_cells_) {
      parallel::parallel_for(0, num_cells_, [&](std::int64_t c) { xs[c] = is_unknown(c) ? x[std::size_t(c)] : 0.0; });
    } else {
      std::fill(x_.begin(), x_.end(), 0.0);
    }
    ProjectionReport rep = solve_in_place(opt);
    x.assign(x_.begin() + pad_, x_.begin() + pad_ + num_cells_);
    return rep;
  }

  /// Projects g's face velocities: assembles A, solves for p (warm start from g.pressure),
  /// subtracts dt/rho grad p on open faces next to fluid, sets u = u_solid on closed faces and
  /// valid = 1 exactly on the updated faces. Writes g.pressure (0 outside the fluid).
  /// `target_flux`, if given (one value per cell), asks for D_c = target_flux[c] instead of 0
  /// (dx times a target divergence, for the FLIP volume correction); max_divergence then
  /// measures |D_c - target_flux[c]| / dx.
  ProjectionReport project(Grid& g, T dt, const ProjectionOptions& opt, const double* target_flux = nullptr) {
    opt.validate();
    prepare_for(opt.preconditioner, opt.mic_blocks);
    assemble(g, opt.ghost_fluid);
    const double scale = opt.density * double(g.dx) / double(dt);  // b = -(rho dx / dt) D
    // b and the warm start p go straight into the solver's own vectors, over the rows' spans of
    // unknowns only: the solve reads b nowhere else, and assemble() has zeroed p (x_).
    std::vector<double>& b = rhs_;
    b.resize(std::size_t(num_cells_));
    double* const p = x_.data() + pad_;
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      IVec i = row_coord(g.res, row);
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        i[Dim - 1] = k;
        const std::int64_t c = row * nz_ + k;
        const bool unknown = is_unknown(c);
        const double target = target_flux ? target_flux[c] : 0.0;
        b[std::size_t(c)] = unknown ? -scale * (double(open_flux_sum(g, i)) - target) : 0.0;
        p[std::size_t(c)] = unknown ? double(g.pressure[std::size_t(c)]) : 0.0;
      }
    });
    ProjectionReport rep = solve_in_place(opt);
    parallel::parallel_for(0, num_cells_, [&](std::int64_t c) { g.pressure[std::size_t(c)] = T(p[c]); });
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
        const auto rest = [&](int j0, int j1) {
          T* u = g.u[d].data() + f0;
          const T* us = g.u_solid[d].data() + f0;
          const T* w = open_[d].data() + f0;
          std::uint8_t* valid = g.valid[d].data() + f0;
          for (int j = j0; j < j1; ++j) {
            u[j] = w[j] <= T(0) ? us[j] : u[j];
            valid[j] = 0;
          }
        };
        rest(0, j_lo);
        rest(j_hi, n);
        for (int j = j_lo; j < j_hi; ++j) {
          const std::size_t fs = std::size_t(f0 + j);
          const T w = open_[d][fs];
          if (w <= T(0)) {
            g.u[d][fs] = g.u_solid[d][fs];
            g.valid[d][fs] = 0;
            continue;
          }
          const std::int64_t b_cell = c0 + j;  // upper cell; open faces are interior
          const std::int64_t a_cell = b_cell - down;
          const bool ua = is_unknown(a_cell), ub = is_unknown(b_cell);
          if (!ua && !ub) {
            g.valid[d][fs] = 0;
            continue;
          }
          double dp;
          if (ua && ub) {
            dp = p[b_cell] - p[a_cell];
          } else if (ua) {
            // b is air (an open face next to an unknown is fluid or air): ghost p_b.
            dp = -p[a_cell] / theta(g, a_cell, b_cell);
          } else {
            dp = p[b_cell] / theta(g, b_cell, a_cell);
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
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          i[Dim - 1] = k;
          const std::int64_t c = row * nz_ + k;
          if (is_unknown(c))
            m = std::max(m, std::abs(double(open_flux_sum(g, i)) - (target_flux ? target_flux[c] : 0.0)) / double(g.dx));
        }
      }
      return m;
    });
    return rep;
  }

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
        const T flux = w * g.u[d][fs] + (T(1) - w) * g.u_solid[d][fs];
        s += side ? flux : -flux;
      }
    }
    return s;
  }

  /// flux_sum() with the open weights cached by assemble().
  T open_flux_sum(const Grid& g, const IVec& i) const {
    T s = T(0);
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t lower = g.face(d, i);
      for (int side = 0; side < 2; ++side) {
        const std::size_t fs = std::size_t(side ? lower + face_up_[d] : lower);
        const T w = open_[d][fs];
        const T flux = w * g.u[d][fs] + (T(1) - w) * g.u_solid[d][fs];
        s += side ? flux : -flux;
      }
    }
    return s;
  }

  /// Free-surface fraction between fluid cell c and air cell a: theta = phi_c / (phi_c - phi_a)
  /// when phi changes sign between them, clamped to [kThetaMin, 1]; 1 without ghost fluid.
  double theta(const Grid& g, std::int64_t c, std::int64_t a) const {
    if (!ghost_fluid_) return 1.0;
    const double pc = double(g.phi[std::size_t(c)]), pa = double(g.phi[std::size_t(a)]);
    if (!(pc < 0 && pa >= 0)) return 1.0;
    return std::clamp(pc / (pc - pa), kThetaMin, 1.0);
  }

 private:
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

  T* plus(int d) { return plus_[d].data() + pad_; }
  const T* plus(int d) const { return plus_[d].data() + pad_; }

  void setup_layout(const Grid& g) {
    res_ = g.res;
    num_cells_ = g.num_cells();
    nz_ = res_[Dim - 1];
    n0_ = res_[0];
    n1_ = Dim == 3 ? res_[1] : 1;
    num_rows_ = num_cells_ / std::max(nz_, 1);
    for (int d = 0; d < Dim; ++d) stride_[d] = g.cell_stride(d);
    pad_ = stride_[0];
    tiles0_ = (n0_ + kTile - 1) / kTile;
    tiles1_ = (n1_ + kTile - 1) / kTile;
  }

  /// Per row of cells along the last axis: the range [lo, hi) holding its unknowns.
  void compute_spans() {
    span_lo_.assign(std::size_t(num_rows_), 0);
    span_hi_.assign(std::size_t(num_rows_), 0);
    const double* diag = diag_.data() + pad_;
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      int lo = nz_, hi = 0;
      for (int k = 0; k < nz_; ++k)
        if (diag[row * nz_ + k] > 0) lo = std::min(lo, k), hi = k + 1;
      span_lo_[std::size_t(row)] = lo < hi ? lo : 0;
      span_hi_[std::size_t(row)] = lo < hi ? hi : 0;
    });
    unknowns_ = rows_sum<std::int64_t>([&](std::int64_t row) {
      std::int64_t m = 0;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) m += diag[row * nz_ + k] > 0;
      return m;
    });
  }

  /// Slab bounds along axis 0 for mic_blocks_ > 0: equal shares of the unknowns (a function of
  /// the fluid only, never of the thread count).
  void compute_blocks() {
    block_start_.assign(1, 0);
    if (mic_blocks_ <= 0) return;
    std::vector<std::int64_t> per_i(std::size_t(n0_), 0);
    const double* diag = diag_.data() + pad_;
    for (std::int64_t row = 0; row < num_rows_; ++row)
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k)
        per_i[std::size_t(row / n1_)] += diag[row * nz_ + k] > 0;
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
    const std::int64_t n = num_cells_;
    std::vector<std::uint8_t>& seen = flood_seen_;  // members: no allocation per solve
    std::vector<std::int64_t>& queue = flood_queue_;
    seen.assign(std::size_t(n), 0);
    queue.clear();
    const auto flood = [&](std::vector<std::int64_t>& q, std::size_t head) {
      while (head < q.size()) {
        const std::int64_t c = q[head++];
        for (int d = 0; d < Dim; ++d) {
          const std::int64_t up = c + stride_[d], down = c - stride_[d];
          if (plus(d)[c] != 0 && !seen[std::size_t(up)]) seen[std::size_t(up)] = 1, q.push_back(up);
          if (down >= 0 && plus(d)[down] != 0 && !seen[std::size_t(down)]) seen[std::size_t(down)] = 1, q.push_back(down);
        }
      }
    };
    for (std::int64_t c = 0; c < n; ++c)
      if (dirichlet_[std::size_t(c)] && is_unknown(c)) seen[std::size_t(c)] = 1, queue.push_back(c);
    flood(queue, 0);
    if (std::int64_t(queue.size()) == unknowns_) return;
    for (std::int64_t c = 0; c < n; ++c) {
      if (!is_unknown(c) || seen[std::size_t(c)]) continue;
      closed_start_.push_back(std::int64_t(closed_cells_.size()));
      seen[std::size_t(c)] = 1;
      const std::size_t head = closed_cells_.size();
      closed_cells_.push_back(c);
      flood(closed_cells_, head);
    }
    closed_start_.push_back(std::int64_t(closed_cells_.size()));
  }

  /// v -= its mean over each closed component (serial: closed components are rare and small).
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
    const double* diag = diag_.data() + pad_;
    double* pc = precon_.data() + pad_;
    sweep(true, [&](std::int64_t row, bool cut_lo, bool cut_hi) {
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = row * nz_ + k;
        if (!(diag[c] > 0)) continue;
        double e = diag[c];
        for (int d = cut_lo ? 1 : 0; d < Dim; ++d) {
          const std::int64_t m = c - stride_[d];
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
    const double* diag = diag_.data() + pad_;
    return rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = row * nz_ + k;
        if (!(diag[c] > 0)) {
          y[c] = 0;
          continue;
        }
        double v = diag[c] * x[c];
        for (int d = 0; d < Dim; ++d)
          v += plus(d)[c] * x[c + stride_[d]] + plus(d)[c - stride_[d]] * x[c - stride_[d]];
        y[c] = v;
        s += x[c] * v;
      }
      return s;
    });
  }

  /// Multigrid hierarchy from the assembled system (level 0 in float).
  void build_multigrid() {
    std::array<const T*, Dim> plus_ptr{};
    std::array<const T*, Dim> open_ptr{};
    for (int d = 0; d < Dim; ++d) plus_ptr[d] = plus(d), open_ptr[d] = open_[d].data();
    multigrid_.build(res_, diag_.data() + pad_, plus_ptr, kind_.data(), open_ptr, ghost_fluid_ ? phi_.data() : nullptr);
  }

  /// z = M^-1 r; returns r . z.
  double precondition(const ProjectionOptions& opt, const double* r, double* z) {
    const Preconditioner kind = opt.preconditioner;
    if (kind == Preconditioner::Multigrid)
      return multigrid_.apply(r, z, opt.multigrid_smoothing, opt.multigrid_boundary_smoothing);
    const double* diag = diag_.data() + pad_;
    if (kind != Preconditioner::MIC0) {
      const bool jacobi = kind == Preconditioner::Jacobi;
      return rows_sum<double>([&](std::int64_t row) {
        double s = 0;
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = row * nz_ + k;
          z[c] = diag[c] > 0 ? (jacobi ? r[c] / diag[c] : r[c]) : 0.0;
          s += r[c] * z[c];
        }
        return s;
      });
    }
    // pc > 0 exactly at the unknowns (build_mic0; zero elsewhere): the sweeps test it, which
    // they read anyway, instead of the diagonal.
    const double* pc = precon_.data() + pad_;
    sweep(true, [&](std::int64_t row, bool cut_lo, bool) {  // L q = r, q stored in z
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = row * nz_ + k;
        if (!(pc[c] > 0)) {
          z[c] = 0;
          continue;
        }
        double t = r[c];
        for (int d = cut_lo ? 1 : 0; d < Dim; ++d) {
          const std::int64_t m = c - stride_[d];
          t -= plus(d)[m] * pc[m] * z[m];
        }
        z[c] = t * pc[c];
      }
      return 0.0;
    });
    return sweep(false, [&](std::int64_t row, bool, bool cut_hi) {  // L^T z = q in place
      double s = 0;
      for (int k = span_hi_[std::size_t(row)] - 1; k >= span_lo_[std::size_t(row)]; --k) {
        const std::int64_t c = row * nz_ + k;
        if (!(pc[c] > 0)) continue;
        double t = z[c];
        for (int d = cut_hi ? 1 : 0; d < Dim; ++d) t -= plus(d)[c] * pc[c] * z[c + stride_[d]];
        z[c] = t * pc[c];
        s += r[c] * z[c];
      }
      return s;
    });
  }

  /// Solves with the right-hand side in rhs_ (zero off the unknowns) and the initial guess in
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
    remove_closed_means(rhs_.data());
    ProjectionReport rep = pcg(rhs_.data(), opt);
    remove_closed_means(x_.data() + pad_);
    return rep;
  }

  /// PCG (Saad 2003, Alg. 9.1) on x_ with right-hand side b (zero outside the unknowns).
  ProjectionReport pcg(const double* b, const ProjectionOptions& opt) {
    ProjectionReport rep;
    rep.unknowns = unknowns_;
    double* x = x_.data() + pad_;
    double* r = r_.data() + pad_;
    double* z = z_.data() + pad_;
    double* p = p_.data() + pad_;
    double* q = q_.data() + pad_;
    const double b_norm = std::sqrt(rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) s += b[row * nz_ + k] * b[row * nz_ + k];
      return s;
    }));
    if (b_norm == 0) {
      std::fill(x_.begin(), x_.end(), 0.0);
      rep.converged = true;
      return rep;
    }
    matvec(x, q);
    double rr = rows_sum<double>([&](std::int64_t row) {
      double s = 0;
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
        const std::int64_t c = row * nz_ + k;
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
      rr = rows_sum<double>([&](std::int64_t row) {
        double s = 0;
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = row * nz_ + k;
          x[c] += alpha * p[c];
          r[c] -= alpha * q[c];
          s += r[c] * r[c];
        }
        return s;
      });
      ++rep.iterations;
      rep.relative_residual = std::sqrt(rr) / b_norm;
      if (rep.relative_residual <= opt.tolerance) {
        rep.converged = true;
        break;
      }
      const double rz_new = precondition(opt, r, z);
      const double beta = rz_new / rz;
      rz = rz_new;
      parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
        for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) {
          const std::int64_t c = row * nz_ + k;
          p[c] = z[c] + beta * p[c];
        }
      });
    }
    return rep;
  }

  void copy_rows(const double* from, double* to) const {
    parallel::parallel_for(0, num_rows_, [&](std::int64_t row) {
      for (int k = span_lo_[std::size_t(row)]; k < span_hi_[std::size_t(row)]; ++k) to[row * nz_ + k] = from[row * nz_ + k];
    });
  }

  IVec res_ = IVec::Zero();
  std::int64_t num_cells_ = 0, num_rows_ = 0, pad_ = 0, unknowns_ = 0;
  int nz_ = 0, n0_ = 0, n1_ = 0, tiles0_ = 0, tiles1_ = 0;
  mutable std::vector<int> wave_progress_;   ///< sweep(): the wavefront's per-row counters
  mutable std::vector<double> tile_sums_;    ///< sweep(): each tile's sum
  std::array<std::int64_t, Dim> stride_{};
  bool ghost_fluid_ = true;
  bool mic_built_ = false, multigrid_built_ = false;
  int mic_blocks_ = 0;
  std::vector<int> block_start_;
  Preconditioner preconditioner_wanted_ = ProjectionOptions().preconditioner;
  // Padded by pad_ = stride_[0] cells on both ends so that neighbour reads never leave the
  // arrays; the pads hold zeros, and so do coefficients across the domain boundary.
  std::vector<double> diag_, precon_, x_, r_, z_, p_, q_;
  std::vector<double> rhs_;  ///< right-hand side of solve_in_place()
  /// A(c, c + e_d) = -w, stored at c in T: w is an open weight of type T, so -w is exact in T,
  /// and the products with the double vectors are those of the double value (half the bytes
  /// that the matrix-vector product and the MIC(0) sweeps read).
  std::array<std::vector<T>, Dim> plus_;
  bool zero_all_ = true;  ///< assemble() zeroes the whole vectors (first use, new size, apply())
  std::vector<std::uint8_t> dirichlet_;
  using Multigrid = MultigridPreconditioner<Dim, float>;
  std::vector<std::uint8_t> kind_;  ///< Multigrid::Kind per cell: unknown (kFluid), air or solid
  std::vector<T> phi_;              ///< g.phi, for the multigrid's coarse ghost-fluid terms
  Multigrid multigrid_;
  std::array<std::vector<T>, Dim> open_;  ///< MacGrid::open_weight per face, cached by assemble()
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
