#pragma once
/// \file svd.h
/// Rotation-variant singular value decomposition and polar decomposition of 2x2 and 3x3
/// matrices, for float and double, written for the MPM hot path (one call per particle per step).
///
/// Convention (Irving, Teran and Fedkiw 2004, "Invertible finite elements for robust simulation
/// of large deformation"): F = U diag(sigma) V^T with det U = det V = +1 and
/// sigma_0 >= sigma_1 >= |sigma_last|. Only the last (smallest) singular value may be negative,
/// and it is negative exactly when det F < 0, so that an inverted element is reported as a
/// reflection along its weakest direction rather than as an improper U or V.
///
/// 2x2: closed form, from writing F as the sum of a scaled rotation and a scaled reflection.
///
/// 3x3: the structure of McAdams, Selle, Tamstorf, Teran and Sifakis 2011, "Computing the
/// singular value decomposition of 3x3 matrices with minimal branching and elementary floating
/// point operations" -- eigenvectors V of F^T F, then a QR factorisation of F V whose diagonal
/// gives the signed singular values -- but with a non-iterative eigensolver instead of their
/// Jacobi sweeps (see detail::sym_eigen3). We measured McAdams' approximate Jacobi angles to need
/// 6 (float) and 7 (double) sweeps to reach round-off on the worst of 1e5 random matrices, and
/// exact Jacobi angles 4 sweeps; the direct solver is about twice as fast as the latter at the
/// same accuracy (about 120 against 210 ns per float SVD on one core during development;
/// benchmarks/bench_svd.cpp compares with Eigen::JacobiSVD). The QR is Gram-Schmidt with u2 = u0 x
/// u1, and a final closed-form 2x2 SVD on the two smallest columns restores accuracy when those two
/// singular values are both far below the largest (where F^T F cannot resolve them).
///
/// Accuracy (tests/constitutive/svd_test.cpp): ||U diag(sigma) V^T - F|| <= ~1e-15 ||F|| in
/// double and ~2e-6 ||F|| in float, including singular, rank-1, nearly singular, inverted and
/// repeated-singular-value inputs. Inputs are assumed finite, with entries in about
/// [1e-8, 1e8] (float) or [1e-70, 1e70] (double) so that the squares in F^T F stay normal;
/// deformation gradients are far inside that.
#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <utility>

namespace slurry::constitutive {

/// Rotation-variant SVD of a 2x2 matrix, closed form: F = U diag(sigma) V^T, see file comment.
///
/// With e = (F00+F11)/2, h = (F10-F01)/2, f = (F00-F11)/2, g = (F10+F01)/2, F is the sum of the
/// scaled rotation q Rot(a2), (q cos a2, q sin a2) = (e, h), and the scaled reflection
/// r Refl(a1), (r cos a1, r sin a1) = (f, g). Then U = Rot((a1+a2)/2), V = Rot((a1-a2)/2),
/// sigma = (q + r, q - r); q - r < 0 exactly when det F = q^2 - r^2 < 0.
///
/// Never inlined: GCC fuses multiply-adds (-ffp-contract=fast) differently in different callers,
/// and 2D snow frames changed bits whenever a change elsewhere made GCC inline this function
/// into SnowPlasticity::project_by_svd or stop doing so. One out-of-line copy keeps the same
/// roundings for every caller.
template <class T>
__attribute__((noinline)) void svd(const Eigen::Matrix<T, 2, 2>& F, Eigen::Matrix<T, 2, 2>& U,
                                   Eigen::Matrix<T, 2, 1>& sigma, Eigen::Matrix<T, 2, 2>& V) {
  using std::sqrt;
  const T e = T(0.5) * (F(0, 0) + F(1, 1));
  const T f = T(0.5) * (F(0, 0) - F(1, 1));
  const T g = T(0.5) * (F(1, 0) + F(0, 1));
  const T h = T(0.5) * (F(1, 0) - F(0, 1));
  const T q = sqrt(e * e + h * h);
  const T r = sqrt(f * f + g * g);
  // Unit directions of the rotation and reflection parts. Either part may be absent (q or r = 0);
  // its angle is then arbitrary and 0 is as good as any.
  const T iq = q > T(0) ? T(1) / q : T(0);
  const T ir = r > T(0) ? T(1) / r : T(0);
  const T c2 = q > T(0) ? e * iq : T(1), s2 = h * iq;
  const T c1 = r > T(0) ? f * ir : T(1), s1 = g * ir;
  // (cw, sw) = (cos, sin) of a1 - a2 = 2v. The half angle v is the direction of (1 + cw, sw),
  // and also of (sw, 1 - cw); take the one without cancellation. Getting v + pi instead of v is
  // harmless because U is built from V below.
  const T cw = c1 * c2 + s1 * s2;
  const T sw = s1 * c2 - c1 * s2;
  const T x = cw >= T(0) ? T(1) + cw : sw;
  const T y = cw >= T(0) ? sw : T(1) - cw;
  const T inv = T(1) / sqrt(x * x + y * y);  // x^2 + y^2 >= 1
  const T cv = x * inv, sv = y * inv;
  // u = a2 + v keeps U V^T = Rot(a2) exact up to rounding.
  const T cu = c2 * cv - s2 * sv, su = s2 * cv + c2 * sv;
  U << cu, -su, su, cu;
  V << cv, -sv, sv, cv;
  sigma(0) = q + r;
  // det / sigma_0 rather than q - r: keeps a small singular value relatively accurate when the
  // entries are (e.g. F = diag(1, 1e-8)).
  const T det = F(0, 0) * F(1, 1) - F(0, 1) * F(1, 0);
  sigma(1) = sigma(0) > T(0) ? det / sigma(0) : T(0);
}

namespace detail {

/// Jacobi rotation (c, s) = (cos t, sin t) that diagonalises the symmetric 2x2 matrix
/// [[app, apq], [apq, aqq]]: with G = [[c, -s], [s, c]], G^T A G is diagonal. The angle solves
/// tan(2t) = 2 apq / (app - aqq), |t| <= pi/4, and (c, s) is the normalised half-angle vector
/// (r + |x|, +-y) of (x, y) = (app - aqq, 2 apq), r = |(x, y)|, whose squared length is
/// 2 r (r + |x|): no trigonometry and no cancellation (Golub and Van Loan, "Matrix computations",
/// the 2x2 symmetric Schur decomposition). Returns c = 1, s = 0 when apq is negligible, where the
/// squares would underflow.
template <class T>
inline void jacobi_rotation(T app, T aqq, T apq, T& c, T& s) {
  using std::abs;
  using std::sqrt;
  constexpr T kTiny = std::numeric_limits<T>::epsilon() * std::numeric_limits<T>::epsilon();
  const bool rotate = abs(apq) > kTiny * (abs(app) + abs(aqq));
  const T x = rotate ? app - aqq : T(1);
  const T y = rotate ? T(2) * apq : T(0);
  const T r = sqrt(x * x + y * y);
  const T d = r + abs(x);
  const T k = T(1) / sqrt(T(2) * r * d);
  c = d * k;
  s = (x >= T(0) ? y : -y) * k;
}

/// Right-handed orthonormal basis (u, w) of the plane orthogonal to the unit vector v, without
/// branches or square roots: Duff, Burgess, Christensen, Hery, Kensler, Liani and Villemin 2017,
/// "Building an orthonormal basis, revisited", JCGT 6(1).
template <class T>
inline void orthonormal_basis(const Eigen::Matrix<T, 3, 1>& v, Eigen::Matrix<T, 3, 1>& u,
                              Eigen::Matrix<T, 3, 1>& w) {
  const T sg = std::copysign(T(1), v(2));
  const T a = T(-1) / (sg + v(2));
  const T b = v(0) * v(1) * a;
  u = Eigen::Matrix<T, 3, 1>(T(1) + sg * v(0) * v(0) * a, sg * b, -sg * v(0));
  w = Eigen::Matrix<T, 3, 1>(b, sg + v(1) * v(1) * a, -v(1));
}

template <class T>
inline Eigen::Matrix<T, 3, 1> cross(const Eigen::Matrix<T, 3, 1>& a,
                                    const Eigen::Matrix<T, 3, 1>& b) {
  return Eigen::Matrix<T, 3, 1>(a(1) * b(2) - a(2) * b(1), a(2) * b(0) - a(0) * b(2),
                                a(0) * b(1) - a(1) * b(0));
}

/// Eigenvectors of the symmetric 3x3 matrix A (entries a_ij), as the columns of the rotation V,
/// ordered by decreasing eigenvalue (ties in any order).
///
/// Non-iterative, after D. Eberly, "A robust eigensolver for 3x3 symmetric matrices" (Geometric
/// Tools, 2014): with C = (A - q I)/p, q = tr(A)/3, p^2 = tr((A - qI)^2)/6, the eigenvalues of C
/// are 2 cos(acos(det(C)/2)/3 + 2 pi k/3) (O. K. Smith 1961, CACM 4(4):168). Only the one
/// farthest from the other two is used -- the largest if det C >= 0, else the smallest; it is
/// at least sqrt(3) away from both, so it is computed to round-off even when the other two
/// coincide. Its eigenvector is the largest cross product of two rows of C - lambda I. The other
/// two eigenvectors are those of the 2x2 restriction of C to the orthogonal plane, found with one
/// exact Jacobi rotation, which stays accurate when their eigenvalues are equal or close.
/// Every residual ||A v - lambda v|| is therefore O(eps ||A||), which is all the SVD needs.
template <class T>
inline void sym_eigen3(T a00, T a11, T a22, T a01, T a02, T a12, Eigen::Matrix<T, 3, 3>& V) {
  using Vec = Eigen::Matrix<T, 3, 1>;
  using std::abs;
  using std::sqrt;
  constexpr T kEps = std::numeric_limits<T>::epsilon();
  const T q = (a00 + a11 + a22) / T(3);
  // The rounded q can leave tr(A - qI) at a few ulps of q. That is harmless when the spread p
  // below is large, but when A is the identity to a few ulps (a deformation gradient at rest)
  // the leftover trace is as large as p itself, and the trigonometric formula, which assumes
  // tr C = 0, then returns an eigenvalue with no eigenvector (C - lambda I of full rank, all
  // row cross products zero): NaN. Removing the leftover mean keeps C traceless to round-off.
  const T t = ((a00 - q) + (a11 - q) + (a22 - q)) / T(3);
  const T b00 = (a00 - q) - t, b11 = (a11 - q) - t, b22 = (a22 - q) - t;
  const T p2 =
      (b00 * b00 + b11 * b11 + b22 * b22 + T(2) * (a01 * a01 + a02 * a02 + a12 * a12)) / T(6);
  const T p = sqrt(p2);
  // A is a multiple of the identity to round-off: every orthonormal V is an eigenbasis.
  if (!(p > kEps * kEps * abs(q)) || !(p2 > std::numeric_limits<T>::min())) {
    V.setIdentity();
    return;
  }
  const T ip = T(1) / p;
  const T c00 = b00 * ip, c11 = b11 * ip, c22 = b22 * ip;
  const T c01 = a01 * ip, c02 = a02 * ip, c12 = a12 * ip;
  const T half_det = T(0.5) * (c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02) +
                               c02 * (c01 * c12 - c11 * c02));
  const bool smallest = half_det < T(0);  // the isolated eigenvalue is the smallest one
  const T ra = std::fmin(abs(half_det), T(1));
  const T lambda = std::copysign(T(2) * std::cos(std::acos(ra) / T(3)), half_det);

  // Eigenvector of the isolated eigenvalue: C - lambda I has rank 2; pick the best-conditioned
  // cross product of its rows (selects, not branches: the choice is data-dependent).
  const Vec m0(c00 - lambda, c01, c02), m1(c01, c11 - lambda, c12), m2(c02, c12, c22 - lambda);
  const Vec x01 = cross(m0, m1), x02 = cross(m0, m2), x12 = cross(m1, m2);
  const T n01 = x01.squaredNorm(), n02 = x02.squaredNorm(), n12 = x12.squaredNorm();
  const bool pick01 = n01 >= n02 && n01 >= n12;
  const bool pick02 = !pick01 && n02 >= n12;
  const T nv = pick01 ? n01 : (pick02 ? n02 : n12);
  // C - lambda I has rank 2, so some cross product is O(1); a zero one means C was round-off
  // noise after all (A a multiple of the identity), where any basis is an eigenbasis.
  if (!(nv > kEps * kEps)) {
    V.setIdentity();
    return;
  }
  const T inv_len = T(1) / sqrt(nv);
  Vec v;
  for (int i = 0; i < 3; ++i) v(i) = (pick01 ? x01(i) : (pick02 ? x02(i) : x12(i))) * inv_len;

  // The other two: 2x2 eigenproblem of C restricted to span(u, w) = v^perp.
  Vec u, w;
  orthonormal_basis(v, u, w);
  const Vec Cw(c00 * w(0) + c01 * w(1) + c02 * w(2), c01 * w(0) + c11 * w(1) + c12 * w(2),
               c02 * w(0) + c12 * w(1) + c22 * w(2));
  const Vec Cu(c00 * u(0) + c01 * u(1) + c02 * u(2), c01 * u(0) + c11 * u(1) + c12 * u(2),
               c02 * u(0) + c12 * u(1) + c22 * u(2));
  const T muu = u.dot(Cu), mww = w.dot(Cw), muw = u.dot(Cw);
  T c, s;
  jacobi_rotation(muu, mww, muw, c, s);
  // (Rayleigh quotient along c u + s w) - (along -s u + c w).
  const bool first_larger = (c * c - s * s) * (muu - mww) + T(4) * c * s * muw >= T(0);
  const T cb = first_larger ? c : -s, sb = first_larger ? s : c;
  const Vec larger = cb * u + sb * w, smaller = -sb * u + cb * w;
  for (int i = 0; i < 3; ++i) {
    V(i, 0) = smallest ? larger(i) : v(i);
    V(i, 1) = smallest ? smaller(i) : larger(i);
  }
  V.col(2) = cross<T>(V.col(0), V.col(1));
}

/// Swap columns i and j of B and V and negate the new column j: keeps B = F V and det V = +1.
template <class T>
inline void swap_columns(Eigen::Matrix<T, 3, 3>& B, Eigen::Matrix<T, 3, 3>& V, T& ni, T& nj, int i,
                         int j) {
  const Eigen::Matrix<T, 3, 1> bi = B.col(i), vi = V.col(i);
  B.col(i) = B.col(j);
  B.col(j) = -bi;
  V.col(i) = V.col(j);
  V.col(j) = -vi;
  std::swap(ni, nj);
}

}  // namespace detail

/// Rotation-variant SVD of a 3x3 matrix: F = U diag(sigma) V^T, see the file comment.
template <class T>
inline void svd(const Eigen::Matrix<T, 3, 3>& F, Eigen::Matrix<T, 3, 3>& U,
                Eigen::Matrix<T, 3, 1>& sigma, Eigen::Matrix<T, 3, 3>& V) {
  using Vec = Eigen::Matrix<T, 3, 1>;
  using std::abs;
  using std::sqrt;
  constexpr T kEps = std::numeric_limits<T>::epsilon();

  // 1. F^T F = V diag(sigma^2) V^T.
  detail::sym_eigen3(F.col(0).squaredNorm(), F.col(1).squaredNorm(), F.col(2).squaredNorm(),
                     F.col(0).dot(F.col(1)), F.col(0).dot(F.col(2)), F.col(1).dot(F.col(2)), V);

  // 2. B = F V has orthogonal columns of lengths |sigma_i|. V is already ordered, so these
  //    swaps only repair ties broken the other way by round-off (and are rarely taken).
  Eigen::Matrix<T, 3, 3> B = F * V;
  T n0 = B.col(0).squaredNorm(), n1 = B.col(1).squaredNorm(), n2 = B.col(2).squaredNorm();
  if (n0 < n1) detail::swap_columns(B, V, n0, n1, 0, 1);
  if (n0 < n2) detail::swap_columns(B, V, n0, n2, 0, 2);
  if (n1 < n2) detail::swap_columns(B, V, n1, n2, 1, 2);

  // 3. QR of B by Gram-Schmidt with u2 = u0 x u1, so det U = +1 and the sign of det F lands on
  //    sigma_2 (det V = +1 already).
  if (!(n0 > T(0))) {  // F = 0
    U.setIdentity();
    sigma.setZero();
    return;
  }
  const T s0 = sqrt(n0);
  const Vec u0 = B.col(0) / s0;
  Vec w = B.col(1) - u0.dot(B.col(1)) * u0;
  // Project twice ("twice is enough", Giraud, Langou and Rozloznik 2005): when
  // sigma_1 << eps sigma_0, b1 is mostly round-off along u0 and one pass leaves w visibly
  // non-orthogonal to u0.
  w -= u0.dot(w) * u0;
  const T s1 = w.norm();
  Vec u1;
  if (s1 > kEps * kEps * s0) {
    u1 = w / s1;
  } else {  // rank 1: b1 is round-off and any direction orthogonal to u0 will do
    Vec unused;
    detail::orthonormal_basis(u0, u1, unused);
  }
  const Vec u2 = detail::cross(u0, u1);
  U.col(0) = u0;
  U.col(1) = u1;
  U.col(2) = u2;
  sigma(0) = s0;
  sigma(1) = s1;
  sigma(2) = u2.dot(B.col(2));

  // 4. F^T F holds sigma_1^2 and sigma_2^2 only to ~eps sigma_0^2, so when both are << sigma_0
  //    the coupling r12 = u1 . b2 that QR drops can exceed eps sigma_0. Then finish the 2x2
  //    block [[sigma_1, r12], [0, sigma_2]] with the closed form. The same step also restores
  //    the order when sigma_1 and sigma_2 are both round-off and came out the wrong way round.
  const T r12 = u1.dot(B.col(2));
  if (abs(r12) > T(4) * kEps * s0 || abs(sigma(2)) > sigma(1)) {
    Eigen::Matrix<T, 2, 2> M, P, Q;
    Eigen::Matrix<T, 2, 1> t;
    M << sigma(1), r12, T(0), sigma(2);
    svd(M, P, t, Q);
    const Eigen::Matrix<T, 3, 2> Ub = U.template rightCols<2>() * P;
    const Eigen::Matrix<T, 3, 2> Vb = V.template rightCols<2>() * Q;
    U.template rightCols<2>() = Ub;
    V.template rightCols<2>() = Vb;
    sigma(1) = t(0);
    sigma(2) = t(1);
  }
}

/// Rotation-variant polar decomposition F = R S, R = U V^T a rotation (det R = +1), and
/// S = V diag(sigma) V^T symmetric (indefinite when det F < 0). 2x2: closed form, R is the
/// rotation by atan2(F10 - F01, F00 + F11), the one that maximises tr(R^T F).
template <class T>
inline void polar(const Eigen::Matrix<T, 2, 2>& F, Eigen::Matrix<T, 2, 2>& R,
                  Eigen::Matrix<T, 2, 2>& S) {
  using std::sqrt;
  const T e = F(0, 0) + F(1, 1), h = F(1, 0) - F(0, 1);
  const T q = sqrt(e * e + h * h);
  const T iq = q > T(0) ? T(1) / q : T(0);
  const T c = q > T(0) ? e * iq : T(1), s = h * iq;
  R << c, -s, s, c;
  const Eigen::Matrix<T, 2, 2> RtF = R.transpose() * F;
  S(0, 0) = RtF(0, 0);
  S(1, 1) = RtF(1, 1);
  S(0, 1) = S(1, 0) =
      T(0.5) * (RtF(0, 1) + RtF(1, 0));  // symmetric by construction, up to rounding
}

/// Rotation-variant polar decomposition F = R S of a 3x3 matrix, from svd().
template <class T>
inline void polar(const Eigen::Matrix<T, 3, 3>& F, Eigen::Matrix<T, 3, 3>& R,
                  Eigen::Matrix<T, 3, 3>& S) {
  Eigen::Matrix<T, 3, 3> U, V;
  Eigen::Matrix<T, 3, 1> sigma;
  svd(F, U, sigma, V);
  R.noalias() = U * V.transpose();
  S.noalias() = V * sigma.asDiagonal() * V.transpose();
}

}  // namespace slurry::constitutive
