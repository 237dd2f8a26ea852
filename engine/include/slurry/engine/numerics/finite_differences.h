#pragma once
/// \file finite_differences.h
/// Finite differences on callables and on regular-grid arrays, and assembly of the Poisson
/// problem on a regular grid.
///
/// Difference quotients (LeVeque, Finite Difference Methods for ODEs and PDEs, SIAM 2007, ch. 1):
///   forward  (f(x+h) - f(x)) / h             O(h)
///   backward (f(x) - f(x-h)) / h             O(h)
///   central  (f(x+h) - f(x-h)) / (2h)        O(h^2)
///   second   (f(x+h) - 2 f(x) + f(x-h)) / h^2  O(h^2)
/// First-order upwind for the advection term u f_x (LeVeque, Finite Volume Methods for
/// Hyperbolic Problems, CUP 2002, section 4.8): backward difference where u > 0, forward where
/// u < 0.
///
/// Grid layout. A Dim-dimensional grid has nodes[a] nodes along axis a, spacing h in every axis,
/// node (i, j, k) at origin + h (i, j, k) and flat index i + nodes[0] (j + nodes[1] k) (x
/// fastest). Boundary nodes lie on the domain boundary (vertex-centred grid).
///
/// Poisson conventions (assemble_poisson, poisson_matrix_1d).
///  - Sign: we assemble A u = b for -Lap u = f, i.e. A = -Lap_h with the 2 Dim / h^2 on the
///    diagonal and -1 / h^2 for each neighbour. With at least one Dirichlet node and symmetrized
///    Neumann rows, A is symmetric positive definite.
///  - Dirichlet: Dirichlet nodes are eliminated. They are not unknowns; their known values move to
///    the right-hand side (b_p += g_q / h^2 for an unknown p next to a Dirichlet node q), which
///    keeps A symmetric. A node on both a Dirichlet and a Neumann face is a Dirichlet node; on
///    several Dirichlet faces it takes g of the first in PoissonGrid::faces order.
///  - Neumann: ghost-node method with the central difference of the outward normal derivative
///    g = du/dn: the ghost value is u_ghost = u_mirror + 2 h g, so the row of a Neumann boundary
///    node couples to its inner neighbour with -2 / h^2 and gains 2 g / h on the right-hand side.
///    In 1D the row is [2, -2] / h^2 (NeumannRows::kGhostNode). By default
///    (NeumannRows::kSymmetrized) every row is then multiplied by the node's dual-cell fraction
///    (1/2 per axis on whose boundary the node lies; 1/4 at a 2D corner), which makes A
///    symmetric: in 1D the row becomes [1, -1] / h^2 with right-hand side f / 2 + g / h. This is
///    the vertex-centred finite-volume discretization; both forms have the same solution.
///  - Pure Neumann (no Dirichlet node): A is singular with the constants as null space; call
///    PoissonSystem::make_rhs_compatible() and fix the mean of the solution (CG converges on such
///    a consistent system; IC(0) is not recommended there).
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <array>
#include <cassert>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace slurry::numerics {

// ---------------------------------------------------------------------------------------------
// Difference quotients of a callable
// ---------------------------------------------------------------------------------------------

/// (f(x + h) - f(x)) / h, first order.
template <class F, class T>
T forward_difference(const F& f, T x, T h) {
  return (f(x + h) - f(x)) / h;
}

/// (f(x) - f(x - h)) / h, first order.
template <class F, class T>
T backward_difference(const F& f, T x, T h) {
  return (f(x) - f(x - h)) / h;
}

/// (f(x + h) - f(x - h)) / (2 h), second order.
template <class F, class T>
T central_difference(const F& f, T x, T h) {
  return (f(x + h) - f(x - h)) / (T(2) * h);
}

/// (f(x + h) - 2 f(x) + f(x - h)) / h^2, second order.
template <class F, class T>
T second_difference(const F& f, T x, T h) {
  return (f(x + h) - T(2) * f(x) + f(x - h)) / (h * h);
}

// ---------------------------------------------------------------------------------------------
// Difference quotients on a 1D array of samples f_i = f(x_0 + i h)
// ---------------------------------------------------------------------------------------------
// Each returns one value per node. Where a stencil would leave the array, a one-sided stencil of
// the same order is used instead, so the order holds at every node.

namespace detail {
template <class T>
void require_samples(const Eigen::VectorX<T>& f, Eigen::Index min_size, const char* who) {
  if (f.size() < min_size) {
    std::ostringstream msg;
    msg << who << ": " << f.size() << " samples; need at least " << min_size;
    throw std::invalid_argument(msg.str());
  }
}
}  // namespace detail

/// Forward differences; the last node uses the backward difference.
template <class T>
Eigen::VectorX<T> forward_difference(const Eigen::VectorX<T>& f, T h) {
  detail::require_samples(f, 2, "forward_difference");
  const Eigen::Index n = f.size();
  Eigen::VectorX<T> d(n);
  d.head(n - 1) = (f.tail(n - 1) - f.head(n - 1)) / h;
  d[n - 1] = (f[n - 1] - f[n - 2]) / h;
  return d;
}

/// Backward differences; the first node uses the forward difference.
template <class T>
Eigen::VectorX<T> backward_difference(const Eigen::VectorX<T>& f, T h) {
  detail::require_samples(f, 2, "backward_difference");
  const Eigen::Index n = f.size();
  Eigen::VectorX<T> d(n);
  d.tail(n - 1) = (f.tail(n - 1) - f.head(n - 1)) / h;
  d[0] = (f[1] - f[0]) / h;
  return d;
}

/// Central differences; the end nodes use the second-order one-sided stencil
/// (-3 f_0 + 4 f_1 - f_2) / (2h) and its mirror image.
template <class T>
Eigen::VectorX<T> central_difference(const Eigen::VectorX<T>& f, T h) {
  detail::require_samples(f, 3, "central_difference");
  const Eigen::Index n = f.size();
  Eigen::VectorX<T> d(n);
  d.segment(1, n - 2) = (f.tail(n - 2) - f.head(n - 2)) / (T(2) * h);
  d[0] = (-T(3) * f[0] + T(4) * f[1] - f[2]) / (T(2) * h);
  d[n - 1] = (T(3) * f[n - 1] - T(4) * f[n - 2] + f[n - 3]) / (T(2) * h);
  return d;
}

/// Second differences; the end nodes use the second-order one-sided stencil
/// (2 f_0 - 5 f_1 + 4 f_2 - f_3) / h^2 and its mirror image.
template <class T>
Eigen::VectorX<T> second_difference(const Eigen::VectorX<T>& f, T h) {
  detail::require_samples(f, 4, "second_difference");
  const Eigen::Index n = f.size();
  const T h2 = h * h;
  Eigen::VectorX<T> d(n);
  d.segment(1, n - 2) = (f.tail(n - 2) - T(2) * f.segment(1, n - 2) + f.head(n - 2)) / h2;
  d[0] = (T(2) * f[0] - T(5) * f[1] + T(4) * f[2] - f[3]) / h2;
  d[n - 1] = (T(2) * f[n - 1] - T(5) * f[n - 2] + T(4) * f[n - 3] - f[n - 4]) / h2;
  return d;
}

/// First-order upwind approximation of the advection term u_i (df/dx)_i with a velocity per node:
/// (f_i - f_{i-1}) / h where u_i > 0, (f_{i+1} - f_i) / h where u_i < 0, 0 where u_i = 0.
/// At an inflow end (no upwind neighbour) the one-sided difference into the array is used; in a
/// solver that node's value comes from the boundary condition instead.
template <class T>
Eigen::VectorX<T> upwind_advection(const Eigen::VectorX<T>& f, const Eigen::VectorX<T>& u, T h) {
  detail::require_samples(f, 2, "upwind_advection");
  if (u.size() != f.size()) {
    std::ostringstream msg;
    msg << "upwind_advection: " << f.size() << " samples but " << u.size() << " velocities";
    throw std::invalid_argument(msg.str());
  }
  const Eigen::Index n = f.size();
  Eigen::VectorX<T> out(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    T dfdx = T(0);
    if (u[i] > T(0))
      dfdx = i > 0 ? (f[i] - f[i - 1]) / h : (f[1] - f[0]) / h;
    else if (u[i] < T(0))
      dfdx = i < n - 1 ? (f[i + 1] - f[i]) / h : (f[n - 1] - f[n - 2]) / h;
    out[i] = u[i] * dfdx;
  }
  return out;
}

/// Upwind advection term with one constant velocity u; see the overload above.
template <class T>
Eigen::VectorX<T> upwind_advection(const Eigen::VectorX<T>& f, T u, T h) {
  return upwind_advection(f, Eigen::VectorX<T>::Constant(f.size(), u).eval(), h);
}

// ---------------------------------------------------------------------------------------------
// Regular grids
// ---------------------------------------------------------------------------------------------

/// Flat index of a node from its integer coordinates (x fastest).
template <int Dim>
Eigen::Index grid_index(const Eigen::Vector<int, Dim>& ijk, const Eigen::Vector<int, Dim>& nodes) {
  Eigen::Index index = 0;
  for (int a = Dim - 1; a >= 0; --a) index = index * nodes[a] + ijk[a];
  return index;
}

/// Integer coordinates of the node with flat index `index`.
template <int Dim>
Eigen::Vector<int, Dim> grid_coords(Eigen::Index index, const Eigen::Vector<int, Dim>& nodes) {
  Eigen::Vector<int, Dim> ijk;
  for (int a = 0; a < Dim; ++a) {
    ijk[a] = static_cast<int>(index % nodes[a]);
    index /= nodes[a];
  }
  return ijk;
}

/// Total number of nodes of the grid.
template <int Dim>
Eigen::Index grid_size(const Eigen::Vector<int, Dim>& nodes) {
  Eigen::Index n = 1;
  for (int a = 0; a < Dim; ++a) n *= nodes[a];
  return n;
}

/// The standard (2 Dim + 1)-point Laplacian (5-point in 2D, 7-point in 3D) of nodal values u:
/// (Lap u)_p = sum_a (u_{p+e_a} - 2 u_p + u_{p-e_a}) / h^2 at interior nodes, O(h^2);
/// 0 at boundary nodes, where the stencil does not fit.
template <class T, int Dim>
Eigen::VectorX<T> laplacian(const Eigen::VectorX<T>& u, const Eigen::Vector<int, Dim>& nodes, T h) {
  const Eigen::Index n = grid_size<Dim>(nodes);
  if (u.size() != n) {
    std::ostringstream msg;
    msg << "laplacian: " << u.size() << " values for a grid of " << n << " nodes";
    throw std::invalid_argument(msg.str());
  }
  Eigen::Index stride[3] = {1, 1, 1};
  for (int a = 1; a < Dim; ++a) stride[a] = stride[a - 1] * nodes[a - 1];
  const T inv_h2 = T(1) / (h * h);
  Eigen::VectorX<T> out = Eigen::VectorX<T>::Zero(n);
  for (Eigen::Index p = 0; p < n; ++p) {
    const Eigen::Vector<int, Dim> ijk = grid_coords<Dim>(p, nodes);
    bool interior = true;
    for (int a = 0; a < Dim; ++a) interior = interior && ijk[a] > 0 && ijk[a] < nodes[a] - 1;
    if (!interior) continue;
    T sum = T(0);
    for (int a = 0; a < Dim; ++a) sum += u[p + stride[a]] - T(2) * u[p] + u[p - stride[a]];
    out[p] = sum * inv_h2;
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Poisson problem -Lap u = f on a regular grid
// ---------------------------------------------------------------------------------------------

/// Kind of boundary condition on one face of the box.
enum class Boundary {
  kDirichlet,  ///< u = g on the face
  kNeumann,    ///< du/dn = g on the face, n the outward normal
};

/// Form of the rows of Neumann boundary nodes; see the file comment.
enum class NeumannRows {
  kSymmetrized,  ///< ghost-node rows scaled by the dual-cell fraction: A symmetric ([1, -1] in 1D)
  kGhostNode,    ///< plain ghost-node rows ([2, -2] in 1D): A not symmetric
};

/// The grid and boundary conditions of a Poisson problem on a box.
template <class T, int Dim>
struct PoissonGrid {
  static_assert(Dim >= 1 && Dim <= 3, "PoissonGrid: Dim must be 1, 2 or 3");
  Eigen::Vector<int, Dim> nodes = Eigen::Vector<int, Dim>::Constant(3);  ///< per axis, >= 2
  T spacing = T(1);                                                      ///< h > 0
  Eigen::Vector<T, Dim> origin = Eigen::Vector<T, Dim>::Zero();          ///< position of node 0
  /// faces[2 a] is the low side of axis a, faces[2 a + 1] its high side; all Dirichlet by default.
  std::array<Boundary, 2 * Dim> faces{};
  NeumannRows neumann_rows = NeumannRows::kSymmetrized;

  void validate() const {
    for (int a = 0; a < Dim; ++a)
      if (nodes[a] < 2) {
        std::ostringstream msg;
        msg << "PoissonGrid.nodes[" << a << "] = " << nodes[a] << "; allowed: >= 2";
        throw std::invalid_argument(msg.str());
      }
    if (!(spacing > T(0)) || !std::isfinite(spacing)) {
      std::ostringstream msg;
      msg << "PoissonGrid.spacing = " << spacing << "; allowed: finite and > 0";
      throw std::invalid_argument(msg.str());
    }
  }

  Eigen::Vector<T, Dim> position(const Eigen::Vector<int, Dim>& ijk) const {
    return origin + spacing * ijk.template cast<T>();
  }
};

/// The assembled system A u = b over the unknown (non-Dirichlet) nodes.
template <class T>
struct PoissonSystem {
  Eigen::SparseMatrix<T> matrix;              ///< A, unknowns x unknowns
  Eigen::VectorX<T> rhs;                      ///< b
  std::vector<Eigen::Index> node_of_unknown;  ///< grid node of each unknown
  std::vector<Eigen::Index> unknown_of_node;  ///< unknown of each node, -1 for Dirichlet nodes
  Eigen::VectorX<T> dirichlet_values;         ///< per node: g at Dirichlet nodes, 0 elsewhere
  /// Per unknown: the dual-cell fraction D_p (1/2 per axis on whose boundary the node lies).
  /// With symmetrized rows A_sym = D A_ghost and b_sym = D b_ghost.
  Eigen::VectorX<T> dual_fraction;
  NeumannRows neumann_rows = NeumannRows::kSymmetrized;
  bool singular = false;  ///< no Dirichlet node: the constants are in the null space of A

  Eigen::Index unknowns() const { return rhs.size(); }

  /// Nodal values on the whole grid: the solution at the unknowns, g at Dirichlet nodes.
  Eigen::VectorX<T> to_grid(const Eigen::VectorX<T>& u) const {
    assert(u.size() == unknowns());
    Eigen::VectorX<T> out = dirichlet_values;
    for (Eigen::Index k = 0; k < u.size(); ++k) out[node_of_unknown[static_cast<size_t>(k)]] = u[k];
    return out;
  }

  /// For a pure Neumann problem: shift f by the constant c that makes b orthogonal to the left
  /// null vector of A (the discrete form of int f + int_boundary g = 0), so that A u = b has
  /// solutions (unique up to a constant). No-op for a nonsingular system.
  void make_rhs_compatible() {
    if (!singular) return;
    if (neumann_rows == NeumannRows::kSymmetrized) {
      // A symmetric, null space 1: need sum(b) = 0; shifting f by c changes b by c D.
      rhs -= (rhs.sum() / dual_fraction.sum()) * dual_fraction;
    } else {
      // Left null vector D: need D . b = 0; shifting f by c changes b by c 1.
      rhs.array() -= dual_fraction.dot(rhs) / dual_fraction.sum();
    }
  }
};

/// Assembles -Lap u = f with boundary data g on `grid`; conventions in the file comment.
/// f(x) gives the source at position x (an Eigen::Vector<T, Dim>); g(x, face) gives u on a
/// Dirichlet face or du/dn (outward) on a Neumann face, face numbered as in PoissonGrid::faces.
template <class T, int Dim, class SourceF, class BoundaryG>
PoissonSystem<T> assemble_poisson(const PoissonGrid<T, Dim>& grid, const SourceF& f,
                                  const BoundaryG& g) {
  grid.validate();
  const auto& nodes = grid.nodes;
  const Eigen::Index n_nodes = grid_size<Dim>(nodes);
  const T h = grid.spacing;
  const T inv_h2 = T(1) / (h * h);

  PoissonSystem<T> sys;
  sys.neumann_rows = grid.neumann_rows;
  sys.unknown_of_node.assign(static_cast<size_t>(n_nodes), -1);
  sys.dirichlet_values = Eigen::VectorX<T>::Zero(n_nodes);

  // Pass 1: classify nodes. dirichlet_face < 0 marks an unknown.
  std::vector<int> dirichlet_face(static_cast<size_t>(n_nodes), -1);
  for (Eigen::Index p = 0; p < n_nodes; ++p) {
    const Eigen::Vector<int, Dim> ijk = grid_coords<Dim>(p, nodes);
    for (int face = 0; face < 2 * Dim && dirichlet_face[static_cast<size_t>(p)] < 0; ++face) {
      const int a = face / 2;
      const bool on_face = (face % 2 == 0) ? ijk[a] == 0 : ijk[a] == nodes[a] - 1;
      if (on_face && grid.faces[static_cast<size_t>(face)] == Boundary::kDirichlet)
        dirichlet_face[static_cast<size_t>(p)] = face;
    }
    if (dirichlet_face[static_cast<size_t>(p)] >= 0) {
      sys.dirichlet_values[p] = g(grid.position(ijk), dirichlet_face[static_cast<size_t>(p)]);
    } else {
      sys.unknown_of_node[static_cast<size_t>(p)] =
          static_cast<Eigen::Index>(sys.node_of_unknown.size());
      sys.node_of_unknown.push_back(p);
    }
  }
  const Eigen::Index n = static_cast<Eigen::Index>(sys.node_of_unknown.size());
  sys.singular = n == n_nodes;
  sys.rhs.resize(n);
  sys.dual_fraction.resize(n);

  // Pass 2: rows of the unknowns.
  std::vector<Eigen::Triplet<T>> triplets;
  triplets.reserve(static_cast<size_t>(n) * (2 * Dim + 1));
  for (Eigen::Index row = 0; row < n; ++row) {
    const Eigen::Index p = sys.node_of_unknown[static_cast<size_t>(row)];
    const Eigen::Vector<int, Dim> ijk = grid_coords<Dim>(p, nodes);
    const Eigen::Vector<T, Dim> x = grid.position(ijk);

    T fraction = T(1);
    for (int a = 0; a < Dim; ++a)
      if (ijk[a] == 0 || ijk[a] == nodes[a] - 1) fraction *= T(0.5);
    const T scale = grid.neumann_rows == NeumannRows::kSymmetrized ? fraction : T(1);
    sys.dual_fraction[row] = fraction;

    T b = f(x);
    triplets.emplace_back(row, row, scale * T(2 * Dim) * inv_h2);
    // Adds `weight` times u at node `ijk_q` to the left-hand side of row p.
    const auto couple = [&](const Eigen::Vector<int, Dim>& ijk_q, T weight) {
      const Eigen::Index q = grid_index<Dim>(ijk_q, nodes);
      const Eigen::Index col = sys.unknown_of_node[static_cast<size_t>(q)];
      if (col >= 0)
        triplets.emplace_back(row, col, scale * weight);
      else
        b -= weight * sys.dirichlet_values[q];
    };
    for (int a = 0; a < Dim; ++a) {
      for (int side = 0; side < 2; ++side) {
        const int step = side == 0 ? -1 : 1;
        Eigen::Vector<int, Dim> ijk_q = ijk;
        ijk_q[a] += step;
        if (ijk_q[a] >= 0 && ijk_q[a] < nodes[a]) {
          couple(ijk_q, -inv_h2);
        } else {
          // Outside across face 2a + side, which is Neumann (p would be Dirichlet otherwise):
          // u_ghost = u_mirror + 2 h g.
          Eigen::Vector<int, Dim> ijk_m = ijk;
          ijk_m[a] -= step;
          couple(ijk_m, -inv_h2);
          b += T(2) * g(x, 2 * a + side) / h;
        }
      }
    }
    sys.rhs[row] = scale * b;
  }
  sys.matrix.resize(n, n);
  sys.matrix.setFromTriplets(triplets.begin(), triplets.end());  // sums duplicate entries
  sys.matrix.makeCompressed();
  return sys;
}

/// The matrix of -u'' on n nodes with spacing h in 1D, with the given condition at each end
/// (see the file comment): e.g. Dirichlet at both ends gives the (n-2) x (n-2) matrix
/// tridiag(-1, 2, -1) / h^2; a Neumann left end adds node 0 with row [1, -1] / h^2
/// (kSymmetrized) or [2, -2] / h^2 (kGhostNode). For n = 8: 6 x 6 with Dirichlet at both ends,
/// 7 x 7 with Neumann at one end and Dirichlet at the other.
template <class T>
Eigen::SparseMatrix<T> poisson_matrix_1d(int n, T h, Boundary left, Boundary right,
                                         NeumannRows rows = NeumannRows::kSymmetrized) {
  PoissonGrid<T, 1> grid;
  grid.nodes[0] = n;
  grid.spacing = h;
  grid.faces = {left, right};
  grid.neumann_rows = rows;
  const auto zero_f = [](const Eigen::Vector<T, 1>&) { return T(0); };
  const auto zero_g = [](const Eigen::Vector<T, 1>&, int) { return T(0); };
  return assemble_poisson(grid, zero_f, zero_g).matrix;
}

}  // namespace slurry::numerics
