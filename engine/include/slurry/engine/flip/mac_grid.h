#pragma once
/// \file mac_grid.h
/// Staggered (MAC) grid of the FLIP liquid solver (Harlow & Welch 1965; Bridson, "Fluid
/// Simulation for Computer Graphics", 2nd ed., ch. 2): pressure, labels and the liquid level set
/// live at cell centres, velocity component d lives on the faces normal to axis d.
///
/// Layout: `res` cells per axis; cell i spans [origin + i dx, origin + (i + 1) dx] and its centre
/// is origin + (i + 1/2) dx. Axis-d faces number res + e_d; face i on axis d separates cells
/// i - e_d and i, and sits at origin + dx (i + 1/2 - 1/2 e_d). Every array is row-major with the
/// last axis fastest (the order of `cell()` and `face()`).
///
/// Per face: `u` (velocity), `weight` (fraction of the face open to fluid, 1 = open, 0 = closed
/// by a solid; Batty et al. 2007 / Ng et al. 2009 use it as the face-area fraction), `u_solid`
/// (normal velocity of the solid at the face) and `valid` (the velocity is known; extrapolation
/// fills the others). A grid without colliders stores neither `weight` nor `u_solid` (both
/// empty: every face inside the domain open, u_solid = 0; 27 MB on a 150 x 100 x 75 grid in
/// float); read them through face_weight() and face_u_solid(). Per cell: `label` (Air / Fluid /
/// Solid), `phi` (liquid signed distance, negative inside) and `pressure` (kept between steps to
/// warm-start the solve).
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "slurry/transfer/lattice.h"

namespace slurry::flip {

template <class T, int Dim>
struct MacGrid {
  static_assert(Dim == 2 || Dim == 3, "MacGrid is 2D or 3D");
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using IVec = Eigen::Matrix<int, Dim, 1>;
  enum Label : std::uint8_t { Air = 0, Fluid = 1, Solid = 2 };

  IVec res = IVec::Zero();  ///< cells per axis
  T dx = T(1);              ///< cell size
  Vec origin = Vec::Zero(); ///< cell (0,..) spans [origin + offset dx, origin + (offset + 1) dx]
  /// Where cell (0,..) lies in a larger grid of the same origin, of which this grid is a window
  /// (a run split over processes, flip/split.h); zero otherwise. Positions are scaled to that
  /// grid's cells first, (x - origin) / dx, and the offset subtracted after: the subtraction of
  /// an integer is exact, so a window finds a particle's cell and weights bit for bit as the
  /// whole grid does.
  IVec offset = IVec::Zero();
  std::array<std::vector<T>, Dim> u;                  ///< face velocities; axis-d faces: res + e_d
  std::array<std::vector<T>, Dim> weight;             ///< open fraction of each face, [0, 1] (or none)
  std::array<std::vector<T>, Dim> u_solid;            ///< solid velocity component at each face (or none)
  std::array<std::vector<std::uint8_t>, Dim> valid;   ///< face velocity known (extrapolation)
  std::vector<std::uint8_t> label;                    ///< per cell (Label)
  std::vector<T> phi;       ///< liquid signed distance at cell centres (< 0 inside)
  std::vector<T> pressure;  ///< per cell; kept between steps (warm start)

  /// Allocates every array: u = 0, weight = 1, u_solid = 0, valid = 0, label = Air,
  /// phi = +3 dx (outside), pressure = 0. Without `solid_faces` weight and u_solid stay empty.
  void resize(const IVec& new_res, T new_dx, const Vec& new_origin, bool solid_faces = true) {
    res = new_res;
    dx = new_dx;
    origin = new_origin;
    const std::size_t n = std::size_t(num_cells());
    label.assign(n, std::uint8_t(Air));
    phi.assign(n, T(3) * dx);
    pressure.assign(n, T(0));
    for (int d = 0; d < Dim; ++d) {
      const std::size_t nf = std::size_t(num_faces(d));
      u[d].assign(nf, T(0));
      weight[d].assign(solid_faces ? nf : 0, T(1));
      u_solid[d].assign(solid_faces ? nf : 0, T(0));
      valid[d].assign(nf, std::uint8_t(0));
    }
  }

  /// Number of cells.
  std::int64_t num_cells() const {
    std::int64_t n = 1;
    for (int d = 0; d < Dim; ++d) n *= res[d];
    return n;
  }
  /// Number of axis-d faces.
  std::int64_t num_faces(int d) const {
    const IVec fr = face_res(d);
    std::int64_t n = 1;
    for (int a = 0; a < Dim; ++a) n *= fr[a];
    return n;
  }

  /// Row-major cell index, last axis fastest.
  std::int64_t cell(const IVec& i) const { return transfer::lattice_index<Dim>(i, res); }
  /// Stride of the cell index along axis d.
  std::int64_t cell_stride(int d) const {
    std::int64_t s = 1;
    for (int a = Dim - 1; a > d; --a) s *= res[a];
    return s;
  }
  /// Cell coordinates of a cell index (inverse of cell()).
  IVec cell_coord(std::int64_t k) const { return transfer::lattice_coord<Dim>(k, res); }
  /// Whether pred(j) holds for a face neighbour j of cell k inside the grid.
  template <class Pred>
  bool any_face_neighbour(std::int64_t k, Pred&& pred) const {
    return any_face_neighbour(k, cell_coord(k), pred);
  }
  /// The same for cell k at coordinates i.
  template <class Pred>
  bool any_face_neighbour(std::int64_t k, const IVec& i, Pred&& pred) const {
    for (int d = 0; d < Dim; ++d) {
      const std::int64_t s = cell_stride(d);
      if ((i[d] > 0 && pred(k - s)) || (i[d] + 1 < res[d] && pred(k + s))) return true;
    }
    return false;
  }

  /// Axis-d face i separates cells i - e_d and i; it sits at origin + dx (i + 1/2 - 1/2 e_d).
  std::int64_t face(int d, const IVec& i) const { return transfer::lattice_index<Dim>(i, face_res(d)); }
  /// Stride of the axis-d face index along axis a.
  std::int64_t face_stride(int d, int a) const {
    const IVec fr = face_res(d);
    std::int64_t s = 1;
    for (int b = Dim - 1; b > a; --b) s *= fr[b];
    return s;
  }
  /// Face coordinates of an axis-d face index (inverse of face()).
  IVec face_coord(int d, std::int64_t k) const { return transfer::lattice_coord<Dim>(k, face_res(d)); }
  /// Axis-d faces per axis: res + e_d.
  IVec face_res(int d) const {
    IVec r = res;
    r[d] += 1;
    return r;
  }

  Vec face_position(int d, const IVec& i) const {
    Vec x = origin + dx * ((i + offset).template cast<T>() + Vec::Constant(T(0.5)));
    x[d] -= T(0.5) * dx;
    return x;
  }
  Vec cell_center(const IVec& i) const {
    return origin + dx * ((i + offset).template cast<T>() + Vec::Constant(T(0.5)));
  }

  /// Open fraction of axis-d face i as the pressure solve sees it: `weight` clamped to [0, 1],
  /// but 0 on the domain boundary (walls) and next to a cell labelled Solid. A face with open
  /// weight 0 is closed: its velocity is the solid's (u = u_solid).
  T open_weight(int d, const IVec& i) const {
    return open_weight(d, i[d], face(d, i), cell(i));  // cell(i) is only an index on the boundary
  }
  /// open_weight() from indices a loop already has: axis-d face f, whose coordinate along d is
  /// fd, between cells b - cell_stride(d) and b (b is not read on the domain boundary).
  T open_weight(int d, int fd, std::int64_t f, std::int64_t b) const {
    if (fd <= 0 || fd >= res[d]) return T(0);
    if (label[std::size_t(b - cell_stride(d))] == Solid || label[std::size_t(b)] == Solid) return T(0);
    return std::clamp(face_weight(d, f), T(0), T(1));
  }

  /// Whether the grid stores `weight` and `u_solid` (a scene with colliders).
  bool has_solid_faces() const { return !weight[0].empty(); }
  /// weight[d][f], or 1 without solid faces.
  T face_weight(int d, std::int64_t f) const { return weight[d].empty() ? T(1) : weight[d][std::size_t(f)]; }
  /// u_solid[d][f], or 0 without solid faces.
  T face_u_solid(int d, std::int64_t f) const { return u_solid[d].empty() ? T(0) : u_solid[d][std::size_t(f)]; }

  /// Component d at x by (bi/tri)linear interpolation of the axis-d face values; x is clamped
  /// to the box spanned by the face positions, so points outside read the nearest boundary.
  /// Flat index arithmetic: one base index and 2^Dim loads (the advection's inner loop).
  T sample(int d, const Vec& x) const {
    const T inv_dx = T(1) / dx;
    std::int64_t base = 0, step[Dim];
    T frac[Dim];
    std::int64_t stride = 1;
    for (int a = Dim - 1; a >= 0; --a) {
      const int n = res[a] + (a == d ? 1 : 0);
      // Faces of axis d sit at integer positions along d, half-integer ones along the others.
      T s = (x[a] - origin[a]) * inv_dx - (a == d ? T(0) : T(0.5)) - T(offset[a]);
      s = std::clamp(s, T(0), T(n - 1));
      int b = int(s);  // s >= 0: truncation is floor
      if (b >= n - 1) b = std::max(n - 2, 0);
      frac[a] = n > 1 ? s - T(b) : T(0);
      step[a] = n > 1 ? stride : 0;
      base += std::int64_t(b) * stride;
      stride *= n;
    }
    const T* f = u[d].data() + base;
    if constexpr (Dim == 2) {
      const T a0 = f[0] + frac[1] * (f[step[1]] - f[0]);
      const T a1 = f[step[0]] + frac[1] * (f[step[0] + step[1]] - f[step[0]]);
      return a0 + frac[0] * (a1 - a0);
    } else {
      const std::int64_t s0 = step[0], s1 = step[1], s2 = step[2];
      const T a00 = f[0] + frac[2] * (f[s2] - f[0]);
      const T a01 = f[s1] + frac[2] * (f[s1 + s2] - f[s1]);
      const T a10 = f[s0] + frac[2] * (f[s0 + s2] - f[s0]);
      const T a11 = f[s0 + s1] + frac[2] * (f[s0 + s1 + s2] - f[s0 + s1]);
      const T b0 = a00 + frac[1] * (a01 - a00);
      const T b1 = a10 + frac[1] * (a11 - a10);
      return b0 + frac[0] * (b1 - b0);
    }
  }

  /// All components at x (sample() per axis).
  Vec velocity(const Vec& x) const {
    Vec v;
    for (int d = 0; d < Dim; ++d) v[d] = sample(d, x);
    return v;
  }
};

}  // namespace slurry::flip
