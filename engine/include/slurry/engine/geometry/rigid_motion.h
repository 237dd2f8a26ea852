#pragma once
/// \file rigid_motion.h
/// A rigid motion through keyframes: translation interpolated linearly and rotation by
/// spherical linear interpolation of unit quaternions (Shoemake 1985, "Animating rotation with
/// quaternion curves"), held at the first key before it and at the last key after it, plus a
/// constant drift velocity. Between two keys the rotation turns at the constant angular velocity
/// omega = theta a / (t1 - t0), with a and theta the axis and angle of R1 R0^T, so the velocity of
/// a point of the body at x is v = dc/dt + omega x (x - c).
#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace slurry::geometry {

struct Pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();  ///< of the origin of the body's frame
  Eigen::Vector3d omega = Eigen::Vector3d::Zero();     ///< angular velocity (rad/s), world frame

  /// World position of body-frame point y, and the body-frame point of world position x.
  Eigen::Vector3d to_world(const Eigen::Vector3d& y) const { return rotation * y + translation; }
  Eigen::Vector3d to_body(const Eigen::Vector3d& x) const {
    return rotation.transpose() * (x - translation);
  }
  /// Velocity of the body's material point at world position x.
  Eigen::Vector3d velocity_at(const Eigen::Vector3d& x) const {
    const Eigen::Vector3d r = x - translation;  // omega x r, written out (no Eigen/Geometry here)
    return velocity + Eigen::Vector3d(omega[1] * r[2] - omega[2] * r[1],
                                      omega[2] * r[0] - omega[0] * r[2],
                                      omega[0] * r[1] - omega[1] * r[0]);
  }
};

class RigidMotion {
 public:
  struct Key {
    double time = 0;
    Eigen::Vector3d translation = Eigen::Vector3d::Zero();
    Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  };

  /// A fixed pose moving at `drift`. Keys, if given, must have increasing times and replace
  /// the fixed pose.
  RigidMotion(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
              const Eigen::Vector3d& drift, std::vector<Key> keys = {});

  /// The pose at time t. Grid updates ask for the same t at every node: the last few poses
  /// each thread computed are kept (keyed by motion and t), since a slerp costs trigonometry.
  Pose at(double t) const;
  /// Whether anything moves: a drift, or keys that differ.
  bool moves() const { return moves_; }

 private:
  Pose compute(double t) const;

  std::uint64_t serial_ = 0;  ///< unique per object: keys the per-thread pose cache
  std::vector<Key> keys_;
  std::vector<Eigen::Vector4d>
      q_;  ///< unit quaternion of each key (w, x, y, z), same hemisphere as the one before
  Eigen::Vector3d drift_;
  bool moves_ = false;
};

}  // namespace slurry::geometry
