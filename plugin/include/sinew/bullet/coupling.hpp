// sinew::bullet::Coupling — runs sinew's deformables inside an existing Bullet world, two-way coupled
// to its rigid bodies by the scheme of Sifakis et al. 2007, section 5. This folder is the only code
// of sinew that includes Bullet headers.
//
// The application keeps calling world->stepSimulation(dt, maxSubSteps, fixedStep); the coupling runs
// once per internal tick from Bullet's pre-tick callback (after any pre-tick callback the application
// had installed, which it chains), so rigid bodies and deformables advance with the same fixed step.
// A post-tick callback (also chained) puts the hard-bound points back on the frames Bullet has just
// integrated, so a point bound to a body is exactly on it whenever the application looks.
//
// Bodies the application changes between ticks are followed at the next tick: a coupled body made
// static or kinematic (mass 0, CF_STATIC_OBJECT, CF_KINEMATIC_OBJECT) gets a kinematic rigid-body
// particle, and a dynamic one again when it is made dynamic again (with the mass it has then). A
// coupled body removed from the world is found missing from the world's object list and released as
// by remove(), without its pointer being read: the application may delete a body once it has removed
// it from the world, or once it has called remove(). (A body deleted while still in the world, or
// removed, deleted and replaced by a new body at the same address before the next tick, cannot be
// told from a live one: call remove() first in such code.)
#pragma once

#include "sinew/system.hpp"

#include <LinearMath/btScalar.h>
#include <LinearMath/btVector3.h>

#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

class btCollisionObject;
class btManifoldPoint;
class btDynamicsWorld;
class btRigidBody;

namespace sinew::bullet {

struct CouplingSettings {
  /// Gravity for the deformables is read from the world at every tick (so world->setGravity takes
  /// effect at the next one); rigid bodies get theirs from Bullet alone.
  bool use_world_gravity = true;
  /// Settings of the deformable system; absorb_bound_mass_into_rigid_bodies is forced off because
  /// Bullet owns the bodies' mass properties (the mass of a point hard-bound to a body is dropped).
  SystemSettings system;
  /// Collisions of free and soft-bound particles with every collision object of the world.
  bool collisions = true;
  double thickness = 0.01;  ///< [m]
  double friction = 0.3;    ///< Coulomb coefficient
};

class BulletCollisions;

class Coupling {
 public:
  /// Attaches to `world` (which must outlive the coupling).
  explicit Coupling(btDynamicsWorld* world, const CouplingSettings& settings = {});
  /// Detaches and restores the application's pre-tick callback.
  ~Coupling();
  Coupling(const Coupling&) = delete;
  Coupling& operator=(const Coupling&) = delete;

  /// The deformable system: add cloth, forces and bindings here (between ticks too).
  System& system() { return m_system; }
  const System& system() const { return m_system; }

  /// The rigid-body particle standing for `body`, created on first use (also between ticks: the next
  /// tick sets the system up again). The body must be in the coupling's world (an error names it
  /// otherwise). Static and kinematic bodies become kinematic rigid-body particles (infinite mass).
  /// A rigid body added to the system directly (System::add_rigid_body) is sinew's own: it stands for
  /// no Bullet body, meets none of Bullet's objects and keeps its index.
  Index rigid_particle(btRigidBody* body);
  /// The Bullet body a rigid-body particle stands for; null for sinew's own bodies and released ones.
  btRigidBody* body(Index rigid_particle) const { return m_bodies.at(static_cast<std::size_t>(rigid_particle)); }
  /// Releases `body` from the coupling (call it before deleting a body that is still in the world):
  /// points hard-bound to it with mass of their own become free particles with that mass, keeping
  /// their position and velocity; its massless body points are removed, and with them the binding
  /// springs and soft bindings that end on them. Its rigid-body particle stays, kinematic, at rest
  /// and unused (indices keep their meaning). The body itself is then a plain Bullet body.
  void remove(btRigidBody* body);
  /// Hard-binds `particle` to `body` at `local` (in the body's centre-of-mass frame, metres).
  Index bind(Index particle, btRigidBody* body, const Vec3& local);
  /// Hard-binds `particle` to `body` where the particle is now.
  Index bind_here(Index particle, btRigidBody* body);
  /// A massless point hard-bound to `body` at `local`: an end for binding springs. Returns the particle.
  Index add_body_point(btRigidBody* body, const Vec3& local);
  /// Ties `point` (a node, a point inside a triangle or tet from System::add_embedded_point, or a body
  /// point) to `body` at `local` by a zero-rest-length binding spring, implicit in the step (eq. 5),
  /// damped with ratio `damping_ratio` of critical. Returns the spring (System::binding_spring_force
  /// reads what it carries; System::set_binding_spring_active releases it).
  Index attach(Index point, btRigidBody* body, const Vec3& local, double stiffness, double damping_ratio = 1.0);

  /// One coupled tick of size dt (what the pre-tick callback runs): section 5, steps 1-6.
  StepStats tick(double dt);
  /// Statistics of the last tick.
  const StepStats& last_stats() const { return m_last; }
  btDynamicsWorld* world() const { return m_world; }
  /// Deepest penetration below the thickness found (and removed) in the last tick's step 3 [m].
  double deepest_penetration() const;

 private:
  static void pre_tick(btDynamicsWorld* world, btScalar dt);
  static void post_tick(btDynamicsWorld* world, btScalar dt);
  /// After Bullet's integration: bound rows move onto the bodies' new frames (they are W of them).
  void follow_bodies(double dt);
  /// The contacts Bullet resolved this tick also hold the end-of-tick velocities (see coupling.cpp).
  void hold_contacts_at_tick_end(double dt);
  /// At the start of a tick: releases coupled bodies that left the world, follows the mass and
  /// static/kinematic state of the others.
  void follow_world();
  /// Slots for rigid bodies added to the system directly (sinew's own: no Bullet body).
  void add_own_body_slots();
  /// The rigid-body particle of a body the application changed: kinematic when Bullet's body is
  /// static or kinematic, else dynamic with Bullet's mass.
  void follow_mass(Index b);
  /// What remove() does, without reading the Bullet body (which may be gone).
  void release(Index b);
  void copy_state_in();
  /// The equality rows of Bullet's joints on coupled bodies, for the step's solves (JointRow).
  void copy_joints_in(double dt);
  /// Step 6, first half: Bullet's bodies get the velocity that moves them along the Newmark step.
  void hand_over_position_velocity(double dt);
  /// Sets the velocities that Bullet's solver turns into (v, w) before joints and contacts act.
  void hand_over(btRigidBody* body, const Vec3& v, const Vec3& w, double dt);
  /// Step 6, second half (post-tick): they end the tick with the Newmark velocity plus Bullet's changes.
  void take_back_momentum();

  btDynamicsWorld* m_world;
  System m_system;
  std::vector<btRigidBody*> m_bodies;  // rigid-body particle b stands for m_bodies[b] (null: own or released)
  // Per body: Bullet's inverse mass and local inverse inertia when last seen, to notice the
  // application changing them; and which bodies this tick found in the world (scratch).
  std::vector<btScalar> m_seen_inverse_mass;
  std::vector<btVector3> m_seen_inverse_inertia;
  std::vector<std::uint8_t> m_in_world;
  // Per body: state copied in, the Newmark end-of-step twist and the position twist handed to Bullet.
  Vectors3 m_x_in, m_v_in, m_w_in, m_v_next, m_w_next, m_v_position, m_w_position;
  std::vector<Quat> m_q_in;
  std::vector<JointRow> m_joint_rows;
  // hold_contacts_at_tick_end's scratch: the islands of coupled dynamic bodies, and per contact point
  // the two bodies and the normal and friction impulses the passes have applied there.
  std::vector<int> m_islands;
  struct EndContact {
    btManifoldPoint* point;
    btRigidBody* a;
    btRigidBody* b;
    double normal;
    Vec3 friction;
  };
  std::vector<EndContact> m_end_contacts;
  std::vector<btScalar> m_joint_buffer;  // Bullet's btConstraintInfo2 arrays for one joint
  bool m_handed_over = false;
  bool m_use_world_gravity = true;
  Vectors3 m_tick_start_x, m_tick_start_v;  // the deformables at the tick's start (restored if it throws)
  RigidBodyParticles m_tick_start_bodies;
  void (*m_app_pre_tick)(btDynamicsWorld*, btScalar) = nullptr;
  void (*m_app_post_tick)(btDynamicsWorld*, btScalar) = nullptr;
  StepStats m_last;
  BulletCollisions* m_collisions = nullptr;                               // owned by the system's collision sources
  std::unordered_map<const btCollisionObject*, Index> m_rigid_particles;  // m_bodies' inverse
};

}  // namespace sinew::bullet
