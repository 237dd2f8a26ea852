#pragma once
/// \file corotated_fem.h
/// Co-rotated linear finite elements on a tetrahedral (3D) or triangle (2D) mesh, following
/// Mueller and Gross 2004, "Interactive virtual materials" (Graphics Interface), and the FEM
/// chapter of Mueller, Stam, James and Thuerey, "Real time physics" (SIGGRAPH 2008 course
/// notes). Per element e with rest vertices X_0..X_Dim and current vertices x_0..x_Dim:
///
///   Dm = [X_1 - X_0, ..., X_Dim - X_0]   (rest edge matrix; Dm^-1 and W = |det Dm| / Dim! precomputed)
///   Ds = [x_1 - x_0, ..., x_Dim - x_0],  F = Ds Dm^-1              (deformation gradient)
///   F = R S                                                         (polar decomposition)
///   eps = (R^T F + F^T R) / 2 - I                                   (linear strain, rotated frame)
///   sigma = 2 mu eps + lambda tr(eps) I
///   f_i = R sigma b_i,  b_i = A_i n_i / Dim                         (nodal forces)
///
/// where A_i n_i is the rest area-weighted outward normal of the face opposite vertex i (the
/// edge in 2D); equivalently b_i = -(A_j n_j summed over the faces adjacent to i) / Dim, and
/// b_i = -W Dm^-T e_i (i >= 1), which the tests check. The forces are exactly minus the gradient
/// of the co-rotated energy E = sum_e W (mu eps:eps + lambda/2 tr(eps)^2) (R depends on x, but
/// sigma commutes with S, so its derivative adds nothing; see corotated_linear.h).
///
/// Stiffness warping: with K0_e the element's linear-elasticity stiffness, its (i, j) block
///   K0_ij = W (mu (g_i . g_j) I + mu g_j g_i^T + lambda g_i g_j^T),   g_i = grad of the hat function i,
/// the global K = sum_e R K0_e R^T, and the elastic force equals -sum_e R K0_e (R^T x - X)
/// (the rotated rest-offset form), identical to the nodal forces above.
///
/// Damping (optional, per material) is Rayleigh stiffness-proportional, D = beta K: it adds
/// beta sigma(eps_v), eps_v = sym(R^T Vs Dm^-1), to sigma, and damps deformation but not rigid
/// motion. Masses are lumped: m_i = sum over the elements around i of rho W / (Dim + 1).
///
/// The explicit step is bounded by 2 / omega_max (reduced for damping), omega_max from the
/// element eigenvalue bound (max_frequency()), which unlike h / c also sees flat elements.
///
/// Time steps (x, v per vertex; g gravity; boundary conditions through a Boundary object):
///   symplectic Euler         v += dt (f(x, v) / m + g), boundary, x += dt v
///   linearly implicit Euler  (M + dt D + dt^2 K) v' = M v + dt (f(x) + M g), boundary, x += dt v'
///                            (Mueller and Gross 2004, eq. 9, with K warped at x: one Newton step
///                            of backward Euler without the derivative of R), solved by PCG with an
///                            IC(0) (or Jacobi) preconditioner; sticky (pinned) vertices get identity
///                            rows and columns and their velocity moved to the right-hand side.
///
/// A Boundary has `bool pin(int i, const Vec& x, Vec& vb)` (true: vertex i moves at vb this
/// step, used by the implicit solve) and `void apply(int i, const Vec& x_predicted, Vec& v)`
/// (velocity conditions after the update, at the predicted position x + dt v).
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Sparse>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <limits>
#include <string>
#include <type_traits>
#include <vector>

#include "slurry/constitutive/kinematics.h"
#include "slurry/constitutive/lame.h"
#include "slurry/engine/fem/mesh.h"
#include "slurry/engine/numerics/pcg.h"
#include "slurry/transfer/parallel.h"

namespace slurry::fem {

/// Material of the co-rotated linear model.
template <class T>
struct FemMaterial {
  T mu = T(0);        ///< shear modulus (Pa)
  T lambda = T(0);    ///< first Lame parameter (Pa)
  T density = T(1000);  ///< kg/m^3 (kg/m^2 in 2D)
  T damping = T(0);   ///< Rayleigh stiffness-proportional coefficient beta (s), >= 0

  /// From Young's modulus and Poisson's ratio (lame.h).
  static FemMaterial from_young(T E, T nu, T density, T damping = T(0)) {
    const auto l = constitutive::lame_from_young(E, nu);
    return {l.mu, l.lambda, density, damping};
  }
  /// P-wave speed sqrt((lambda + 2 mu) / rho).
  T wave_speed() const { return std::sqrt((lambda + T(2) * mu) / density); }
};

/// No boundary conditions.
template <class T, int Dim>
struct FreeBoundary {
  bool pin(int, const Eigen::Matrix<T, Dim, 1>&, Eigen::Matrix<T, Dim, 1>&) const { return false; }
  void apply(int, const Eigen::Matrix<T, Dim, 1>&, Eigen::Matrix<T, Dim, 1>&) const {}
};

namespace detail {
/// Loops shorter than this run on the calling thread: a parallel region costs more than a few
/// thousand element updates, much more when the cores are shared.
inline constexpr std::int64_t kParallelGrain = 8192;
template <class Fn>
void for_each(std::int64_t begin, std::int64_t end, Fn&& fn) {
  if (end - begin < kParallelGrain) {
    for (std::int64_t i = begin; i < end; ++i) fn(i);
  } else {
    parallel::parallel_for(begin, end, fn);
  }
}
}  // namespace detail

template <class T, int Dim>
class CorotatedFem {
 public:
  static constexpr int kNodes = Dim + 1;
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;
  using VecX = Eigen::VectorX<T>;
  using Element = std::array<int, Dim + 1>;

  /// Current positions and velocities, one per vertex (start at the rest positions, at rest).
  std::vector<Vec> x, v;

  /// Preconditioner of the implicit step's PCG: IC(0) (falls back to Jacobi if it breaks down)
  /// or Jacobi (pcg.h).
  enum class Preconditioner { IncompleteCholesky, Jacobi };
  Preconditioner preconditioner = Preconditioner::IncompleteCholesky;

  /// A mesh (checked with check_mesh) whose element e has material materials[element_material[e]].
  CorotatedFem(const Mesh<Dim>& mesh, std::vector<FemMaterial<T>> materials, std::vector<int> element_material)
      : materials_(std::move(materials)), element_material_(std::move(element_material)) {
    check_mesh(mesh, "CorotatedFem");
    if (element_material_.size() != mesh.elements.size())
      throw std::invalid_argument("CorotatedFem: element_material has " + std::to_string(element_material_.size()) +
                                  " entries, expected one per element (" + std::to_string(mesh.elements.size()) + ")");
    for (const auto& m : materials_)
      if (!(m.mu >= T(0)) || !(m.lambda + T(2) * m.mu / T(Dim) >= T(0)) || !(m.density > T(0)) || !(m.damping >= T(0)))
        throw std::invalid_argument("CorotatedFem: a material has mu < 0, a negative bulk modulus, density <= 0 or damping < 0");
    for (int k : element_material_)
      if (k < 0 || std::size_t(k) >= materials_.size())
        throw std::invalid_argument("CorotatedFem: element_material index " + std::to_string(k) + " out of range");
    const std::size_t n = mesh.x.size(), ne = mesh.elements.size();
    elements_ = mesh.elements;
    rest_.resize(n);
    for (std::size_t i = 0; i < n; ++i) rest_[i] = mesh.x[i].template cast<T>();
    x = rest_;
    v.assign(n, Vec::Zero());
    Dm_inv_.resize(ne);
    volume_.resize(ne);
    normals_.resize(ne);
    mass_.assign(n, T(0));
    for (std::size_t e = 0; e < ne; ++e) {
      const Eigen::Matrix<double, Dim, Dim> Dm = mesh.edge_matrix(e);
      Dm_inv_[e] = Dm.inverse().template cast<T>();
      volume_[e] = T(std::abs(Dm.determinant()) / (Dim == 2 ? 2.0 : 6.0));
      normals_[e] = area_weighted_normals(mesh, e);
      const T m = materials_[std::size_t(element_material_[e])].density * volume_[e] / T(kNodes);
      for (int k : elements_[e]) mass_[std::size_t(k)] += m;
    }
    // Vertex -> (element, local index) incidences, so that per-vertex sums are gathers
    // (race free and independent of the thread count).
    incidence_offset_.assign(n + 1, 0);
    for (const auto& el : elements_)
      for (int k : el) ++incidence_offset_[std::size_t(k) + 1];
    for (std::size_t i = 0; i < n; ++i) incidence_offset_[i + 1] += incidence_offset_[i];
    incidence_.resize(ne * kNodes);
    std::vector<int> fill(incidence_offset_.begin(), incidence_offset_.end() - 1);
    for (std::size_t e = 0; e < ne; ++e)
      for (int a = 0; a < kNodes; ++a) incidence_[std::size_t(fill[std::size_t(elements_[e][a])]++)] = int(e * kNodes + a);
    element_force_.resize(ne * kNodes);
    rotation_.assign(ne, Mat::Identity());
  }

  /// One material for every element.
  CorotatedFem(const Mesh<Dim>& mesh, const FemMaterial<T>& material)
      : CorotatedFem(mesh, {material}, std::vector<int>(mesh.elements.size(), 0)) {}

  std::size_t vertex_count() const { return rest_.size(); }
  std::size_t element_count() const { return elements_.size(); }
  const std::vector<Vec>& rest() const { return rest_; }
  const std::vector<Element>& elements() const { return elements_; }
  const std::vector<T>& mass() const { return mass_; }
  T volume(std::size_t e) const { return volume_[e]; }
  const Mat& rest_inverse(std::size_t e) const { return Dm_inv_[e]; }
  /// b_i = A_i n_i / Dim of element e (see the file comment).
  const std::array<Vec, kNodes>& normals(std::size_t e) const { return normals_[e]; }
  const FemMaterial<T>& material(std::size_t e) const { return materials_[std::size_t(element_material_[e])]; }
  int material_index(std::size_t e) const { return element_material_[e]; }
  std::size_t bytes() const {
    return (x.size() + v.size() + rest_.size()) * sizeof(Vec) + mass_.size() * sizeof(T) +
           elements_.size() * (sizeof(Element) + 2 * sizeof(Mat) + sizeof(T) + sizeof(int) + kNodes * 2 * sizeof(Vec)) +
           incidence_.size() * sizeof(int) + incidence_offset_.size() * sizeof(int) +
           std::size_t(stiffness_.nonZeros() + system_.nonZeros()) * (sizeof(T) + sizeof(int)) + slot_.size() * sizeof(int);
  }

  /// F = Ds Dm^-1 of element e at positions xs.
  Mat deformation_gradient(std::size_t e, const std::vector<Vec>& xs) const {
    return edges(e, xs) * Dm_inv_[e];
  }
  /// The rotation R of the polar decomposition of F (Newton iteration, kinematics.h).
  Mat rotation(std::size_t e, const std::vector<Vec>& xs) const {
    Mat R;
    constitutive::polar_rotation<T, Dim>(deformation_gradient(e, xs), R);
    return R;
  }
  /// Linear strain in the rotated frame, eps = sym(R^T F) - I.
  Mat strain(std::size_t e, const std::vector<Vec>& xs) const {
    const Mat F = deformation_gradient(e, xs);
    Mat R;
    constitutive::polar_rotation<T, Dim>(F, R);
    const Mat S = R.transpose() * F;
    return T(0.5) * (S + S.transpose()) - Mat::Identity();
  }
  /// sigma = 2 mu eps + lambda tr(eps) I for material m.
  static Mat linear_stress(const FemMaterial<T>& m, const Mat& eps) {
    return T(2) * m.mu * eps + m.lambda * eps.trace() * Mat::Identity();
  }
  /// The element's stress in world axes, R sigma R^T.
  Mat world_stress(std::size_t e, const std::vector<Vec>& xs) const {
    const Mat R = rotation(e, xs);
    return R * linear_stress(material(e), strain(e, xs)) * R.transpose();
  }

  /// Co-rotated elastic energy sum_e W (mu eps:eps + lambda/2 tr(eps)^2).
  T energy(const std::vector<Vec>& xs) const {
    T sum = 0;
    for (std::size_t e = 0; e < elements_.size(); ++e) {
      const Mat eps = strain(e, xs);
      const auto& m = material(e);
      sum += volume_[e] * (m.mu * eps.squaredNorm() + T(0.5) * m.lambda * eps.trace() * eps.trace());
    }
    return sum;
  }
  /// Kinetic energy sum_i m_i |v_i|^2 / 2 of the current state.
  T kinetic_energy() const {
    T sum = 0;
    for (std::size_t i = 0; i < v.size(); ++i) sum += T(0.5) * mass_[i] * v[i].squaredNorm();
    return sum;
  }

  /// Nodal forces f_i = sum_e R sigma b_i at positions xs (elastic), plus the Rayleigh damping
  /// forces of velocities vs when given. Also stores each element's R for stiffness().
  void forces(const std::vector<Vec>& xs, std::vector<Vec>& f, const std::vector<Vec>* vs = nullptr) {
    const std::int64_t ne = std::int64_t(elements_.size());
    detail::for_each(0, ne, [&](std::int64_t ei) {
      const std::size_t e = std::size_t(ei);
      const Mat F = edges(e, xs) * Dm_inv_[e];
      Mat R;
      constitutive::polar_rotation<T, Dim>(F, R);
      rotation_[e] = R;
      const Mat S = R.transpose() * F;
      Mat eps = T(0.5) * (S + S.transpose()) - Mat::Identity();
      const auto& m = material(e);
      if (vs && m.damping > T(0)) {
        const Mat L = R.transpose() * edges(e, *vs) * Dm_inv_[e];
        eps += m.damping * T(0.5) * (L + L.transpose());
      }
      const Mat Rsigma = R * linear_stress(m, eps);
      for (int a = 0; a < kNodes; ++a) element_force_[e * kNodes + std::size_t(a)] = Rsigma * normals_[e][std::size_t(a)];
    });
    gather(f);
  }

  /// The warped stiffness K = sum_e R K0_e R^T (Dim x Dim blocks, vertex-major dof order
  /// i * Dim + d) with the rotations of the last forces() call.
  const Eigen::SparseMatrix<T>& stiffness() {
    return assemble([](std::size_t) { return T(1); });
  }

  /// Largest angular frequency of the mesh, bounded element by element: with lumped masses
  /// omega_max^2 <= max_e lambda_max(K0_e) / m_e, m_e = rho W / (Dim + 1) (the element
  /// eigenvalue inequality, Irons 1970; see Hughes, "The finite element method", 2000,
  /// sec. 9.3). Unlike h / c it also sees flat elements (slivers), whose limit is far smaller.
  T max_frequency() const {
    T w = 0;
    for (std::size_t e = 0; e < elements_.size(); ++e) w = std::max(w, element_frequency(e));
    return w;
  }

  /// The explicit step: elastic_cfl times the stability limit of symplectic Euler,
  /// dt <= (2 / omega_max) (sqrt(1 + zeta^2) - zeta), zeta = beta omega_max / 2 (the limit of
  /// x'' = -omega^2 x - 2 zeta omega x' under symplectic Euler with the damping taken
  /// explicitly), per element with its own beta, omega_max from max_frequency()'s element
  /// bound. elastic_cfl <= 1 is stable; computed once (the bound uses rest quantities).
  T explicit_dt(T elastic_cfl) const {
    if (!(element_dt_ > T(0))) {
      T dt = std::numeric_limits<T>::max();
      for (std::size_t e = 0; e < elements_.size(); ++e) {
        const T w = element_frequency(e);
        const T zeta = material(e).damping * w / T(2);
        dt = std::min(dt, T(2) / w * (std::sqrt(T(1) + zeta * zeta) - zeta));
      }
      element_dt_ = dt;
    }
    return elastic_cfl * element_dt_;
  }

  /// One symplectic Euler step (see the file comment).
  template <class Boundary = FreeBoundary<T, Dim>>
  void step_symplectic(T dt, const Vec& gravity, const Boundary& boundary = {}) {
    forces(x, force_, &v);
    const std::int64_t n = std::int64_t(x.size());
    detail::for_each(0, n, [&](std::int64_t ii) {
      const std::size_t i = std::size_t(ii);
      v[i] += dt * (force_[i] / mass_[i] + gravity);
      boundary.apply(int(i), Vec(x[i] + dt * v[i]), v[i]);
      x[i] += dt * v[i];
    });
  }

  /// One linearly implicit Euler step (see the file comment); returns the PCG outcome.
  template <class Boundary = FreeBoundary<T, Dim>>
  numerics::PcgResult<T> step_implicit(T dt, const Vec& gravity, const Boundary& boundary = {},
                                       numerics::PcgOptions<T> options = default_pcg_options()) {
    forces(x, force_);  // elastic forces and rotations at x
    const std::size_t n = x.size();
    const Eigen::Index N = Eigen::Index(n) * Dim;
    VecX b(N), mdiag(N), z = VecX::Zero(N);
    std::vector<char> pinned(std::size_t(N), 0);
    for (std::size_t i = 0; i < n; ++i) {
      Vec vb;
      const bool pin = boundary.pin(int(i), x[i], vb);
      for (int d = 0; d < Dim; ++d) {
        const Eigen::Index k = Eigen::Index(i) * Dim + d;
        mdiag[k] = mass_[i];
        b[k] = mass_[i] * v[i][d] + dt * (force_[i][d] + mass_[i] * gravity[d]);
        if (pin) pinned[std::size_t(k)] = 1, z[k] = vb[d];
      }
    }
    // A = M + sum_e (dt^2 + dt beta_e) R K0_e R^T on the free dofs, identity on the pinned ones.
    const Eigen::SparseMatrix<T>& K = assemble([&](std::size_t e) { return dt * dt + dt * material(e).damping; });
    // rhs = b - A z on the free dofs (z: the pinned velocities), 0 on the pinned ones.
    VecX rhs = b - K * z - mdiag.cwiseProduct(z);
    system_ = K;
    for (Eigen::Index col = 0; col < N; ++col)
      for (typename Eigen::SparseMatrix<T>::InnerIterator it(system_, col); it; ++it) {
        if (pinned[std::size_t(it.row())] || pinned[std::size_t(col)])
          it.valueRef() = it.row() == col ? T(1) : T(0);
        else if (it.row() == col)
          it.valueRef() += mdiag[col];
      }
    for (Eigen::Index k = 0; k < N; ++k)
      if (pinned[std::size_t(k)]) rhs[k] = T(0);
    VecX y(N);
    for (std::size_t i = 0; i < n; ++i)
      for (int d = 0; d < Dim; ++d) {
        const Eigen::Index k = Eigen::Index(i) * Dim + d;
        y[k] = pinned[std::size_t(k)] ? T(0) : v[i][d];  // warm start from the current velocity
      }
    numerics::PcgResult<T> result;
    bool done = false;
    if (preconditioner == Preconditioner::IncompleteCholesky) {
      try {
        const numerics::IncompleteCholesky0<T> ic(system_);
        result = numerics::pcg(system_, rhs, y, ic, options);
        done = true;
      } catch (const std::domain_error&) {
        // IC(0) broke down (a non-positive pivot; it is guaranteed only for M-matrices): Jacobi.
      }
    }
    if (!done) result = numerics::pcg(system_, rhs, y, numerics::JacobiPreconditioner<T>(system_), options);
    y += z;
    const std::int64_t nn = std::int64_t(n);
    detail::for_each(0, nn, [&](std::int64_t ii) {
      const std::size_t i = std::size_t(ii);
      for (int d = 0; d < Dim; ++d) v[i][d] = y[Eigen::Index(i) * Dim + d];
      boundary.apply(int(i), Vec(x[i] + dt * v[i]), v[i]);
      x[i] += dt * v[i];
    });
    return result;
  }

  /// PCG tolerance suited to T: 1e-8 relative in double, 1e-5 in float.
  static numerics::PcgOptions<T> default_pcg_options() {
    numerics::PcgOptions<T> o;
    o.tolerance = std::is_same_v<T, float> ? T(1e-5) : T(1e-8);
    o.max_iterations = 2000;
    return o;
  }

  /// Last forces(): the total force on each vertex (elastic and damping, without gravity).
  const std::vector<Vec>& last_forces() const { return force_; }

 private:
  Mat edges(std::size_t e, const std::vector<Vec>& xs) const {
    Mat D;
    const auto& el = elements_[e];
    for (int k = 0; k < Dim; ++k) D.col(k) = xs[std::size_t(el[std::size_t(k + 1)])] - xs[std::size_t(el[0])];
    return D;
  }

  /// The notes' area-weighted rest normals: b_i = A_i n_i / Dim of the face opposite vertex i
  /// (outward), from the rest geometry.
  static std::array<Vec, kNodes> area_weighted_normals(const Mesh<Dim>& mesh, std::size_t e) {
    std::array<Vec, kNodes> b;
    const auto& el = mesh.elements[e];
    const auto X = [&](int k) { return mesh.x[std::size_t(el[std::size_t(k)])]; };
    if constexpr (Dim == 2) {
      // Opposite edges of a counter-clockwise triangle, walked counter-clockwise; the outward
      // normal of edge p -> q times its length is (q - p) turned by -90 degrees.
      static constexpr int kEdge[3][2] = {{1, 2}, {2, 0}, {0, 1}};
      for (int a = 0; a < 3; ++a) {
        const Eigen::Vector2d t = X(kEdge[a][1]) - X(kEdge[a][0]);
        b[std::size_t(a)] = (Eigen::Vector2d(t.y(), -t.x()) / 2.0).cast<T>();
      }
    } else {
      // Faces opposite each vertex, ordered so that (q - p) x (r - p) = 2 A n points outward.
      static constexpr int kFace[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
      for (int a = 0; a < 4; ++a) {
        const Eigen::Vector3d p = X(kFace[a][0]), q = X(kFace[a][1]), r = X(kFace[a][2]);
        b[std::size_t(a)] = ((q - p).cross(r - p) / 6.0).cast<T>();
      }
    }
    return b;
  }

  void gather(std::vector<Vec>& f) const {
    const std::int64_t n = std::int64_t(rest_.size());
    f.resize(rest_.size());
    detail::for_each(0, n, [&](std::int64_t i) {
      Vec s = Vec::Zero();
      for (int k = incidence_offset_[std::size_t(i)]; k < incidence_offset_[std::size_t(i) + 1]; ++k)
        s += element_force_[std::size_t(incidence_[std::size_t(k)])];
      f[std::size_t(i)] = s;
    });
  }

  /// The sparsity pattern of K and, per element and block entry, its position in valuePtr().
  void build_pattern() {
    if (stiffness_.nonZeros() > 0) return;
    const Eigen::Index N = Eigen::Index(rest_.size()) * Dim;
    std::vector<Eigen::Triplet<T>> t;
    t.reserve(elements_.size() * kNodes * kNodes * Dim * Dim);
    for (const auto& el : elements_)
      for (int a : el)
        for (int b : el)
          for (int r = 0; r < Dim; ++r)
            for (int c = 0; c < Dim; ++c) t.emplace_back(a * Dim + r, b * Dim + c, T(1));
    stiffness_.resize(N, N);
    stiffness_.setFromTriplets(t.begin(), t.end());
    stiffness_.makeCompressed();
    slot_.resize(elements_.size() * kNodes * kNodes * Dim * Dim);
    std::size_t s = 0;
    const auto* outer = stiffness_.outerIndexPtr();
    const auto* inner = stiffness_.innerIndexPtr();
    for (const auto& el : elements_)
      for (int a : el)
        for (int b : el)
          for (int r = 0; r < Dim; ++r)
            for (int c = 0; c < Dim; ++c) {
              // column-major: column b*Dim+c, find row a*Dim+r
              const int col = b * Dim + c, row = a * Dim + r;
              const auto* lo = inner + outer[col];
              const auto* hi = inner + outer[col + 1];
              slot_[s++] = int(std::lower_bound(lo, hi, row) - inner);
            }
  }

  /// sqrt(lambda_max(K0_e) / m_e) of element e (see max_frequency()).
  T element_frequency(std::size_t e) const {
    using Block = Eigen::Matrix<T, Dim * kNodes, Dim * kNodes>;
    const auto& m = material(e);
    std::array<Vec, kNodes> g;
    for (int a = 0; a < kNodes; ++a) g[std::size_t(a)] = -normals_[e][std::size_t(a)] / volume_[e];
    Block K;
    for (int a = 0; a < kNodes; ++a)
      for (int b = 0; b < kNodes; ++b) {
        const Vec& ga = g[std::size_t(a)];
        const Vec& gb = g[std::size_t(b)];
        K.template block<Dim, Dim>(a * Dim, b * Dim) =
            volume_[e] * (m.mu * ga.dot(gb) * Mat::Identity() + m.mu * gb * ga.transpose() + m.lambda * ga * gb.transpose());
      }
    const T lambda_max = Eigen::SelfAdjointEigenSolver<Block>(K, Eigen::EigenvaluesOnly).eigenvalues().maxCoeff();
    return std::sqrt(std::max(lambda_max, T(0)) / (m.density * volume_[e] / T(kNodes)));
  }

  /// sum_e factor(e) R K0_e R^T into the fixed pattern (rotations of the last forces()).
  template <class Factor>
  const Eigen::SparseMatrix<T>& assemble(const Factor& factor) {
    build_pattern();
    T* val = stiffness_.valuePtr();
    std::fill(val, val + stiffness_.nonZeros(), T(0));
    for (std::size_t e = 0; e < elements_.size(); ++e) {
      const auto& m = material(e);
      const T w = factor(e) * volume_[e];
      const Mat& R = rotation_[e];
      std::array<Vec, kNodes> g;  // rotated hat-function gradients R g_i = -R b_i / W
      for (int a = 0; a < kNodes; ++a) g[std::size_t(a)] = -(R * normals_[e][std::size_t(a)]) / volume_[e];
      const int* slots = &slot_[e * kNodes * kNodes * Dim * Dim];
      for (int a = 0; a < kNodes; ++a)
        for (int b = 0; b < kNodes; ++b) {
          const Vec& ga = g[std::size_t(a)];
          const Vec& gb = g[std::size_t(b)];
          const Mat block =
              w * (m.mu * ga.dot(gb) * Mat::Identity() + m.mu * gb * ga.transpose() + m.lambda * ga * gb.transpose());
          for (int r = 0; r < Dim; ++r)
            for (int c = 0; c < Dim; ++c) val[*slots++] += block(r, c);
        }
    }
    return stiffness_;
  }

  std::vector<FemMaterial<T>> materials_;
  std::vector<int> element_material_;
  std::vector<Element> elements_;
  std::vector<Vec> rest_;
  std::vector<Mat> Dm_inv_;
  std::vector<T> volume_;
  std::vector<std::array<Vec, kNodes>> normals_;
  std::vector<T> mass_;
  std::vector<int> incidence_offset_, incidence_;
  std::vector<Vec> element_force_, force_;
  std::vector<Mat> rotation_;
  Eigen::SparseMatrix<T> stiffness_;
  std::vector<int> slot_;
  Eigen::SparseMatrix<T> system_;  // M + dt^2 K + dt D of the last implicit step, pinned dofs identity
  mutable T element_dt_ = T(0);  // cached stability limit of explicit_dt
};

}  // namespace slurry::fem
