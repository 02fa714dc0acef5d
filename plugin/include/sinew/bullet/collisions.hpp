// Deformable collisions against Bullet's collision objects (step 3 of the Newmark step, section 3.3;
// "collisions for deformables only", section 5).
#pragma once

#include "sinew/ccd.hpp"
#include "sinew/system.hpp"

#include <BulletCollision/BroadphaseCollision/btDbvt.h>
#include <btBulletDynamicsCommon.h>

#include <deque>
#include <functional>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

namespace sinew::bullet {

/// Signed distance from a world point to a collision shape at a world transform, with the outward
/// unit normal at the closest point. Convex primitives and hulls are exact (analytic or GJK/EPA);
/// compounds take the closest child; concave shapes (triangle meshes, height fields) give the
/// unsigned distance to the nearest triangle within `reach`. Returns false when nothing is within
/// `reach` (concave) or the shape type is not supported.
bool signed_distance(const btCollisionShape* shape, const btTransform& frame, const Vec3& x, double reach, double& phi,
                     Vec3& normal);

/// The velocity of a particle at v that stops approaching a surface moving at v_body along the unit
/// normal n, with Coulomb friction taking up to mu |dv_n| of the tangential slip; v itself when it does
/// not approach.
Vec3 stop_approach(const Vec3& v, const Vec3& v_body, const Vec3& n, double mu);

/// How a body's velocity at lever r (from its centre of mass) answers an impulse j there: dv = K j with
/// K = m^-1 diag(linear_factor) - [r]x I^-1 [r]x (inverse_inertia in world axes, locks applied).
Mat3 body_point_inverse_mass(double inverse_mass, const Vec3& linear_factor, const Mat3& inverse_inertia,
                             const Vec3& r);

/// The impulse on a contact point that stops its approach to a body of finite mass: `v_rel` the point's
/// velocity relative to the body's surface, n the unit normal out of the body, `K` the pair's inverse
/// mass at the point (the point's own, times the identity, plus body_point_inverse_mass). Its normal
/// part leaves the two with the same normal velocity (a perfectly inelastic impact between the point
/// and the body, never more); its tangential part then takes up to all of the slip that is left,
/// bounded by mu times the normal part (where the body's lever couples the directions, it may leave
/// a small approach, which the end-of-tick pass removes). Neither part adds kinetic energy for a
/// symmetric K (a body with partial angular locks and a tilted inertia makes it slightly not so). Zero when the point
/// does not approach. Against a body of infinite mass (K = I / m) this is stop_approach's change times m; against a
/// light one it does not throw the body off at the point's whole approach speed times the point's mass ratio.
Vec3 inelastic_impulse(const Vec3& v_rel, const Vec3& n, double mu, const Mat3& K);

struct CollisionSettings {
  double thickness = 0.01;  ///< particles keep this distance from every surface [m]
  double friction = 0.3;    ///< Coulomb coefficient between cloth and rigid surfaces
  /// The corners and edges of polyhedral bodies (boxes, convex hulls, and such children of compounds)
  /// against the faces and edges of the registered collision surfaces (System::add_collision_surface),
  /// so a box edge or corner between two cloth nodes does not poke through the face between them.
  bool features = true;
};

/// The Bullet world's collision objects as a collision source of step 3: collides free and soft-bound
/// particles with every object whose filter admits them (CollisionGeometry::collides with the
/// object's broadphase group and mask), in the world's object order (deterministic), found through a
/// dynamic AABB tree (Bullet's btDbvt) of the objects' boxes swept over the step: each particle's path
/// meets only the objects whose swept box it crosses, so the cost follows the contacts, not particles
/// times objects. It projects
/// penetrating particles out to the thickness, removes their approaching normal velocity relative to
/// the surface with Coulomb friction on the tangential part, and hands step 4 a velocity constraint
/// against prescribed (static, kinematic) surfaces. A particle caught between a body Bullet alone moves
/// and a static or kinematic object that Bullet keeps the body off follows the object and gives the
/// body nothing (process()). Otherwise a dynamic body takes the opposite impulse: through
/// its rigid-body particle when the system has one (so the step carries it, and Bullet receives it
/// with the rest of the step's momentum), else summed per body and handed to Bullet once, by
/// apply_pending_impulses() after the step.
class BulletCollisions final : public CollisionSource {
 public:
  /// rigid_particles: the coupling's map from a Bullet body to its rigid-body particle (outlives this).
  BulletCollisions(btCollisionWorld* world, const CollisionSettings& settings,
                   const std::unordered_map<const btCollisionObject*, Index>* rigid_particles);
  std::string_view name() const override { return "bullet shapes"; }
  /// Bullet's frame (centre of mass, world) of the body that rigid-body particle `particle` stands
  /// for, when the particle is at centre x with orientation q.
  using BulletFrame = std::function<btTransform(Index particle, const Vec3& x, const Quat& q)>;
  /// Where each step meets the bodies: a body with a rigid-body particle at the particle's frames at
  /// t^n and at the step's prediction (its merged frame turned into Bullet's by `frame`); any other
  /// object at its pose at `tick_start` (the time of the tick's start, when Bullet's poses were read)
  /// moved on with its velocities to the step's start and end. Without a call: Bullet's poses as
  /// they are.
  void set_motion(BulletFrame frame, double tick_start) {
    m_bullet_frame = std::move(frame);
    m_tick_start = tick_start;
  }
  void process(CollisionContext& context) override;
  /// A particle within the thickness of a dynamic body in the last process() call, with the normal
  /// step 3 used (the coupling holds these at the end of the tick: Coupling::hold_contacts_at_tick_end).
  struct DynamicContact {
    Index particle;
    btRigidBody* body;
    Vec3 normal;
  };
  const std::vector<DynamicContact>& dynamic_contacts() const { return m_dynamic_contacts; }
  double friction() const { return m_settings.friction; }
  double thickness() const { return m_settings.thickness; }
  /// Forgets the last process() call's contacts (a tick in which the system slept ran no step 3).
  void forget_contacts() {
    m_dynamic_contacts.clear();
    m_deepest = 0.0;
    m_contacts = 0;
  }
  /// Applies the summed impulses on dynamic bodies without a rigid-body particle, once each.
  void apply_pending_impulses();
  /// Forgets them (the tick that gathered them failed).
  void discard_pending_impulses() { m_pending.clear(); }
  /// Deepest penetration below the thickness seen at the last call, before projection [m].
  double deepest_penetration() const { return m_deepest; }
  int contacts() const { return m_contacts; }
  /// Pairs (particle, rigid-body particle) that do not collide: a particle tied by a binding spring to
  /// a point on a body (Coupling::attach) passes through that body, as Bullet's constraints may turn
  /// off collisions between the bodies they link. Sorted; the coupling sets them every tick.
  void set_tied(const std::vector<std::pair<Index, Index>>& tied) { m_tied = tied; }
  /// Figure 10's pinches (Coupling, CouplingSettings::pinching). A particle in `only` meets that
  /// object alone (a pinched node's duplicate); a pair in `passes` lets the particle through that
  /// object (the pinched node itself, which its duplicates hold). The coupling sets them every tick.
  using ObjectPairs = std::vector<std::pair<Index, const btCollisionObject*>>;
  void set_pinches(const ObjectPairs& only, const ObjectPairs& passes);
  /// The pair inverse mass (body_point_inverse_mass) of a dynamic body at `arm` (from its centre of
  /// mass) as Bullet has it: its locks, and its world inverse inertia with rows scaled by the angular
  /// factor, as applyTorqueImpulse applies them.
  static Mat3 bullet_point_inverse_mass(const btRigidBody* body, const btVector3& arm);
  /// Whether the pinches let particle i meet object o.
  bool pinch_admits(Index i, const btCollisionObject* o) const;

  /// The continuous test samples a path at most this many times: a body thinner than 1/64 of its
  /// motion relative to a particle within one step can still pass it.
  static constexpr int kMaxSweepSamples = 64;

 private:
  /// The object nearest to x within reach whose filter admits particle i: index, signed distance and
  /// normal (taken from the side the particle came from when it entered this step), and whether it
  /// came into the object within this step. -1 when none.
  int closest_object(const CollisionContext& c, Index i, double& phi, Vec3& normal, bool& entered) const;
  /// Whether object o may meet particle i: contact response, the pinches, ties, collision filters.
  bool admits(const CollisionContext& c, Index i, int o) const;
  /// A static or kinematic object that holds particle i against `hit`: the particle is inside `hit`
  /// (phi_hit < 0) and within the object's thickness, or pushed out of `hit` along n_hit it would be
  /// within the object's thickness from the opposite side (`move`: the push is taken first).
  /// `entered`: the particle came into `hit` within this step (closest_object). The nearest such
  /// object, with its signed distance and normal there; -1 when none.
  int pinching_object(const CollisionContext& c, Index i, int hit, double phi_hit, const Vec3& n_hit, bool entered,
                      bool& move, double& phi, Vec3& normal) const;
  /// A dynamic body that Bullet alone moves (not a rigid-body particle of the system).
  bool held_by_bullet_alone(int o) const;

  /// Whether particle i, outside object o at t^n (x0), passed through it on its way to x1 while the
  /// object moved from m_frame_n to m_frame: the path in the object's frame sampled at no more than
  /// m_spacing[o] apart (at most kMaxSweepSamples), the entry found by bisection. On a crossing, phi
  /// and normal are the end position's distance and normal against the plane through the surface
  /// point it entered by, carried to the object's end pose (negative: the projection along the normal
  /// puts the particle back on the side it came from, keeping its motion along the surface). Convex shapes and
  /// compounds of them; a concave shape has no inside.
  bool crossed(int o, const Vec3& x0, const Vec3& x1, double& phi, Vec3& normal) const;
  /// Fills m_frame_n and m_frame (object o at t^n and at the step's prediction) and the AABBs (swept
  /// and padded; a static object's kept while its pose, shape and scale are), and brings the tree up
  /// to date (refitted leaves; rebuilt when the world's objects changed).
  void place_objects(const CollisionContext& c);
  /// The corners and edges of the polyhedral objects near the surfaces against the surfaces' faces
  /// and edges (CollisionSettings::features), after the particles.
  void process_features(CollisionContext& c);
  /// A polyhedral shape's corners and edges in its own frame (the hull of its vertices, from Bullet's
  /// btConvexHullComputer), and the extra reach of its rounding margin (none for a box, whose
  /// corners are its surface); computed once per shape, vertices and margin.
  struct Features {
    const btCollisionShape* shape = nullptr;  // the shape, vertices and margin the hull was made from
    std::vector<double> vertices;
    std::vector<Vec3> corners;
    std::vector<std::array<int, 2>> edges;
    double margin = 0.0;
  };
  /// features_of keeps the hulls of at most this many shapes (then starts again).
  static constexpr std::size_t kMaxFeatureShapes = 256;
  const Features& features_of(const btPolyhedralConvexShape* shape) const;
  /// Takes back particle i's tangential displacement relative to prescribed object o, up to the
  /// friction coefficient times `push` (the normal displacement the contact imposed along n).
  void hold_by_friction(CollisionContext& c, Index i, std::size_t o, const Vec3& n, double push);
  /// Pushes the surface points `points` (weights summing to 1, -1 for none) of a contact with object o
  /// at world point `at` along n (from the body towards the surface) by `gap`, stops their approach
  /// relative to the body's surface there with friction, and gives the body the opposite impulse.
  void respond_to_body(CollisionContext& c, int o, const std::array<Index, 3>& points,
                       const std::array<double, 3>& weights, const Vec3& at, const Vec3& n, double gap);
  BulletCollisions(const BulletCollisions&) = delete;  // the tree owns its nodes
  BulletCollisions& operator=(const BulletCollisions&) = delete;

  btCollisionWorld* m_world;
  BulletFrame m_bullet_frame;
  double m_tick_start = 0.0;
  std::vector<btTransform> m_frame_n, m_frame;
  CollisionSettings m_settings;
  const std::unordered_map<const btCollisionObject*, Index>* m_rigid_particles;
  std::vector<btVector3> m_aabb_min, m_aabb_max;        // swept: the boxes at both poses, padded
  std::vector<double> m_spacing;                        // crossed()'s sample spacing per object, 0: not swept
  std::vector<const btCollisionShape*> m_placed_shape;  // the shape and scale each box was made for
  std::vector<btVector3> m_placed_scaling;
  btDbvt m_tree;                                    // the objects' padded boxes, leaf data: object index
  std::vector<btDbvtNode*> m_leaves;                // per object
  std::vector<const btCollisionObject*> m_indexed;  // the objects the leaves stand for, in world order
  mutable btNodeStack m_stack;                      // the tree queries' stack (kept: no allocation per query)
  mutable std::vector<int> m_candidates;            // one particle's objects, sorted into world order
  struct Pending {
    btRigidBody* body;
    btVector3 impulse, torque_impulse;
  };
  /// What the impulses held for body (applied after the step) add to its velocity at `arm` (from its
  /// centre of mass), as Bullet's applyCentralImpulse and applyTorqueImpulse will.
  Vec3 pending_velocity(const btRigidBody* body, const btVector3& arm) const;
  std::vector<Pending> m_pending;
  std::vector<DynamicContact> m_dynamic_contacts;
  // process_features: the surfaces' triangles and edges binned by their boxes over the step, and each
  // shape's features (keyed by shape and scale).
  ccd::BoxGrid m_triangle_grid, m_segment_grid;
  std::vector<Eigen::AlignedBox3d> m_triangle_box, m_segment_box;
  mutable std::deque<Features> m_features;  // a deque: the references features_of returns stay valid
  std::vector<int> m_particle_object;       // per particle: the object the particle tests held it off, or -1
  std::vector<Index> m_seen_feature;        // per triangle or edge: the last feature that tested it
  void push_pending(btRigidBody* body, const btVector3& arm, const Vec3& j);
  double m_deepest = 0.0;
  int m_contacts = 0;
  std::vector<std::pair<Index, Index>> m_tied;
  ObjectPairs m_pinch_only, m_pinch_passes;  // sorted by particle, then object address
};

}  // namespace sinew::bullet
