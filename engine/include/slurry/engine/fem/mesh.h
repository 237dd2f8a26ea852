#pragma once
/// \file mesh.h
/// Simplicial meshes for the Lagrangian FEM solver: tetrahedra in 3D, triangles in 2D.
///
/// A Mesh<Dim> holds rest positions and elements of Dim + 1 vertex indices. Elements are stored
/// positively oriented, det Dm > 0 with Dm = [X_1 - X_0, ..., X_Dim - X_0] the rest edge matrix
/// (counter-clockwise triangles; tetrahedra whose first three vertices are counter-clockwise seen
/// from X_3, the fourth). `check_mesh` enforces
/// this and rejects degenerate elements; `orient_mesh` first flips a mesh whose elements all
/// follow the opposite convention (other mesh generators' choice) but rejects a mesh that mixes
/// both, which is a folded (inverted) mesh.
///
/// `box_mesh` meshes a box structurally: 2D cells are split into two triangles whose diagonal
/// alternates with the parity of the cell, 3D cells into five tetrahedra (one central, four
/// corner tetrahedra) with the split mirrored on alternate cells, so that neighbouring cells
/// share face diagonals and the mesh is symmetric under the box's reflections.
///
/// `ball_mesh` maps the structured mesh of a cube radially onto a ball (a disk in 2D).
///
/// `boundary_faces` extracts the surface: in 3D the triangles that belong to exactly one
/// tetrahedron, oriented with outward normals ((b - a) x (c - a) points out of the body); in 2D
/// the triangles themselves (a 2D body is drawn as its filled triangles).
#include <Eigen/Core>
#include <Eigen/LU>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "slurry/engine/errors.h"

namespace slurry::fem {

template <int Dim>
struct Mesh {
  static_assert(Dim == 2 || Dim == 3, "Mesh: Dim must be 2 or 3");
  static constexpr int kNodes = Dim + 1;  ///< vertices per element
  using Vec = Eigen::Matrix<double, Dim, 1>;
  using Element = std::array<int, Dim + 1>;

  std::vector<Vec> x;              ///< rest positions (m)
  std::vector<Element> elements;  ///< vertex indices into x

  std::size_t vertex_count() const { return x.size(); }
  std::size_t element_count() const { return elements.size(); }

  /// The rest edge matrix Dm = [X_1 - X_0, ..., X_Dim - X_0] of element e.
  Eigen::Matrix<double, Dim, Dim> edge_matrix(std::size_t e) const {
    Eigen::Matrix<double, Dim, Dim> Dm;
    for (int k = 0; k < Dim; ++k) Dm.col(k) = x[elements[e][k + 1]] - x[elements[e][0]];
    return Dm;
  }
  /// Signed rest volume det(Dm) / Dim! (area in 2D).
  double signed_volume(std::size_t e) const {
    return edge_matrix(e).determinant() / (Dim == 2 ? 2.0 : 6.0);
  }
  /// Longest and shortest edge of element e.
  std::pair<double, double> edge_range(std::size_t e) const {
    double lo = HUGE_VAL, hi = 0;
    for (int a = 0; a < kNodes; ++a)
      for (int b = a + 1; b < kNodes; ++b) {
        const double l = (x[elements[e][a]] - x[elements[e][b]]).norm();
        lo = std::min(lo, l);
        hi = std::max(hi, l);
      }
    return {lo, hi};
  }
  /// Shortest edge of the mesh (bounds the explicit time step).
  double shortest_edge() const {
    double h = HUGE_VAL;
    for (std::size_t e = 0; e < elements.size(); ++e) h = std::min(h, edge_range(e).first);
    return h;
  }
};

/// An element is degenerate when |det Dm| < kDegenerateRatio L^Dim, L its longest edge (a
/// regular element has |det Dm| of about 0.87 L^2 in 2D and 0.71 L^3 in 3D).
inline constexpr double kDegenerateRatio = 1e-8;

namespace detail {
inline std::string element_text(const int* v, int n) {
  std::string s;
  for (int k = 0; k < n; ++k) s += (k ? " " : "") + std::to_string(v[k]);
  return s;
}
}  // namespace detail

/// Throws SceneError naming `source` and the first bad element unless every element has
/// distinct vertex indices in range, is not degenerate, and is positively oriented.
template <int Dim>
void check_mesh(const Mesh<Dim>& mesh, const std::string& source) {
  const auto bad = [&](std::size_t e, const std::string& what) {
    throw SceneError(source + ": element " + std::to_string(e) + " (vertices " +
                     detail::element_text(mesh.elements[e].data(), Dim + 1) + ") " + what);
  };
  if (mesh.x.empty() || mesh.elements.empty())
    throw SceneError(source + ": the mesh is empty (expected at least one element)");
  for (std::size_t e = 0; e < mesh.elements.size(); ++e) {
    const auto& el = mesh.elements[e];
    for (int a = 0; a < Dim + 1; ++a) {
      if (el[a] < 0 || std::size_t(el[a]) >= mesh.x.size())
        bad(e, "refers to a vertex out of range (expected 0 to " + std::to_string(mesh.x.size() - 1) + ")");
      for (int b = 0; b < a; ++b)
        if (el[a] == el[b]) bad(e, "repeats a vertex (expected " + std::to_string(Dim + 1) + " distinct vertices)");
    }
    const double det = mesh.edge_matrix(e).determinant();
    const double L = mesh.edge_range(e).second;
    if (!(std::abs(det) >= kDegenerateRatio * std::pow(L, Dim)))
      bad(e, "is degenerate (volume " + std::to_string(det / (Dim == 2 ? 2.0 : 6.0)) +
                 " for a longest edge of " + std::to_string(L) + "; expected a non-flat element)");
    if (det < 0) bad(e, "is inverted (negative signed volume; expected positively oriented elements)");
  }
}

/// Makes every element positively oriented when the mesh consistently uses the opposite
/// orientation (swapping its last two vertices), then runs check_mesh. A mesh mixing both
/// orientations is folded: the first element against the majority is reported as inverted.
template <int Dim>
void orient_mesh(Mesh<Dim>& mesh, const std::string& source) {
  std::size_t negative = 0;
  for (std::size_t e = 0; e < mesh.elements.size(); ++e) {
    bool in_range = true;
    for (int v : mesh.elements[e]) in_range = in_range && v >= 0 && std::size_t(v) < mesh.x.size();
    if (in_range && mesh.edge_matrix(e).determinant() < 0) ++negative;
  }
  if (negative * 2 > mesh.elements.size())
    for (auto& el : mesh.elements) std::swap(el[Dim - 1], el[Dim]);
  check_mesh(mesh, source);
}

/// Structured mesh of the box [lo, hi] with `cells` cells per axis (see the file comment).
template <int Dim>
Mesh<Dim> box_mesh(const Eigen::Matrix<double, Dim, 1>& lo, const Eigen::Matrix<double, Dim, 1>& hi,
                   const Eigen::Matrix<int, Dim, 1>& cells) {
  Mesh<Dim> m;
  Eigen::Matrix<int, Dim, 1> n = cells.array() + 1;  // vertices per axis
  const auto id = [&](const Eigen::Matrix<int, Dim, 1>& c) {
    int i = c[Dim - 1];
    for (int d = Dim - 2; d >= 0; --d) i = i * n[d] + c[d];
    return i;
  };
  const int total = n.prod();
  m.x.resize(std::size_t(total));
  for (int i = 0; i < total; ++i) {
    int r = i;
    Eigen::Matrix<double, Dim, 1> p;
    for (int d = 0; d < Dim; ++d) {
      const int c = r % n[d];
      r /= n[d];
      p[d] = c == cells[d] ? hi[d] : lo[d] + (hi[d] - lo[d]) * double(c) / double(cells[d]);
    }
    m.x[std::size_t(i)] = p;
  }
  const int ncells = cells.prod();
  for (int ci = 0; ci < ncells; ++ci) {
    Eigen::Matrix<int, Dim, 1> c;
    int r = ci;
    for (int d = 0; d < Dim; ++d) c[d] = r % cells[d], r /= cells[d];
    const bool odd = c.sum() % 2 == 1;
    // corner(a, b[, z]): the cell's corner with offsets in {0, 1}.
    if constexpr (Dim == 2) {
      const auto k = [&](int a, int b) { return id(Eigen::Vector2i(c[0] + a, c[1] + b)); };
      if (!odd) {  // diagonal (0,0)-(1,1)
        m.elements.push_back({k(0, 0), k(1, 0), k(1, 1)});
        m.elements.push_back({k(0, 0), k(1, 1), k(0, 1)});
      } else {  // diagonal (1,0)-(0,1)
        m.elements.push_back({k(0, 0), k(1, 0), k(0, 1)});
        m.elements.push_back({k(1, 0), k(1, 1), k(0, 1)});
      }
    } else {
      const auto k = [&](int a, int b, int z) { return id(Eigen::Vector3i(c[0] + a, c[1] + b, c[2] + z)); };
      // Five-tetrahedron split: the central tetrahedron on the corners of one parity, and a
      // corner tetrahedron at each corner of the other parity (the corner and its three
      // neighbours). Alternating the parity between cells makes the face diagonals match.
      const int p = odd ? 1 : 0;
      std::array<Eigen::Vector3i, 4> central, tips;
      int nc = 0, nt = 0;
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b)
          for (int z = 0; z < 2; ++z) {
            if ((a + b + z + p) % 2 == 0)
              central[std::size_t(nc++)] = {a, b, z};
            else
              tips[std::size_t(nt++)] = {a, b, z};
          }
      const auto at = [&](const Eigen::Vector3i& o) { return k(o[0], o[1], o[2]); };
      m.elements.push_back({at(central[0]), at(central[1]), at(central[2]), at(central[3])});
      for (const auto& t : tips) {
        typename Mesh<3>::Element el{at(t), 0, 0, 0};
        for (int d = 0; d < 3; ++d) {
          Eigen::Vector3i o = t;
          o[d] = 1 - o[d];
          el[std::size_t(d + 1)] = at(o);
        }
        m.elements.push_back(el);
      }
    }
  }
  // The split above fixes vertex sets; orientation is made positive here.
  for (std::size_t e = 0; e < m.elements.size(); ++e)
    if (m.edge_matrix(e).determinant() < 0) std::swap(m.elements[e][Dim - 1], m.elements[e][Dim]);
  return m;
}

/// Structured mesh of [lo, hi] with cells as close to `spacing` as whole numbers allow (at
/// least one per axis).
template <int Dim>
Mesh<Dim> box_mesh(const Eigen::Matrix<double, Dim, 1>& lo, const Eigen::Matrix<double, Dim, 1>& hi,
                   double spacing) {
  Eigen::Matrix<int, Dim, 1> cells;
  for (int d = 0; d < Dim; ++d)
    cells[d] = std::max(1, int(std::lround((hi[d] - lo[d]) / spacing)));
  return box_mesh<Dim>(lo, hi, cells);
}

/// A ball (a disk in 2D) of `radius` around `center`: the structured mesh of the cube
/// [-1, 1]^Dim with `cells` cells per axis, each vertex p moved radially by the factor
/// 1 - s + s |p|_inf / |p|_2 with s = |p|_inf: the centre stays as it is and the cube's faces
/// go onto the sphere, which distorts the elements much less than scaling every vertex by
/// |p|_inf / |p|_2. Elements with every vertex on the cube's surface (at its edges and
/// corners) are dropped first: on the sphere they would be flat caps (slivers) that limit the
/// explicit step. Then scaled and shifted; every element is checked.
template <int Dim>
Mesh<Dim> ball_mesh(const Eigen::Matrix<double, Dim, 1>& center, double radius, int cells) {
  using V = Eigen::Matrix<double, Dim, 1>;
  Mesh<Dim> m = box_mesh<Dim>(V::Constant(-1), V::Constant(1), Eigen::Matrix<int, Dim, 1>::Constant(std::max(2, cells)));
  // Elements whose vertices all lie on the cube's surface (along its edges and corners) would
  // become flat caps on the sphere: drop them, and the vertices only they used.
  std::vector<char> surface(m.x.size()), used(m.x.size(), 0);
  for (std::size_t i = 0; i < m.x.size(); ++i) surface[i] = m.x[i].cwiseAbs().maxCoeff() > 1 - 1e-12;
  std::vector<typename Mesh<Dim>::Element> kept;
  for (const auto& el : m.elements) {
    bool all = true;
    for (int k : el) all = all && surface[std::size_t(k)];
    if (all) continue;
    kept.push_back(el);
    for (int k : el) used[std::size_t(k)] = 1;
  }
  std::vector<int> index(m.x.size(), -1);
  std::vector<V> xs;
  for (std::size_t i = 0; i < m.x.size(); ++i)
    if (used[i]) index[i] = int(xs.size()), xs.push_back(m.x[i]);
  for (auto& el : kept)
    for (int& k : el) k = index[std::size_t(k)];
  m.x = std::move(xs);
  m.elements = std::move(kept);
  for (auto& p : m.x) {
    const double n2 = p.norm(), ninf = p.cwiseAbs().maxCoeff();
    const V q = n2 > 0 ? V(p * (1 - ninf + ninf * ninf / n2)) : V::Zero();
    p = center + radius * q;
  }
  check_mesh(m, "ball_mesh");
  return m;
}

/// The surface for output: see the file comment. Each face lists Dim vertex indices in 3D
/// (outward triangles) and 3 in 2D (the triangles).
template <int Dim>
std::vector<std::array<int, 3>> boundary_faces(const Mesh<Dim>& mesh) {
  std::vector<std::array<int, 3>> faces;
  if constexpr (Dim == 2) {
    faces.reserve(mesh.elements.size());
    for (const auto& el : mesh.elements) faces.push_back({el[0], el[1], el[2]});
  } else {
    // Faces opposite vertex 0..3 of a positively oriented tetrahedron, with outward normals.
    static constexpr int kFace[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    std::map<std::array<int, 3>, std::pair<int, std::array<int, 3>>> seen;  // sorted -> (count, face)
    for (const auto& el : mesh.elements)
      for (const auto& f : kFace) {
        std::array<int, 3> face{el[std::size_t(f[0])], el[std::size_t(f[1])], el[std::size_t(f[2])]};
        std::array<int, 3> key = face;
        std::sort(key.begin(), key.end());
        auto [it, inserted] = seen.try_emplace(key, 0, face);
        ++it->second.first;
      }
    for (const auto& [key, value] : seen)
      if (value.first == 1) faces.push_back(value.second);
  }
  return faces;
}

}  // namespace slurry::fem
