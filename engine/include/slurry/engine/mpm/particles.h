#pragma once
/// \file particles.h
/// Lagrangian particles as a structure of arrays, one std::vector per named channel.
///
/// Only the channels a scene's materials need are allocated (`Channels`): position, velocity,
/// mass and rest volume always; the deformation gradient F for solids; the volume ratio J for
/// fluids (weakly compressible materials need det F only); the affine matrix C for APIC and
/// MLS transfers; a plastic state for plastic materials; a material id when a scene has more than
/// one material. Unallocated channels are empty vectors.
///
/// Mass and rest volume are the same for every particle of a body, and usually of a whole
/// scene: they are `ScalarChannel`s, stored once while every particle has the same value and per
/// particle from the first particle that differs (8 bytes per particle in 3D float).
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

namespace slurry {

/// Which optional channels exist.
struct Channels {
  bool F = false;
  bool J = false;
  bool C = false;
  bool plastic = false;
  bool material = false;
};

/// A scalar per particle that is stored once while every particle has the same value (the same
/// bits), and one value per particle from the first particle that differs. `c[p]` reads either
/// way; a hot loop reads c.read_base()[p & c.read_mask()], the same code for both storages
/// (no branch, and no second copy of the loop).
template <class T>
class ScalarChannel {
 public:
  /// Whether `value()` is every particle's value (then nothing is stored per particle).
  bool uniform() const { return uniform_; }
  /// Every particle's value, while uniform().
  T value() const { return value_; }
  /// The values per particle, or null while uniform().
  const T* per_particle() const { return uniform_ ? nullptr : values_.data(); }
  /// Particle p's value.
  T operator[](std::size_t p) const { return uniform_ ? value_ : values_[p]; }
  /// Particle p's value is read_base()[p & read_mask()]: the one value and mask 0 while
  /// uniform(), the values and mask ~0 otherwise. Valid until the channel changes.
  const T* read_base() const { return uniform_ ? &value_ : values_.data(); }
  std::size_t read_mask() const { return uniform_ ? 0 : ~std::size_t(0); }

  /// The per-particle storage: empty while uniform(). Code that moves whole particles
  /// (Particles::for_each_channel) resizes and permutes it like any other channel.
  std::vector<T>& values() { return values_; }
  const std::vector<T>& values() const { return values_; }

  /// Appends the value of a particle to `count` particles (the count before it).
  void push_back(T v, std::size_t count) {
    if (uniform_ && (count == 0 || same_bits(v, value_))) {
      value_ = v;
      return;
    }
    materialize(count);
    values_.push_back(v);
  }
  /// Stores a value per particle from now on: `count` particles of value().
  void materialize(std::size_t count) {
    if (!uniform_) return;
    values_.assign(count, value_);
    uniform_ = false;
  }
  /// Every particle has value v.
  void assign_uniform(T v) {
    values_ = std::vector<T>();
    value_ = v;
    uniform_ = true;
  }
  /// One value per particle: stored once if they all have the same bits (or there are none).
  void assign(std::vector<T> v) {
    bool same = true;
    for (std::size_t p = 1; p < v.size() && same; ++p) same = same_bits(v[p], v[0]);
    if (same) {
      assign_uniform(v.empty() ? T(0) : v[0]);
    } else {
      values_ = std::move(v);
      uniform_ = false;
    }
  }
  /// No values, stored as this channel is: once with the same value, or per particle.
  ScalarChannel empty_like() const {
    ScalarChannel c;
    if (uniform_)
      c.assign_uniform(value_);
    else
      c.materialize(0);
    return c;
  }
  /// Bytes held (capacity).
  std::size_t bytes() const { return values_.capacity() * sizeof(T); }

  /// Whether a and b have the same bits (-0 and 0, or two NaNs, may not).
  static bool same_bits(T a, T b) { return std::memcmp(&a, &b, sizeof(T)) == 0; }

 private:
  std::vector<T> values_;
  T value_ = T(0);
  bool uniform_ = true;
};

template <class T, int Dim>
struct Particles {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;

  Channels channels;
  std::vector<Vec> x;      ///< position (m)
  std::vector<Vec> v;      ///< velocity (m/s)
  ScalarChannel<T> m;      ///< mass (kg)
  ScalarChannel<T> vol0;   ///< rest volume (m^3; m^2 in 2D)
  std::vector<Mat> F;      ///< (elastic) deformation gradient, solids
  std::vector<T> J;        ///< volume ratio det F, fluids
  std::vector<Mat> C;      ///< affine velocity matrix, APIC/MLS
  std::vector<T> plastic;  ///< plastic state: Jp (snow) or accumulated plastic strain
  std::vector<std::uint16_t> material;  ///< index into the scene's materials
  /// Seeding index: the solver re-stores particles in grid-block order for speed, frames list
  /// them by id, so particle k of every frame is the same particle.
  std::vector<std::uint32_t> id;

  std::size_t size() const { return x.size(); }

  /// Appends one particle; optional channels start at rest (F = I, J = 1, C = 0, Jp = 1 for
  /// snow is set by the caller through `plastic_init`).
  void push_back(const Vec& pos, const Vec& vel, T mass, T volume, std::uint16_t mat, T plastic_init) {
    m.push_back(mass, size());
    vol0.push_back(volume, size());
    x.push_back(pos);
    v.push_back(vel);
    if (channels.F) F.push_back(Mat::Identity());
    if (channels.J) J.push_back(T(1));
    if (channels.C) C.push_back(Mat::Zero());
    if (channels.plastic) plastic.push_back(plastic_init);
    if (channels.material) material.push_back(mat);
    id.push_back(std::uint32_t(id.size()));
  }
  /// Appends particle p of Q (the same channels) with every value it carries, its id included.
  void push_back_from(const Particles& Q, std::size_t p) {
    m.push_back(Q.m[p], size());
    vol0.push_back(Q.vol0[p], size());
    x.push_back(Q.x[p]);
    v.push_back(Q.v[p]);
    if (channels.F) F.push_back(Q.F[p]);
    if (channels.J) J.push_back(Q.J[p]);
    if (channels.C) C.push_back(Q.C[p]);
    if (channels.plastic) plastic.push_back(Q.plastic[p]);
    if (channels.material) material.push_back(Q.material[p]);
    id.push_back(Q.id[p]);
  }

  /// No particles, and the same stored channels as this set, mass and rest volume included
  /// (stored once with the same value, or per particle): a set to unpack this one's particles
  /// into (domain_split.h).
  Particles empty_like() const {
    Particles P;
    P.channels = channels;
    P.m = m.empty_like();
    P.vol0 = vol0.empty_like();
    return P;
  }

  /// fn(channel) for every stored channel (the optional ones as `channels` says; mass and rest
  /// volume while stored per particle), in a fixed order: for code that moves whole particles
  /// (the re-sort by grid block, packing for another process, dropping). A uniform mass or rest
  /// volume needs no moving: it is every particle's.
  template <class Fn>
  void for_each_channel(Fn&& fn) {
    for_each_channel_of(*this, fn);
  }
  template <class Fn>
  void for_each_channel(Fn&& fn) const {
    for_each_channel_of(*this, fn);
  }

  /// Bytes held by the channels (capacity, not size).
  std::size_t bytes() const {
    return x.capacity() * sizeof(Vec) + v.capacity() * sizeof(Vec) + m.bytes() + vol0.bytes() +
           F.capacity() * sizeof(Mat) + J.capacity() * sizeof(T) + C.capacity() * sizeof(Mat) +
           plastic.capacity() * sizeof(T) + material.capacity() * sizeof(std::uint16_t) +
           id.capacity() * sizeof(std::uint32_t);
  }

 private:
  template <class Self, class Fn>
  static void for_each_channel_of(Self& P, Fn& fn) {
    fn(P.x), fn(P.v);
    if (!P.m.uniform()) fn(P.m.values());
    if (!P.vol0.uniform()) fn(P.vol0.values());
    if (P.channels.F) fn(P.F);
    if (P.channels.J) fn(P.J);
    if (P.channels.C) fn(P.C);
    if (P.channels.plastic) fn(P.plastic);
    if (P.channels.material) fn(P.material);
    fn(P.id);
  }
};

}  // namespace slurry
