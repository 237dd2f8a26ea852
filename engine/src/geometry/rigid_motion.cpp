#include "slurry/engine/geometry/rigid_motion.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>

namespace slurry::geometry {

namespace {
Eigen::Quaterniond to_quaternion(const Eigen::Vector4d& q) {
  return Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
}
}  // namespace

RigidMotion::RigidMotion(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                         const Eigen::Vector3d& drift, std::vector<Key> keys)
    : keys_(std::move(keys)), drift_(drift) {
  static std::atomic<std::uint64_t> serials{0};
  serial_ = ++serials;
  if (keys_.empty()) keys_.push_back({0, translation, rotation});
  for (std::size_t k = 0; k < keys_.size(); ++k) {
    Eigen::Quaterniond q(keys_[k].rotation);
    q.normalize();
    // Neighbouring keys on the same hemisphere: slerp then takes the shorter way round.
    if (k > 0 && to_quaternion(q_.back()).dot(q) < 0) q.coeffs() = -q.coeffs();
    q_.emplace_back(q.w(), q.x(), q.y(), q.z());
  }
  moves_ = !drift_.isZero();
  for (std::size_t k = 1; k < keys_.size(); ++k)
    moves_ = moves_ || keys_[k].translation != keys_[0].translation ||
             !keys_[k].rotation.isApprox(keys_[0].rotation, 0);
}

Pose RigidMotion::at(double t) const {
  struct Entry {
    std::uint64_t serial = 0;
    double t = 0;
    Pose pose;
  };
  thread_local Entry cache[4];
  thread_local int next = 0;
  for (const auto& e : cache)
    if (e.serial == serial_ && e.t == t) return e.pose;
  Entry& e = cache[next];
  next = (next + 1) % 4;
  e.serial = serial_, e.t = t, e.pose = compute(t);
  return e.pose;
}

Pose RigidMotion::compute(double t) const {
  Pose p;
  p.velocity = drift_;
  if (t <= keys_.front().time || keys_.size() == 1) {
    p.rotation = to_quaternion(q_.front()).toRotationMatrix();
    p.translation = keys_.front().translation;
  } else if (t >= keys_.back().time) {
    p.rotation = to_quaternion(q_.back()).toRotationMatrix();
    p.translation = keys_.back().translation;
  } else {
    const auto next = std::upper_bound(keys_.begin(), keys_.end(), t,
                                       [](double v, const Key& k) { return v < k.time; });
    const std::size_t k1 = std::size_t(next - keys_.begin()), k0 = k1 - 1;
    const double span = keys_[k1].time - keys_[k0].time, s = (t - keys_[k0].time) / span;
    const Eigen::Quaterniond q0 = to_quaternion(q_[k0]), q1 = to_quaternion(q_[k1]);
    p.rotation = q0.slerp(s, q1).toRotationMatrix();
    p.translation = (1 - s) * keys_[k0].translation + s * keys_[k1].translation;
    p.velocity += (keys_[k1].translation - keys_[k0].translation) / span;
    const Eigen::AngleAxisd turn(q1 * q0.conjugate());
    p.omega = turn.axis() * (turn.angle() / span);
  }
  p.translation += drift_ * t;
  return p;
}

}  // namespace slurry::geometry
