// Collisions in step 3 of the Newmark step (Sifakis et al. 2007, section 3.3): (x~^{n+1}, v^n) ->
// (x^{n+1}, v~^n), deformables only (section 5, step 4).
//
// A System runs an ordered list of collision sources (System::add_collision_source). Each sees the
// predicted positions, the velocities, the rigid-body particles at their predicted frames and the
// collision geometry the builders registered (surface triangles, their edges, per-particle filter
// groups and masks as in Bullet), and may move free and soft-bound particles, change their
// velocities, hand the step-4 solve velocity constraints on weighted stencils of particles, and
// give rigid-body particles impulses. Impulses go to the rigid-body particles through the context,
// so that a rigid solver coupled to the system receives the bodies' momentum change once, from the
// step, with everything else (section 5).
#pragma once

#include "sinew/particles.hpp"
#include "sinew/rigid_body_particles.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace sinew {

class HardBindings;
struct SoftBindings;

/// A velocity constraint from step 3 on a weighted stencil of up to four particles, enforced in the
/// step-4 solve by projection: sum_i w_i n . v_i = normal_velocity. A node against a rigid surface is
/// one particle of weight 1; a node against a triangle (1, -b0, -b1, -b2) with b the barycentric
/// coordinates of the closest point; an edge against an edge (a0, a1, -b0, -b1). Every particle of a
/// stencil must have unknowns (free or soft-spring) and appear once.
struct CollisionConstraint {
  std::array<Index, 4> particles{-1, -1, -1, -1};
  std::array<double, 4> weights{1.0, 0.0, 0.0, 0.0};
  int size = 1;
  Vec3 normal = Vec3::UnitY();
  double normal_velocity = 0.0;  ///< [m/s]
  /// Coulomb friction on the stencil's tangential velocity sum_i w_i v_i, relative to the tangential
  /// part of `velocity` (the surface's velocity at the contact), bounded by `friction` times the
  /// normal impulse the solve's projection exerts: after the step-4 solve, as a contact between a
  /// body and a prescribed surface sees it. 0: frictionless.
  double friction = 0.0;
  Vec3 velocity = Vec3::Zero();  ///< [m/s] the surface's velocity (only its tangential part is used)

  /// One particle against a surface moving at normal_velocity along the unit normal n.
  static CollisionConstraint point(Index particle, const Vec3& n, double normal_velocity) {
    CollisionConstraint c;
    c.particles[0] = particle;
    c.normal = n;
    c.normal_velocity = normal_velocity;
    return c;
  }
  /// One particle against a surface moving at `surface_velocity`, with Coulomb coefficient mu.
  static CollisionConstraint point(Index particle, const Vec3& n, const Vec3& surface_velocity, double mu) {
    CollisionConstraint c = point(particle, n, n.dot(surface_velocity));
    c.velocity = surface_velocity;
    c.friction = mu;
    return c;
  }
};

/// Bullet's default collision filter: every particle is in group 1 and collides with every group.
inline constexpr std::uint32_t kDefaultCollisionGroup = 1;
inline constexpr std::uint32_t kAllCollisionGroups = 0xffffffffu;

/// What the builders registered for the collision sources: the deformables' surface triangles and
/// their edges (particle indices), and each particle's filter (group, mask). Two things collide only
/// when each one's group is in the other's mask, as in Bullet's broadphase filtering.
struct CollisionGeometry {
  std::vector<std::array<Index, 3>> triangles;
  std::vector<std::array<Index, 2>> segments;  ///< each edge of `triangles` once, (lower, higher)
  std::vector<std::uint32_t> group, mask;      ///< per particle

  /// True when particle i and a thing with filter (group, mask) may collide.
  bool collides(Index i, std::uint32_t other_group, std::uint32_t other_mask) const {
    return (group[static_cast<std::size_t>(i)] & other_mask) != 0 &&
           (other_group & mask[static_cast<std::size_t>(i)]) != 0;
  }
};

/// What a collision source sees and may change in step 3. Only free and soft-bound rows may be
/// moved; hard-bound rows are recomputed from their parents afterwards and kinematic rows are
/// prescribed.
class CollisionContext {
 public:
  double time = 0;  ///< t^n
  double dt = 0;
  const Vectors3* x_n = nullptr;  ///< positions at t^n
  Vectors3* x = nullptr;          ///< in: x~^{n+1}, out: x^{n+1}
  Vectors3* v = nullptr;          ///< in: v^n, out: v~^n
  const Particles* particles = nullptr;
  const RigidBodyParticles* bodies = nullptr;   ///< at the predicted frames (x~_c^{n+1}, q~^{n+1})
  const Vectors3* body_x_n = nullptr;           ///< the bodies' centres of mass at t^n
  const std::vector<Quat>* body_q_n = nullptr;  ///< their orientations at t^n
  const CollisionGeometry* geometry = nullptr;

  /// Hands step 4 a velocity constraint (checked after every source has run).
  void add_constraint(const CollisionConstraint& c) { m_constraints->push_back(c); }
  /// Impulse j [N s] at world point `point` on rigid-body particle `body`: dv_c = j / m, dw = I^-1
  /// (r x j) with r from the predicted centre of mass, and the body's angular momentum at t^n, from
  /// which step 4 starts, gains r x j. Kinematic bodies (infinite mass) do not move.
  void apply_body_impulse(Index body, const Vec3& point, const Vec3& j);

  // ---- synchronized soft particles (section 3.1), one contact at a time ---------------------------
  /// Puts synchronized soft particle `particle` (and its target's row) on its target as the target's
  /// parents are now, after the contacts resolved before it moved them; false (nothing done) for any
  /// other particle. A source that resolves contacts one after the other calls it before testing the
  /// particle and push_drift after changing it, as the paper's authors do: many collision particles
  /// on the same parents (a sprinkled surface resting on the ground, a dozen samples a tet) then each
  /// see the corrections made before them (Gauss-Seidel), where drifts summed at the end of step 3
  /// would push the shared parents as many times too far.
  bool synchronize(Index particle);
  /// Pushes what the source did to synchronized particle `particle` since synchronize (dx, dv) to its
  /// target's parents now (W^T with the effective mass, SoftBindings::push_drift), and puts it back on
  /// its moved target.
  void push_drift(Index particle);
  /// For a synchronized particle whose target is a linear binding's point with at most four parents,
  /// all dynamic: the target's stencil (parents and weights) in c, so that a contact on the particle
  /// can hold the target in step 4. False otherwise.
  bool target_stencil(Index particle, CollisionConstraint& c) const;

  // Set by the step.
  std::vector<CollisionConstraint>* m_constraints = nullptr;
  RigidBodyParticles* m_bodies = nullptr;
  Vectors3* m_body_L = nullptr;
  Particles* m_particles = nullptr;  ///< the same as `particles`, for push_drift
  HardBindings* m_hard = nullptr;
  const SoftBindings* m_soft = nullptr;
  const VectorXd* m_effective_mass = nullptr;

 private:
  Index target_of(Index particle) const;
  mutable std::vector<Index> m_target;  // per particle: its synchronized target, -1 none (built on first use)
};

/// One collision source of step 3 (a rigid solver's shapes, a ground plane, self-contact, ...).
class CollisionSource {
 public:
  virtual ~CollisionSource() = default;
  /// Used in messages and timings.
  virtual std::string_view name() const = 0;
  virtual void process(CollisionContext& context) = 0;
  /// The work of the last process() call, counted in items visited (a box binned, a candidate pair
  /// looked at; a continuous test counts kContinuousTestWork). System::advance weighs a substep's
  /// contact work with its solves when it chooses the substep count: a count, not a clock, so the
  /// choice is the same run to run. Zero for sources that do not count.
  virtual double work() const { return 0.0; }
  /// True for a source whose result must be the step's final positions (a continuous test's guarantee
  /// is about them): the step spreads what the sources before it moved through the implicit forces
  /// (StepSettings::spread_collisions) before it runs, and nothing after.
  virtual bool needs_final_positions() const { return false; }
  /// What one continuous (swept) pair test counts in work(): a cubic's roots, bisected, against a
  /// box test and a closest-point query.
  static constexpr double kContinuousTestWork = 8.0;
};

/// A collision source from a function (tests, applications with their own contact code).
std::unique_ptr<CollisionSource> make_collision_source(std::string name,
                                                       std::function<void(CollisionContext&)> process);

}  // namespace sinew
