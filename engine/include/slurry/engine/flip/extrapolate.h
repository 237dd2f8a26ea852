#pragma once
/// \file extrapolate.h
/// Extends face velocities from the faces where they are known (`valid`, set by the pressure
/// projection on faces next to fluid) into the air, layer by layer, so that particles near the
/// free surface and the advection read fluid velocities (Bridson, "Fluid Simulation for Computer
/// Graphics", 2nd ed., sec. 4.4 and 7.x: breadth-first extrapolation).
///
/// Layer L fills every invalid, open face that has a neighbour (along any axis, in the same
/// component's face grid) valid before layer L. Its value:
/// - Linear (default): the mean over axes and directions of the linear extrapolations
///   2 u(f - s) - u(f - 2s) where both faces behind f were valid; this reproduces a linear field
///   exactly. Faces without such a pair take the constant rule below.
/// - Constant: the mean of the valid neighbours (Bridson's rule).
/// A layer reads only faces valid before it, so the result does not depend on the order or the
/// thread count. Faces of open weight 0 (MacGrid::open_weight: walls, solids) keep u = u_solid
/// and are neither sources nor targets. Filled faces are marked valid.
///
/// Cost: one pass over every face for the closed/valid stamps, and one for layer 1 that compares
/// stamp bytes row by row and evaluates only the unknown faces next to a valid one; each later
/// layer visits only the faces filled by the layer before it (a narrow band around the liquid,
/// not the whole grid). A face of layer L is found from its neighbour of layer L - 1 with the smallest
/// index, so the band lists are built in parallel without atomics; the values depend only on
/// faces of earlier layers, so the result is bitwise independent of the thread count.
#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "slurry/engine/flip/mac_grid.h"
#include "slurry/transfer/parallel.h"

namespace slurry::flip {

enum class Extrapolation { Constant, Linear };

/// Extrapolation with its scratch kept between calls (no allocation once sizes have settled).
template <class T, int Dim>
class Extrapolator {
 public:
  using IVec = typename MacGrid<T, Dim>::IVec;

  /// Bytes held by the scratch (capacity).
  std::size_t bytes() const {
    std::size_t b = stamp_.capacity();
    for (const auto& set : lists_)
      for (const auto& l : set) b += l.capacity() * sizeof(IVec);
    return b;
  }

  /// Fills up to `layers` (at most 120) layers of invalid faces from valid neighbours; returns
  /// the number of faces filled. With `mark_valid` false the filled faces stay invalid (`valid`
  /// is left as it was): for extending a field other than the velocity held in g.u.
  std::int64_t run(MacGrid<T, Dim>& g, int layers, Extrapolation rule = Extrapolation::Linear, bool mark_valid = true) {
    layers = std::clamp(layers, 0, 120);
    std::int64_t filled = 0;
    for (int d = 0; d < Dim; ++d) filled += run_axis(g, d, layers, rule, mark_valid);
    return filled;
  }

 private:
  static constexpr int L = Dim - 1;       // rows run along the last axis
  static constexpr std::int64_t kRowsPerTask = 32;
  static constexpr int kBlock = 64;  // faces per block of layer 1's scan of a row
  std::vector<std::int8_t> stamp_;       // -2 closed, -1 unknown, 0 valid on entry, L filled by layer L
  // Faces are listed by their coordinates: the next layer needs them, and dividing a face
  // index back into coordinates cost more than the rest of a band face's work. A layer's faces
  // stay in the lists of the tasks that found them (one list per task of layer 1's rows), and
  // task t of the next layer reads list t of one set and writes list t of the other: no
  // serial concatenation between layers.
  std::array<std::vector<std::vector<IVec>>, 2> lists_;

  // Per-axis geometry of the face grid being filled.
  IVec fr_;
  std::array<std::int64_t, Dim> stride_{};

  std::int64_t index(const IVec& i) const {
    std::int64_t f = 0;
    for (int a = 0; a < Dim; ++a) f += std::int64_t(i[a]) * stride_[a];
    return f;
  }

  bool known(std::int64_t f, int layer) const {
    const int s = stamp_[std::size_t(f)];
    return s >= 0 && s < layer;
  }

  /// Value of face f (coordinates fi) from the faces known before `layer`; false if none is.
  bool value(const MacGrid<T, Dim>& g, int d, std::int64_t f, const IVec& fi, int layer, Extrapolation rule,
             T& out) const {
    const T* u = g.u[d].data();
    double lin = 0, con = 0;
    int n_lin = 0, n_con = 0;
    for (int a = 0; a < Dim; ++a) {
      for (int dir = -1; dir <= 1; dir += 2) {
        const int i1 = fi[a] + dir, i2 = fi[a] + 2 * dir;
        if (i1 < 0 || i1 >= fr_[a]) continue;
        const std::int64_t f1 = f + dir * stride_[a];
        if (!known(f1, layer)) continue;
        const double u1 = double(u[f1]);
        con += u1;
        ++n_con;
        if (rule == Extrapolation::Linear && i2 >= 0 && i2 < fr_[a]) {
          const std::int64_t f2 = f + 2 * dir * stride_[a];
          if (known(f2, layer)) {
            lin += 2 * u1 - double(u[f2]);
            ++n_lin;
          }
        }
      }
    }
    if (n_con == 0) return false;
    out = T(n_lin > 0 ? lin / n_lin : con / n_con);
    return true;
  }

  void ensure_lists(std::int64_t tasks) {
    for (auto& set : lists_)
      if (std::int64_t(set.size()) < tasks) set.resize(std::size_t(tasks));
  }

  std::int64_t run_axis(MacGrid<T, Dim>& g, int d, int layers, Extrapolation rule, bool mark_valid) {
    const std::int64_t nf = g.num_faces(d);
    fr_ = g.face_res(d);
    for (int a = 0; a < Dim; ++a) stride_[a] = g.face_stride(d, a);
    stamp_.resize(std::size_t(nf));
    const std::int64_t row_len = fr_[L], rows = nf / row_len;
    std::array<std::int64_t, Dim> cstride{};
    for (int a = 0; a < Dim; ++a) cstride[a] = g.cell_stride(a);
    T* u = g.u[d].data();
    const T* us = g.has_solid_faces() ? g.u_solid[d].data() : nullptr;  // none: weight 1, u_solid 0
    const T* w = g.has_solid_faces() ? g.weight[d].data() : nullptr;
    std::uint8_t* valid = g.valid[d].data();
    std::uint8_t* marked = mark_valid ? valid : nullptr;
    const std::uint8_t* label = g.label.data();
    const auto row_coord = [&](std::int64_t r, IVec& i) {
      for (int a = L - 1; a >= 0; --a) {
        i[a] = int(r % fr_[a]);
        r /= fr_[a];
      }
      i[L] = 0;
    };
    // Stamps: closed faces (MacGrid::open_weight <= 0) take u_solid; valid faces are layer 0.
    parallel::parallel_chunks(0, rows, [&](std::int64_t r0, std::int64_t r1) {
      IVec i;
      for (std::int64_t r = r0; r < r1; ++r) {
        row_coord(r, i);
        bool row_closed = false;
        std::int64_t cell0 = 0;  // cell i (with i[L] = 0) when the row's faces are interior along d
        for (int a = 0; a < L; ++a) cell0 += std::int64_t(i[a]) * cstride[a];
        if (d != L) row_closed = i[d] <= 0 || i[d] >= g.res[d];
        const std::int64_t f0 = r * row_len;
        for (std::int64_t j = 0; j < row_len; ++j) {
          const std::int64_t f = f0 + j;
          bool closed = row_closed;
          if (!closed) {
            if (d == L) {
              closed = j <= 0 || j >= g.res[L] || label[cell0 + j - 1] == MacGrid<T, Dim>::Solid ||
                       label[cell0 + j] == MacGrid<T, Dim>::Solid;
            } else {
              closed = label[cell0 + j - cstride[d]] == MacGrid<T, Dim>::Solid ||
                       label[cell0 + j] == MacGrid<T, Dim>::Solid;
            }
            closed = closed || (w && !(w[f] > T(0)));
          }
          if (closed) {
            stamp_[std::size_t(f)] = -2;
            u[f] = us ? us[f] : T(0);
          } else {
            stamp_[std::size_t(f)] = valid[f] ? 0 : -1;
          }
        }
      }
    });
    if (layers == 0) return 0;
    // Layer 1: every unknown face next to a valid one (one pass over the grid).
    const std::int64_t row_tasks = (rows + kRowsPerTask - 1) / kRowsPerTask;
    ensure_lists(row_tasks);
    std::int64_t filled = parallel::parallel_sum<std::int64_t>(0, row_tasks, 1, [&](std::int64_t t, std::int64_t) {
      // Appended to through a local vector: the vectors' headers of neighbouring tasks share
      // cache lines, and a push_back writes its vector's header.
      std::vector<IVec> list;
      list.swap(lists_[0][std::size_t(t)]);
      list.clear();
      IVec i;
      const std::int64_t r1 = std::min(rows, (t + 1) * kRowsPerTask);
      const std::int8_t* stamp = stamp_.data();
      for (std::int64_t r = t * kRowsPerTask; r < r1; ++r) {
        row_coord(r, i);
        const std::int64_t f0 = r * row_len;
        // The rows beside this one (across the other axes), inside the face grid.
        const std::int8_t* side[2 * L + 1];
        int n_side = 0;
        for (int a = 0; a < L; ++a) {
          if (i[a] > 0) side[n_side++] = stamp + f0 - stride_[a];
          if (i[a] + 1 < fr_[a]) side[n_side++] = stamp + f0 + stride_[a];
        }
        const std::int8_t* s = stamp + f0;
        // Most faces are far from the liquid: find the unknown faces with a neighbour valid on
        // entry (stamp 0) with byte compares over blocks of the row, and evaluate only those
        // (value() would return false for every other face, so the result is the same).
        for (std::int64_t j0 = 0; j0 < row_len; j0 += kBlock) {
          const int nj = int(std::min<std::int64_t>(kBlock, row_len - j0));
          std::uint8_t near[kBlock];
          for (int k = 0; k < nj; ++k) near[k] = 0;
          for (int q = 0; q < n_side; ++q)
            for (int k = 0; k < nj; ++k) near[k] |= std::uint8_t(side[q][j0 + k] == 0);
          for (int k = 0; k < nj; ++k) {
            const std::int64_t j = j0 + k;
            const bool along = (j > 0 && s[j - 1] == 0) || (j + 1 < row_len && s[j + 1] == 0);
            near[k] = std::uint8_t((near[k] | std::uint8_t(along)) & std::uint8_t(s[j] == -1));
          }
          for (int k = 0; k < nj; ++k) {
            if (!near[k]) continue;
            const std::int64_t j = j0 + k, f = f0 + j;
            i[L] = int(j);
            T v;
            if (!value(g, d, f, i, 1, rule, v)) continue;
            u[f] = v;  // safe: this layer reads only faces known before it, and f is not one
            list.push_back(i);
          }
        }
      }
      const std::int64_t found = std::int64_t(list.size());
      list.swap(lists_[0][std::size_t(t)]);
      return found;
    });
    mark(lists_[0], row_tasks, marked, 1);
    // Later layers: the unknown neighbours of the last layer's faces.
    std::int64_t last = filled;
    int from = 0;
    for (int layer = 2; layer <= layers && last > 0; ++layer) {
      const auto& in = lists_[std::size_t(from)];
      auto& out = lists_[std::size_t(1 - from)];
      last = parallel::parallel_sum<std::int64_t>(0, row_tasks, 1, [&](std::int64_t t, std::int64_t) {
        std::vector<IVec> list;  // local, as in layer 1
        list.swap(out[std::size_t(t)]);
        list.clear();
        for (const IVec& si : in[std::size_t(t)]) {
          const std::int64_t src = index(si);
          for (int a = 0; a < Dim; ++a)
            for (int dir = -1; dir <= 1; dir += 2) {
              const int ia = si[a] + dir;
              if (ia < 0 || ia >= fr_[a]) continue;
              const std::int64_t f = src + dir * stride_[a];
              if (stamp_[std::size_t(f)] != -1) continue;
              IVec fi = si;
              fi[a] = ia;
              if (owner(f, fi, layer - 1) != src) continue;  // found once, by its lowest source
              T v;
              value(g, d, f, fi, layer, rule, v);  // src is known: never false
              u[f] = v;
              list.push_back(fi);
            }
        }
        const std::int64_t found = std::int64_t(list.size());
        list.swap(out[std::size_t(t)]);
        return found;
      });
      filled += last;
      mark(out, row_tasks, marked, layer);
      from = 1 - from;
    }
    return filled;
  }

  /// Lowest-index neighbour of f (coordinates fi) stamped `layer`.
  std::int64_t owner(std::int64_t f, const IVec& fi, int layer) const {
    std::int64_t best = -1;
    // Neighbours in increasing index order: -stride along axes 0..L, then +stride along L..0.
    for (int a = 0; a < Dim && best < 0; ++a)
      if (fi[a] > 0 && stamp_[std::size_t(f - stride_[a])] == layer) best = f - stride_[a];
    for (int a = Dim - 1; a >= 0 && best < 0; --a)
      if (fi[a] + 1 < fr_[a] && stamp_[std::size_t(f + stride_[a])] == layer) best = f + stride_[a];
    return best;
  }

  /// Stamps the faces of the first `n` lists with `layer` and marks them valid (unless `valid`
  /// is null).
  void mark(const std::vector<std::vector<IVec>>& lists, std::int64_t n, std::uint8_t* valid, int layer) {
    parallel::parallel_for_grain(0, n, 1, [&](std::int64_t t) {
      for (const IVec& i : lists[std::size_t(t)]) {
        const std::int64_t f = index(i);
        stamp_[std::size_t(f)] = std::int8_t(layer);
        if (valid) valid[f] = 1;
      }
    });
  }
};

/// Fills up to `layers` layers of invalid faces from valid neighbours; returns the number of faces
/// filled (one-call form of Extrapolator::run).
template <class T, int Dim>
std::int64_t extrapolate(MacGrid<T, Dim>& g, int layers, Extrapolation rule = Extrapolation::Linear) {
  Extrapolator<T, Dim> e;
  return e.run(g, layers, rule);
}

}  // namespace slurry::flip
