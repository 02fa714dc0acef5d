// Rigid-body particles (section 5): the full state of a rigid body stored as a particle, so that a
// rigid body enters the implicit solves as a 6-DOF parent of the points bound to its frame.
#pragma once

#include "sinew/types.hpp"

#include <cstdint>
#include <vector>

namespace sinew {

struct RigidBodySettings {
  Vec3 x = Vec3::Zero();        ///< centre of mass, world [m]
  Quat q = Quat::Identity();    ///< orientation of the principal frame
  Vec3 v = Vec3::Zero();        ///< linear velocity of the centre of mass [m/s]
  Vec3 w = Vec3::Zero();        ///< angular velocity, world [rad/s]
  double mass = 1.0;            ///< [kg]; ignored for kinematic bodies
  Vec3 inertia = Vec3::Ones();  ///< principal moments I0 in the principal frame [kg m^2]
  bool kinematic = false;       ///< prescribed motion (static when v = w = 0), infinite mass
  bool gravity = true;          ///< false when another solver (Bullet) already applies gravity
};

struct RigidBodyParticles {
  Vectors3 x;           ///< centres of mass (3 x R)
  std::vector<Quat> q;  ///< orientations of the principal frames
  Vectors3 v;           ///< linear velocities (3 x R)
  Vectors3 w;           ///< angular velocities, world (3 x R)
  VectorXd mass;        ///< +inf for kinematic bodies
  Vectors3 inertia;     ///< principal moments I0 (3 x R); +inf for kinematic bodies
  std::vector<std::uint8_t> kinematic;
  std::vector<std::uint8_t> gravity;
  /// Applied force and torque about the centre of mass, world (3 x R) [N], [N m], held constant over
  /// a step and added to the body's wrench with gravity (a rigid solver's own forces on the body, so
  /// that the step moves the body the way that solver will).
  Vectors3 force;
  Vectors3 torque;

  Index size() const { return static_cast<Index>(q.size()); }

  /// I = R I0 R^T.
  Mat3 world_inertia(Index b) const;
  /// I^-1 = R I0^-1 R^T; zero for kinematic bodies.
  Mat3 world_inverse_inertia(Index b) const;
  /// L = I w.
  Vec3 angular_momentum(Index b) const { return world_inertia(b) * w.col(b); }
  /// Impulse matrix of a point at world offset r from the centre of mass: the velocity change per
  /// unit impulse there, K = I/m + r*^T I^-1 r* (zero for kinematic bodies).
  Mat3 impulse_matrix(Index b, const Vec3& r) const;
};

/// Validates settings (finite state, positive mass and inertia, unit-norm orientation) and appends
/// a body; the message names the body index.
Index add_rigid_body(RigidBodyParticles& bodies, const RigidBodySettings& settings);

/// Throws naming body b unless mass is positive and finite and the principal moments are positive,
/// finite and satisfy the triangle inequality.
void validate_rigid_body_mass(Index b, double mass, const Vec3& inertia);

/// Rotation by the rotation vector theta (angle |theta| about theta/|theta|): q(theta).
Quat rotation_from_vector(const Vec3& theta);

/// The left Jacobian of the rotation group at theta, J(theta) = sum_k (theta*)^k / (k+1)!
///   = I + (1 - cos t)/t^2 theta* + (t - sin t)/t^3 theta*^2,   t = |theta|,
/// for which R(theta) r - r = theta x (J(theta) r) for every r: a point at offset r on a frame turned by
/// theta moves along the chord theta x J r, whatever the angle (J r is the arm that chord is seen from).
Mat3 rotation_left_jacobian(const Vec3& theta);

}  // namespace sinew
