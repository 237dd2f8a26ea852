#pragma once
// What the three solvers' frame() functions share (private to the engine): the number format of
// messages and frame comments, and a builder for the "vertex" table of a frame.
#include <cstdint>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "slurry/engine/frame.h"

namespace slurry::detail {

/// x with 6 significant digits, for messages and frame comments.
inline std::string fmt(double x) {
  std::ostringstream o;
  o.precision(6);
  o << x;
  return o.str();
}

/// Builds a frame: the comment "slurry <kind>frame t=<t> source=<source>" and a "vertex" element
/// of n rows. Values of data index i land in row `rows[i]` (the MPM solver stores particles in
/// bin order and writes them in seeding order), or in row i when `rows` is null.
class VertexFrame {
 public:
  static constexpr const char* kPositionNames[3] = {"x", "y", "z"};
  static constexpr const char* kVelocityNames[3] = {"vx", "vy", "vz"};

  VertexFrame(const std::string& kind, double t, const std::string& source, std::size_t n,
              const std::uint32_t* rows = nullptr)
      : n_(n), rows_(rows) {
    data_.comments.push_back("slurry " + kind + "frame t=" + fmt(t) + " source=" + source);
    auto& el = data_.tables.emplace_back();
    el.name = "vertex";
    el.count = n;
  }

  /// A column called `name` whose value for data index i is value(i).
  template <class Value>
  void add(const char* name, Value&& value) {
    using V = std::decay_t<decltype(value(std::size_t(0)))>;
    std::vector<V> c(n_);
    for (std::size_t i = 0; i < n_; ++i) c[rows_ ? rows_[i] : i] = value(i);
    vertex().columns.push_back({name, std::move(c)});
  }
  /// An already ordered column (moved in as is).
  template <class V>
  void add_column(const char* name, std::vector<V> column) {
    vertex().columns.push_back({name, std::move(column)});
  }
  /// Dim columns x, y(, z) from positions or vx, vy(, vz) from velocities.
  template <int Dim, class Vecs>
  void add_positions(const Vecs& x) {
    for (int d = 0; d < Dim; ++d) add(kPositionNames[d], [&](std::size_t i) { return x[i][d]; });
  }
  template <int Dim, class Vecs>
  void add_velocities(const Vecs& v) {
    for (int d = 0; d < Dim; ++d) add(kVelocityNames[d], [&](std::size_t i) { return v[i][d]; });
  }

  /// Columns read in place when the frame is written (ColumnRef), for a frame that is
  /// written without a copy of the particles (Solver::frame_view): valid while the
  /// arrays are unchanged. Only for frames in storage order (no `rows`). A frame made of
  /// borrowed columns alone keeps the order of the calls, as add() does.
  template <class V>
  void borrow_column(const char* name, const std::vector<V>& column) {
    vertex().refs.push_back(ColumnRef::of(name, n_ ? column.data() : nullptr));
  }
  /// A column holding `value` on every row (read from one place: a stride of 0).
  template <class V>
  void borrow_constant(const char* name, const V& value) {
    vertex().refs.push_back(ColumnRef::of(name, &value, 0));
  }
  /// Dim columns x, y(, z) (or vx, vy(, vz)), each reading one component of the vectors.
  template <int Dim, class Vecs>
  void borrow_positions(const Vecs& x) {
    borrow_components<Dim>(kPositionNames, x);
  }
  template <int Dim, class Vecs>
  void borrow_velocities(const Vecs& v) {
    borrow_components<Dim>(kVelocityNames, v);
  }

  Frame& data() { return data_; }

 private:
  Table& vertex() { return data_.tables.front(); }

  template <int Dim, class Vecs>
  void borrow_components(const char* const* names, const Vecs& x) {
    using S = std::decay_t<decltype(x[0][0])>;
    for (int d = 0; d < Dim; ++d)
      vertex().refs.push_back(ColumnRef::of(names[d], n_ ? &x[0][d] : static_cast<const S*>(nullptr), sizeof(x[0])));
  }

  Frame data_;
  std::size_t n_;
  const std::uint32_t* rows_;
};

}  // namespace slurry::detail
