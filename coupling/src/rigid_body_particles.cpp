#include "sinew/rigid_body_particles.hpp"

namespace sinew {

Mat3 RigidBodyParticles::world_inertia(Index b) const {
  const Mat3 r = q[b].toRotationMatrix();
  if (kinematic[b]) return Mat3::Zero();  // never used as a mass: kinematic twists are prescribed
  return r * inertia.col(b).asDiagonal() * r.transpose();
}

Mat3 RigidBodyParticles::world_inverse_inertia(Index b) const {
  if (kinematic[b]) return Mat3::Zero();
  const Mat3 r = q[b].toRotationMatrix();
  return r * inertia.col(b).cwiseInverse().asDiagonal() * r.transpose();
}

Mat3 RigidBodyParticles::impulse_matrix(Index b, const Vec3& r) const {
  if (kinematic[b]) return Mat3::Zero();
  const Mat3 rs = cross_matrix(r);
  return Mat3::Identity() / mass[b] + rs.transpose() * world_inverse_inertia(b) * rs;
}

void validate_rigid_body_mass(Index b, double mass, const Vec3& I) {
  if (!(std::isfinite(mass) && mass > 0.0)) fail("rigid body ", b, ": mass ", mass, " must be positive and finite");
  for (int i = 0; i < 3; ++i)
    if (!(std::isfinite(I[i]) && I[i] > 0.0))
      fail("rigid body ", b, ": principal inertia ", i, " is ", I[i], ", must be positive and finite");
  // A physical inertia satisfies the triangle inequality I_a <= I_b + I_c.
  if (I[0] > I[1] + I[2] + 1e-12 * I.sum() || I[1] > I[0] + I[2] + 1e-12 * I.sum() ||
      I[2] > I[0] + I[1] + 1e-12 * I.sum())
    fail("rigid body ", b, ": principal inertia (", I.transpose(), ") violates the triangle inequality");
}

Index add_rigid_body(RigidBodyParticles& bodies, const RigidBodySettings& s) {
  const Index b = bodies.size();
  if (!all_finite(s.x) || !all_finite(s.v) || !all_finite(s.w)) fail("rigid body ", b, ": state is not finite");
  if (!std::isfinite(s.q.norm()) || std::abs(s.q.norm() - 1.0) > 1e-6)
    fail("rigid body ", b, ": orientation is not a unit quaternion (norm ", s.q.norm(), ")");
  if (!s.kinematic) validate_rigid_body_mass(b, s.mass, s.inertia);
  const Index n = b + 1;
  bodies.x.conservativeResize(3, n);
  bodies.v.conservativeResize(3, n);
  bodies.w.conservativeResize(3, n);
  bodies.inertia.conservativeResize(3, n);
  bodies.mass.conservativeResize(n);
  bodies.force.conservativeResize(3, n);
  bodies.torque.conservativeResize(3, n);
  bodies.force.col(b).setZero();
  bodies.torque.col(b).setZero();
  bodies.x.col(b) = s.x;
  bodies.v.col(b) = s.v;
  bodies.w.col(b) = s.w;
  bodies.q.push_back(s.q.normalized());
  bodies.mass[b] = s.kinematic ? kInfinity : s.mass;
  bodies.inertia.col(b) = s.kinematic ? Vec3::Constant(kInfinity) : s.inertia;
  bodies.kinematic.push_back(s.kinematic ? 1 : 0);
  bodies.gravity.push_back(s.gravity ? 1 : 0);
  return b;
}

Quat rotation_from_vector(const Vec3& theta) {
  const double angle = theta.norm();
  if (angle < 1e-300) return Quat::Identity();
  return Quat(Eigen::AngleAxisd(angle, theta / angle));
}

Mat3 rotation_left_jacobian(const Vec3& theta) {
  const double t2 = theta.squaredNorm();
  const Mat3 c = cross_matrix(theta);
  double a, b;  // (1 - cos t) / t^2 and (t - sin t) / t^3, by their series near 0 (round-off otherwise)
  if (t2 < 1e-6) {
    a = 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0);
    b = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0);
  } else {
    const double t = std::sqrt(t2);
    a = (1.0 - std::cos(t)) / t2;
    b = (t - std::sin(t)) / (t2 * t);
  }
  return Mat3::Identity() + a * c + b * c * c;
}

}  // namespace sinew
