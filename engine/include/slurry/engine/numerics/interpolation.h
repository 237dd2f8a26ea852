#pragma once
/// \file interpolation.h
/// Interpolation and fitting on cells, simplices and scattered samples.
///
/// - Multilinear interpolation on a unit cell (linear, bilinear, trilinear): corner values and
///   local coordinates in [0,1]^Dim; the weights are products of 1D hat functions.
/// - Signed barycentric coordinates of a point in a triangle (2D, or 3D after projection onto the
///   triangle's plane) and in a tetrahedron, as ratios of signed areas / volumes, with an inside
///   test that accepts a tolerance.
/// - Polynomial interpolation through n+1 points: Lagrange form (evaluation only) and Newton's
///   divided-difference form (coefficients, then nested evaluation).
///   Ref: Burden & Faires, Numerical Analysis, 9th ed., sections 3.1 and 3.3.
/// - Weighted linear least squares for a user-given basis, by Householder QR (Golub & Van Loan,
///   Matrix Computations, 4th ed., section 5.3) or by the normal equations with LDLT (kept for
///   comparison: it squares the condition number, GvL section 5.3.7).
/// - Moving least squares (MLS) reconstruction from scattered samples, following Shen, O'Brien &
///   Shewchuk, "Interpolating and approximating implicit surfaces from polygon soup", ACM TOG 23(3)
///   (SIGGRAPH 2004): at every evaluation point x, a weighted least-squares polynomial fit with
///   weights w(|p_i - x|) is solved and evaluated at x.
///
/// Errors in the arguments (mismatched sizes, repeated nodes, too few samples) throw
/// std::invalid_argument; an MLS fit that is rank deficient at the evaluation point throws
/// std::domain_error. Degenerate simplices are caught by assert only (hot path).
#include <Eigen/Dense>

#include <array>
#include <cassert>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace slurry::numerics {

// ---------------------------------------------------------------------------------------------
// Multilinear interpolation on a cell
// ---------------------------------------------------------------------------------------------

/// Weights of the 2^Dim corners of a unit cell at local coordinates s in [0,1]^Dim.
/// Corner c lies on the high side of axis a when bit a of c is set, so c = i + 2 j + 4 k.
/// w_c = prod_a (bit_a(c) ? s_a : 1 - s_a); the weights sum to one for any s.
template <class T, int Dim>
std::array<T, (1 << Dim)> multilinear_weights(const Eigen::Vector<T, Dim>& s) {
  static_assert(Dim >= 1 && Dim <= 3, "multilinear_weights: Dim must be 1, 2 or 3");
  std::array<T, (1 << Dim)> w{};
  for (int c = 0; c < (1 << Dim); ++c) {
    T wc = T(1);
    for (int a = 0; a < Dim; ++a) wc *= ((c >> a) & 1) ? s[a] : T(1) - s[a];
    w[c] = wc;
  }
  return w;
}

/// Multilinear interpolation of corner values (scalars or Eigen vectors) ordered as in
/// multilinear_weights().
template <class T, int Dim, class V>
V multilinear(const std::array<V, (1 << Dim)>& corners, const Eigen::Vector<T, Dim>& s) {
  const auto w = multilinear_weights<T, Dim>(s);
  V acc = w[0] * corners[0];
  for (int c = 1; c < (1 << Dim); ++c) acc += w[c] * corners[c];
  return acc;
}

/// Linear interpolation: v0 at s = 0, v1 at s = 1.
template <class T, class V>
V linear(const V& v0, const V& v1, T s) {
  return V((T(1) - s) * v0 + s * v1);
}

/// Bilinear weights at (s, t), corner order (0,0), (1,0), (0,1), (1,1).
template <class T>
std::array<T, 4> bilinear_weights(T s, T t) {
  return multilinear_weights<T, 2>(Eigen::Vector<T, 2>(s, t));
}

/// Bilinear interpolation; corners[i + 2 j] is the value at corner (i, j).
template <class T, class V>
V bilinear(const std::array<V, 4>& corners, T s, T t) {
  return multilinear<T, 2, V>(corners, Eigen::Vector<T, 2>(s, t));
}

/// Trilinear weights at (s, t, u), corner order i + 2 j + 4 k.
template <class T>
std::array<T, 8> trilinear_weights(T s, T t, T u) {
  return multilinear_weights<T, 3>(Eigen::Vector<T, 3>(s, t, u));
}

/// Trilinear interpolation; corners[i + 2 j + 4 k] is the value at corner (i, j, k).
template <class T, class V>
V trilinear(const std::array<V, 8>& corners, T s, T t, T u) {
  return multilinear<T, 3, V>(corners, Eigen::Vector<T, 3>(s, t, u));
}

// ---------------------------------------------------------------------------------------------
// Barycentric coordinates
// ---------------------------------------------------------------------------------------------

/// Signed barycentric coordinates (l_a, l_b, l_c) of p in the 2D triangle (a, b, c):
/// l_a = area(p, b, c) / area(a, b, c) and cyclically. Negative outside the edge opposite the
/// vertex; independent of the triangle's orientation. The triangle must not be degenerate.
template <class T>
Eigen::Vector<T, 3> barycentric(const Eigen::Vector<T, 2>& p, const Eigen::Vector<T, 2>& a,
                                const Eigen::Vector<T, 2>& b, const Eigen::Vector<T, 2>& c) {
  const auto cross = [](const Eigen::Vector<T, 2>& u, const Eigen::Vector<T, 2>& v) {
    return u.x() * v.y() - u.y() * v.x();
  };
  const T area2 = cross(b - a, c - a);
  assert(area2 != T(0) && "barycentric: degenerate triangle");
  return Eigen::Vector<T, 3>(cross(b - p, c - p), cross(c - p, a - p), cross(a - p, b - p)) / area2;
}

/// Signed barycentric coordinates of the orthogonal projection of p onto the plane of the 3D
/// triangle (a, b, c): l_a = n . ((c - b) x (p - b)) / |n|^2 with n = (b - a) x (c - a), and
/// cyclically. The distance of p from the plane does not change them.
template <class T>
Eigen::Vector<T, 3> barycentric(const Eigen::Vector<T, 3>& p, const Eigen::Vector<T, 3>& a,
                                const Eigen::Vector<T, 3>& b, const Eigen::Vector<T, 3>& c) {
  const Eigen::Vector<T, 3> n = (b - a).cross(c - a);
  const T nn = n.squaredNorm();
  assert(nn != T(0) && "barycentric: degenerate triangle");
  return Eigen::Vector<T, 3>(n.dot((c - b).cross(p - b)), n.dot((a - c).cross(p - c)),
                             n.dot((b - a).cross(p - a))) /
         nn;
}

/// Signed barycentric coordinates of p in the tetrahedron (a, b, c, d): each is the signed volume
/// of the tetrahedron with that vertex replaced by p, divided by the signed volume of (a, b, c, d).
template <class T>
Eigen::Vector<T, 4> barycentric(const Eigen::Vector<T, 3>& p, const Eigen::Vector<T, 3>& a,
                                const Eigen::Vector<T, 3>& b, const Eigen::Vector<T, 3>& c,
                                const Eigen::Vector<T, 3>& d) {
  const auto det = [](const Eigen::Vector<T, 3>& u, const Eigen::Vector<T, 3>& v,
                      const Eigen::Vector<T, 3>& w) { return u.dot(v.cross(w)); };
  const T vol6 = det(b - a, c - a, d - a);
  assert(vol6 != T(0) && "barycentric: degenerate tetrahedron");
  return Eigen::Vector<T, 4>(det(b - p, c - p, d - p), det(p - a, c - a, d - a),
                             det(b - a, p - a, d - a), det(b - a, c - a, p - a)) /
         vol6;
}

/// Inside test on barycentric coordinates: true when every coordinate is >= -tolerance, so
/// points on the boundary count as inside and a positive tolerance widens the simplex.
template <class T, int N>
bool is_inside(const Eigen::Vector<T, N>& weights, T tolerance = T(0)) {
  return (weights.array() >= -tolerance).all();
}

// ---------------------------------------------------------------------------------------------
// Polynomial interpolation through n+1 points
// ---------------------------------------------------------------------------------------------

namespace detail {
template <class T>
void check_nodes(const Eigen::VectorX<T>& xs, Eigen::Index n_values, const char* who) {
  if (xs.size() == 0 || xs.size() != n_values) {
    std::ostringstream msg;
    msg << who << ": got " << xs.size() << " nodes and " << n_values
        << " values; expected the same, nonzero number";
    throw std::invalid_argument(msg.str());
  }
  for (Eigen::Index i = 0; i < xs.size(); ++i)
    for (Eigen::Index j = i + 1; j < xs.size(); ++j)
      if (xs[i] == xs[j]) {
        std::ostringstream msg;
        msg << who << ": nodes " << i << " and " << j << " coincide (x = " << xs[i]
            << "); the nodes must be distinct";
        throw std::invalid_argument(msg.str());
      }
}
}  // namespace detail

/// Value at x of the polynomial of degree <= n through (xs[i], ys[i]), i = 0..n, in Lagrange form:
/// p(x) = sum_i ys[i] prod_{j != i} (x - xs[j]) / (xs[i] - xs[j]). O(n^2) per evaluation.
template <class T>
T lagrange_interpolate(const Eigen::VectorX<T>& xs, const Eigen::VectorX<T>& ys, T x) {
  detail::check_nodes(xs, ys.size(), "lagrange_interpolate");
  T sum = T(0);
  for (Eigen::Index i = 0; i < xs.size(); ++i) {
    T basis = T(1);
    for (Eigen::Index j = 0; j < xs.size(); ++j)
      if (j != i) basis *= (x - xs[j]) / (xs[i] - xs[j]);
    sum += ys[i] * basis;
  }
  return sum;
}

/// Newton divided differences c_k = f[x_0, ..., x_k], k = 0..n, so that
/// p(x) = c_0 + c_1 (x - x_0) + ... + c_n (x - x_0)...(x - x_{n-1}).
template <class T>
Eigen::VectorX<T> newton_divided_differences(const Eigen::VectorX<T>& xs,
                                             const Eigen::VectorX<T>& ys) {
  detail::check_nodes(xs, ys.size(), "newton_divided_differences");
  Eigen::VectorX<T> c = ys;
  const Eigen::Index n = xs.size();
  // Column j of the divided-difference table overwrites c[j..n-1] from the bottom up.
  for (Eigen::Index j = 1; j < n; ++j)
    for (Eigen::Index i = n - 1; i >= j; --i) c[i] = (c[i] - c[i - 1]) / (xs[i] - xs[i - j]);
  return c;
}

/// Nested (Horner-like) evaluation of the Newton form with nodes xs and coefficients from
/// newton_divided_differences(): p = c_n; p = p (x - x_k) + c_k for k = n-1..0.
template <class T>
T newton_evaluate(const Eigen::VectorX<T>& xs, const Eigen::VectorX<T>& coefficients, T x) {
  assert(xs.size() == coefficients.size() && xs.size() > 0);
  const Eigen::Index n = coefficients.size();
  T p = coefficients[n - 1];
  for (Eigen::Index k = n - 2; k >= 0; --k) p = p * (x - xs[k]) + coefficients[k];
  return p;
}

// ---------------------------------------------------------------------------------------------
// Linear least squares with a user basis
// ---------------------------------------------------------------------------------------------

/// How the least-squares problem min_c || W^(1/2) (A c - y) || is solved.
enum class LeastSquaresMethod {
  kHouseholderQR,        ///< A = QR, R c = Q^T y. Error ~ cond(A) eps.
  kColPivHouseholderQR,  ///< QR with column pivoting: also copes with rank deficiency.
  kNormalEquations,      ///< (A^T W A) c = A^T W y by LDLT. Error ~ cond(A)^2 eps.
};

/// Monomial basis 1, x, ..., x^degree as a callable for least_squares_fit().
template <class T>
auto monomial_basis(int degree) {
  if (degree < 0) throw std::invalid_argument("monomial_basis: degree must be >= 0");
  return [degree](T x) {
    Eigen::VectorX<T> phi(degree + 1);
    T xp = T(1);
    for (int k = 0; k <= degree; ++k, xp *= x) phi[k] = xp;
    return phi;
  };
}

/// Coefficients c minimizing sum_i w_i (sum_k c_k phi_k(x_i) - y_i)^2, where basis(x) returns
/// the Eigen vector (phi_0(x), ..., phi_{m-1}(x)). Samples may be of any type the basis accepts.
/// The weights must be non-negative; rows are scaled by sqrt(w_i).
template <class T, class Sample, class Basis>
Eigen::VectorX<T> weighted_least_squares_fit(
    const std::vector<Sample>& xs, const Eigen::VectorX<T>& ys, const Eigen::VectorX<T>& weights,
    const Basis& basis, LeastSquaresMethod method = LeastSquaresMethod::kHouseholderQR) {
  const Eigen::Index n = static_cast<Eigen::Index>(xs.size());
  if (n == 0 || ys.size() != n || weights.size() != n) {
    std::ostringstream msg;
    msg << "weighted_least_squares_fit: got " << n << " samples, " << ys.size() << " values and "
        << weights.size() << " weights; expected the same, nonzero number";
    throw std::invalid_argument(msg.str());
  }
  const Eigen::VectorX<T> phi0 = basis(xs[0]);
  const Eigen::Index m = phi0.size();
  if (m == 0 || m > n) {
    std::ostringstream msg;
    msg << "weighted_least_squares_fit: " << m << " basis functions for " << n
        << " samples; need 1 <= basis size <= samples";
    throw std::invalid_argument(msg.str());
  }
  if ((weights.array() < T(0)).any())
    throw std::invalid_argument("weighted_least_squares_fit: weights must be >= 0");

  Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> a(n, m);
  Eigen::VectorX<T> rhs(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const T sw = std::sqrt(weights[i]);
    a.row(i) = sw * basis(xs[static_cast<std::size_t>(i)]).transpose();
    rhs[i] = sw * ys[i];
  }
  switch (method) {
    case LeastSquaresMethod::kHouseholderQR:
      return a.householderQr().solve(rhs);
    case LeastSquaresMethod::kColPivHouseholderQR:
      return a.colPivHouseholderQr().solve(rhs);
    case LeastSquaresMethod::kNormalEquations:
      break;
  }
  const Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> ata = a.transpose() * a;
  return ata.ldlt().solve(a.transpose() * rhs);
}

/// Unweighted least_squares fit (all w_i = 1); see weighted_least_squares_fit().
template <class T, class Sample, class Basis>
Eigen::VectorX<T> least_squares_fit(
    const std::vector<Sample>& xs, const Eigen::VectorX<T>& ys, const Basis& basis,
    LeastSquaresMethod method = LeastSquaresMethod::kHouseholderQR) {
  return weighted_least_squares_fit(xs, ys, Eigen::VectorX<T>::Ones(ys.size()).eval(), basis,
                                    method);
}

/// Value at x of the fitted combination sum_k c_k phi_k(x).
template <class T, class Sample, class Basis>
T evaluate_fit(const Eigen::VectorX<T>& coefficients, const Basis& basis, const Sample& x) {
  return basis(x).dot(coefficients);
}

// ---------------------------------------------------------------------------------------------
// Moving least squares
// ---------------------------------------------------------------------------------------------

/// Radial weight of the MLS fit, with radius h and q = r / h.
enum class MlsWeight {
  kGaussian,  ///< w = exp(-q^2); never zero, so every sample takes part.
  kWendland,  ///< Wendland's C2 function w = (1 - q)^4 (4 q + 1) for q < 1, else 0
              ///< (Wendland, Adv. Comput. Math. 4, 1995).
};

/// Parameters of MovingLeastSquares.
template <class T>
struct MlsOptions {
  int degree = 1;   ///< total degree of the local polynomial: 0, 1 or 2
  T radius = T(1);  ///< h: support radius (Wendland) or length scale (Gaussian), > 0
  MlsWeight weight = MlsWeight::kWendland;

  void validate() const {
    if (degree < 0 || degree > 2) {
      std::ostringstream msg;
      msg << "MlsOptions.degree = " << degree << "; allowed: 0, 1, 2";
      throw std::invalid_argument(msg.str());
    }
    if (!(radius > T(0)) || !std::isfinite(radius)) {
      std::ostringstream msg;
      msg << "MlsOptions.radius = " << radius << "; allowed: finite and > 0";
      throw std::invalid_argument(msg.str());
    }
  }
};

/// MLS reconstruction of a scalar field from samples (p_i, phi_i) in Dim = 1, 2, 3.
/// At x: minimize sum_i w(|p_i - x| / h) (b((p_i - x) / h) . c - phi_i)^2 over c, where b lists
/// the monomials of total degree <= d in the centred, scaled offset; the value is b(0) . c = c_0.
/// Centring and scaling keep the local system well conditioned. Any polynomial of degree <= d is
/// reproduced exactly. Each evaluation visits all samples (no spatial index): O(N m^2).
template <class T, int Dim>
class MovingLeastSquares {
  static_assert(Dim >= 1 && Dim <= 3, "MovingLeastSquares: Dim must be 1, 2 or 3");

 public:
  using Point = Eigen::Vector<T, Dim>;

  MovingLeastSquares(std::vector<Point> points, Eigen::VectorX<T> values,
                     MlsOptions<T> options = {})
      : points_(std::move(points)), values_(std::move(values)), options_(options) {
    options_.validate();
    if (static_cast<Eigen::Index>(points_.size()) != values_.size()) {
      std::ostringstream msg;
      msg << "MovingLeastSquares: " << points_.size() << " points but " << values_.size()
          << " values";
      throw std::invalid_argument(msg.str());
    }
  }

  /// Number of monomials of total degree <= degree in Dim variables: C(Dim + degree, degree).
  static int basis_size(int degree) {
    int num = 1, den = 1;
    for (int k = 1; k <= degree; ++k) {
      num *= Dim + k;
      den *= k;
    }
    return num / den;
  }

  /// The radial weight at distance r.
  T weight(T r) const {
    const T q = r / options_.radius;
    if (options_.weight == MlsWeight::kGaussian) return std::exp(-q * q);
    if (q >= T(1)) return T(0);
    const T omq = T(1) - q;
    return omq * omq * omq * omq * (T(4) * q + T(1));
  }

  /// Reconstructed value at x. Throws std::domain_error when the samples with nonzero weight
  /// cannot determine the local polynomial (too few of them, or all on a line/plane).
  T operator()(const Point& x) const {
    const int m = basis_size(options_.degree);
    std::vector<Eigen::Index> used;
    std::vector<T> sqrt_w;
    for (std::size_t i = 0; i < points_.size(); ++i) {
      const T w = weight((points_[i] - x).norm());
      if (w > T(0)) {
        used.push_back(static_cast<Eigen::Index>(i));
        sqrt_w.push_back(std::sqrt(w));
      }
    }
    const Eigen::Index k = static_cast<Eigen::Index>(used.size());
    Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic> a(k, m);
    Eigen::VectorX<T> rhs(k);
    Eigen::VectorX<T> b(m);
    for (Eigen::Index r = 0; r < k; ++r) {
      const Eigen::Index i = used[static_cast<std::size_t>(r)];
      monomials((points_[static_cast<std::size_t>(i)] - x) / options_.radius, b);
      a.row(r) = sqrt_w[static_cast<std::size_t>(r)] * b.transpose();
      rhs[r] = sqrt_w[static_cast<std::size_t>(r)] * values_[i];
    }
    const Eigen::ColPivHouseholderQR<Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>> qr(a);
    if (k < m || qr.rank() < m) {
      std::ostringstream msg;
      msg << "MovingLeastSquares: at x = (" << x.transpose() << ") " << k
          << " samples with nonzero weight span rank " << (k == 0 ? 0 : qr.rank()) << " of the "
          << m << " basis functions of degree " << options_.degree
          << "; increase MlsOptions.radius or lower the degree";
      throw std::domain_error(msg.str());
    }
    const Eigen::VectorX<T> c = qr.solve(rhs);
    return c[0];
  }

  const MlsOptions<T>& options() const { return options_; }

 private:
  /// b = (1, q_0, .., q_{Dim-1}, q_a q_b for a <= b) truncated at the configured degree.
  void monomials(const Point& q, Eigen::VectorX<T>& b) const {
    int k = 0;
    b[k++] = T(1);
    if (options_.degree >= 1)
      for (int a = 0; a < Dim; ++a) b[k++] = q[a];
    if (options_.degree >= 2)
      for (int a = 0; a < Dim; ++a)
        for (int c = a; c < Dim; ++c) b[k++] = q[a] * q[c];
  }

  std::vector<Point> points_;
  Eigen::VectorX<T> values_;
  MlsOptions<T> options_;
};

/// One-call MLS: the value at x of MovingLeastSquares built from (points, values, options).
template <class T, int Dim>
T mls_reconstruct(const std::vector<Eigen::Vector<T, Dim>>& points, const Eigen::VectorX<T>& values,
                  const Eigen::Vector<T, Dim>& x, const MlsOptions<T>& options = {}) {
  return MovingLeastSquares<T, Dim>(points, values, options)(x);
}

}  // namespace slurry::numerics
