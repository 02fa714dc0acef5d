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
//
// The mass of points hard-bound to a dynamic body is the body's (SystemSettings::
// absorb_bound_mass_into_rigid_bodies, on by default): sinew's rigid-body particle is the merged body
// (mass, centre of mass, inertia and principal frame, section 2's m = W^T m_bar), and Bullet's body
// is handed the merged mass (so Bullet's gravity is the weight of both) and the merged inertia about
// its own centre of mass (its diagonal in the body's frame, all Bullet's btRigidBody takes). Bullet's
// frame stays the application's: joints, collision shapes, motion states and applyForce offsets keep
// their meaning, and sinew converts between it and the merged frame at every exchange, so the step
// moves the body exactly as the merged body moves. What Bullet solves alone (contacts, limits, motors,
// breakable joints) sees the merged mass at the application's centre, an approximation where the
// centres differ. A point's momentum enters its body when it is bound (total momentum is kept; not
// when the application runs the set-up itself with System::finalize before the next tick); the
// body gets its own mass properties back when the points go, when it is released, and when the
// coupling is destroyed. centre_of_mass(body) is where the merged centre is.
//
// A dynamic or static body the application moves between ticks (setWorldTransform, or
// setCenterOfMassTransform: its frame at a tick's start is not the one the last tick left it in, which
// Bullet's own integration never does) is a teleport: each deformable component bound to it (particles
// joined by elements, collision surfaces, embeddings, soft bindings and binding springs) is carried with
// it, positions by the same rigid transform and velocities turned by its rotation, so the cloth keeps
// its shape on the body and is not flung. A component also bound to something the move did not carry
// (another body, a kinematic particle, particles added since the last tick) stays where it is, and its
// ties to the moved body are stretched. Kinematic bodies are animated by Bullet between ticks: their
// moves are prescribed motion, which the cloth sweeps with, never teleports.
#pragma once

#include "sinew/system.hpp"

#include <LinearMath/btScalar.h>
#include <LinearMath/btVector3.h>

#include <cstdint>
#include <memory>
#include <span>
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
  /// Settings of the deformable system. With absorb_bound_mass_into_rigid_bodies (the default) the
  /// mass of points hard-bound to a dynamic body is carried by the body, in sinew's step and in
  /// Bullet (see Coupling); off, it is dropped (its weight and momentum with it).
  SystemSettings system;
  /// Collisions of free and soft-bound particles with every collision object of the world.
  bool collisions = true;
  double thickness = 0.01;  ///< [m]
  double friction = 0.3;    ///< Coulomb coefficient
  /// With collisions: the corners and edges of polyhedral bodies (boxes, convex hulls, compounds of
  /// them) against the faces and edges of the registered surfaces (CollisionSettings::features), so
  /// a box edge between two cloth nodes does not poke through the face between them.
  bool feature_contacts = true;
  /// Contacts between a coupled dynamic body and any other body are solved in sinew's step, with the
  /// binding springs and joints (JointRow::unilateral, from Bullet's contact manifolds, found again at
  /// the tick's start), instead of by Bullet after it: a stiff binding spring on a light body then
  /// agrees with the body's contacts (a net of 0.1 kg rods on 2e5 N/m springs catching a 5 kg ball
  /// gained energy at every landing without it). For that, a dynamic body that touches a coupled
  /// dynamic body joins the coupling (it gets a rigid-body particle with nothing bound to it, and stays
  /// coupled). Friction holds a contact that sticks in the step's solves, and one that slides at the
  /// step's end. Off: Bullet resolves them alone, after the step.
  bool body_contacts = true;
  /// Contact between the deformables and within each (sinew::SelfCollisions, after Bullet's shapes):
  /// cloth on cloth, a cloth folding onto itself. Off by default: it costs a pass over every
  /// surface triangle and edge each step.
  bool self_collisions = false;
  double self_thickness = 0.005;  ///< [m] the surfaces keep this distance from each other
  /// Conflicting contacts (figure 10): a free particle between two objects that close on it (within
  /// twice the thickness of both, their normals opposed) is pinched. It stops colliding with the
  /// two, and gets two soft-bound duplicates (section 3: the node's effective mass, its elastic and
  /// external accelerations mapped to them), each colliding with one of the two objects only, tied to
  /// it by binding springs of `pinch_stiffness`; the node hangs between them, held by their friction.
  /// Released (the duplicates removed) when either object is more than four thicknesses away from the
  /// node, or a duplicate is. Off (the default): the particle is pushed out of the nearer object,
  /// which may push it into the other; caught between a body Bullet alone moves and a static or
  /// kinematic object, it follows the object instead (BulletCollisions::process). Not on by default: on the curtain,
  /// whose thin rings bunch on the rod at up to 2 m/s, nodes between neighbouring rings were pinched and their
  /// duplicates struck off them (600 frames: deepest penetration 11 cm instead of 3.4, binding-spring stretch 13.5 cm
  /// instead of 2.8).
  bool pinching = false;
  /// [N/m] The duplicates' binding springs. Their pull presses the duplicates on and sets the grip
  /// (with `friction`); stiffer ones leave each step's end velocity further from the motion (friction
  /// acts in step 3 only): in the pinch scene the hold's velocity RMS is 0.005 m/s at 10 N/m, 0.09
  /// at 100 and 0.25 at 300, while the nodes move at under 1 mm/s in all three.
  double pinch_stiffness = 10.0;
};

/// Collision particles sprinkled on an embedded surface (Sifakis et al. 2007, section 2, figure 3): a
/// coarse tet mesh collides only where its nodes are, and a small body passes between them; points of
/// the embedded surface, denser than the tets, collide instead. Each sample is a hard-bound point (the
/// surface of add_embedded_volume, a point from System::add_embedded_point); its collision particle is
/// a synchronized soft particle on it (section 3.1: it starts every step on the sample, and whatever a
/// contact does to it goes to the sample's parents through W^T, so it adds no mass, momentum or
/// unknown).
struct SprinkleSettings {
  /// false: every sample gets its collision particle at once and keeps it (static sprinkling). true: a
  /// sample gets one while a Bullet object's surface is within `reach` of it (plus how far both can
  /// move in the tick), and loses it once none has been for `linger` seconds.
  bool adaptive = true;
  double reach = 0.05;   ///< [m] finite, >= 0
  double linger = 0.25;  ///< [s] finite, >= 0
  /// false: the samples' parents (the tets' nodes, which for a lattice around the surface lie outside
  /// it) stop meeting Bullet's objects (their collision mask is cleared), so the body meets them with
  /// its surface alone; true: they keep colliding as before.
  bool hosts_collide = false;
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
  /// Hard-binds `particle` to `body` at `local` (in Bullet's centre-of-mass frame of the body, metres).
  Index bind(Index particle, btRigidBody* body, const Vec3& local);
  /// The centre of mass of `body` with the mass hard-bound to it (world, metres): Bullet's own centre
  /// of mass when nothing with mass is bound. Its linear momentum is Bullet's mass times the velocity
  /// of this point.
  Vec3 centre_of_mass(const btRigidBody* body) const;
  /// Where rigid hard binding k (HardBindings::rigid) holds its point, in Bullet's centre-of-mass
  /// frame of its body (the system's offset is in the merged body's principal frame).
  Vec3 body_offset(Index k) const;
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
  /// Statistics summed over every tick since construction.
  const StepStats& total_stats() const { return m_total; }
  btDynamicsWorld* world() const { return m_world; }
  /// Deepest penetration below the thickness found (and removed) in the last tick's step 3 [m].
  double deepest_penetration() const;
  /// A node pinched between two objects (CouplingSettings::pinching, figure 10): its duplicates
  /// (soft-bound to it), duplicate[k] colliding with object[k] only.
  struct Pinch {
    Index node = -1;
    const btCollisionObject* object[2] = {nullptr, nullptr};
    Index duplicate[2] = {-1, -1};
  };
  /// The pinches of the last tick, in node order.
  const std::vector<Pinch>& pinches() const { return m_pinches; }
  /// Sprinkles collision particles on hard-bound points `samples` (SprinkleSettings); returns the set's
  /// index. Throws naming the sample that does not exist or is not hard-bound to a deformable, or the
  /// bad setting; with collisions off there is nothing to sprinkle for, which is an error too.
  Index sprinkle(std::span<const Index> samples, const SprinkleSettings& settings = {});
  /// The collision particles sprinkle set `set` holds now (per sample, -1 where it has none).
  std::span<const Index> sprinkled(Index set) const;
  /// How many collision particles sprinkle set `set` holds now.
  Index sprinkled_count(Index set) const;

 private:
  static void pre_tick(btDynamicsWorld* world, btScalar dt);
  static void post_tick(btDynamicsWorld* world, btScalar dt);
  /// After Bullet's integration: bound rows move onto the bodies' new frames (they are W of them).
  void follow_bodies(double dt);
  /// The contacts Bullet resolved this tick also hold the end-of-tick velocities (see coupling.cpp).
  void hold_contacts_at_tick_end(double dt);
  /// A body as the end-of-tick contacts push it: a coupled dynamic one as the merged body of its
  /// particle (centre, mass, inertia), any other as Bullet has it; velocities read from and written to
  /// Bullet. Levers are from `centre`.
  struct BodyView {
    btRigidBody* body = nullptr;
    Index particle = -1;
    Vec3 centre = Vec3::Zero();
    Vec3 offset = Vec3::Zero();  // from Bullet's centre of mass to the merged one, now
    double inverse_mass = 0.0;
    Vec3 linear_factor = Vec3::Ones();    // Bullet's per-axis locks (uncoupled bodies)
    Mat3 inverse_inertia = Mat3::Zero();  // with the angular locks applied
    Vec3 velocity(const Vec3& lever) const;
    double inverse_mass_along(const Vec3& lever, const Vec3& u) const;
    void push(const Vec3& lever, const Vec3& j) const;
  };
  /// `at_tick_start`: levers from the centre where the tick's collision detection saw the body.
  BodyView body_view(btRigidBody* body, bool at_tick_start) const;
  /// At the start of a tick: releases coupled bodies that left the world, follows the mass and
  /// static/kinematic state of the others.
  void follow_world();
  /// At the start of a tick, after copy_state_in: the deformables that follow a body the application
  /// moved since the last tick go with it (see coupling.cpp).
  void follow_teleports();
  /// At the end of a tick: where each coupled body is, for follow_teleports.
  void note_frames_left();
  /// Slots for rigid bodies added to the system directly (sinew's own: no Bullet body).
  void add_own_body_slots();
  /// The rigid-body particle of a body the application changed: kinematic when Bullet's body is
  /// static or kinematic, else dynamic with Bullet's mass.
  void follow_mass(Index b);
  /// What remove() does, without reading the Bullet body (which may be gone).
  void release(Index b);
  /// Sets up the system after a change (the core merges bound masses into bodies), puts the merged
  /// frames in Bullet's terms, hands Bullet the merged masses and gives each body the momentum of the
  /// points newly bound to it.
  void set_up();
  /// After a set-up (the coupling's or one the application ran): the merged frames in Bullet's terms
  /// and the merged masses in Bullet.
  void adopt_set_up();
  /// System::set_rigid_body_mass, which takes every merged mass out: the frames are Bullet's again.
  void set_particle_mass(Index b, bool kinematic, double mass = 1.0, const Vec3& inertia = Vec3::Ones());
  /// Bullet's body b gets the mass properties of its particle (merged) or its own back.
  void hand_mass_to_bullet(Index b);
  void restore_own_mass(Index b);
  /// The offset in the merged frame of a point at `local` in Bullet's frame of body b.
  Vec3 merged_offset(Index b, const Vec3& local) const;
  void copy_state_in();
  /// While the system sleeps: wakes it when a moving Bullet body may reach the deformables this tick.
  void wake_on_approach(double dt);
  /// The equality rows of Bullet's joints on coupled bodies, for the step's solves (JointRow), and
  /// with CouplingSettings::body_contacts the contacts of coupled dynamic bodies (add_contact_rows).
  void copy_joints_in(double dt);
  void add_contact_rows(double dt);
  /// CouplingSettings::body_contacts: dynamic bodies touching coupled dynamic ones join the coupling.
  void join_touching_bodies();
  /// The (particle, body) pairs collisions skip: a particle tied by an active binding spring to a point
  /// hard-bound to a body's frame. Its spring's target sits on the body's surface (or inside it), where
  /// the thickness keeps the particle out: the two would fight, and a collision's projection does work
  /// on the stretched spring at every step (the README's hello cloth, tied to a falling sphere's top,
  /// gained 5 J in 35 frames at one step per tick).
  void find_tied_particles();
  /// CouplingSettings::pinching, at the start of a tick: finds the nodes pinched between two objects,
  /// gives new ones their duplicates, releases those whose objects parted (see coupling.cpp).
  void update_pinches();
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
  // Per body: its mass properties in Bullet as the application gave them (mass, local principal
  // inertia), whether Bullet has the merged ones instead, and where the merged frame is in Bullet's
  // frame of the body: centre at offset d, principal frame turned by q_rel (x' = c + R d, q' = q q_rel).
  std::vector<btScalar> m_own_mass;
  std::vector<btVector3> m_own_inertia;
  std::vector<std::uint8_t> m_mass_handed;
  std::uint64_t m_set_ups_seen = 0;  // System::set_ups() when the offsets below were last taken
  Vectors3 m_merged_offset;
  std::vector<Quat> m_merged_turn;
  // set_up's scratch: the particles' kinds and velocities before set-up.
  std::vector<ParticleKind> m_kind_before;
  Vectors3 m_v_before;
  // Per body, in Bullet's frame: the state copied in, the Newmark end-of-step twist and the position
  // twist handed to Bullet.
  Vectors3 m_x_in, m_v_in, m_w_in, m_v_next, m_w_next, m_v_position, m_w_position;
  std::vector<Quat> m_q_in;
  std::vector<JointRow> m_joint_rows;
  // Per body: Bullet's frame as the last tick left it (origin, basis), valid where m_frame_left_known,
  // and how many particles there were then; follow_teleports' scratch: per body the move found (rotation,
  // translation), per particle its component's root, per component what carries it.
  Vectors3 m_origin_left;
  std::vector<Mat3> m_basis_left;
  std::vector<std::uint8_t> m_frame_left_known;
  Index m_particles_left = 0;
  std::vector<Mat3> m_move_rotation;
  Vectors3 m_move_translation;
  std::vector<Index> m_moved_by;
  std::vector<Index> m_root;
  std::vector<Index> m_carrier;
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
  std::vector<btScalar> m_joint_buffer;
  std::vector<Index> m_point_body;              // find_tied_particles' scratch: each point's rigid body, or -1
  std::vector<std::pair<Index, Index>> m_tied;  // and its answer  // Bullet's btConstraintInfo2 arrays for one joint
  bool m_handed_over = false;
  bool m_use_world_gravity = true;
  bool m_body_contacts = true;
  bool m_pinching = false;
  double m_pinch_stiffness = 10.0;
  std::vector<Pinch> m_pinches;
  struct SprinkleSet {
    std::vector<Index> samples;
    std::vector<Index> particle;    // per sample: its collision particle, -1 none
    std::vector<double> last_near;  // per sample: the last time a Bullet object was within reach
    SprinkleSettings settings;
  };
  std::vector<SprinkleSet> m_sprinkles;
  /// At the start of a tick: adaptive sprinkle sets gain collision particles on samples near Bullet's
  /// objects and lose those that have been far for longer than `linger`.
  void update_sprinkles(double dt);
  /// A sprinkled collision particle on `sample` (a synchronized soft particle with its filter).
  Index add_sprinkled(Index sample);
  // update_pinches' scratch (kept: no allocation per tick once sized): the objects near the free
  // nodes with their grown boxes, the world's objects sorted by address, each particle's soft-binding
  // target, the pinches kept and added, the duplicates released, and the filters handed to the
  // collisions.
  struct PinchScratch {
    struct Near {
      int object;
      Eigen::AlignedBox3d box;
    };
    struct Hit {
      const btCollisionObject* object;
      double phi;
      Vec3 normal;
    };
    std::vector<Near> near;
    std::vector<Hit> hits;
    std::vector<const btCollisionObject*> present;
    std::vector<Index> target_of, removed;
    std::vector<std::uint8_t> pinched;
    std::vector<Pinch> kept, added;
    std::vector<std::pair<Index, const btCollisionObject*>> only, passes;
  } m_pinch_scratch;
  Vectors3 m_tick_start_x, m_tick_start_v;  // the deformables at the tick's start (restored if it throws)
  RigidBodyParticles m_tick_start_bodies;
  void (*m_app_pre_tick)(btDynamicsWorld*, btScalar) = nullptr;
  void (*m_app_post_tick)(btDynamicsWorld*, btScalar) = nullptr;
  StepStats m_last;
  StepStats m_total;
  BulletCollisions* m_collisions = nullptr;                               // owned by the system's collision sources
  std::unordered_map<const btCollisionObject*, Index> m_rigid_particles;  // m_bodies' inverse
};

}  // namespace sinew::bullet
