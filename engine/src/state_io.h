// Binary (de)serialisation of solver state for checkpoints and the retry snapshot
// (Solver::save_state / load_state): plain bytes in this machine's byte order, every
// vector prefixed by its length. Nothing is converted: a checkpoint is read back on a machine of
// the byte order that wrote it (its header, checkpoint.h, carries a byte-order mark, a format
// version and a checksum).
#pragma once
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "slurry/engine/errors.h"

namespace slurry::detail {

template <class V>
inline constexpr bool kPlainBytes =
    std::is_trivially_copyable_v<V> || std::is_base_of_v<Eigen::EigenBase<V>, V>;

class StateWriter {
 public:
  using Sink = std::function<void(const char* data, std::size_t size)>;
  /// Appends to `out`.
  explicit StateWriter(std::string& out) : out_([&out](const char* d, std::size_t n) { out.append(d, n); }) {}
  /// Hands the bytes to `sink` (Solver::StateSink), a whole vector at a time.
  explicit StateWriter(const Sink& sink) : out_(sink) {}
  /// A scalar or a fixed-size Eigen object, as its bytes.
  template <class V>
  void pod(const V& v) {
    static_assert(kPlainBytes<V>);
    out_(reinterpret_cast<const char*>(&v), sizeof(V));
  }
  template <class V>
  void vec(const std::vector<V>& v) {
    static_assert(kPlainBytes<V>);
    pod(std::uint64_t(v.size()));
    if (!v.empty()) out_(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(V));
  }
  /// n copies of v, as vec() writes a vector of them, without building that vector (a few
  /// kB at a time).
  template <class V>
  void repeated(const V& v, std::uint64_t n) {
    static_assert(kPlainBytes<V>);
    pod(n);
    constexpr std::size_t kChunk = 1024;
    V chunk[kChunk];
    for (auto& c : chunk) c = v;
    for (std::uint64_t done = 0; done < n;) {
      const std::size_t k = std::size_t(std::min<std::uint64_t>(kChunk, n - done));
      out_(reinterpret_cast<const char*>(chunk), k * sizeof(V));
      done += k;
    }
  }
  void text(const std::string& s) {
    pod(std::uint64_t(s.size()));
    out_(s.data(), s.size());
  }
  /// The generator's state in its standard text form (operator<<, exact for mt19937_64).
  void rng(const std::mt19937_64& g) {
    std::ostringstream o;
    o << g;
    text(o.str());
  }
  /// A section tag: load_state checks it, so that a layout mismatch is named, not misread.
  void tag(std::uint32_t t) { pod(t); }

 private:
  Sink out_;
};

class StateReader {
 public:
  StateReader(std::string_view in, std::string what) : in_(in), what_(std::move(what)) {}
  template <class V>
  void pod(V& v) {
    static_assert(kPlainBytes<V>);
    need(sizeof(V), "a value");
    std::memcpy(static_cast<void*>(&v), in_.data() + at_, sizeof(V));
    at_ += sizeof(V);
  }
  template <class V>
  V get() {
    V v{};
    pod(v);
    return v;
  }
  /// A vector; `expected` (if not -1) is the length it must have.
  template <class V>
  void vec(std::vector<V>& v, std::int64_t expected = -1, const char* name = "a channel") {
    const std::string_view bytes = vec_bytes<V>(expected, name);
    v.resize(bytes.size() / sizeof(V));
    if (!bytes.empty()) std::memcpy(static_cast<void*>(v.data()), bytes.data(), bytes.size());
  }
  /// The bytes of the entries of a vector of V that vec() would read, with the same checks, for
  /// a reader that stores them otherwise (unaligned: copy them out with memcpy).
  template <class V>
  std::string_view vec_bytes(std::int64_t expected, const char* name) {
    static_assert(kPlainBytes<V>);
    const auto n = get<std::uint64_t>();
    if (expected >= 0 && n != std::uint64_t(expected))
      fail(std::string(name) + " has " + std::to_string(n) + " entries, expected " +
           std::to_string(expected));
    if (n > (in_.size() - at_) / std::max<std::size_t>(1, sizeof(V))) need(std::size_t(-1), name);
    const std::string_view bytes = in_.substr(at_, std::size_t(n) * sizeof(V));
    at_ += bytes.size();
    return bytes;
  }
  std::string text() {
    const auto n = get<std::uint64_t>();
    need(n, "a string");
    std::string s(in_.substr(at_, std::size_t(n)));
    at_ += std::size_t(n);
    return s;
  }
  void rng(std::mt19937_64& g) {
    std::istringstream i(text());
    i >> g;
    if (!i) fail("a random generator state does not parse");
  }
  void tag(std::uint32_t t, const char* name) {
    if (get<std::uint32_t>() != t) fail(std::string("expected the ") + name + " section");
  }
  /// Whether every byte was read.
  bool done() const { return at_ == in_.size(); }
  /// Throws unless every byte was read.
  void finish() {
    if (at_ != in_.size())
      fail(std::to_string(in_.size() - at_) + " bytes left over after the state");
  }
  [[noreturn]] void fail(const std::string& why) const {
    throw IoError(what_ + ": the solver state does not fit this scene: " + why);
  }

 private:
  void need(std::size_t n, const char* name) {
    if (n > in_.size() - at_)
      throw IoError(what_ + ": truncated solver state (reading " + name + ")");
  }
  std::string_view in_;
  std::size_t at_ = 0;
  std::string what_;
};

// A checkpoint is untrusted input however valid its checksum: a position outside the grid, a
// repeated id or a non-finite value would index outside an array or poison the run. These
// checks name the channel and the particle.

/// Every entry finite (Eigen vectors and matrices, or scalars).
template <class V>
void require_finite(const StateReader& r, const std::vector<V>& values, const char* name) {
  for (std::size_t i = 0; i < values.size(); ++i) {
    bool ok;
    if constexpr (std::is_arithmetic_v<V>)
      ok = std::isfinite(values[i]);
    else
      ok = values[i].allFinite();
    if (!ok) r.fail(std::string(name) + " of particle " + std::to_string(i) + " is not finite");
  }
}

/// Every position finite and inside the box [lo, hi].
template <class Vec>
void require_inside(const StateReader& r, const std::vector<Vec>& x, const Vec& lo, const Vec& hi) {
  for (std::size_t i = 0; i < x.size(); ++i)
    if (!(x[i].allFinite() && (x[i].array() >= lo.array()).all() && (x[i].array() <= hi.array()).all()))
      r.fail("the position of particle " + std::to_string(i) + " is not finite or lies outside the grid");
}

/// Every value finite and > 0 (masses, volumes, J).
template <class S>
void require_positive(const StateReader& r, const std::vector<S>& values, const char* name) {
  for (std::size_t i = 0; i < values.size(); ++i)
    if (!(values[i] > S(0) && std::isfinite(values[i])))
      r.fail(std::string(name) + " of particle " + std::to_string(i) + " is not a finite value > 0");
}

/// Ids distinct and below `bound`.
inline void require_unique_ids(const StateReader& r, const std::vector<std::uint32_t>& id, std::uint64_t bound) {
  std::vector<bool> seen(std::size_t(std::min<std::uint64_t>(bound, id.size() * 4 + 64)), false);
  std::vector<std::uint32_t> big;  // ids beyond the bitmap (emitters and reseeding leave gaps)
  for (std::size_t i = 0; i < id.size(); ++i) {
    if (id[i] >= bound) r.fail("the id " + std::to_string(id[i]) + " of particle " + std::to_string(i) + " is not below " + std::to_string(bound));
    if (id[i] < seen.size()) {
      if (seen[id[i]]) r.fail("the id " + std::to_string(id[i]) + " is held by more than one particle");
      seen[id[i]] = true;
    } else {
      big.push_back(id[i]);
    }
  }
  std::sort(big.begin(), big.end());
  if (std::adjacent_find(big.begin(), big.end()) != big.end())
    r.fail("the id " + std::to_string(*std::adjacent_find(big.begin(), big.end())) + " is held by more than one particle");
}


/// Section tags ("MPM ", "FLIP", "FEM ") and the (Dim, sizeof T) check shared by the solvers.
inline constexpr std::uint32_t kTagMpm = 0x204d504d, kTagFlip = 0x50494c46, kTagFem = 0x204d4546,
                               kTagEnd = 0x20444e45,
                               kTagPart = 0x54524150;  // "PART": one process's part of a split run's state

template <class T, int Dim>
void write_layout(StateWriter& w, std::uint32_t solver) {
  w.tag(solver);
  w.pod(std::uint32_t(Dim));
  w.pod(std::uint32_t(sizeof(T)));
}

template <class T, int Dim>
void read_layout(StateReader& r, std::uint32_t solver, const char* name) {
  r.tag(solver, name);
  const auto dim = r.get<std::uint32_t>(), size = r.get<std::uint32_t>();
  if (dim != std::uint32_t(Dim) || size != std::uint32_t(sizeof(T)))
    r.fail("it was written by a " + std::to_string(dim) + "D " + (size == 4 ? "float" : "double") +
           " simulation, this one is " + std::to_string(Dim) + "D " +
           (sizeof(T) == 4 ? "float" : "double"));
}

}  // namespace slurry::detail
