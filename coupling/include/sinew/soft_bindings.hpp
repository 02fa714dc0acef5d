// Soft bindings (Sifakis et al. 2007, section 3): a full particle tied to a target, which is a free
// particle, a hard-bound point on a mesh or a point on a rigid frame.
//
// The soft particle's mass is the target's effective mass (eq. 4; for a rigid frame the smallest
// effective mass over directions, 1/lambda_max(K)). It inherits the target's elastic and external
// accelerations, f_s += m_s a_target, so that it follows its target without lag; damping is not
// mapped (it would break the symmetry of the implicit damping matrix) and neither is the binding
// spring's own pull on the target. It receives no gravity of its own: a_target already has g.
//
// Two couplings:
//   spring        a binding spring (eq. 5) between particle and target, solved fully implicitly;
//                 long-term drift is allowed (section 3.2);
//   synchronized  the particle is overwritten with its target's state at fixed points of the step;
//                 whatever drift collisions cause is pushed back to the target's parents before
//                 the next synchronisation (section 3.1).
#pragma once

#include "sinew/hard_bindings.hpp"
#include "sinew/particles.hpp"
#include "sinew/rigid_body_particles.hpp"

#include <cstdint>
#include <vector>

namespace sinew {

enum class SoftCoupling : std::uint8_t { spring, synchronized };

struct SoftBindingSettings {
  Index particle = -1;  ///< the soft particle (must not be bound otherwise)
  Index target = -1;    ///< a free or hard-bound particle row
  SoftCoupling coupling = SoftCoupling::spring;
  double stiffness = 1e4;      ///< binding spring k [N/m] (spring coupling)
  double damping_ratio = 1.0;  ///< zeta, 1 = critical from effective masses
  /// Mass of the soft particle; 0 means the target's effective mass (required when the target has
  /// infinite mass, i.e. it is kinematic or on a kinematic frame).
  double mass = 0.0;
};

struct SoftBindings {
  std::vector<Index> particle;
  std::vector<Index> target;
  std::vector<SoftCoupling> coupling;
  std::vector<Index> spring;  ///< binding spring index (spring coupling), -1 otherwise
  std::vector<double> mass_override;

  Index size() const { return static_cast<Index>(particle.size()); }
  bool has_synchronized() const;

  // ---- the soft bindings' maths (each kind's rule in one place) ----------------------------------
  /// Copies each synchronized particle's target state into it (section 3.1).
  void synchronize(Particles& p, bool positions, bool velocities) const;
  /// The same on one 3 x N array (the implicit solves' trial velocities).
  void synchronize(Vectors3& y) const;
  /// Adds each synchronized row's force to its target row and clears the soft row: a synchronized
  /// particle is its target, so what acts on it acts on the target.
  void gather_synchronized(Vectors3& f) const;
  /// The same for the block-Jacobi diagonal blocks (9 x N, column-major 3x3).
  void gather_synchronized(Eigen::Matrix<double, 9, Eigen::Dynamic>& blocks) const;
  /// Section 3: f_s += m_s a_target on every spring-coupled particle, a_target the acceleration its
  /// target gets from the parents' forces (f on particles, wrench on rigid bodies, already passed
  /// through W^T). Returns the sum of the mapped forces (the momentum the mapping adds per second).
  Vec3 map_forces(const Particles& p, const RigidBodyParticles& bodies, const HardBindings& hard, Vectors3& f,
                  const Vectors6& wrench) const;
  /// Section 3.1: pushes the drift of synchronized particles from their targets (collisions moved
  /// them) back to the targets' parents, so that the next synchronisation keeps it. L_n: the rigid
  /// bodies' angular momenta at the step's start, which an impulse at a rigid target changes.
  void push_drift(Particles& p, RigidBodyParticles& bodies, HardBindings& hard, const VectorXd& effective_mass,
                  Vectors3& L_n) const;
};

}  // namespace sinew
