// One kind of hard binding (Sifakis et al. 2007, sections 2 and 5): a list of bound points, each with
// no degrees of freedom of its own, whose state is a linear map W of its parents' state.
//
// A kind owns every rule that depends on how its points hang on their parents: the map W itself
// (clamping positions and velocities), its transpose W^T (forces, and masses m = W^T m_bar), the
// effective mass of eq. 4, impulses, the acceleration a point inherits (what soft bindings map onto
// their particles, section 3), the drift push-back of synchronized soft bindings (section 3.1), the
// W^T B W blocks of the block-Jacobi preconditioner and the measured drift. HardBindings holds one
// object of each kind and visits them in a fixed order, so no other part of sinew decides by kind.
//
// Parents are never themselves bound (HardBindings::flatten resolves chains before the first step),
// except a mixed point's frame points, which W maps before it and W^T after it (MixedBindings).
#pragma once

#include "sinew/particles.hpp"
#include "sinew/rigid_body_particles.hpp"

#include <string_view>
#include <vector>

namespace sinew {

/// 3x3 diagonal blocks of the implicit system, one column-major 3x3 block per particle (9 x N).
using DiagonalBlocks = Eigen::Matrix<double, 9, Eigen::Dynamic>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

class BindingKind {
 public:
  virtual ~BindingKind() = default;
  /// "embedded point", "rigid frame point": used in messages.
  virtual std::string_view name() const = 0;
  virtual Index size() const = 0;
  /// The bound particle of binding k.
  virtual Index particle(Index k) const = 0;
  /// The order in which binding k was added among all hard bindings: names it in messages.
  virtual Index id(Index k) const = 0;
  /// Removes binding k (later bindings move down by one).
  virtual void remove(Index k) = 0;
  /// True when the parents are rigid bodies: changing such a binding changes a body's mass
  /// properties where SystemSettings::absorb_bound_mass_into_rigid_bodies merges them.
  virtual bool on_rigid_frames() const { return false; }

  // ---- W and W^T over every binding of the kind ----------------------------------------------------
  /// Caches what depends on the rigid frames' orientations (world offsets); call when they change.
  virtual void update_offsets(const RigidBodyParticles& bodies) { (void)bodies; }
  /// Within a step's solves: each rigid frame's points sit at arm_maps[b] r0 and move with the
  /// angular velocity angular_maps[b] w (see Newmark::set_step_maps): W (v, w) = v + (A w) x r and
  /// W^T f = (f, A^T (r x f)), which the preconditioner blocks use too, until the next update_offsets.
  virtual void set_step_arms(const std::vector<Mat3>& arm_maps, const std::vector<Mat3>& angular_maps) {
    (void)arm_maps, (void)angular_maps;
  }
  /// x_e = W x_parents (body_x: the rigid bodies' centres of mass, 3 x R).
  virtual void clamp_positions(Vectors3& x, const Vectors3& body_x) const = 0;
  /// v_e = W v_parents, rigid twists given as linear and angular velocities (3 x R each).
  virtual void clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const = 0;
  /// The same with the twists stacked (6 x R: linear then angular).
  virtual void clamp_velocities(Vectors3& v, const Vectors6& twist) const = 0;
  /// W^T: adds each bound row's force to its parents (particles, or rigid wrenches) and zeroes the row.
  virtual void distribute(Vectors3& f, Vectors6& wrench) const = 0;
  /// m = W^T m_bar: passes each bound row's mass to its particle parents and zeroes the row (points on
  /// rigid frames have theirs merged into the bodies before, or dropped).
  virtual void distribute_masses(VectorXd& mass) const = 0;
  /// Adds each bound row's 3x3 diagonal block B to its parents' blocks as W^T B W: w_i^2 B on particle
  /// parents, the 6x6 [B, B r*^T; r* B, r* B r*^T] on a rigid body's twist.
  virtual void add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const = 0;
  /// Largest |x_e - W x_parents| over the kind's bindings: zero by construction, measured to prove it.
  virtual double max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const = 0;

  // ---- one binding ------------------------------------------------------------------------------------
  /// The acceleration of bound point k given its parents' forces (f: particles, wrench: bodies, both
  /// already passed through W^T): sum_i w_i f_i / m_i, or a_c + alpha x r. The centripetal term
  /// w x (w x r) is left out, as in the paper's force mapping: it is not a force.
  /// Binding k's velocity W (v, twist) from its parents' velocities v and the bodies' twists (with the
  /// offsets of the last update_offsets).
  virtual Vec3 point_velocity(Index k, const Vectors3& v, const RigidBodyParticles& bodies) const = 0;
  virtual Vec3 point_acceleration(Index k, const Particles& p, const RigidBodyParticles& bodies, const Vectors3& f,
                                  const Vectors6& wrench) const = 0;
  /// 1/m_e (eq. 4): sum_i w_i^2 / m_i, or the largest eigenvalue of the impulse matrix K of a frame
  /// point (the smallest effective mass over directions); 0 when no parent can move.
  virtual double inverse_effective_mass(Index k, const VectorXd& mass, const RigidBodyParticles& bodies) const = 0;
  /// The effective mass along unit direction n: 1 / (n^T K n) for a frame point; `scalar` (the
  /// point's eq. 4 mass) where it does not depend on the direction.
  virtual double effective_mass_along(Index k, const Vec3& n, double scalar,
                                      const RigidBodyParticles& bodies) const = 0;
  /// Impulse j at bound point k, applied to its parents: dv_i = w_i j / m_i, or dv_c = j / m,
  /// dw = I^-1 (r x j). Kinematic parents do not move.
  virtual void apply_impulse(Index k, const Vec3& j, Particles& p, RigidBodyParticles& bodies) const = 0;
  /// Section 3.1: moves the parents of bound point k so that the point moves by dx and changes its
  /// velocity by dv (to first order), m_e being its effective mass; L_n: the bodies' angular momenta
  /// at the step's start, which the impulse changes.
  virtual void push_drift(Index k, const Vec3& dx, const Vec3& dv, double m_e, Particles& p, RigidBodyParticles& bodies,
                          Vectors3& L_n) = 0;
};

}  // namespace sinew
