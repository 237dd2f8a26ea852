#pragma once
/// \file svd_lanes.h
/// The rotation-variant 3x3 SVD of svd.h for W matrices at once, one per SIMD lane (lanes.h):
/// every scalar of svd.h's algorithm becomes a lane value, and every data-dependent branch a
/// per-lane select, so one call decomposes 16 float (or 8 double) matrices in packet
/// instructions. For the MPM hot path, where the scalar svd() costs about 130 ns per float
/// matrix on one core (benchmarks/bench_svd.cpp compares the two).
///
/// Same algorithm and conventions as svd.h: F = U diag(sigma) V^T, det U = det V = +1,
/// sigma_0 >= sigma_1 >= |sigma_2|, sigma_2 < 0 exactly when det F < 0; the structure of
/// McAdams, Selle, Tamstorf, Teran and Sifakis 2011 (eigenvectors of F^T F, then QR of F V) with
/// the non-iterative eigensolver of D. Eberly, "A robust eigensolver for 3x3 symmetric matrices"
/// (Geometric Tools, 2014). One step differs: the isolated eigenvalue 2 cos(acos(r)/3) of the
/// normalised deviator (O. K. Smith 1961), which is the largest root t of t^3 - 3t = 2r on
/// [sqrt(3), 2] for r in [0, 1], is found by Newton's method instead of acos and cos (Eigen has
/// no packet acos). The start t0 = sqrt(3) + r/3 + (2 - sqrt(3) - 1/3) r^2 matches the root's
/// value at both ends and its slope 1/3 at r = 0, and is within 3.4e-3 of it; Newton's error
/// then falls to 8e-6, 5e-11 and 2e-16 (f'' / 2f' < 1 on the interval), so 2 steps suffice
/// for float and 3 for double. Results agree with svd() to round-off, not bitwise.
///
/// Accuracy (tests/constitutive/svd_test.cpp, the cases with lanes = true): the same bounds as
/// svd.h, on the same hard inputs (singular, rank 1, inverted, repeated singular values, zero).
///
/// Also left_eigen(): U and the squared singular values alone, from the eigenvectors of F F^T,
/// for the batched Drucker-Prager return mapping (plasticity.h), which needs no V.
#include <Eigen/Core>

#include <limits>

#include "lanes.h"

namespace slurry::constitutive::lanes {

/// W 3-vectors, component-major.
template <class T, int W>
struct Vec3 {
  Lane<T, W> c[3];
};

/// W 3x3 matrices: a[i][j] holds entry (i, j) of each.
template <class T, int W>
struct Mat3 {
  Lane<T, W> a[3][3];

  Vec3<T, W> col(int j) const { return {{a[0][j], a[1][j], a[2][j]}}; }
  void set_col(int j, const Vec3<T, W>& v) {
    for (int i = 0; i < 3; ++i) a[i][j] = v.c[i];
  }
  /// Lane l as an Eigen matrix, and back.
  Eigen::Matrix<T, 3, 3> get(int l) const {
    Eigen::Matrix<T, 3, 3> m;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) m(i, j) = a[i][j][l];
    return m;
  }
  void put(int l, const Eigen::Matrix<T, 3, 3>& m) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) a[i][j][l] = m(i, j);
  }
};

namespace detail {

template <class T, int W>
inline Lane<T, W> dot(const Vec3<T, W>& a, const Vec3<T, W>& b) {
  return a.c[0] * b.c[0] + a.c[1] * b.c[1] + a.c[2] * b.c[2];
}
template <class T, int W>
inline Vec3<T, W> cross(const Vec3<T, W>& a, const Vec3<T, W>& b) {
  return {{a.c[1] * b.c[2] - a.c[2] * b.c[1], a.c[2] * b.c[0] - a.c[0] * b.c[2], a.c[0] * b.c[1] - a.c[1] * b.c[0]}};
}
template <class T, int W>
inline Vec3<T, W> scaled(const Lane<T, W>& s, const Vec3<T, W>& v) {
  return {{s * v.c[0], s * v.c[1], s * v.c[2]}};
}
/// a u + b v.
template <class T, int W>
inline Vec3<T, W> combine(const Lane<T, W>& a, const Vec3<T, W>& u, const Lane<T, W>& b, const Vec3<T, W>& v) {
  return {{a * u.c[0] + b * v.c[0], a * u.c[1] + b * v.c[1], a * u.c[2] + b * v.c[2]}};
}
/// v - s u.
template <class T, int W>
inline Vec3<T, W> minus_scaled(const Vec3<T, W>& v, const Lane<T, W>& s, const Vec3<T, W>& u) {
  return {{v.c[0] - s * u.c[0], v.c[1] - s * u.c[1], v.c[2] - s * u.c[2]}};
}
template <class T, int W>
inline Vec3<T, W> select(const Mask<T, W>& m, const Vec3<T, W>& a, const Vec3<T, W>& b) {
  return {{lanes::select(m, a.c[0], b.c[0]), lanes::select(m, a.c[1], b.c[1]), lanes::select(m, a.c[2], b.c[2])}};
}

/// svd.h's detail::jacobi_rotation, per lane.
template <class T, int W>
inline void jacobi_rotation(const Lane<T, W>& app, const Lane<T, W>& aqq, const Lane<T, W>& apq, Lane<T, W>& c,
                            Lane<T, W>& s) {
  using L = Lane<T, W>;
  constexpr T kTiny = std::numeric_limits<T>::epsilon() * std::numeric_limits<T>::epsilon();
  const Mask<T, W> rotate = gt(L(apq.abs()), L(kTiny * (app.abs() + aqq.abs())));
  const L x = select(rotate, L(app - aqq), T(1));
  const L y = select(rotate, L(T(2) * apq), T(0));
  const L r = lanes::sqrt(L(x * x + y * y));
  const L d = r + x.abs();
  const L k = lanes::sqrt(L(T(2) * r * d)).inverse();
  c = d * k;
  s = select(ge(x, T(0)), y, L(-y)) * k;
}

/// svd.h's detail::orthonormal_basis (Duff et al. 2017), per lane.
template <class T, int W>
inline void orthonormal_basis(const Vec3<T, W>& v, Vec3<T, W>& u, Vec3<T, W>& w) {
  using L = Lane<T, W>;
  const L sg = select(lt(v.c[2], T(0)), T(-1), T(1));
  const L a = T(-1) * (sg + v.c[2]).inverse();
  const L b = v.c[0] * v.c[1] * a;
  u = {{T(1) + sg * v.c[0] * v.c[0] * a, sg * b, -sg * v.c[0]}};
  w = {{b, sg + v.c[1] * v.c[1] * a, -v.c[1]}};
}

/// svd.h's detail::sym_eigen3 per lane, with the isolated eigenvalue by Newton's method (see the
/// file comment): eigenvectors of the symmetric A as the columns of the rotation V, by
/// decreasing eigenvalue.
template <class T, int W>
inline Mat3<T, W> sym_eigen3(const Lane<T, W>& a00, const Lane<T, W>& a11, const Lane<T, W>& a22,
                             const Lane<T, W>& a01, const Lane<T, W>& a02, const Lane<T, W>& a12) {
  using L = Lane<T, W>;
  using V3 = Vec3<T, W>;
  constexpr T kEps = std::numeric_limits<T>::epsilon();
  const L q = (a00 + a11 + a22) / T(3);
  const L t = ((a00 - q) + (a11 - q) + (a22 - q)) / T(3);  // see svd.h: keeps C traceless
  const L b00 = (a00 - q) - t, b11 = (a11 - q) - t, b22 = (a22 - q) - t;
  const L p2 = (b00 * b00 + b11 * b11 + b22 * b22 + T(2) * (a01 * a01 + a02 * a02 + a12 * a12)) / T(6);
  const L p = lanes::sqrt(p2);
  // Lanes where A is a multiple of the identity to round-off take V = I at the end; their
  // arithmetic below runs on C = 0 and stays finite.
  const Mask<T, W> spread = gt(p, L(kEps * kEps * q.abs())) & gt(p2, std::numeric_limits<T>::min());
  const L ip = select(spread, L(p.inverse()), T(0));
  const L c00 = b00 * ip, c11 = b11 * ip, c22 = b22 * ip;
  const L c01 = a01 * ip, c02 = a02 * ip, c12 = a12 * ip;
  const L half_det =
      T(0.5) * (c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02) + c02 * (c01 * c12 - c11 * c02));
  const Mask<T, W> smallest = lt(half_det, T(0));
  const L abs_det = half_det.abs();
  const L ra = select(lt(abs_det, T(1)), abs_det, T(1));
  // Largest root of t^3 - 3t = 2 ra: Newton from the quadratic start (file comment).
  constexpr double kSqrt3 = 1.7320508075688772935;
  L root = T(kSqrt3) + ra * (T(1.0 / 3.0) + ra * T(2.0 - kSqrt3 - 1.0 / 3.0));
  for (int k = 0; k < (sizeof(T) > 4 ? 3 : 2); ++k) {
    const L r2 = root * root;
    root -= (root * (r2 - T(3)) - T(2) * ra) / (T(3) * (r2 - T(1)));
  }
  const L lambda = select(smallest, L(-root), root);

  // Eigenvector of the isolated eigenvalue: the largest cross product of two rows of C - lambda I.
  const V3 m0{{c00 - lambda, c01, c02}}, m1{{c01, c11 - lambda, c12}}, m2{{c02, c12, c22 - lambda}};
  const V3 x01 = cross(m0, m1), x02 = cross(m0, m2), x12 = cross(m1, m2);
  const L n01 = dot(x01, x01), n02 = dot(x02, x02), n12 = dot(x12, x12);
  const Mask<T, W> pick01 = ge(n01, n02) & ge(n01, n12);
  const Mask<T, W> pick02 = ~pick01 & ge(n02, n12);
  const L nv = select(pick01, n01, select(pick02, n02, n12));
  const Mask<T, W> found = spread & gt(nv, kEps * kEps);
  const L inv_len = select(found, L(lanes::sqrt(nv).inverse()), T(0));
  const V3 v = scaled(inv_len, select(pick01, x01, select(pick02, x02, x12)));

  // The other two: one exact Jacobi rotation of C restricted to v^perp = span(u, w).
  V3 u, w;
  orthonormal_basis(v, u, w);
  const V3 Cw{{c00 * w.c[0] + c01 * w.c[1] + c02 * w.c[2], c01 * w.c[0] + c11 * w.c[1] + c12 * w.c[2],
               c02 * w.c[0] + c12 * w.c[1] + c22 * w.c[2]}};
  const V3 Cu{{c00 * u.c[0] + c01 * u.c[1] + c02 * u.c[2], c01 * u.c[0] + c11 * u.c[1] + c12 * u.c[2],
               c02 * u.c[0] + c12 * u.c[1] + c22 * u.c[2]}};
  const L muu = dot(u, Cu), mww = dot(w, Cw), muw = dot(u, Cw);
  L c, s;
  jacobi_rotation(muu, mww, muw, c, s);
  const Mask<T, W> first_larger = ge(L((c * c - s * s) * (muu - mww) + T(4) * c * s * muw), T(0));
  const L cb = select(first_larger, c, L(-s)), sb = select(first_larger, s, c);
  const V3 larger = combine(cb, u, sb, w), smaller = combine(L(-sb), u, cb, w);
  const V3 v0 = select(smallest, larger, v), v1 = select(smallest, smaller, larger);
  const V3 v2 = cross(v0, v1);
  Mat3<T, W> V;  // the identity where no eigenvector was found
  const V3* cols[3] = {&v0, &v1, &v2};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) V.a[i][j] = lanes::select(found, cols[j]->c[i], T(i == j));
  return V;
}

/// Per lane where m: swap columns i and j of B and V and negate the new column j (svd.h's
/// detail::swap_columns).
template <class T, int W>
inline void swap_columns(const Mask<T, W>& m, Mat3<T, W>& B, Mat3<T, W>& V, Lane<T, W>& ni, Lane<T, W>& nj, int i,
                         int j) {
  using L = Lane<T, W>;
  for (int r = 0; r < 3; ++r) {
    const L bi = B.a[r][i], vi = V.a[r][i];
    B.a[r][i] = lanes::select(m, B.a[r][j], bi);
    B.a[r][j] = lanes::select(m, L(-bi), B.a[r][j]);
    V.a[r][i] = lanes::select(m, V.a[r][j], vi);
    V.a[r][j] = lanes::select(m, L(-vi), V.a[r][j]);
  }
  const L n = ni;
  ni = lanes::select(m, nj, ni);
  nj = lanes::select(m, n, nj);
}

}  // namespace detail

/// svd.h's closed-form 2x2 SVD per lane, for M = [[m00, m01], [m10, m11]]: U and V are the
/// rotations by the angles with (cos, sin) = (cu, su) and (cv, sv).
template <class T, int W>
inline void svd2(const Lane<T, W>& m00, const Lane<T, W>& m01, const Lane<T, W>& m10, const Lane<T, W>& m11,
                 Lane<T, W>& cu, Lane<T, W>& su, Lane<T, W>& sigma0, Lane<T, W>& sigma1, Lane<T, W>& cv,
                 Lane<T, W>& sv) {
  using L = Lane<T, W>;
  const L e = T(0.5) * (m00 + m11), f = T(0.5) * (m00 - m11);
  const L g = T(0.5) * (m10 + m01), h = T(0.5) * (m10 - m01);
  const L q = lanes::sqrt(L(e * e + h * h));
  const L r = lanes::sqrt(L(f * f + g * g));
  const Mask<T, W> has_q = gt(q, T(0)), has_r = gt(r, T(0));
  const L iq = select(has_q, L(q.inverse()), T(0)), ir = select(has_r, L(r.inverse()), T(0));
  const L c2 = select(has_q, L(e * iq), T(1)), s2 = h * iq;
  const L c1 = select(has_r, L(f * ir), T(1)), s1 = g * ir;
  const L cw = c1 * c2 + s1 * s2;
  const L sw = s1 * c2 - c1 * s2;
  const Mask<T, W> pos = ge(cw, T(0));
  const L x = select(pos, L(T(1) + cw), sw);
  const L y = select(pos, sw, L(T(1) - cw));
  const L inv = lanes::sqrt(L(x * x + y * y)).inverse();
  cv = x * inv;
  sv = y * inv;
  cu = c2 * cv - s2 * sv;
  su = s2 * cv + c2 * sv;
  sigma0 = q + r;
  const L det = m00 * m11 - m01 * m10;
  sigma1 = select(gt(sigma0, T(0)), L(det / sigma0), T(0));
}

/// Rotation-variant SVD of W 3x3 matrices, F = U diag(sigma) V^T in each lane: see the file
/// comment and svd.h's svd() for the steps.
template <class T, int W>
inline void svd(const Mat3<T, W>& F, Mat3<T, W>& U, Vec3<T, W>& sigma, Mat3<T, W>& V) {
  using L = Lane<T, W>;
  using V3 = Vec3<T, W>;
  using detail::dot;
  constexpr T kEps = std::numeric_limits<T>::epsilon();

  // 1. F^T F = V diag(sigma^2) V^T.
  const V3 f0 = F.col(0), f1 = F.col(1), f2 = F.col(2);
  V = detail::sym_eigen3<T, W>(dot(f0, f0), dot(f1, f1), dot(f2, f2), dot(f0, f1), dot(f0, f2), dot(f1, f2));

  // 2. B = F V; the swaps repair ties broken the wrong way by round-off.
  Mat3<T, W> B;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) B.a[i][j] = F.a[i][0] * V.a[0][j] + F.a[i][1] * V.a[1][j] + F.a[i][2] * V.a[2][j];
  L n0 = dot(B.col(0), B.col(0)), n1 = dot(B.col(1), B.col(1)), n2 = dot(B.col(2), B.col(2));
  detail::swap_columns(lt(n0, n1), B, V, n0, n1, 0, 1);
  detail::swap_columns(lt(n0, n2), B, V, n0, n2, 0, 2);
  detail::swap_columns(lt(n1, n2), B, V, n1, n2, 1, 2);

  // 3. QR of B by Gram-Schmidt (projected twice), u2 = u0 x u1. F = 0 lanes: U = I, sigma = 0.
  const V3 b1 = B.col(1), b2 = B.col(2);
  const Mask<T, W> nonzero = gt(n0, T(0));
  const L s0 = lanes::sqrt(n0);
  const V3 u0 = detail::scaled(select(nonzero, L(s0.inverse()), T(0)), B.col(0));
  V3 w = detail::minus_scaled(b1, dot(u0, b1), u0);
  w = detail::minus_scaled(w, dot(u0, w), u0);
  const L s1 = lanes::sqrt(dot(w, w));
  const Mask<T, W> rank2 = gt(s1, L(kEps * kEps * s0));  // else rank 1: any u1 orthogonal to u0
  V3 any_u1, unused;
  detail::orthonormal_basis(u0, any_u1, unused);
  const V3 u1 = detail::select(rank2, detail::scaled(select(rank2, L(s1.inverse()), T(0)), w), any_u1);
  const V3 u2 = detail::cross(u0, u1);
  sigma.c[0] = s0;
  sigma.c[1] = s1;
  sigma.c[2] = dot(u2, b2);
  U.set_col(0, u0);
  U.set_col(1, u1);
  U.set_col(2, u2);

  // 4. The 2x2 block [[sigma_1, r12], [0, sigma_2]] by the closed form where QR left a coupling
  //    above round-off or the order wrong (svd.h, step 4). Skipped when no lane needs it.
  const L r12 = dot(u1, b2);
  const Mask<T, W> finish = gt(L(r12.abs()), L(T(4) * kEps * s0)) | gt(L(sigma.c[2].abs()), sigma.c[1]);
  if (any(finish)) {
    L cu, su, t0, t1, cv, sv;
    svd2<T, W>(sigma.c[1], r12, L::Zero(), sigma.c[2], cu, su, t0, t1, cv, sv);
    const V3 v1 = V.col(1), v2 = V.col(2);
    U.set_col(1, detail::select(finish, detail::combine(cu, u1, su, u2), u1));
    U.set_col(2, detail::select(finish, detail::combine(L(-su), u1, cu, u2), u2));
    V.set_col(1, detail::select(finish, detail::combine(cv, v1, sv, v2), v1));
    V.set_col(2, detail::select(finish, detail::combine(L(-sv), v1, cv, v2), v2));
    sigma.c[1] = select(finish, t0, sigma.c[1]);
    sigma.c[2] = select(finish, t1, sigma.c[2]);
  }
  for (int i = 0; i < 3; ++i) {
    sigma.c[i] = select(nonzero, sigma.c[i], T(0));
    for (int j = 0; j < 3; ++j) U.a[i][j] = select(nonzero, U.a[i][j], T(i == j));
  }
}

/// The eigen-decomposition of the left Cauchy-Green tensor b = F F^T = U diag(lambda) U^T of W
/// 3x3 matrices, for the return mappings that need U and the squared singular values but not V
/// (plasticity.h's batched Drucker-Prager): U is svd()'s U up to the order and signs of its
/// columns (a rotation, eigenvectors by decreasing eigenvalue as sym_eigen3 orders them),
/// M = U^T F (so F = U M, and row i of M is sigma_i v_i^T), and lambda_i = |row i of M|^2 =
/// sigma_i^2 >= 0 (a Rayleigh quotient: an error delta in u_i changes it by delta^2 only).
///
/// Cheaper than svd() (no F V, column swaps, QR or 2x2 clean-up), but b's eigenvalues are only
/// accurate to about eps sigma_max / sigma_i relative (the rows of M are rounded at the scale of
/// F), and F's sign (det F < 0) is lost: callers take this path where det F > 0 and
/// sigma_min / sigma_max is not small, and svd() elsewhere.
template <class T, int W>
inline void left_eigen(const Mat3<T, W>& F, Mat3<T, W>& U, Vec3<T, W>& lambda, Mat3<T, W>& M) {
  using V3 = Vec3<T, W>;
  using detail::dot;
  const V3 r0{{F.a[0][0], F.a[0][1], F.a[0][2]}}, r1{{F.a[1][0], F.a[1][1], F.a[1][2]}},
      r2{{F.a[2][0], F.a[2][1], F.a[2][2]}};
  U = detail::sym_eigen3<T, W>(dot(r0, r0), dot(r1, r1), dot(r2, r2), dot(r0, r1), dot(r0, r2), dot(r1, r2));
  for (int k = 0; k < 3; ++k) {
    for (int j = 0; j < 3; ++j) M.a[k][j] = U.a[0][k] * F.a[0][j] + U.a[1][k] * F.a[1][j] + U.a[2][k] * F.a[2][j];
    lambda.c[k] = M.a[k][0] * M.a[k][0] + M.a[k][1] * M.a[k][1] + M.a[k][2] * M.a[k][2];
  }
}

}  // namespace slurry::constitutive::lanes
