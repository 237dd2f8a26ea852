#pragma once
/// \file integrators.h
/// One-step time integrators.
///
/// First-order systems y' = f(t, y), y a scalar or an Eigen vector, f(t, y) returning the same
/// type (Hairer, Norsett & Wanner, Solving ODEs I, 2nd ed., section II.1):
///   explicit Euler                 y1 = y0 + dt f(t0, y0)                                 order 1
///   Heun (explicit trapezoidal)    y1 = y0 + dt/2 (k1 + f(t0 + dt, y0 + dt k1))          order 2
///   explicit midpoint (RK2)        y1 = y0 + dt f(t0 + dt/2, y0 + dt/2 k1)                order 2
///   classical Runge-Kutta (RK4)                                                           order 4
///
/// Second-order mechanical systems M x'' = f(x, v) with a lumped (diagonal) mass, given as the
/// vector of its diagonal, and a state (x, v) of Eigen vectors:
///   explicit Euler       x1 = x0 + dt v0,  v1 = v0 + dt M^-1 f(x0, v0)
///   symplectic Euler     v1 = v0 + dt M^-1 f(x0, v0),  x1 = x0 + dt v1 (velocity first)
///                        (Hairer, Lubich & Wanner, Geometric Numerical Integration, 2nd ed., I.1)
///   improved Euler       Heun's method on the first-order form (x, v)' = (v, M^-1 f)
///   backward Euler       M (v1 - v0) = dt f(x0 + dt v1, v1), x1 = x0 + dt v1, by Newton's method
///                        with a Jacobian callable (user's, or finite_difference_jacobian())
///   linearly implicit    one Newton step of backward Euler from v0 (Baraff & Witkin, "Large steps
///   Euler                in cloth simulation", SIGGRAPH 1998, eq. 6):
///                        (M - dt df/dv - dt^2 df/dx) dv = dt (f0 + dt df/dx v0), v1 = v0 + dv
///   linear springs       f = -K (x - x_rest) - D v + f_ext, for which the above reads
///                        (M + dt^2 K + dt D) v1 = M v0 + dt (-K (x0 - x_rest) + f_ext),
///                        x1 = x0 + dt v1.
///
/// The implicit steps factorize a sparse matrix every call (SparseLU, or SimplicialLDLT for the
/// symmetric linear-spring system) and throw std::domain_error when it is singular.
#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <Eigen/SparseLU>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>
#include <vector>

namespace slurry::numerics {

// ---------------------------------------------------------------------------------------------
// First-order systems y' = f(t, y)
// ---------------------------------------------------------------------------------------------

/// One explicit Euler step from (t, y).
template <class T, class Y, class F>
Y euler_step(const F& f, T t, const Y& y, T dt) {
  const Y k1 = f(t, y);
  return Y(y + dt * k1);
}

/// One step of Heun's method (explicit trapezoidal rule) from (t, y).
template <class T, class Y, class F>
Y heun_step(const F& f, T t, const Y& y, T dt) {
  const Y k1 = f(t, y);
  const Y y_pred = y + dt * k1;
  const Y k2 = f(t + dt, y_pred);
  return Y(y + (dt / T(2)) * (k1 + k2));
}

/// One step of the explicit midpoint rule (RK2) from (t, y).
template <class T, class Y, class F>
Y midpoint_step(const F& f, T t, const Y& y, T dt) {
  const Y k1 = f(t, y);
  const Y y_half = y + (dt / T(2)) * k1;
  const Y k2 = f(t + dt / T(2), y_half);
  return Y(y + dt * k2);
}

/// One step of the classical fourth-order Runge-Kutta method from (t, y).
template <class T, class Y, class F>
Y rk4_step(const F& f, T t, const Y& y, T dt) {
  const T half = dt / T(2);
  const Y k1 = f(t, y);
  const Y y2 = y + half * k1;
  const Y k2 = f(t + half, y2);
  const Y y3 = y + half * k2;
  const Y k3 = f(t + half, y3);
  const Y y4 = y + dt * k3;
  const Y k4 = f(t + dt, y4);
  return Y(y + (dt / T(6)) * (k1 + T(2) * k2 + T(2) * k3 + k4));
}

// ---------------------------------------------------------------------------------------------
// Second-order mechanical systems M x'' = f(x, v)
// ---------------------------------------------------------------------------------------------

/// Positions and velocities of a mechanical system.
template <class T>
struct MechanicalState {
  Eigen::VectorX<T> x;
  Eigen::VectorX<T> v;
};

/// Jacobians of the force at a state; sparse because forces couple few degrees of freedom.
template <class T>
struct ForceJacobian {
  Eigen::SparseMatrix<T> dfdx;
  Eigen::SparseMatrix<T> dfdv;
};

/// Newton iteration controls for backward_euler_step().
template <class T>
struct NewtonOptions {
  /// Converged when ||R(v)|| <= tolerance * ||R(v0)||, R the backward Euler residual.
  T tolerance = T(1e-10);
  int max_iterations = 20;
};

/// Outcome of an implicit step.
template <class T>
struct ImplicitStepResult {
  int newton_iterations = 0;
  T residual = T(0);  ///< ||R|| at return, relative to ||R(v0)|| (0 when R(v0) = 0)
  bool converged = false;
};

namespace detail {
template <class T>
void check_mechanical(const Eigen::VectorX<T>& mass, const MechanicalState<T>& s, const char* who) {
  if (s.x.size() != s.v.size() || mass.size() != s.x.size()) {
    std::ostringstream msg;
    msg << who << ": sizes x " << s.x.size() << ", v " << s.v.size() << ", mass " << mass.size()
        << "; expected equal";
    throw std::invalid_argument(msg.str());
  }
}

template <class T>
Eigen::SparseMatrix<T> diagonal_matrix(const Eigen::VectorX<T>& d) {
  Eigen::SparseMatrix<T> m(d.size(), d.size());
  std::vector<Eigen::Triplet<T>> t;
  t.reserve(static_cast<size_t>(d.size()));
  for (Eigen::Index i = 0; i < d.size(); ++i) t.emplace_back(i, i, d[i]);
  m.setFromTriplets(t.begin(), t.end());
  return m;
}

/// Solves a general sparse system; throws when the matrix is singular.
template <class T>
Eigen::VectorX<T> sparse_lu_solve(const Eigen::SparseMatrix<T>& a, const Eigen::VectorX<T>& b,
                                  const char* who) {
  Eigen::SparseLU<Eigen::SparseMatrix<T>> lu;
  lu.compute(a);
  if (lu.info() != Eigen::Success) {
    std::ostringstream msg;
    msg << who << ": the implicit system matrix is singular (" << lu.lastErrorMessage() << ")";
    throw std::domain_error(msg.str());
  }
  return lu.solve(b);
}
}  // namespace detail

/// Explicit (forward) Euler on the mechanical system; shown for comparison: on an undamped
/// oscillator it gains energy every step for any dt.
template <class T, class Force>
void explicit_euler_step(const Force& force, const Eigen::VectorX<T>& mass, MechanicalState<T>& s,
                         T dt) {
  const Eigen::VectorX<T> a = force(s.x, s.v).cwiseQuotient(mass);
  s.x += dt * s.v;
  s.v += dt * a;
}

/// Symplectic Euler, velocity first: v1 = v0 + dt M^-1 f(x0, v0), x1 = x0 + dt v1.
/// On x'' = -omega^2 x it is stable exactly for dt < 2 / omega and keeps the energy error bounded.
template <class T, class Force>
void symplectic_euler_step(const Force& force, const Eigen::VectorX<T>& mass, MechanicalState<T>& s,
                           T dt) {
  s.v += dt * force(s.x, s.v).cwiseQuotient(mass);
  s.x += dt * s.v;
}

/// Improved Euler: Heun's method on (x, v)' = (v, M^-1 f(x, v)). Second order; on an undamped
/// oscillator its energy grows by the factor 1 + (omega dt)^4 / 4 every step.
template <class T, class Force>
void improved_euler_step(const Force& force, const Eigen::VectorX<T>& mass, MechanicalState<T>& s,
                         T dt) {
  const Eigen::VectorX<T> a0 = force(s.x, s.v).cwiseQuotient(mass);
  const Eigen::VectorX<T> x_pred = s.x + dt * s.v;
  const Eigen::VectorX<T> v_pred = s.v + dt * a0;
  const Eigen::VectorX<T> a1 = force(x_pred, v_pred).cwiseQuotient(mass);
  s.x += (dt / T(2)) * (s.v + v_pred);
  s.v += (dt / T(2)) * (a0 + a1);
}

/// A Jacobian callable for forces without an analytic one: central differences of `force` with
/// step eps * max(1, |component|), assembled densely then stored sparse (zeros dropped).
/// Costs 4 n force evaluations: meant for small systems and for testing analytic Jacobians.
template <class T, class Force>
auto finite_difference_jacobian(const Force& force, T eps = T(1e-6)) {
  return [force, eps](const Eigen::VectorX<T>& x, const Eigen::VectorX<T>& v) {
    const Eigen::Index n = x.size();
    std::vector<Eigen::Triplet<T>> tx, tv;
    for (Eigen::Index j = 0; j < n; ++j) {
      Eigen::VectorX<T> xp = x, xm = x, vp = v, vm = v;
      const T hx = eps * std::max(T(1), std::abs(x[j]));
      const T hv = eps * std::max(T(1), std::abs(v[j]));
      xp[j] += hx;
      xm[j] -= hx;
      vp[j] += hv;
      vm[j] -= hv;
      const Eigen::VectorX<T> cx = (force(xp, v) - force(xm, v)) / (T(2) * hx);
      const Eigen::VectorX<T> cv = (force(x, vp) - force(x, vm)) / (T(2) * hv);
      for (Eigen::Index i = 0; i < n; ++i) {
        if (cx[i] != T(0)) tx.emplace_back(i, j, cx[i]);
        if (cv[i] != T(0)) tv.emplace_back(i, j, cv[i]);
      }
    }
    ForceJacobian<T> jac;
    jac.dfdx.resize(n, n);
    jac.dfdv.resize(n, n);
    jac.dfdx.setFromTriplets(tx.begin(), tx.end());
    jac.dfdv.setFromTriplets(tv.begin(), tv.end());
    return jac;
  };
}

/// Backward Euler: solves R(v1) = M (v1 - v0) - dt f(x0 + dt v1, v1) = 0 by Newton's method from
/// v1 = v0, with dR/dv1 = M - dt^2 df/dx - dt df/dv from jacobian(x, v) -> ForceJacobian<T>;
/// then x1 = x0 + dt v1. Updates s (also when Newton did not converge; check the result).
template <class T, class Force, class Jacobian>
ImplicitStepResult<T> backward_euler_step(const Force& force, const Jacobian& jacobian,
                                          const Eigen::VectorX<T>& mass, MechanicalState<T>& s,
                                          T dt, const NewtonOptions<T>& options = {}) {
  detail::check_mechanical(mass, s, "backward_euler_step");
  const Eigen::SparseMatrix<T> m = detail::diagonal_matrix(mass);
  const Eigen::VectorX<T> x0 = s.x;
  const Eigen::VectorX<T> v0 = s.v;
  Eigen::VectorX<T> v = v0;
  const auto residual = [&](const Eigen::VectorX<T>& vv) -> Eigen::VectorX<T> {
    return mass.cwiseProduct(vv - v0) - dt * force(x0 + dt * vv, vv);
  };
  Eigen::VectorX<T> r = residual(v);
  const T r0 = r.norm();
  ImplicitStepResult<T> result;
  result.converged = r0 == T(0);
  while (!result.converged && result.newton_iterations < options.max_iterations) {
    const Eigen::VectorX<T> x = x0 + dt * v;
    const ForceJacobian<T> jac = jacobian(x, v);
    const Eigen::SparseMatrix<T> dr = m - (dt * dt) * jac.dfdx - dt * jac.dfdv;
    v -= detail::sparse_lu_solve<T>(dr, r, "backward_euler_step");
    r = residual(v);
    ++result.newton_iterations;
    result.residual = r.norm() / r0;
    result.converged = result.residual <= options.tolerance;
  }
  s.v = v;
  s.x = x0 + dt * v;
  return result;
}

/// Linearly implicit Euler for a general force: one Newton step of backward Euler with the
/// Jacobians at the current state (Baraff & Witkin 1998):
/// (M - dt df/dv - dt^2 df/dx) dv = dt (f(x0, v0) + dt df/dx v0); v1 = v0 + dv; x1 = x0 + dt v1.
template <class T, class Force, class Jacobian>
void linearly_implicit_euler_step(const Force& force, const Jacobian& jacobian,
                                  const Eigen::VectorX<T>& mass, MechanicalState<T>& s, T dt) {
  detail::check_mechanical(mass, s, "linearly_implicit_euler_step");
  const ForceJacobian<T> jac = jacobian(s.x, s.v);
  const Eigen::SparseMatrix<T> a =
      detail::diagonal_matrix(mass) - dt * jac.dfdv - (dt * dt) * jac.dfdx;
  const Eigen::VectorX<T> rhs = dt * (force(s.x, s.v) + dt * (jac.dfdx * s.v));
  s.v += detail::sparse_lu_solve<T>(a, rhs, "linearly_implicit_euler_step");
  s.x += dt * s.v;
}

/// Linearly implicit Euler for linear springs f = -K (x - x_rest) - D v + f_ext with symmetric
/// positive semidefinite K and D: (M + dt^2 K + dt D) v1 = M v0 + dt (-K (x0 - x_rest) + f_ext),
/// x1 = x0 + dt v1. The matrix is SPD, so it is solved by sparse LDLT. Exact backward Euler for
/// this linear force: unconditionally stable.
template <class T>
void linear_spring_implicit_euler_step(const Eigen::VectorX<T>& mass,
                                       const Eigen::SparseMatrix<T>& stiffness,
                                       const Eigen::SparseMatrix<T>& damping,
                                       const Eigen::VectorX<T>& x_rest,
                                       const Eigen::VectorX<T>& f_ext, MechanicalState<T>& s,
                                       T dt) {
  detail::check_mechanical(mass, s, "linear_spring_implicit_euler_step");
  const Eigen::Index n = s.x.size();
  if (stiffness.rows() != n || stiffness.cols() != n || damping.rows() != n ||
      damping.cols() != n || x_rest.size() != n || f_ext.size() != n) {
    std::ostringstream msg;
    msg << "linear_spring_implicit_euler_step: K is " << stiffness.rows() << "x" << stiffness.cols()
        << ", D is " << damping.rows() << "x" << damping.cols() << ", x_rest has " << x_rest.size()
        << " and f_ext " << f_ext.size() << " entries; expected " << n << " (the state size)";
    throw std::invalid_argument(msg.str());
  }
  const Eigen::SparseMatrix<T> a =
      detail::diagonal_matrix(mass) + (dt * dt) * stiffness + dt * damping;
  const Eigen::VectorX<T> rhs = mass.cwiseProduct(s.v) + dt * (f_ext - stiffness * (s.x - x_rest));
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<T>> ldlt(a);
  if (ldlt.info() != Eigen::Success)
    throw std::domain_error(
        "linear_spring_implicit_euler_step: M + dt^2 K + dt D is not positive definite; "
        "expected K and D symmetric positive semidefinite and positive masses");
  s.v = ldlt.solve(rhs);
  s.x += dt * s.v;
}

}  // namespace slurry::numerics
