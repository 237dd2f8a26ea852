#pragma once
/// \file particles.h
/// Lagrangian particles as a structure of arrays, one std::vector per named channel.
///
/// Only the channels a scene's materials need are allocated (`Channels`): position, velocity,
/// mass and rest volume always; the deformation gradient F for solids; the volume ratio J for
/// fluids (weakly compressible materials need det F only); the affine matrix C for APIC and
/// MLS transfers; a plastic state for plastic materials; a material id when a scene has more than
/// one material. Unallocated channels are empty vectors.
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
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

template <class T, int Dim>
struct Particles {
  using Vec = Eigen::Matrix<T, Dim, 1>;
  using Mat = Eigen::Matrix<T, Dim, Dim>;

  Channels channels;
  std::vector<Vec> x;      ///< position (m)
  std::vector<Vec> v;      ///< velocity (m/s)
  std::vector<T> m;        ///< mass (kg)
  std::vector<T> vol0;     ///< rest volume (m^3; m^2 in 2D)
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
    x.push_back(pos);
    v.push_back(vel);
    m.push_back(mass);
    vol0.push_back(volume);
    if (channels.F) F.push_back(Mat::Identity());
    if (channels.J) J.push_back(T(1));
    if (channels.C) C.push_back(Mat::Zero());
    if (channels.plastic) plastic.push_back(plastic_init);
    if (channels.material) material.push_back(mat);
    id.push_back(std::uint32_t(id.size()));
  }

  /// fn(channel) for every stored channel (the optional ones as `channels` says), in a fixed
  /// order: for code that moves whole particles (the re-sort by grid block, packing for another
  /// process, dropping).
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
    return x.capacity() * sizeof(Vec) + v.capacity() * sizeof(Vec) + m.capacity() * sizeof(T) +
           vol0.capacity() * sizeof(T) + F.capacity() * sizeof(Mat) + J.capacity() * sizeof(T) +
           C.capacity() * sizeof(Mat) + plastic.capacity() * sizeof(T) +
           material.capacity() * sizeof(std::uint16_t) + id.capacity() * sizeof(std::uint32_t);
  }

 private:
  template <class Self, class Fn>
  static void for_each_channel_of(Self& P, Fn& fn) {
    fn(P.x), fn(P.v), fn(P.m), fn(P.vol0);
    if (P.channels.F) fn(P.F);
    if (P.channels.J) fn(P.J);
    if (P.channels.C) fn(P.C);
    if (P.channels.plastic) fn(P.plastic);
    if (P.channels.material) fn(P.material);
    fn(P.id);
  }
};

}  // namespace slurry
