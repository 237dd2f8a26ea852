#pragma once
/// \file pcg.h
/// Preconditioned conjugate gradients for symmetric positive (semi)definite systems A x = b.
///
/// The iteration is Algorithm 9.1 of Saad, Iterative Methods for Sparse Linear Systems, 2nd ed.
/// (SIAM 2003); see also Shewchuk, "An Introduction to the Conjugate Gradient Method Without the
/// Agonizing Pain" (1994). It stops when the (recursively updated) residual satisfies
/// ||b - A x|| <= tolerance ||b|| or after max_iterations iterations.
///
/// Two entry points: pcg(SparseMatrix, ...) and a matrix-free pcg(apply_a, ...) where apply_a and
/// the preconditioner are callables, either `void(const VectorX<T>& in, VectorX<T>& out)` or
/// `VectorX<T>(const VectorX<T>& in)`.
///
/// Preconditioners: IdentityPreconditioner (plain CG), JacobiPreconditioner (inverse diagonal),
/// IncompleteCholesky0 (IC(0): L L^T ~ A with L on the sparsity pattern of A's lower triangle;
/// Saad section 10.3, Golub & Van Loan, Matrix Computations, 4th ed., section 11.5.8).
/// IC(0) exists for M-matrices such as the Poisson matrices of finite_differences.h; otherwise a
/// nonpositive pivot can appear, and the constructor throws std::domain_error.
///
/// On a singular but consistent system (pure Neumann Poisson) CG with the identity or Jacobi
/// preconditioner converges to a solution; the component along the null space is that of x0.
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <type_traits>
#include <vector>

namespace slurry::numerics {

/// Stopping criteria of pcg().
template <class T>
struct PcgOptions {
  T tolerance = T(1e-8);      ///< on ||b - A x|| / ||b||, > 0
  int max_iterations = 1000;  ///< >= 0

  void validate() const {
    if (!(tolerance > T(0))) {
      std::ostringstream msg;
      msg << "PcgOptions.tolerance = " << tolerance << "; allowed: > 0";
      throw std::invalid_argument(msg.str());
    }
    if (max_iterations < 0) {
      std::ostringstream msg;
      msg << "PcgOptions.max_iterations = " << max_iterations << "; allowed: >= 0";
      throw std::invalid_argument(msg.str());
    }
  }
};

/// Outcome of pcg().
template <class T>
struct PcgResult {
  int iterations = 0;          ///< matrix-vector products after the initial residual
  T relative_residual = T(0);  ///< ||r|| / ||b|| at return (0 when b = 0)
  bool converged = false;      ///< relative_residual <= tolerance
};

/// z = r: turns pcg() into plain CG.
struct IdentityPreconditioner {
  template <class T>
  void operator()(const Eigen::VectorX<T>& r, Eigen::VectorX<T>& z) const {
    z = r;
  }
};

/// z = D^-1 r with D the diagonal of A.
template <class T>
class JacobiPreconditioner {
 public:
  explicit JacobiPreconditioner(const Eigen::SparseMatrix<T>& a) : inv_diag_(a.rows()) {
    const Eigen::VectorX<T> d = a.diagonal();
    for (Eigen::Index i = 0; i < d.size(); ++i) {
      if (!(d[i] > T(0))) {
        std::ostringstream msg;
        msg << "JacobiPreconditioner: diagonal entry " << i << " is " << d[i]
            << "; expected > 0 (a symmetric positive definite matrix)";
        throw std::domain_error(msg.str());
      }
      inv_diag_[i] = T(1) / d[i];
    }
  }
  void operator()(const Eigen::VectorX<T>& r, Eigen::VectorX<T>& z) const {
    z = inv_diag_.cwiseProduct(r);
  }

 private:
  Eigen::VectorX<T> inv_diag_;
};

/// Zero fill-in incomplete Cholesky factor L of a symmetric A (only its lower triangle is read);
/// applies z = (L L^T)^-1 r by two triangular solves.
template <class T>
class IncompleteCholesky0 {
 public:
  explicit IncompleteCholesky0(const Eigen::SparseMatrix<T>& a) {
    if (a.rows() != a.cols()) throw std::invalid_argument("IncompleteCholesky0: A is not square");
    l_ = a.template triangularView<Eigen::Lower>();
    l_.makeCompressed();
    const Eigen::Index n = l_.cols();
    const auto* outer = l_.outerIndexPtr();
    const auto* inner = l_.innerIndexPtr();
    T* val = l_.valuePtr();
    // pos[i]: position of entry (i, j) in the column j being updated, -1 when not in the pattern.
    std::vector<Eigen::Index> pos(static_cast<size_t>(n), -1);
    for (Eigen::Index k = 0; k < n; ++k) {
      const Eigen::Index kk = outer[k];
      const Eigen::Index end_k = outer[k + 1];
      if (kk == end_k || inner[kk] != k) {
        std::ostringstream msg;
        msg << "IncompleteCholesky0: no diagonal entry in row " << k;
        throw std::domain_error(msg.str());
      }
      if (!(val[kk] > T(0))) {
        std::ostringstream msg;
        msg << "IncompleteCholesky0: pivot " << k << " is " << val[kk]
            << "; IC(0) needs positive pivots (e.g. an SPD M-matrix)";
        throw std::domain_error(msg.str());
      }
      val[kk] = std::sqrt(val[kk]);
      for (Eigen::Index idx = kk + 1; idx < end_k; ++idx) val[idx] /= val[kk];
      // Right-looking update of the later columns j, restricted to the pattern:
      // L(i, j) -= L(i, k) L(j, k) for i >= j > k.
      for (Eigen::Index jdx = kk + 1; jdx < end_k; ++jdx) {
        const Eigen::Index j = inner[jdx];
        const T l_jk = val[jdx];
        for (Eigen::Index t = outer[j]; t < outer[j + 1]; ++t)
          pos[static_cast<size_t>(inner[t])] = t;
        for (Eigen::Index idx = jdx; idx < end_k; ++idx) {
          const Eigen::Index p = pos[static_cast<size_t>(inner[idx])];
          if (p >= 0) val[p] -= val[idx] * l_jk;
        }
        for (Eigen::Index t = outer[j]; t < outer[j + 1]; ++t)
          pos[static_cast<size_t>(inner[t])] = -1;
      }
    }
  }

  void operator()(const Eigen::VectorX<T>& r, Eigen::VectorX<T>& z) const {
    const Eigen::Index n = l_.cols();
    const auto* outer = l_.outerIndexPtr();
    const auto* inner = l_.innerIndexPtr();
    const T* val = l_.valuePtr();
    z = r;
    for (Eigen::Index k = 0; k < n; ++k) {  // L y = r, column by column
      z[k] /= val[outer[k]];
      for (Eigen::Index idx = outer[k] + 1; idx < outer[k + 1]; ++idx)
        z[inner[idx]] -= val[idx] * z[k];
    }
    for (Eigen::Index k = n - 1; k >= 0; --k) {  // L^T z = y: column k of L is row k of L^T
      T s = z[k];
      for (Eigen::Index idx = outer[k] + 1; idx < outer[k + 1]; ++idx)
        s -= val[idx] * z[inner[idx]];
      z[k] = s / val[outer[k]];
    }
  }

  /// The factor L (lower triangular, column major).
  const Eigen::SparseMatrix<T>& factor() const { return l_; }

 private:
  Eigen::SparseMatrix<T> l_;
};

namespace detail {
template <class T, class Op>
void apply_operator(const Op& op, const Eigen::VectorX<T>& in, Eigen::VectorX<T>& out) {
  if constexpr (std::is_invocable_v<const Op&, const Eigen::VectorX<T>&, Eigen::VectorX<T>&>)
    op(in, out);
  else
    out = op(in);
}

template <class T, class Op>
inline constexpr bool is_vector_operator_v =
    std::is_invocable_v<const Op&, const Eigen::VectorX<T>&, Eigen::VectorX<T>&> ||
    std::is_invocable_v<const Op&, const Eigen::VectorX<T>&>;
}  // namespace detail

/// Matrix-free PCG: solves A x = b with A given by apply_a and the preconditioner M^-1 by
/// precondition (both symmetric positive definite). x holds the initial guess on entry (reset to
/// zero if its size differs from b's) and the solution on exit.
template <class T, class ApplyA, class Precond,
          std::enable_if_t<detail::is_vector_operator_v<T, ApplyA>, int> = 0>
PcgResult<T> pcg(const ApplyA& apply_a, const Eigen::VectorX<T>& b, Eigen::VectorX<T>& x,
                 const Precond& precondition, const PcgOptions<T>& options = {}) {
  options.validate();
  const Eigen::Index n = b.size();
  if (x.size() != n) x = Eigen::VectorX<T>::Zero(n);
  PcgResult<T> result;
  const T b_norm = b.norm();
  if (b_norm == T(0)) {
    x.setZero();
    result.converged = true;
    return result;
  }
  Eigen::VectorX<T> r(n), z(n), p(n), q(n);
  detail::apply_operator(apply_a, x, q);
  r = b - q;
  result.relative_residual = r.norm() / b_norm;
  result.converged = result.relative_residual <= options.tolerance;
  if (result.converged) return result;

  detail::apply_operator(precondition, r, z);
  p = z;
  T rz = r.dot(z);
  while (result.iterations < options.max_iterations) {
    detail::apply_operator(apply_a, p, q);
    const T pq = p.dot(q);
    if (!(pq > T(0))) break;  // A is not positive definite along p: no progress possible
    const T alpha = rz / pq;
    x += alpha * p;
    r -= alpha * q;
    ++result.iterations;
    result.relative_residual = r.norm() / b_norm;
    if (result.relative_residual <= options.tolerance) {
      result.converged = true;
      break;
    }
    detail::apply_operator(precondition, r, z);
    const T rz_new = r.dot(z);
    p = z + (rz_new / rz) * p;
    rz = rz_new;
  }
  return result;
}

/// PCG on a sparse matrix (only A x products are used; A must be symmetric positive definite).
template <class T, class Precond>
PcgResult<T> pcg(const Eigen::SparseMatrix<T>& a, const Eigen::VectorX<T>& b, Eigen::VectorX<T>& x,
                 const Precond& precondition, const PcgOptions<T>& options = {}) {
  if (a.rows() != a.cols() || a.rows() != b.size()) {
    std::ostringstream msg;
    msg << "pcg: A is " << a.rows() << "x" << a.cols() << " and b has " << b.size()
        << " entries; expected a square A matching b";
    throw std::invalid_argument(msg.str());
  }
  const auto apply_a = [&a](const Eigen::VectorX<T>& in, Eigen::VectorX<T>& out) {
    out.noalias() = a * in;
  };
  return pcg(apply_a, b, x, precondition, options);
}

/// Plain conjugate gradients: pcg() with the identity preconditioner.
template <class T>
PcgResult<T> conjugate_gradient(const Eigen::SparseMatrix<T>& a, const Eigen::VectorX<T>& b,
                                Eigen::VectorX<T>& x, const PcgOptions<T>& options = {}) {
  return pcg(a, b, x, IdentityPreconditioner{}, options);
}

}  // namespace slurry::numerics
