#pragma once
/// \file implicit_update.h
/// Linearly implicit backward-Euler grid update for MPM solids (Stomakhin et al. 2013, "A
/// material point method for snow simulation", sec. 9 with beta = 1; Baraff & Witkin 1998,
/// "Large steps in cloth simulation", eq. 6 for the linearization).
///
/// After P2G with the explicit stress impulse, the grid holds v* = v^n + dt (f^n / m + g). With
/// H the Hessian of the elastic energy Phi(x^) = sum_p V_p^0 psi(F^_p(x^)) with respect to the
/// grid node positions x^_i = x_i + dt v_i, at the current F, one Newton step of backward Euler
/// M v = M v* + dt (f(x + dt v) - f(x)) ~ M v* - dt^2 H v reads
///
///   (M + dt^2 H) v^{n+1} = M v*.
///
/// (One file of about 840 lines: the matrix-free product, the assembled matrix of the IC0
/// preconditioner and the block-Jacobi blocks are built from the same per-node stencils and must
/// agree term by term, which is easiest to keep true when they sit side by side.)
///
/// H is applied matrix-free (Stomakhin et al. 2013, sec. 9). For a field u on the nodes,
///
///   G_p(u) = sum_i u_i g_ip^T,   (H u)_i = sum_p Q_p g_ip,   vec(Q_p) = K_p vec(G_p),
///   K_p = V_p^0 d^2/dG^2 psi((I + G) F_p) at G = 0, i.e. K_p vec(G) = vec(V_p^0 dP(F_p, G F_p) F_p^T)
///
/// where dP is the stress differential of each constitutive model (snow: the model scaled by its
/// hardening, as in the explicit stress) and g_ip the weight gradient grad w_ip for PIC, FLIP and
/// APIC, and the MLS gradient w_ip D_p^-1 (x_i - x_p) for MLS-MPM (Hu et al. 2018, eq. 17; that
/// is how their F update and stress force see the grid). Then w^T H u = sum_p vec(G_p(w))^T K_p
/// vec(G_p(u)): H is symmetric, and positive semidefinite when every K_p is. K_p is built once
/// per substep by applying dP to the Dim^2 unit directions (so no SVD runs inside CG) and, when
/// it is indefinite (compression, inversion), projected onto its nonnegative eigenvalues (the
/// definiteness fix of Teran, Sifakis, Irving and Fedkiw 2005, "Robust quasistatic finite elements
/// and flesh simulation", applied per particle), so M + dt^2 H is positive definite and CG applies.
///
/// Boundary conditions enter as a projection (filtered CG, Baraff & Witkin 1998 sec. 5;
/// Stomakhin et al. 2013 sec. 9): the explicit rule of update_grid (colliders.h) is applied to
/// v*, which also applies the Coulomb friction impulse of "separate" boundaries, and each node
/// gets a projection S_i = I - sum_q q q^T onto the components the solve may change: none for
/// sticky, the tangent plane for slip, and for "separate" the tangent plane if the node was
/// approaching the boundary at v* (linearized as slip), everything if it was separating. With
/// v0 the result, the solve is S A S x = S (M v0 - A v0), v^{n+1} = v0 + x; the boundary rule
/// is then applied once more, so that a node left free that ends up approaching is stopped.
///
/// The operator is assembled once per substep (after the per-particle K_p) as Dim x Dim node
/// blocks: H_ij = sum_p sum_{b,e} g_ip[b] K_p[(., b), (., e)] g_jp[e] for every pair of nodes
/// in one particle's stencil, stored by block rows over the nodes with mass (row i holds the
/// unknowns within the kernel order of node i along every axis: up to 5^3 blocks for the
/// quadratic kernel in 3D). The sums run in particle order on one thread, so the matrix, and
/// the run, do not depend on the thread count. The filtered system is stored as
/// A = S (M + dt^2 H) S + (I - S), positive definite on the whole space; a CG iteration is one
/// block product A p (rows in parallel) instead of a gather and scatter over every particle's
/// stencil: fewer operations once a node row has fewer blocks than its particles have stencil
/// pairs (in 3D at 8 particles per cell, 27^2/2 pairs per particle against about 80 blocks per
/// node on a small body).
///
/// Preconditioner (solver.implicit_preconditioner): "ic0" (default), block incomplete Cholesky
/// with zero fill-in on A's block pattern, A ~ F^T F with F block upper triangular (Saad 2003,
/// "Iterative Methods for Sparse Linear Systems", sec. 10.3 and 10.7), factored once per substep
/// on one thread; a diagonal block that is not positive definite during the factorization
/// (possible, A is not an M-matrix) falls back to block Jacobi for that substep. "block_jacobi":
/// the inverses of A's diagonal blocks. "jacobi": the inverse of A's diagonal. CG stops when the
/// residual is below solver.cg_tolerance times the initial one, ||S (M v0 - A v0)|| (the elastic
/// impulse to correct), or below the round-off of A v0's terms (64 eps ||diag(A) v0||),
/// whichever is larger. A tolerance relative to M v0 instead would let a fast rigid motion hide
/// the elastic error, which the explicit impulse in v0 amplifies step after step at large dt.
///
/// Precision: the assembled path runs for double only. Float simulations keep the matrix-free
/// form with Jacobi (apply_stiffness(): gather G_p, Q_p = K_p G_p, scatter over the cached
/// stencils; solver.implicit_preconditioner is ignored): assembled in float, each block carries a
/// round-off of about eps |H_ij|, which breaks the positive semidefiniteness of H (exact in the
/// per-particle form, sum_p G_p^T K_p G_p) by more than the mass of light nodes at
/// dt^2 |H| / m ~ 1e5 (the 3D float example scene broke CG down at its first collider contact
/// with each of the three preconditioners). apply_stiffness() is also the reference the tests
/// compare the assembled blocks with.
///
/// Every transfer scheme and kernel of the explicit path is supported (MLS needs quadratic or
/// cubic, as there). Fluid materials are rejected at validation: fluid particles carry J, not F,
/// and their pressure term is not linearized here.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <memory>
#include <stdexcept>
#include <vector>

#include "slurry/engine/geometry/colliders.h"
#include "slurry/engine/mpm/material.h"
#include "slurry/engine/numerics/pcg.h"
#include "slurry/engine/mpm/particles.h"
#include "slurry/engine/scene/scene.h"
#include "slurry/transfer/grid.h"
#include "slurry/transfer/kernels.h"
#include "slurry/transfer/parallel.h"

namespace slurry {

/// Where the domain walls hold (node index ranges) and the colliders, for a grid update.
template <class T, int Dim>
struct GridBoundaries {
  int lo = 0;                                             ///< nodes with an index < lo lie in a wall
  Eigen::Matrix<int, Dim, 1> hi = Eigen::Matrix<int, Dim, 1>::Zero();  ///< ... or > hi[d]
  Condition walls = Condition::Separate;
  T friction = 0;
  const std::vector<Collider<T, Dim>>* colliders = nullptr;
  T time = 0;  ///< time at the end of the substep (collider positions)
};

/// Calls fn(boundary velocity, normal into the domain, condition, friction) for every domain wall
/// and collider that holds node `idx`, walls first (axis by axis, low side then high side), then
/// colliders in scene order; `position()` gives the node's position and is evaluated only when
/// there are colliders. The explicit grid update and the implicit solve both go through it.
template <class T, int Dim, class Position, class Fn>
void for_each_grid_condition(const Eigen::Matrix<int, Dim, 1>& idx, Position&& position,
                             const GridBoundaries<T, Dim>& bc, Fn&& fn) {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  for (int d = 0; d < Dim; ++d) {
    if (idx[d] < bc.lo) fn(Vec(Vec::Zero()), Vec(Vec::Unit(d)), bc.walls, bc.friction);
    if (idx[d] > bc.hi[d]) fn(Vec(Vec::Zero()), Vec(-Vec::Unit(d)), bc.walls, bc.friction);
  }
  if (bc.colliders && !bc.colliders->empty()) {
    const Vec xi = position();
    Vec n;
    for (const auto& c : *bc.colliders)
      if (c.inside(xi, bc.time, n)) fn(c.velocity_at(xi, bc.time), n, c.condition, c.friction);
  }
}

/// The implicit grid solve; one object per simulation keeps its scratch buffers between steps.
template <class T, int Dim>
class ImplicitUpdate {
 public:
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  using Grid = transfer::DenseGrid<T, Dim>;
  using VectorX = Eigen::Matrix<T, Eigen::Dynamic, 1>;
  static constexpr int D2 = Dim * Dim;
  /// Per-particle stiffness K_p acting on column-major vec(G).
  using Stiffness = Eigen::Matrix<T, D2, D2>;

  /// CG preconditioner: the inverse diagonal of A, the inverses of its Dim x Dim node blocks,
  /// or zero fill-in incomplete Cholesky on A's scalar pattern (block Jacobi where it breaks down).
  enum class Preconditioner { Jacobi, BlockJacobi, IC0 };

  struct Options {
    T tolerance = T(1e-6);     ///< CG stops at ||S (M v0 - A v)|| <= tolerance ||S (M v0 - A v0)||
    int max_iterations = 500;  ///< CG iteration cap
    bool definite = true;      ///< project each K_p onto its nonnegative eigenvalues
    Preconditioner preconditioner = Preconditioner::IC0;  ///< of the assembled CG
  };

  /// Outcome of one solve.
  struct Result {
    int iterations = 0;
    T residual = 0;  ///< ||S (M v0 - A v)|| / ||S (M v0 - A v0)|| at return
    bool converged = true;
    std::int64_t unknowns = 0;  ///< nodes with mass
    bool ic0_failed = false;    ///< IC(0) met a nonpositive pivot; block Jacobi was used
  };

  ImplicitUpdate(KernelKind kernel, TransferKind transfer, const Options& options)
      : order_(kernel == KernelKind::Linear ? 1 : kernel == KernelKind::Quadratic ? 2 : 3),
        mls_(transfer == TransferKind::MLS),
        options_(options) {}

  const Options& options() const { return options_; }
  Options& options() { return options_; }

  /// The whole grid update of an implicit substep, after P2G: v* = p/m + dt g (FLIP keeps p/m as
  /// the old velocity), boundary conditions, the solve, boundary conditions again. Writes the
  /// new velocities into the nodes. `ranges` lists {material, begin, end} particle ranges.
  template <class Ranges>
  Result update_grid(Grid& grid, const Particles<T, Dim>& P, const std::vector<Material<T, Dim>>& materials,
                     const Ranges& ranges, const GridBoundaries<T, Dim>& bc, const Vec& gravity, T dt) {
    collect_unknowns(grid);
    const std::int64_t n = unknowns();
    const bool flip = grid.keeps_old_velocity();
    v0_.resize(Dim * n);
    mass_.resize(n);
    boundary_.clear();
    projections_.clear();
    projection_of_.assign(std::size_t(n), -1);
    for (std::int64_t i = 0; i < n; ++i) {
      const std::int64_t k = nodes_[std::size_t(i)];
      const auto& node = grid.node(k);
      const T m = node[Dim];
      Vec v = node.template head<Dim>() / m;
      if (flip) grid.old_velocity(k) = v;
      v += dt * gravity;
      Basis basis;
      if (apply_boundaries(grid, grid.coord(k), bc, v, &basis)) {
        boundary_.push_back(i);
        if (basis.rank > 0) {
          projection_of_[std::size_t(i)] = std::int32_t(projections_.size());
          projections_.push_back(basis.projection());
        }
      }
      mass_[i] = m;
      v0_.template segment<Dim>(Dim * i) = v;
    }
    linearize(P, materials, ranges);
    // Float simulations keep the matrix-free form: assembled in float, the blocks' round-off
    // (about eps |H| per entry, with dt^2 |H| / m up to 1e5 at light nodes) makes A indefinite
    // (the 3D float example broke CG down at its first collider contact).
    VectorX x;
    bool ic0_failed = false;
    numerics::PcgResult<T> r;
    if constexpr (std::is_same_v<T, double>)
      r = solve_assembled(dt, x, ic0_failed);
    else
      r = solve_matrix_free(dt, x);

    filter(x);
    for (std::int64_t i = 0; i < n; ++i) {
      auto& node = grid.node(nodes_[std::size_t(i)]);
      node.template head<Dim>() = v0_.template segment<Dim>(Dim * i) + x.template segment<Dim>(Dim * i);
    }
    for (const std::int64_t i : boundary_) {
      const std::int64_t k = nodes_[std::size_t(i)];
      Vec v = grid.node(k).template head<Dim>();
      apply_boundaries(grid, grid.coord(k), bc, v, nullptr);
      grid.node(k).template head<Dim>() = v;
    }
    Result result;
    result.iterations = r.iterations;
    result.residual = r.relative_residual;
    result.converged = r.converged;
    result.unknowns = n;
    result.ic0_failed = ic0_failed;
    return result;
  }

  // ---- the pieces, public for the tests -------------------------------------------------------

  /// Numbers the nodes with mass > 0 in the grid's active box (index order); reads the grid's
  /// geometry for the operator.
  void collect_unknowns(const Grid& grid) {
    if (dof_of_.size() != grid.size()) {
      dof_of_.assign(grid.size(), -1);
    } else {
      for (const std::int64_t k : nodes_) dof_of_[std::size_t(k)] = -1;
    }
    nodes_.clear();
    const int len = grid.active_row_length();
    for (std::int64_t r = 0; r < grid.active_rows(); ++r) {
      const std::int64_t k0 = grid.active_row_start(r);
      for (std::int64_t k = k0; k < k0 + len; ++k)
        if (grid.node(k)[Dim] > T(0)) {
          dof_of_[std::size_t(k)] = std::int32_t(nodes_.size());
          nodes_.push_back(k);
        }
    }
    origin_ = grid.origin();
    dx_ = grid.dx();
    inv_dx_ = grid.inv_dx();
    for (int d = 0; d < Dim; ++d) stride_[d] = grid.stride(d);
    res_ = grid.res();
    coords_.resize(nodes_.size());
    for (std::size_t i = 0; i < nodes_.size(); ++i) coords_[i] = grid.coord(nodes_[i]);
  }

  std::int64_t unknowns() const { return std::int64_t(nodes_.size()); }
  /// Grid index of unknown i.
  std::int64_t node(std::int64_t i) const { return nodes_[std::size_t(i)]; }

  /// Builds K_p for every particle at its current F (see the file comment).
  template <class Ranges>
  void linearize(const Particles<T, Dim>& P, const std::vector<Material<T, Dim>>& materials, const Ranges& ranges) {
    particles_ = std::int64_t(P.size());
    K_.resize(P.size());
    Q_.resize(P.size());
    switch (order_) {
      case 1: cache_stencils<1>(P); break;
      case 2: cache_stencils<2>(P); break;
      default: cache_stencils<3>(P); break;
    }
    const T* vol0 = P.vol0.read_base();  // stored once or per particle (particles.h)
    const std::size_t vol0_mask = P.vol0.read_mask();
    for (const auto& r : ranges) {
      const auto& mat = materials[std::size_t(r.material)];
      mat.visit_elastic([&](const auto& model) {
        parallel::parallel_for(r.begin, r.end, [&](std::int64_t p) {
          if (mat.plastic_kind == PlasticModel::Snow)
            K_[std::size_t(p)] =
                stiffness(model.scaled(mat.hardening_factor(P.plastic[std::size_t(p)])),
                          P.F[std::size_t(p)], vol0[std::size_t(p) & vol0_mask]);
          else
            K_[std::size_t(p)] =
                stiffness(model, P.F[std::size_t(p)], vol0[std::size_t(p) & vol0_mask]);
        });
      });
    }
  }

  /// out = H u for u, out of length Dim * unknowns().
  void apply_stiffness(const VectorX& u, VectorX& out) {
    out.setZero(Dim * unknowns());
    if (parallel::max_threads() == 1) {
      // One pass: each particle's stencil is still in cache for its scatter. The same operations
      // in the same order as the two-pass form, so the result does not depend on the threads.
      for (std::int64_t p = 0; p < particles_; ++p) {
        gather(p, u);
        scatter(p, out);
      }
      return;
    }
    parallel::parallel_for(0, particles_, [&](std::int64_t p) { gather(p, u); });
    for (std::int64_t p = 0; p < particles_; ++p) scatter(p, out);  // serial for now
  }

  /// The diagonal of H (exact), length Dim * unknowns():
  /// e_{i,d}^T H e_{i,d} = sum_p sum_{b,e} g_b K_p[(d,b),(d,e)] g_e.
  void stiffness_diagonal(VectorX& diag) const {
    diag.setZero(Dim * unknowns());
    for (std::int64_t p = 0; p < particles_; ++p) {
      const Stiffness& K = K_[std::size_t(p)];
      for_each_unknown(p, [&](std::int32_t i, const Vec& g) {
        for (int d = 0; d < Dim; ++d) {
          T s = 0;
          for (int b = 0; b < Dim; ++b)
            for (int e = 0; e < Dim; ++e) s += g[b] * K(d + Dim * b, d + Dim * e) * g[e];
          diag[Dim * std::int64_t(i) + d] += s;
        }
      });
    }
  }

  /// The block pattern of H: unknowns i and j couple when their grid coordinates differ by at
  /// most the kernel order along every axis (they can share a particle's stencil). Row i lists
  /// its blocks by increasing j; window slot w of row i (offset j - i, order-shifted, first axis
  /// most significant) maps to its block or -1.
  void build_pattern() {
    const int W = 2 * order_ + 1;
    int Wd = 1;
    for (int d = 0; d < Dim; ++d) Wd *= W;
    window_ = Wd;
    const std::int64_t n = unknowns();
    slot_.assign(std::size_t(n * Wd), -1);
    row_start_.assign(std::size_t(n + 1), 0);
    // Pass 1: the neighbours of each row, window order (= increasing grid index = increasing unknown).
    // Window offset w -> its axis offsets and its grid index offset; and the window offset of
    // the difference of two window offsets (-1 when it leaves the window), for build_ic0.
    if (int(window_off_.size()) != Wd) {
      window_off_.resize(std::size_t(Wd));
      window_step_.resize(std::size_t(Wd));
      for (int w = 0; w < Wd; ++w) {
        int rem = w;
        for (int d = Dim - 1; d >= 0; --d) {
          window_off_[std::size_t(w)][d] = rem % W - order_;
          rem /= W;
        }
      }
      window_diff_.assign(std::size_t(Wd * Wd), -1);
      for (int a = 0; a < Wd; ++a)
        for (int b = 0; b < Wd; ++b) {
          const IVec off = window_off_[std::size_t(b)] - window_off_[std::size_t(a)];
          if ((off.array().abs() > order_).any()) continue;
          int w = 0;
          for (int d = 0; d < Dim; ++d) w = w * W + off[d] + order_;
          window_diff_[std::size_t(a * Wd + b)] = w;
        }
    }
    for (int w = 0; w < Wd; ++w) {
      window_step_[std::size_t(w)] = 0;
      for (int d = 0; d < Dim; ++d) window_step_[std::size_t(w)] += window_off_[std::size_t(w)][d] * stride_[d];
    }
    auto neighbours = [&](std::int64_t i, auto&& fn) {
      const IVec& c = coords_[std::size_t(i)];
      const std::int64_t k = nodes_[std::size_t(i)];
      const bool interior = (c.array() >= order_).all() && (c.array() < res_.array() - order_).all();
      for (int w = 0; w < Wd; ++w) {
        if (!interior) {
          const IVec cj = c + window_off_[std::size_t(w)];
          if ((cj.array() < 0).any() || (cj.array() >= res_.array()).any()) continue;
        }
        const std::int32_t j = dof_of_[std::size_t(k + window_step_[std::size_t(w)])];
        if (j >= 0) fn(w, j);
      }
    };
    parallel::parallel_for(0, n, [&](std::int64_t i) {
      std::int64_t count = 0;
      neighbours(i, [&](int, std::int32_t) { ++count; });
      row_start_[std::size_t(i + 1)] = count;
    });
    for (std::int64_t i = 0; i < n; ++i) row_start_[std::size_t(i + 1)] += row_start_[std::size_t(i)];
    const std::int64_t blocks = row_start_[std::size_t(n)];
    col_.resize(std::size_t(blocks));
    block_window_.resize(std::size_t(blocks));
    diag_block_.resize(std::size_t(n));
    parallel::parallel_for(0, n, [&](std::int64_t i) {
      std::int64_t b = row_start_[std::size_t(i)];
      neighbours(i, [&](int w, std::int32_t j) {
        col_[std::size_t(b)] = j;
        block_window_[std::size_t(b)] = w;
        slot_[std::size_t(i * Wd + w)] = std::int32_t(b);
        if (j == i) diag_block_[std::size_t(i)] = b;
        ++b;
      });
    });
    // Stencil node pairs -> window offset.
    const int N = order_ + 1;
    int S = 1;
    for (int d = 0; d < Dim; ++d) S *= N;
    pair_window_.resize(std::size_t(S * S));
    for (int a = 0; a < S; ++a)
      for (int b = 0; b < S; ++b) {
        int ra = a, rb = b, w = 0, scale = 1;
        for (int d = Dim - 1; d >= 0; --d) {
          w += (rb % N - ra % N + order_) * scale;
          ra /= N;
          rb /= N;
          scale *= W;
        }
        pair_window_[std::size_t(a * S + b)] = w;
      }
  }

  /// Assembles H block by block from the particles' K_p, in particle order (one thread, so the
  /// sums do not depend on the thread count): block (i, j), i <= j, gets
  /// sum_p sum_{b,e} g_ip[b] K_p[(., b), (., e)] g_jp[e]; block (j, i) is its transpose.
  void assemble_stiffness() {
    H_.assign(col_.size(), Mat::Zero());
    const int S = stencil_nodes_;
    std::vector<Eigen::Matrix<T, Dim, D2>> Wi(static_cast<std::size_t>(S));
    std::vector<int> local(static_cast<std::size_t>(S));
    for (std::int64_t p = 0; p < particles_; ++p) {
      const Stiffness& K = K_[std::size_t(p)];
      const std::size_t j0 = std::size_t(p * S);
      int m = 0;
      for (int j = 0; j < S; ++j) {
        if (stencil_dof_[j0 + std::size_t(j)] < 0) continue;
        const Vec& g = stencil_grad_[j0 + std::size_t(j)];
        auto& w = Wi[std::size_t(j)];
        w = g[0] * K.template middleRows<Dim>(0);
        for (int b = 1; b < Dim; ++b) w += g[b] * K.template middleRows<Dim>(Dim * b);
        local[std::size_t(m++)] = j;
      }
      for (int x = 0; x < m; ++x) {
        const int a = local[std::size_t(x)];
        const std::int64_t ui = stencil_dof_[j0 + std::size_t(a)];
        const auto& w = Wi[std::size_t(a)];
        for (int y = x; y < m; ++y) {
          const int b = local[std::size_t(y)];
          const Vec& g = stencil_grad_[j0 + std::size_t(b)];
          Mat B = g[0] * w.template middleCols<Dim>(0);
          for (int e = 1; e < Dim; ++e) B += g[e] * w.template middleCols<Dim>(Dim * e);
          H_[std::size_t(slot_[std::size_t(ui * window_ + pair_window_[std::size_t(a * S + b)])])] += B;
        }
      }
    }
    // The lower blocks are the transposed upper ones (stencil order is unknown order, so every
    // pair above went to the upper triangle).
    const std::int64_t n = unknowns();
    parallel::parallel_for(0, n, [&](std::int64_t i) {
      for (std::int64_t b = row_start_[std::size_t(i)]; b < diag_block_[std::size_t(i)]; ++b) {
        const std::int64_t j = col_[std::size_t(b)];
        const int mirror = window_ - 1 - block_window_[std::size_t(b)];
        H_[std::size_t(b)] = H_[std::size_t(slot_[std::size_t(j * window_ + mirror)])].transpose();
      }
    });
  }

  /// out = H u with the assembled H (same H as apply_stiffness up to round-off).
  void multiply_stiffness(const VectorX& u, VectorX& out) const { multiply(H_, u, out); }

  /// Number of assembled blocks (Dim x Dim) of H.
  std::int64_t blocks() const { return std::int64_t(col_.size()); }

  /// Bytes held by the scratch buffers (per particle: K_p, Q_p and the cached stencil).
  std::size_t bytes() const {
    return dof_of_.capacity() * sizeof(std::int32_t) + nodes_.capacity() * sizeof(std::int64_t) +
           std::size_t(mass_.size() + v0_.size() + diag_.size() + tmp_.size()) * sizeof(T) +
           K_.capacity() * sizeof(Stiffness) + Q_.capacity() * sizeof(Mat) +
           stencil_dof_.capacity() * sizeof(std::int32_t) + stencil_grad_.capacity() * sizeof(Vec) +
           (H_.capacity() + block_inverse_.capacity()) * sizeof(Mat) +
           (slot_.capacity() + col_.capacity() + block_window_.capacity()) * sizeof(std::int32_t) +
           (row_start_.capacity() + diag_block_.capacity()) * sizeof(std::int64_t) +
           (U_.capacity() + linv_.capacity()) * sizeof(Mat);
  }

  /// The per-particle stiffness of the last linearize().
  const Stiffness& particle_stiffness(std::int64_t p) const { return K_[std::size_t(p)]; }

 private:
  /// Orthonormal normals of the components a node's boundary conditions fix.
  struct Basis {
    Mat q = Mat::Zero();
    int rank = 0;
    void add(const Vec& n) {
      if (rank == Dim) return;
      Vec r = n;
      for (int j = 0; j < rank; ++j) r -= q.col(j).dot(r) * q.col(j);
      const T len = r.norm();
      if (len > T(1e-4)) q.col(rank++) = r / len;
    }
    void fix_all() { rank = Dim; }
    /// S = I - sum_q q q^T
    Mat projection() const {
      if (rank == Dim) return Mat::Zero();
      Mat S = Mat::Identity();
      for (int j = 0; j < rank; ++j) S -= q.col(j) * q.col(j).transpose();
      return S;
    }
  };

  /// The explicit boundary rule of update_grid at node idx; if `basis` is given, collects the
  /// normals the solve must hold. Returns whether any wall or collider covers the node.
  static bool apply_boundaries(const Grid& g, const IVec& idx, const GridBoundaries<T, Dim>& bc, Vec& v, Basis* basis) {
    bool any = false;
    for_each_grid_condition(idx, [&] { return g.position(idx); }, bc,
                            [&](const Vec& vb, const Vec& n, Condition c, T friction) {
                              any = true;
                              if (basis) {
                                if (c == Condition::Sticky)
                                  basis->fix_all();
                                else if (c == Condition::Slip || (v - vb).dot(n) < T(0))
                                  basis->add(n);
                              }
                              v = apply_condition<T, Dim>(v, vb, n, c, friction);
                            });
    return any;
  }


  /// The assembled solve (double): pattern, blocks, preconditioner, CG; x = the correction.
  numerics::PcgResult<T> solve_assembled(T dt, VectorX& x, bool& ic0_failed) {
    const std::int64_t n = unknowns();
    build_pattern();
    assemble_stiffness();

    // rhs = S (M v0 - (M + dt^2 H) v0) = -dt^2 S H v0
    multiply_stiffness(v0_, tmp_);
    VectorX rhs = (-dt * dt) * tmp_;
    filter(rhs);
    // The diagonal of M + dt^2 H.
    diag_.resize(Dim * n);
    for (std::int64_t i = 0; i < n; ++i)
      diag_.template segment<Dim>(Dim * i) = (dt * dt) * H_[std::size_t(diag_block_[std::size_t(i)])].diagonal().array() + mass_[i];

    // The tolerance is relative to the correction's right-hand side (the elastic impulse). It
    // must not be relative to M v0: a fast rigid motion would then hide errors in the elastic
    // part, which the explicit impulse in v0 amplifies at large dt. A residual at the round-off
    // level of the terms of A v0 counts as converged, so that a rigid motion (H v0 = round-off)
    // needs no iteration.
    tmp_ = diag_.cwiseProduct(v0_);
    filter(tmp_);
    const T floor = T(64) * std::numeric_limits<T>::epsilon() * tmp_.norm(), rhs_norm = rhs.norm();
    form_system(dt);  // H_ now holds A

    Preconditioner pre = options_.preconditioner;
    if (pre == Preconditioner::IC0) {
      try {
        build_ic0();
      } catch (const std::domain_error&) {
        ic0_failed = true;
        pre = Preconditioner::BlockJacobi;
      }
    }
    if (pre == Preconditioner::Jacobi) {
      diag_ = diag_.cwiseInverse();
    } else if (pre == Preconditioner::BlockJacobi) {
      block_inverse_.resize(std::size_t(n));
      for (std::int64_t i = 0; i < n; ++i) block_inverse_[std::size_t(i)] = H_[std::size_t(diag_block_[std::size_t(i)])].inverse();
    }

    const auto apply_a = [&](const VectorX& u, VectorX& out) { multiply(H_, u, out); };
    const auto precondition = [&](const VectorX& r, VectorX& z) {
      if (pre == Preconditioner::IC0) {
        apply_ic0(r, z);
      } else if (pre == Preconditioner::BlockJacobi) {
        z.resize(r.size());
        for (std::int64_t i = 0; i < n; ++i)
          z.template segment<Dim>(Dim * i).noalias() = block_inverse_[std::size_t(i)] * r.template segment<Dim>(Dim * i);
      } else {
        z = diag_.cwiseProduct(r);
      }
      filter(z);
    };
    numerics::PcgOptions<T> cg;
    cg.tolerance = rhs_norm > T(0) ? std::max(options_.tolerance, floor / rhs_norm) : options_.tolerance;
    cg.max_iterations = options_.max_iterations;
    x = VectorX::Zero(Dim * n);
    return numerics::pcg(apply_a, rhs, x, precondition, cg);
  }

  /// The matrix-free solve (float): Jacobi with the exact diagonal of M + dt^2 H, each product
  /// a gather and scatter over the particles' cached stencils.
  numerics::PcgResult<T> solve_matrix_free(T dt, VectorX& x) {
    const std::int64_t n = unknowns();
    apply_stiffness(v0_, tmp_);
    VectorX rhs = (-dt * dt) * tmp_;
    filter(rhs);
    stiffness_diagonal(diag_);
    diag_ *= dt * dt;
    for (std::int64_t i = 0; i < n; ++i) diag_.template segment<Dim>(Dim * i).array() += mass_[i];
    tmp_ = diag_.cwiseProduct(v0_);
    filter(tmp_);
    const T floor = T(64) * std::numeric_limits<T>::epsilon() * tmp_.norm(), rhs_norm = rhs.norm();
    diag_ = diag_.cwiseInverse();
    const auto apply_a = [&](const VectorX& u, VectorX& out) {
      apply_stiffness(u, out);  // u = S u already: CG's iterates stay in the range of S
      out *= dt * dt;
      for (std::int64_t i = 0; i < n; ++i) out.template segment<Dim>(Dim * i) += mass_[i] * u.template segment<Dim>(Dim * i);
      filter(out);
    };
    const auto precondition = [&](const VectorX& r, VectorX& z) {
      z = diag_.cwiseProduct(r);
      filter(z);
    };
    numerics::PcgOptions<T> cg;
    cg.tolerance = rhs_norm > T(0) ? std::max(options_.tolerance, floor / rhs_norm) : options_.tolerance;
    cg.max_iterations = options_.max_iterations;
    x = VectorX::Zero(Dim * n);
    return numerics::pcg(apply_a, rhs, x, precondition, cg);
  }

  /// out = sum over the blocks of each row, rows in parallel (fixed order within a row).
  void multiply(const std::vector<Mat>& blocks, const VectorX& u, VectorX& out) const {
    const std::int64_t n = unknowns();
    out.resize(Dim * n);
    parallel::parallel_for(0, n, [&](std::int64_t i) {
      Vec s = Vec::Zero();
      for (std::int64_t b = row_start_[std::size_t(i)]; b < row_start_[std::size_t(i + 1)]; ++b)
        s.noalias() += blocks[std::size_t(b)] * u.template segment<Dim>(Dim * std::int64_t(col_[std::size_t(b)]));
      out.template segment<Dim>(Dim * i) = s;
    });
  }

  /// A = S (M + dt^2 H) S + (I - S) block by block: on the range of S it is the filtered system,
  /// and the fixed components get the identity, so A is positive definite on the whole space
  /// (for the preconditioners) and CG iterates in the range of S need no filtering.
  void form_system(T dt) {
    const std::int64_t n = unknowns();
    parallel::parallel_for(0, n, [&](std::int64_t i) {
      const std::int32_t pi = projection_of_[std::size_t(i)];
      for (std::int64_t b = row_start_[std::size_t(i)]; b < row_start_[std::size_t(i + 1)]; ++b) {
        Mat a = (dt * dt) * H_[std::size_t(b)];
        const std::int32_t j = col_[std::size_t(b)];
        if (j == i) a.diagonal().array() += mass_[i];
        const std::int32_t pj = projection_of_[std::size_t(j)];
        if (pi >= 0) a = projections_[std::size_t(pi)] * a;
        if (pj >= 0) a = a * projections_[std::size_t(pj)];
        if (j == i && pi >= 0) a += Mat::Identity() - projections_[std::size_t(pi)];
        H_[std::size_t(b)] = a;
      }
    });
  }

  /// Block IC(0) of A on its block pattern (Dim x Dim blocks; Saad 2003, sec. 10.3 and 10.7 on
  /// block incomplete factorizations): A ~ F^T F with F block upper triangular on the pattern
  /// of A's upper triangle, F_kk = L_k^T (L_k L_k^T the Cholesky factor of the updated diagonal
  /// block), F_kj = L_k^-1 A'_kj; the right-looking update A'_jl -= F_kj^T F_kl is kept only
  /// where (j, l) is in the pattern (a window lookup). Rows in order on one thread. Throws
  /// std::domain_error when a diagonal block is not positive definite.
  void build_ic0() {
    const std::int64_t n = unknowns();
    U_ = H_;
    linv_.resize(std::size_t(n));
    for (std::int64_t k = 0; k < n; ++k) {
      const std::int64_t d = diag_block_[std::size_t(k)], end = row_start_[std::size_t(k + 1)];
      Eigen::LLT<Mat> llt(U_[std::size_t(d)]);
      if (llt.info() != Eigen::Success || !(llt.matrixLLT().diagonal().array() > T(0)).all())
        throw std::domain_error("ImplicitUpdate: block IC(0) met a diagonal block that is not positive definite");
      const Mat Linv = llt.matrixL().solve(Mat(Mat::Identity()));
      linv_[std::size_t(k)] = Linv;
      for (std::int64_t b = d + 1; b < end; ++b) U_[std::size_t(b)] = Linv * U_[std::size_t(b)];
      for (std::int64_t b1 = d + 1; b1 < end; ++b1) {
        const std::int64_t j = col_[std::size_t(b1)];
        const Mat Fjt = U_[std::size_t(b1)].transpose();
        const int* diff = window_diff_.data() + std::size_t(block_window_[std::size_t(b1)]) * std::size_t(window_);
        const std::int32_t* row_j = slot_.data() + std::size_t(j * window_);
        for (std::int64_t b2 = b1; b2 < end; ++b2) {
          const int w = diff[block_window_[std::size_t(b2)]];  // window offset of l - j
          if (w < 0) continue;
          U_[std::size_t(row_j[w])].noalias() -= Fjt * U_[std::size_t(b2)];
        }
      }
    }
  }

  /// z = (F^T F)^-1 r by the two block triangular solves, row access only.
  void apply_ic0(const VectorX& r, VectorX& z) const {
    const std::int64_t n = unknowns();
    z = r;
    for (std::int64_t k = 0; k < n; ++k) {  // F^T y = r
      const Vec yk = linv_[std::size_t(k)] * z.template segment<Dim>(Dim * k);
      z.template segment<Dim>(Dim * k) = yk;
      for (std::int64_t b = diag_block_[std::size_t(k)] + 1; b < row_start_[std::size_t(k + 1)]; ++b)
        z.template segment<Dim>(Dim * std::int64_t(col_[std::size_t(b)])).noalias() -= U_[std::size_t(b)].transpose() * yk;
    }
    for (std::int64_t k = n - 1; k >= 0; --k) {  // F z = y
      Vec s = z.template segment<Dim>(Dim * k);
      for (std::int64_t b = diag_block_[std::size_t(k)] + 1; b < row_start_[std::size_t(k + 1)]; ++b)
        s.noalias() -= U_[std::size_t(b)] * z.template segment<Dim>(Dim * std::int64_t(col_[std::size_t(b)]));
      z.template segment<Dim>(Dim * k) = linv_[std::size_t(k)].transpose() * s;
    }
  }

  /// x <- S x, node by node.
  void filter(VectorX& x) const {
    for (std::size_t i = 0; i < projection_of_.size(); ++i)
      if (projection_of_[i] >= 0)
        x.template segment<Dim>(Dim * std::int64_t(i)) =
            projections_[std::size_t(projection_of_[i])] * x.template segment<Dim>(Dim * std::int64_t(i));
  }

  /// K_p = V0 d^2 psi((I + G) F)/dG^2: column (c, e) is vec(V0 dP(F, E_ce F) F^T).
  template <class M, class = void>
  struct HasDifferential : std::false_type {};
  template <class M>
  struct HasDifferential<M, std::void_t<decltype(std::declval<const M&>().differential(std::declval<const Mat&>()))>>
      : std::true_type {};

  template <class Model>
  Stiffness stiffness(const Model& model, const Mat& F, T vol0) const {
    if constexpr (HasDifferential<Model>::value) {
      // The model's F-dependent factors (an SVD for fixed corotated) once, not per direction.
      const auto dP = model.differential(F);
      return stiffness_from(dP, F, vol0);
    } else {
      return stiffness_from([&](const Mat& dF) { return Mat(model.dP(F, dF)); }, F, vol0);
    }
  }

  template <class DP>
  Stiffness stiffness_from(const DP& dP, const Mat& F, T vol0) const {
    Stiffness K;
    for (int e = 0; e < Dim; ++e)
      for (int c = 0; c < Dim; ++c) {
        Mat dF = Mat::Zero();
        dF.row(c) = F.row(e);  // E_ce F
        const Mat Q = dP(dF) * F.transpose();
        K.col(c + Dim * e) = vol0 * Eigen::Map<const Eigen::Matrix<T, D2, 1>>(Q.data());
      }
    K = T(0.5) * (K + K.transpose());  // symmetric up to round-off
    if (!options_.definite) return K;
    // Cheap test first: by Sylvester's law of inertia the pivots of L D L^T carry the signs of
    // the eigenvalues, so only indefinite K_p pay for an eigendecomposition.
    const T scale = K.diagonal().cwiseAbs().maxCoeff();
    Eigen::LDLT<Stiffness> ldlt(K);
    if (ldlt.info() == Eigen::Success && (ldlt.vectorD().array() >= -T(1e-8) * scale).all()) return K;
    Eigen::SelfAdjointEigenSolver<Stiffness> eig(K);
    const Eigen::Matrix<T, D2, 1> lambda = eig.eigenvalues().cwiseMax(T(0));
    return eig.eigenvectors() * lambda.asDiagonal() * eig.eigenvectors().transpose();
  }

  /// Stores, for every particle, the unknown of each node of its stencil (-1 for a node without
  /// mass: it carries no unknown, as in the explicit update) and the gradient g_ip (weight
  /// gradient, or the MLS one). CG then never re-evaluates a kernel.
  template <int Order>
  void cache_stencils(const Particles<T, Dim>& P) {
    using St = transfer::Stencil<T, Dim, Order>;
    stencil_nodes_ = St::nodes;
    stencil_dof_.resize(std::size_t(particles_ * St::nodes));
    stencil_grad_.resize(std::size_t(particles_ * St::nodes));
    const T Dinv = transfer::BSpline<Order>::inverse_inertia(dx_);
    const bool mls = mls_;
    parallel::parallel_for(0, particles_, [&](std::int64_t p) {
      const St s(P.x[std::size_t(p)] - origin_, inv_dx_, dx_);
      std::int64_t k0 = 0;
      for (int d = 0; d < Dim; ++d) k0 += stride_[d] * s.base[d];
      std::size_t j = std::size_t(p * St::nodes);
      transfer::for_each_node(s, [&](int a, int b, int c, T w, const Vec& grad, const Vec& off) {
        std::int64_t k = k0 + a * stride_[0] + b * stride_[1];
        if constexpr (Dim == 3) k += c;
        stencil_dof_[j] = dof_of_[std::size_t(k)];
        stencil_grad_[j] = mls ? Vec((Dinv * w) * off) : grad;
        ++j;
      });
    });
  }

  /// Q_p = K_p vec(G_p) with G_p = sum_i u_i g_ip^T.
  void gather(std::int64_t p, const VectorX& u) {
    Mat G = Mat::Zero();
    for_each_unknown(p, [&](std::int32_t i, const Vec& g) {
      const Vec ui = u.template segment<Dim>(Dim * std::int64_t(i));
      for (int b = 0; b < Dim; ++b)
        for (int a = 0; a < Dim; ++a) G(a, b) += ui[a] * g[b];
    });
    // lazyProduct: a coefficient-wise loop, not the generic matrix-vector kernel, for this size.
    Eigen::Map<Eigen::Matrix<T, D2, 1>>(Q_[std::size_t(p)].data()) =
        K_[std::size_t(p)].lazyProduct(Eigen::Map<const Eigen::Matrix<T, D2, 1>>(G.data()));
  }

  /// out_i += Q_p g_ip over particle p's stencil.
  void scatter(std::int64_t p, VectorX& out) const {
    const Mat& Q = Q_[std::size_t(p)];
    for_each_unknown(p, [&](std::int32_t i, const Vec& g) { out.template segment<Dim>(Dim * std::int64_t(i)).noalias() += Q.lazyProduct(g); });
  }

  /// fn(unknown, g_ip) for the nodes of particle p's stencil that carry an unknown.
  template <class Fn>
  void for_each_unknown(std::int64_t p, Fn&& fn) const {
    const std::size_t j0 = std::size_t(p * stencil_nodes_);
    for (std::size_t j = j0; j < j0 + std::size_t(stencil_nodes_); ++j)
      if (stencil_dof_[j] >= 0) fn(stencil_dof_[j], stencil_grad_[j]);
  }

  int order_;
  bool mls_;
  Options options_;
  // Unknowns.
  std::vector<std::int32_t> dof_of_;  // grid index -> unknown, -1 for nodes without mass
  std::vector<std::int64_t> nodes_;   // unknown -> grid index
  Vec origin_ = Vec::Zero();
  T dx_ = 1, inv_dx_ = 1;
  std::int64_t stride_[Dim] = {};
  IVec res_ = IVec::Zero();
  std::vector<IVec> coords_;  // unknown -> grid coordinates
  // The assembled operator: block rows over the unknowns.
  int window_ = 0;                       // (2 order + 1)^Dim neighbour offsets
  std::vector<std::int32_t> slot_;       // unknown i, window offset -> block, -1 = no unknown there
  std::vector<int> pair_window_;         // stencil node a, stencil node b -> window offset of b - a
  std::vector<std::int64_t> row_start_;  // unknown -> first block of its row
  std::vector<std::int32_t> col_;        // block -> column unknown
  std::vector<int> block_window_;        // block -> its window offset in its row
  std::vector<IVec> window_off_;         // window offset -> axis offsets
  std::vector<std::int64_t> window_step_;  // window offset -> grid index offset
  std::vector<int> window_diff_;         // (window a, window b) -> window of b - a, or -1
  std::vector<std::int64_t> diag_block_; // unknown -> its diagonal block
  std::vector<Mat> H_, block_inverse_;  // H_: H, then A after form_system
  std::vector<Mat> U_, linv_;  // block IC(0): F_kj (j > k) and L_k^-1
  VectorX mass_, v0_, diag_, tmp_;
  std::vector<std::int64_t> boundary_;      // unknowns covered by a wall or collider
  std::vector<std::int32_t> projection_of_;  // unknown -> index into projections_, -1 = free
  std::vector<Mat> projections_;
  // Particles.
  std::int64_t particles_ = 0;
  int stencil_nodes_ = 0;
  std::vector<std::int32_t> stencil_dof_;  // particle p, node j -> unknown (or -1)
  std::vector<Vec> stencil_grad_;          // particle p, node j -> g_ip
  std::vector<Stiffness> K_;
  std::vector<Mat> Q_;
};

}  // namespace slurry
