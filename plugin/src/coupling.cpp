#include "sinew/bullet/coupling.hpp"

#include "sinew/bullet/collisions.hpp"
#include "sinew/bullet/convert.hpp"
#include "sinew/forces/centroid_springs.hpp"
#include "sinew/forces/corotated_tets.hpp"
#include "sinew/forces/dihedral_bending.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/forces/triangle_membrane.hpp"
#include "sinew/self_collisions.hpp"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <mutex>
#include <utility>

namespace sinew::bullet {

namespace {

// Bullet keeps the tick callbacks protected and offers no getter. A pointer to member formed through
// a derived class reads them without touching the world's user-info pointer, which the application
// may be using for its own callbacks.
struct TickCallbackAccess : btDynamicsWorld {
  static btInternalTickCallback pre_tick(const btDynamicsWorld& world) {
    return world.*(&TickCallbackAccess::m_internalPreTickCallback);
  }
  static btInternalTickCallback post_tick(const btDynamicsWorld& world) {
    return world.*(&TickCallbackAccess::m_internalTickCallback);
  }
};

// btTransformUtil's ANGULAR_MOTION_THRESHOLD, a little inside it so that Bullet's own limit never cuts
// what the step hands over by a rounding.
constexpr double kBulletMaxTurn = 0.25 * 3.14159265358979323846 * (1.0 - 1e-9);

// Which coupling serves which world: the callback receives only the world.
std::mutex g_registry_mutex;
std::vector<std::pair<btDynamicsWorld*, Coupling*>> g_registry;

Coupling* find_coupling(btDynamicsWorld* world) {
  std::lock_guard<std::mutex> lock(g_registry_mutex);
  for (const auto& [w, c] : g_registry)
    if (w == world) return c;
  return nullptr;
}

// Bullet's solver uses a row stride of 4 or more (16-byte rows), and some joints write a row as a
// btVector3, four scalars: stride 4, and one spare row at the end of every array.
constexpr int kJointRowSkip = 4;

// Calls joint.getInfo2 as Bullet's solver prepares it: eight arrays (J1 linear, J1 angular, J2 linear,
// J2 angular, error, cfm, lower and upper limits) in `buffer`, each striding by rowskip as the solver's
// row structs do, the global CFM on the first row only and unbounded limits for the joint to narrow.
btTypedConstraint::btConstraintInfo2 joint_info2(btTypedConstraint& joint, int rows, const btContactSolverInfo& solver,
                                                 double dt, std::vector<btScalar>& buffer) {
  constexpr int skip = kJointRowSkip;
  const int length = skip * (rows + 1);
  buffer.assign(static_cast<std::size_t>(8 * length), btScalar(0));
  btScalar* array[8];
  for (int k = 0; k < 8; ++k) array[k] = buffer.data() + k * length;
  btTypedConstraint::btConstraintInfo2 info2;
  info2.fps = btScalar(1.0 / dt);
  info2.erp = solver.m_erp;
  info2.m_J1linearAxis = array[0];
  info2.m_J1angularAxis = array[1];
  info2.m_J2linearAxis = array[2];
  info2.m_J2angularAxis = array[3];
  info2.rowskip = skip;
  info2.m_constraintError = array[4];
  info2.cfm = array[5];
  info2.m_lowerLimit = array[6];
  info2.m_upperLimit = array[7];
  info2.cfm[0] = solver.m_globalCfm;
  for (int r = 0; r < rows; ++r) {
    info2.m_lowerLimit[skip * r] = -SIMD_INFINITY;
    info2.m_upperLimit[skip * r] = SIMD_INFINITY;
  }
  info2.m_numIterations = solver.m_numIterations;
  info2.m_damping = solver.m_damping;
  joint.getInfo2(&info2);
  return info2;
}

// Rows the joint bounded (limits, motors) or softened (a CFM of its own) stay Bullet's.
bool is_equality_row(const btTypedConstraint::btConstraintInfo2& info2, int r, btScalar global_cfm) {
  constexpr int skip = kJointRowSkip;
  const btScalar seeded_cfm = r == 0 ? global_cfm : btScalar(0);
  return !(info2.m_lowerLimit[skip * r] > -SIMD_INFINITY || info2.m_upperLimit[skip * r] < SIMD_INFINITY ||
           info2.cfm[skip * r] > seeded_cfm);
}

// Row r between coupled bodies a and b (-1: outside the coupling). A body outside the coupling keeps
// its velocity (twist_a, twist_b: linear then angular, world): its part of the row moves to the target.
JointRow joint_row(const btTypedConstraint::btConstraintInfo2& info2, int r, Index a, Index b, const Vec6& twist_a,
                   const Vec6& twist_b) {
  constexpr int skip = kJointRowSkip;
  Vec6 j_a, j_b;
  for (int d = 0; d < 3; ++d) {
    j_a[d] = info2.m_J1linearAxis[skip * r + d];
    j_a[3 + d] = info2.m_J1angularAxis[skip * r + d];
    j_b[d] = info2.m_J2linearAxis[skip * r + d];
    j_b[3 + d] = info2.m_J2angularAxis[skip * r + d];
  }
  JointRow row;
  if (a >= 0) {
    row.body_a = a;
    row.j_a = j_a;
  } else {
    row.target -= j_a.dot(twist_a);
  }
  if (b >= 0) {
    (a >= 0 ? row.body_b : row.body_a) = b;
    (a >= 0 ? row.j_b : row.j_a) = j_b;
  } else {
    row.target -= j_b.dot(twist_b);
  }
  return row;
}

Mat3 to_eigen_matrix(const btMatrix3x3& m) {
  Mat3 out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out(r, c) = static_cast<double>(m[r][c]);
  return out;
}

// Components of the particle graph (union-find): the root of i, halving the path on the way; joining
// keeps the smaller index as the root, so the roots do not depend on the order of the joins.
Index find_root(std::vector<Index>& root, Index i) {
  while (root[static_cast<std::size_t>(i)] != i) {
    root[static_cast<std::size_t>(i)] = root[static_cast<std::size_t>(root[static_cast<std::size_t>(i)])];
    i = root[static_cast<std::size_t>(i)];
  }
  return i;
}

void join(std::vector<Index>& root, Index a, Index b) {
  a = find_root(root, a);
  b = find_root(root, b);
  if (a != b) root[static_cast<std::size_t>(std::max(a, b))] = std::min(a, b);
}

template <typename Nodes>
void join_nodes(std::vector<Index>& root, const Nodes& nodes) {
  for (std::size_t k = 1; k < std::size(nodes); ++k) join(root, nodes[0], nodes[k]);
}

template <typename Element>
void join_elements(std::vector<Index>& root, const std::vector<Element>& elements) {
  for (const Element& e : elements) join_nodes(root, e);
}

// The elements of the forces sinew provides join their nodes. A force of the application's own
// exposes no elements; the collision surfaces the builders register cover the meshes it is built on.
void join_force_elements(std::vector<Index>& root, const Force& force) {
  if (const auto* f = dynamic_cast<const EdgeSprings*>(&force)) join_elements(root, f->edges());
  if (const auto* f = dynamic_cast<const TriangleMembrane*>(&force)) join_elements(root, f->triangles());
  if (const auto* f = dynamic_cast<const CorotatedTets*>(&force)) join_elements(root, f->tets());
  if (const auto* f = dynamic_cast<const DihedralBending*>(&force)) join_elements(root, f->hinges());
  if (const auto* f = dynamic_cast<const CentroidSprings*>(&force))
    for (Index e = 0; e < f->stencils().size(); ++e) join_nodes(root, f->stencils()[e]);
}

}  // namespace

Coupling::Coupling(btDynamicsWorld* world, const CouplingSettings& settings) : m_world(world) {
  if (!world) fail("bullet coupling: world is null");
  SystemSettings system = settings.system;
  if (settings.use_world_gravity) system.gravity = to_eigen(world->getGravity());
  m_use_world_gravity = settings.use_world_gravity;
  m_body_contacts = settings.body_contacts;
  m_pinching = settings.pinching;
  if (!(std::isfinite(settings.pinch_stiffness) && settings.pinch_stiffness > 0))
    fail("bullet coupling: pinch_stiffness ", settings.pinch_stiffness, " must be positive and finite");
  m_pinch_stiffness = settings.pinch_stiffness;
  m_system = System(system);
  // Bullet turns a body by at most pi/4 per step whatever its angular velocity (btTransformUtil::
  // integrateTransform's ANGULAR_MOTION_THRESHOLD); the step turns the rigid-body particles and the
  // points on them no further, so that Bullet then moves each body along the step's update.
  m_system.step_settings().max_rotation_per_step =
      std::min(m_system.step_settings().max_rotation_per_step, kBulletMaxTurn);
  {
    std::lock_guard<std::mutex> lock(g_registry_mutex);
    for (const auto& entry : g_registry)
      if (entry.first == world) fail("bullet coupling: this world already has a coupling attached");
    g_registry.emplace_back(world, this);
  }
  if (settings.collisions) {
    auto collisions = std::make_unique<BulletCollisions>(
        world, CollisionSettings{settings.thickness, settings.friction, settings.feature_contacts}, &m_rigid_particles);
    m_collisions = collisions.get();
    m_system.add_collision_source(std::move(collisions));
  }
  // After Bullet's shapes: what the cloths meet there (a box lifting the lower cloth) is then seen by
  // the contact between them in the same step.
  if (settings.self_collisions) {
    SelfCollisionSettings self;
    self.thickness = settings.self_thickness;
    self.friction = settings.friction;
    m_system.add_collision_source(std::make_unique<SelfCollisions>(self));
  }
  m_app_pre_tick = TickCallbackAccess::pre_tick(*world);
  m_app_post_tick = TickCallbackAccess::post_tick(*world);
  world->setInternalTickCallback(&Coupling::pre_tick, world->getWorldUserInfo(), true);
  world->setInternalTickCallback(&Coupling::post_tick, world->getWorldUserInfo(), false);
}

Coupling::~Coupling() {
  // Bodies still in the world get their own mass properties back (removed ones may be gone).
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  for (int o = 0; o < objects.size(); ++o)
    if (const auto found = m_rigid_particles.find(objects[o]); found != m_rigid_particles.end())
      restore_own_mass(found->second);
  m_world->setInternalTickCallback(m_app_pre_tick, m_world->getWorldUserInfo(), true);
  m_world->setInternalTickCallback(m_app_post_tick, m_world->getWorldUserInfo(), false);
  std::lock_guard<std::mutex> lock(g_registry_mutex);
  g_registry.erase(
      std::remove_if(g_registry.begin(), g_registry.end(), [this](const auto& e) { return e.second == this; }),
      g_registry.end());
}

double Coupling::deepest_penetration() const { return m_collisions ? m_collisions->deepest_penetration() : 0.0; }

void Coupling::pre_tick(btDynamicsWorld* world, btScalar dt) {
  Coupling* coupling = find_coupling(world);
  if (!coupling) return;
  if (coupling->m_app_pre_tick) coupling->m_app_pre_tick(world, dt);
  coupling->tick(static_cast<double>(dt));
}

void Coupling::post_tick(btDynamicsWorld* world, btScalar dt) {
  Coupling* coupling = find_coupling(world);
  if (!coupling) return;
  coupling->follow_bodies(static_cast<double>(dt));
  if (coupling->m_app_post_tick) coupling->m_app_post_tick(world, dt);
}

void Coupling::follow_bodies(double dt) {
  if (!m_system.finalized()) return;
  take_back_momentum();
  hold_contacts_at_tick_end(dt);
  copy_state_in();
  m_system.clamp_bound_rows();
  note_frames_left();
}

Index Coupling::rigid_particle(btRigidBody* body) {
  if (!body) fail("bullet coupling: rigid body is null");
  add_own_body_slots();
  if (const auto found = m_rigid_particles.find(body); found != m_rigid_particles.end()) return found->second;
  // A body outside the world would never be integrated by Bullet while sinew integrated its particle.
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const int slot = body->getWorldArrayIndex();
  if (slot < 0 || slot >= objects.size() || objects[slot] != body)
    fail("bullet coupling: rigid body ", static_cast<const void*>(body),
         " is not in the coupling's world; add it (addRigidBody) before binding to it");
  const btTransform& frame = body->getCenterOfMassTransform();
  RigidBodySettings s;
  s.x = to_eigen(frame.getOrigin());
  s.q = to_eigen(frame.getRotation());
  s.kinematic = body->isStaticOrKinematicObject() || body->getInvMass() == btScalar(0);
  if (!s.kinematic) {
    s.mass = 1.0 / static_cast<double>(body->getInvMass());
    const btVector3 inverse = body->getInvInertiaDiagLocal();
    for (int i = 0; i < 3; ++i) {
      if (!(inverse[i] > btScalar(0)))
        fail("bullet coupling: rigid body ", m_bodies.size(), " has a locked rotation axis (inverse inertia ", i,
             " is 0), which rigid-body particles do not support yet");
      s.inertia[i] = 1.0 / static_cast<double>(inverse[i]);
    }
  }
  s.gravity = false;  // gravity comes with Bullet's total force on the body, copied in every tick
  const Index b = m_system.add_rigid_body(s);
  add_own_body_slots();
  const auto i = static_cast<std::size_t>(b);
  m_bodies[i] = body;
  m_seen_inverse_mass[i] = body->getInvMass();
  m_seen_inverse_inertia[i] = body->getInvInertiaDiagLocal();
  m_own_mass[i] = s.kinematic ? btScalar(0) : btScalar(s.mass);
  m_own_inertia[i] = s.kinematic ? btVector3(0, 0, 0) : to_bullet(s.inertia);
  m_rigid_particles.emplace(body, b);
  return b;
}

void Coupling::add_own_body_slots() {
  const auto count = static_cast<std::size_t>(m_system.rigid_bodies().size());
  if (m_bodies.size() >= count) return;
  m_bodies.resize(count, nullptr);
  m_seen_inverse_mass.resize(count, btScalar(0));
  m_seen_inverse_inertia.resize(count, btVector3(0, 0, 0));
  m_own_mass.resize(count, btScalar(0));
  m_own_inertia.resize(count, btVector3(0, 0, 0));
  m_mass_handed.resize(count, 0);
  const auto old = m_merged_offset.cols();
  m_merged_offset.conservativeResize(3, static_cast<Index>(count));
  m_merged_offset.rightCols(static_cast<Index>(count) - old).setZero();
  m_merged_turn.resize(count, Quat::Identity());
  m_origin_left.conservativeResize(3, static_cast<Index>(count));
  m_origin_left.rightCols(static_cast<Index>(count) - old).setZero();
  m_basis_left.resize(count, Mat3::Identity());
  m_frame_left_known.resize(count, 0);
  m_move_rotation.resize(count, Mat3::Identity());
  m_move_translation.conservativeResize(3, static_cast<Index>(count));
  m_move_translation.rightCols(static_cast<Index>(count) - old).setZero();
}

void Coupling::remove(btRigidBody* body) {
  const auto found = body ? m_rigid_particles.find(body) : m_rigid_particles.end();
  if (found == m_rigid_particles.end())
    fail("Coupling::remove: rigid body ", static_cast<const void*>(body), " is not coupled");
  restore_own_mass(found->second);
  release(found->second);
}

Vec3 Coupling::centre_of_mass(const btRigidBody* body) const {
  const btTransform& frame = body->getCenterOfMassTransform();
  const auto found = m_rigid_particles.find(body);
  if (found == m_rigid_particles.end()) return to_eigen(frame.getOrigin());
  return to_eigen(frame * to_bullet(m_merged_offset.col(found->second)));
}

Vec3 Coupling::body_offset(Index k) const {
  const HardBindings& hard = m_system.hard_bindings();
  const Index b = hard.rigid_body(k);
  return Vec3(m_merged_offset.col(b)) + m_merged_turn[static_cast<std::size_t>(b)] * hard.rigid_offset_body(k);
}

Vec3 Coupling::merged_offset(Index b, const Vec3& local) const {
  return m_merged_turn[static_cast<std::size_t>(b)].conjugate() * (local - m_merged_offset.col(b));
}

void Coupling::set_particle_mass(Index b, bool kinematic, double mass, const Vec3& inertia) {
  m_system.set_rigid_body_mass(b, kinematic, mass, inertia);
  m_merged_offset.setZero();
  std::fill(m_merged_turn.begin(), m_merged_turn.end(), Quat::Identity());
}

void Coupling::restore_own_mass(Index b) {
  const auto i = static_cast<std::size_t>(b);
  btRigidBody* body = m_bodies[i];
  if (!body || !m_mass_handed[i]) return;
  body->setMassProps(m_own_mass[i], m_own_inertia[i]);
  body->updateInertiaTensor();
  m_seen_inverse_mass[i] = body->getInvMass();
  m_seen_inverse_inertia[i] = body->getInvInertiaDiagLocal();
  m_mass_handed[i] = 0;
}

// The merged body's mass, and its inertia carried to Bullet's centre of mass (parallel axes) in
// Bullet's frame of the body, of which Bullet keeps the diagonal: the merged inertia about Bullet's
// centre, I = R_rel I' R_rel^T + m' (|d|^2 1 - d d^T), has off-diagonal terms Bullet cannot hold.
void Coupling::hand_mass_to_bullet(Index b) {
  const auto i = static_cast<std::size_t>(b);
  btRigidBody* body = m_bodies[i];
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  if (!body || bodies.kinematic[b]) return;
  if (bodies.mass[b] == static_cast<double>(m_own_mass[i])) {
    restore_own_mass(b);
    return;
  }
  const Mat3 turn = m_merged_turn[i].toRotationMatrix();
  const Vec3 d = m_merged_offset.col(b);
  const double m = bodies.mass[b];
  const Mat3 inertia = turn * bodies.inertia.col(b).asDiagonal() * turn.transpose() +
                       m * (d.squaredNorm() * Mat3::Identity() - d * d.transpose());
  body->setMassProps(btScalar(m), to_bullet(inertia.diagonal()));
  body->updateInertiaTensor();
  m_seen_inverse_mass[i] = body->getInvMass();
  m_seen_inverse_inertia[i] = body->getInvInertiaDiagLocal();
  m_mass_handed[i] = 1;
}

// Where the particles' (merged) frames are in Bullet's frames of the bodies, and Bullet told the
// merged masses.
void Coupling::adopt_set_up() {
  m_set_ups_seen = m_system.set_ups();
  add_own_body_slots();
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  for (std::size_t i = 0; i < m_bodies.size(); ++i) {
    const auto b = static_cast<Index>(i);
    if (!m_bodies[i] || bodies.kinematic[b]) continue;
    if (bodies.mass[b] == static_cast<double>(m_own_mass[i])) {
      m_merged_offset.col(b).setZero();
      m_merged_turn[i] = Quat::Identity();
    } else {
      const btTransform& frame = m_bodies[i]->getCenterOfMassTransform();
      const Quat q = to_eigen(frame.getRotation());
      m_merged_offset.col(b) = q.conjugate() * (bodies.x.col(b) - to_eigen(frame.getOrigin()));
      m_merged_turn[i] = (q.conjugate() * bodies.q[b]).normalized();
    }
    hand_mass_to_bullet(b);
  }
}

// Set-up merges the mass of points hard-bound to a body into it (RigidBindings::absorb_masses: mass,
// centre, inertia, principal frame) and puts the points on the body with its twist, which would drop
// the momentum m (v - v_point) a point brought: that goes into the body as an impulse at the point, so
// the system's linear and angular momentum are what they were. Then Bullet is told.
void Coupling::set_up() {
  const Particles& particles = m_system.particles();
  m_kind_before = particles.kind;
  m_v_before = particles.v;
  m_system.finalize();
  adopt_set_up();
  // The frames again from Bullet's (equal to set-up's to round-off), and the points on them.
  copy_state_in();
  m_system.clamp_bound_rows();
  const RigidBindings& rigid = m_system.hard_bindings().rigid();
  const VectorXd& mass = m_system.input_mass();
  bool pushed = false;
  for (Index k = 0; k < rigid.size(); ++k) {
    const Index p = rigid.particle(k);
    const bool new_point = p >= static_cast<Index>(m_kind_before.size()) ||
                           m_kind_before[static_cast<std::size_t>(p)] != ParticleKind::hard_bound;
    if (!new_point || !(mass[p] > 0.0) || p >= m_v_before.cols()) continue;
    const Vec3 j = mass[p] * (Vec3(m_v_before.col(p)) - Vec3(m_system.particles().v.col(p)));
    if (j.isZero(0.0)) continue;
    m_system.apply_impulse(p, j);
    pushed = true;
  }
  if (!pushed) return;
  // Bullet's velocities from the particles' twists (the velocity of Bullet's centre: v' + w x (c - x')).
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  for (std::size_t i = 0; i < m_bodies.size(); ++i) {
    const auto b = static_cast<Index>(i);
    if (!m_bodies[i] || bodies.kinematic[b]) continue;
    const Vec3 w = bodies.w.col(b);
    const Vec3 e = m_q_in[i] * Vec3(m_merged_offset.col(b));
    m_bodies[i]->setLinearVelocity(to_bullet(Vec3(bodies.v.col(b)) - w.cross(e)));
    m_bodies[i]->setAngularVelocity(to_bullet(w));
  }
  copy_state_in();
  m_system.clamp_bound_rows();
}

void Coupling::release(Index b) {
  // Points with a mass of their own go free with it; massless ones (body points, points embedded
  // among them that set-up has not yet resolved onto the body, and points embedded among free
  // particles and massless body points) have nothing left to follow.
  const RigidBindings& rigid = m_system.hard_bindings().rigid();
  const LinearBindings& linear = m_system.hard_bindings().linear();
  const VectorXd& mass = m_system.input_mass();
  std::vector<Index> freed, removed;
  std::vector<std::uint8_t> is_removed(static_cast<std::size_t>(m_system.particles().size()), 0);
  for (Index k = 0; k < rigid.size(); ++k) {
    if (rigid.body(k) != b) continue;
    const Index p = rigid.particle(k);
    (mass[p] > 0.0 ? freed : removed).push_back(p);
    if (mass[p] == 0.0) is_removed[static_cast<std::size_t>(p)] = 1;
  }
  const MixedBindings& mixed = m_system.hard_bindings().mixed();
  const auto remove_hanging = [&](const auto& kind) {  // massless points with a removed parent
    bool grew = false;
    for (Index k = 0; k < kind.size(); ++k) {
      const Index p = kind.particle(k);
      if (is_removed[static_cast<std::size_t>(p)] || mass[p] > 0.0) continue;
      for (Index parent : kind.parents(k))
        if (is_removed[static_cast<std::size_t>(parent)]) {
          removed.push_back(p);
          is_removed[static_cast<std::size_t>(p)] = 1;
          grew = true;
          break;
        }
    }
    return grew;
  };
  for (bool grew = true; grew;) grew = remove_hanging(linear) | remove_hanging(mixed);
  // The particle stays (indices keep their meaning) as a kinematic body at rest that nothing uses.
  set_particle_mass(b, true);
  m_mass_handed[static_cast<std::size_t>(b)] = 0;
  RigidBodyParticles& bodies = m_system.rigid_bodies();
  bodies.v.col(b).setZero();
  bodies.w.col(b).setZero();
  for (Index p : freed) m_system.unbind(p);
  if (!removed.empty()) m_system.remove_particles(removed);
  m_rigid_particles.erase(m_bodies[static_cast<std::size_t>(b)]);
  m_bodies[static_cast<std::size_t>(b)] = nullptr;
}

void Coupling::follow_world() {
  add_own_body_slots();
  // Which coupled bodies are still in the world, from the world's own list: a body the application
  // removed (and perhaps deleted) is never read.
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  m_in_world.assign(m_bodies.size(), 0);
  for (int o = 0; o < objects.size(); ++o)
    if (const auto found = m_rigid_particles.find(objects[o]); found != m_rigid_particles.end())
      m_in_world[static_cast<std::size_t>(found->second)] = 1;
  for (std::size_t b = 0; b < m_bodies.size(); ++b) {
    if (!m_bodies[b]) continue;
    if (!m_in_world[b]) {
      release(static_cast<Index>(b));
    } else {
      follow_mass(static_cast<Index>(b));
    }
  }
}

void Coupling::follow_mass(Index b) {
  const auto i = static_cast<std::size_t>(b);
  const btRigidBody* body = m_bodies[i];
  RigidBodyParticles& bodies = m_system.rigid_bodies();
  const bool prescribed = body->isStaticOrKinematicObject() || body->getInvMass() == btScalar(0);
  // Mass properties other than the ones the coupling handed over are the application's: the body's own.
  const bool changed =
      body->getInvMass() != m_seen_inverse_mass[i] || body->getInvInertiaDiagLocal() != m_seen_inverse_inertia[i];
  if (changed) {
    m_seen_inverse_mass[i] = body->getInvMass();
    m_seen_inverse_inertia[i] = body->getInvInertiaDiagLocal();
    m_mass_handed[i] = 0;
    if (body->getInvMass() > btScalar(0)) {
      const btVector3 inverse = body->getInvInertiaDiagLocal();
      for (int d = 0; d < 3; ++d)
        if (!(inverse[d] > btScalar(0)))
          fail("bullet coupling: rigid body ", b, " has a locked rotation axis (inverse inertia ", d,
               " is 0), which rigid-body particles do not support yet");
      m_own_mass[i] = btScalar(1) / body->getInvMass();
      m_own_inertia[i] = btVector3(btScalar(1) / inverse.x(), btScalar(1) / inverse.y(), btScalar(1) / inverse.z());
    }
  }
  if (prescribed) {
    if (bodies.kinematic[b]) return;
    set_particle_mass(b, true);
    // From here it moves as Bullet moves it (copy_state_in): from its pose now.
    const btTransform& frame = body->getCenterOfMassTransform();
    bodies.x.col(b) = to_eigen(frame.getOrigin());
    bodies.q[b] = to_eigen(frame.getRotation());
    return;
  }
  if (!bodies.kinematic[b] && !changed) return;
  set_particle_mass(b, false, static_cast<double>(m_own_mass[i]), to_eigen(m_own_inertia[i]));
}

void Coupling::note_frames_left() {
  for (std::size_t b = 0; b < m_bodies.size(); ++b) {
    m_frame_left_known[b] = m_bodies[b] ? 1 : 0;
    if (!m_bodies[b]) continue;
    const btTransform& frame = m_bodies[b]->getCenterOfMassTransform();
    m_origin_left.col(static_cast<Index>(b)) = to_eigen(frame.getOrigin());
    m_basis_left[b] = to_eigen_matrix(frame.getBasis());
  }
  m_particles_left = m_system.particles().size();
}

// Bullet moves a dynamic or static body only inside a tick (integration, and nothing for a static one),
// so a frame at a tick's start that is not the one the last tick left it in was set by the application
// (setWorldTransform, setCenterOfMassTransform): a teleport, by the rigid transform x -> R x + t that
// takes the old frame to the new. The deformables that follow the body go with it: every component of
// the particle graph (elements, collision surfaces, embeddings, soft bindings and active binding
// springs join particles; a rigid body does not) bound to the body, positions moved by the transform
// and velocities turned by R, so its shape on the body and its motion relative to it are what they
// were (it is not given the jump as velocity). The body's own velocities are the application's.
// A component bound to several bodies goes only where all of them went alike (the same transform to
// round-off: the application moved them together); one also held by a body the move left (or a
// kinematic one, or sinew's own), by a kinematic particle, or holding particles added since the last
// tick (placed by the application, perhaps already where it wanted them) stays, and its ties to the
// moved body stretch. Components bound to nothing are never moved.
//
// A kinematic body is moved between ticks by Bullet itself (from its motion state, with the velocity
// that covers the move) and the cloth sweeps with it (copy_state_in): prescribed motion, not a teleport.
// So is the first tick of a body, which has no frame left by a tick to compare with.
void Coupling::follow_teleports() {
  const std::size_t count = m_bodies.size();
  m_moved_by.assign(count, -1);
  bool any = false;
  for (std::size_t b = 0; b < count; ++b) {
    if (!m_frame_left_known[b] || !m_bodies[b] || m_bodies[b]->isKinematicObject()) continue;
    const btTransform& frame = m_bodies[b]->getCenterOfMassTransform();
    const Vec3 origin = to_eigen(frame.getOrigin());
    const Mat3 basis = to_eigen_matrix(frame.getBasis());
    const auto i = static_cast<Index>(b);
    if (origin == Vec3(m_origin_left.col(i)) && basis == m_basis_left[b]) continue;
    m_move_rotation[b] = basis * m_basis_left[b].transpose();
    m_move_translation.col(i) = origin - m_move_rotation[b] * m_origin_left.col(i);
    m_moved_by[b] = i;
    any = true;
  }
  // A tick the post-tick callback does not close (Coupling::tick called alone) leaves nothing to compare.
  std::fill(m_frame_left_known.begin(), m_frame_left_known.end(), std::uint8_t(0));
  if (!any) return;
  // Bodies moved alike share the first one's move. Round-off: the rotations from two frames turned by
  // the same R differ by a few ulps, the translations by that times the distance moved.
  for (std::size_t b = 0; b < count; ++b) {
    if (m_moved_by[b] < 0) continue;
    const auto i = static_cast<Index>(b);
    for (std::size_t c = 0; c < b; ++c) {
      if (m_moved_by[c] != static_cast<Index>(c)) continue;
      const auto j = static_cast<Index>(c);
      const double reach =
          1.0 + m_origin_left.col(i).norm() + m_origin_left.col(j).norm() + m_move_translation.col(i).norm();
      if ((m_move_rotation[b] - m_move_rotation[c]).cwiseAbs().maxCoeff() <= 1e-12 &&
          (m_move_translation.col(i) - m_move_translation.col(j)).norm() <= 1e-12 * reach) {
        m_moved_by[b] = j;
        break;
      }
    }
  }
  Particles& particles = m_system.particles();
  const Index n = particles.size();
  m_root.resize(static_cast<std::size_t>(n));
  for (Index p = 0; p < n; ++p) m_root[static_cast<std::size_t>(p)] = p;
  for (const auto& force : m_system.forces()) join_force_elements(m_root, *force);
  join_elements(m_root, m_system.collision_geometry().triangles);
  const LinearBindings& linear = m_system.hard_bindings().linear();
  for (Index k = 0; k < linear.size(); ++k)
    for (Index parent : linear.parents(k)) join(m_root, linear.particle(k), parent);
  const SoftBindings& soft = m_system.soft_bindings();
  for (Index k = 0; k < soft.size(); ++k)
    join(m_root, soft.particle[static_cast<std::size_t>(k)], soft.target[static_cast<std::size_t>(k)]);
  const BindingSprings& springs = m_system.binding_springs();
  for (Index k = 0; k < springs.size(); ++k)
    if (!springs.removed(k) && springs.active(k)) join(m_root, springs.a(k), springs.b(k));
  // Per component root: the move that carries it, kFree while nothing binds it, kHeld once two things
  // that do not move alike do.
  constexpr Index kFree = -1, kHeld = -2;
  m_carrier.assign(static_cast<std::size_t>(n), kFree);
  auto meet = [&](Index p, Index carrier) {
    Index& c = m_carrier[static_cast<std::size_t>(find_root(m_root, p))];
    c = c == kFree || c == carrier ? carrier : kHeld;
  };
  const RigidBindings& rigid = m_system.hard_bindings().rigid();
  for (Index k = 0; k < rigid.size(); ++k) {
    const auto b = static_cast<std::size_t>(rigid.body(k));
    meet(rigid.particle(k), b < count && m_moved_by[b] >= 0 ? m_moved_by[b] : kHeld);
  }
  for (Index p = 0; p < n; ++p)
    if (particles.kind[p] == ParticleKind::kinematic || p >= m_particles_left) meet(p, kHeld);
  bool carried = false;
  for (Index p = 0; p < n; ++p) {
    if (particles.kind[p] == ParticleKind::removed) continue;
    const Index c = m_carrier[static_cast<std::size_t>(find_root(m_root, p))];
    if (c < 0) continue;
    const Mat3& R = m_move_rotation[static_cast<std::size_t>(c)];
    particles.x.col(p) = R * particles.x.col(p) + m_move_translation.col(c);
    particles.v.col(p) = R * particles.v.col(p);
    carried = true;
  }
  // The bound rows on the bodies' new frames (a set-up, if one is due, puts them there itself).
  if (carried && !m_system.needs_set_up()) m_system.clamp_bound_rows();
}

Index Coupling::bind(Index particle, btRigidBody* body, const Vec3& local) {
  const Index b = rigid_particle(body);
  return m_system.bind_rigid(particle, b, merged_offset(b, local));
}

Index Coupling::bind_here(Index particle, btRigidBody* body) {
  return m_system.bind_rigid_here(particle, rigid_particle(body));
}

Index Coupling::add_body_point(btRigidBody* body, const Vec3& local) {
  const Index b = rigid_particle(body);
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  const Vec3 r0 = merged_offset(b, local);
  const Vec3 r = bodies.q[b] * r0;
  const Vec3 v = bodies.v.col(b) + bodies.w.col(b).cross(r);
  const Index point = m_system.add_particle(bodies.x.col(b) + r, v, 0.0);
  m_system.bind_rigid(point, b, r0);
  return point;
}

Index Coupling::attach(Index point, btRigidBody* body, const Vec3& local, double stiffness, double damping_ratio) {
  const Index end = add_body_point(body, local);
  return m_system.add_binding_spring({point, end, stiffness, damping_ratio});
}

// ---- pinching (figure 10) -----------------------------------------------------------------------
//
// Two objects closing on a node from opposite sides ask for contradictory positions: pushed out of
// the nearer one it is pushed into the other, and once they are closer than twice the thickness no
// position meets both (the node jitters between them, or is squeezed out through one and the cloth
// slides out of the grip). Section 4 (figure 10): the node collides with neither; it gets two
// duplicates, soft-bound to it by binding springs (section 3: each has the node's effective mass and
// the node's elastic and external accelerations mapped to it, so it moves as the node would), each
// colliding with one of the objects only. Each object pushes its duplicate out of itself; the springs
// pull the node both ways and it settles between the two, held by the duplicates' friction on the
// objects, which the springs press them against.
//
// A free node with mass is pinched when two objects that would collide with it (contact response,
// filters, not a body it is tied to) are within twice the thickness of it with opposed outward
// normals (n_a . n_b < -1/2); of several such pairs, the one nearest in summed distance. It stays
// pinched while both are within four times the thickness of it and both duplicates within that of
// it (the hysteresis keeps a pinch from flickering), whatever the normals: two boxes pressed face to face leave the
// nodes at the rim of their faces beside both edges, normals alike, and such a node released was pushed out by the
// thickness at every step and pulled back in by the cloth inside the pinch (the whole cloth jittered
// at 2 m/s). Then its duplicates are removed (System::remove_particles: their indices stay
// reserved). Poses are Bullet's at the tick's start. Cost: one signed distance per node and object
// whose box, grown by the reach, holds the node.
// ---- sprinkled collision particles (section 2, figure 3) --------------------------------------

namespace {
// Per particle: 1 when a linear hard binding holds it (bindings as added, before any set-up).
std::vector<std::uint8_t> linearly_bound(const LinearBindings& linear, Index particles) {
  std::vector<std::uint8_t> bound(static_cast<std::size_t>(particles), 0);
  for (Index k = 0; k < linear.size(); ++k) bound[static_cast<std::size_t>(linear.particle(k))] = 1;
  return bound;
}
}  // namespace

Index Coupling::sprinkle(std::span<const Index> samples, const SprinkleSettings& settings) {
  const Index set = static_cast<Index>(m_sprinkles.size());
  if (!m_collisions) fail("sprinkle ", set, ": the coupling has collisions off, so there is nothing to collide with");
  if (!(std::isfinite(settings.reach) && settings.reach >= 0.0))
    fail("sprinkle ", set, ": reach ", settings.reach, " must be non-negative and finite");
  if (!(std::isfinite(settings.linger) && settings.linger >= 0.0))
    fail("sprinkle ", set, ": linger ", settings.linger, " must be non-negative and finite");
  if (samples.empty()) fail("sprinkle ", set, ": no samples");
  const HardBindings& hard = m_system.hard_bindings();
  const Index n = m_system.particles().size();
  const std::vector<std::uint8_t> embedded = linearly_bound(hard.linear(), n);
  for (const Index i : samples) {
    if (i < 0 || i >= n) fail("sprinkle ", set, ": sample ", i, " does not exist (there are ", n, " particles)");
    if (!embedded[static_cast<std::size_t>(i)])
      fail("sprinkle ", set, ": sample ", i, " is not hard-bound to a deformable (bind_linear, add_embedded_point)");
  }
  SprinkleSet s;
  s.samples.assign(samples.begin(), samples.end());
  s.particle.assign(samples.size(), -1);
  s.last_near.assign(samples.size(), -kInfinity);
  s.settings = settings;
  if (!settings.hosts_collide) {
    const LinearBindings& linear = hard.linear();
    std::vector<std::uint8_t> sample(static_cast<std::size_t>(n), 0);
    for (const Index i : samples) sample[static_cast<std::size_t>(i)] = 1;
    const CollisionGeometry& geometry = m_system.collision_geometry();
    for (Index k = 0; k < linear.size(); ++k)
      if (sample[static_cast<std::size_t>(linear.particle(k))])
        for (const Index parent : linear.parents(k))
          m_system.set_collision_filter(parent, geometry.group[static_cast<std::size_t>(parent)], 0);
  }
  if (!settings.adaptive)
    for (std::size_t k = 0; k < s.samples.size(); ++k) s.particle[k] = add_sprinkled(s.samples[k]);
  m_sprinkles.push_back(std::move(s));
  return set;
}

std::span<const Index> Coupling::sprinkled(Index set) const {
  if (set < 0 || set >= static_cast<Index>(m_sprinkles.size()))
    fail("sprinkle set ", set, " does not exist (there are ", m_sprinkles.size(), ")");
  return m_sprinkles[static_cast<std::size_t>(set)].particle;
}

Index Coupling::sprinkled_count(Index set) const {
  const std::span<const Index> particles = sprinkled(set);
  return static_cast<Index>(std::count_if(particles.begin(), particles.end(), [](Index p) { return p >= 0; }));
}

Index Coupling::add_sprinkled(Index sample) {
  const Particles& p = m_system.particles();
  const Index d = m_system.add_particle(p.x.col(sample), p.v.col(sample), 0.0);
  const CollisionGeometry& geometry = m_system.collision_geometry();
  m_system.set_collision_filter(d, geometry.group[static_cast<std::size_t>(sample)],
                                geometry.mask[static_cast<std::size_t>(sample)]);
  SoftBindingSettings binding;
  binding.particle = d;
  binding.target = sample;
  binding.coupling = SoftCoupling::synchronized;  // mass 0: the sample's effective mass (eq. 4)
  m_system.add_soft_binding(binding);
  return d;
}

// A sample is near when the surface of an object it may collide with (its filter against the object's)
// is within reach, plus how far the sample and the object's surface can move in the tick (the sample's
// speed, and the object's speed plus its spin times its bounding radius, times dt): its collision
// particle is then in place for the step that may meet the object. Samples that were removed or
// released by the application lose theirs in every set.
void Coupling::update_sprinkles(double dt) {
  if (m_sprinkles.empty()) return;
  const Particles& p = m_system.particles();
  const std::vector<std::uint8_t> embedded = linearly_bound(m_system.hard_bindings().linear(), p.size());
  const CollisionGeometry& geometry = m_system.collision_geometry();
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const double now = m_system.time();
  struct Near {
    int object;
    btVector3 lo, hi;
    double speed;  // bound on the surface's speed [m/s]
  };
  std::vector<Near> near;
  std::vector<Index> removed;
  std::vector<std::pair<std::size_t, std::size_t>> added;  // (set, sample)
  for (std::size_t set = 0; set < m_sprinkles.size(); ++set) {
    SprinkleSet& s = m_sprinkles[set];
    near.clear();
    if (s.settings.adaptive) {
      Eigen::AlignedBox3d box;
      double fastest = 0.0;
      for (const Index i : s.samples)
        if (p.kind[i] != ParticleKind::removed) {
          box.extend(Vec3(p.x.col(i)));
          fastest = std::max(fastest, Vec3(p.v.col(i)).norm());
        }
      for (int o = 0; o < objects.size() && !box.isEmpty(); ++o) {
        const btCollisionObject* object = objects[o];
        if (!object->hasContactResponse()) continue;
        double speed = 0.0;
        if (const btRigidBody* body = btRigidBody::upcast(object)) {
          btVector3 centre;
          btScalar radius;
          body->getCollisionShape()->getBoundingSphere(centre, radius);
          speed = double(body->getLinearVelocity().length() + body->getAngularVelocity().length() * radius);
        }
        btVector3 lo, hi;
        object->getCollisionShape()->getAabb(object->getWorldTransform(), lo, hi);
        const double pad = s.settings.reach + (fastest + speed) * dt;
        const Eigen::AlignedBox3d grown(to_eigen(lo) - Vec3::Constant(pad), to_eigen(hi) + Vec3::Constant(pad));
        if (grown.intersects(box)) near.push_back({o, lo, hi, speed});
      }
    }
    for (std::size_t k = 0; k < s.samples.size(); ++k) {
      const Index i = s.samples[k];
      Index& d = s.particle[k];
      if (d >= 0 && p.kind[d] == ParticleKind::removed) d = -1;  // the application removed it
      const bool alive = p.kind[i] != ParticleKind::removed && embedded[static_cast<std::size_t>(i)];
      if (!alive) {
        if (d >= 0) removed.push_back(d);
        d = -1;
        continue;
      }
      if (!s.settings.adaptive) continue;
      const Vec3 x = p.x.col(i);
      const double sample_speed = Vec3(p.v.col(i)).norm();
      bool close = false;
      for (const Near& candidate : near) {
        const btCollisionObject* object = objects[candidate.object];
        if (const btBroadphaseProxy* proxy = object->getBroadphaseHandle())
          if (!geometry.collides(i, static_cast<std::uint32_t>(proxy->m_collisionFilterGroup),
                                 static_cast<std::uint32_t>(proxy->m_collisionFilterMask)))
            continue;
        const double pad = s.settings.reach + (sample_speed + candidate.speed) * dt;
        if (((to_eigen(candidate.lo) - x).array() > pad).any() || ((x - to_eigen(candidate.hi)).array() > pad).any())
          continue;
        double phi;
        Vec3 normal;
        if (signed_distance(object->getCollisionShape(), object->getWorldTransform(), x, pad, phi, normal) &&
            phi < pad) {
          close = true;
          break;
        }
      }
      if (close) s.last_near[k] = now;
      if (close && d < 0) added.emplace_back(set, k);
      if (!close && d >= 0 && now - s.last_near[k] > s.settings.linger) {
        removed.push_back(d);
        d = -1;
      }
    }
  }
  if (!removed.empty()) m_system.remove_particles(removed);
  for (const auto& [set, k] : added) {
    SprinkleSet& s = m_sprinkles[set];
    s.particle[k] = add_sprinkled(s.samples[k]);
  }
}

void Coupling::update_pinches() {
  if (!m_collisions || (!m_pinching && m_pinches.empty())) return;
  PinchScratch& w = m_pinch_scratch;
  const double h = m_collisions->thickness();
  const double reach = 2.0 * h, keep_reach = 4.0 * h;
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const Particles& particles = m_system.particles();
  const CollisionGeometry& geometry = m_system.collision_geometry();
  const Index n = particles.size();
  // m_tied (the last tick's, sorted by particle): a node tied to a body passes through it already.
  const auto pinchable = [&](Index i) {
    const auto tied = std::lower_bound(m_tied.begin(), m_tied.end(), i,
                                       [](const std::pair<Index, Index>& t, Index p) { return t.first < p; });
    return i < n && particles.kind[i] == ParticleKind::free && particles.mass[i] > 0.0 &&
           (tied == m_tied.end() || tied->first != i);
  };
  const auto near_node = [&](Index i, const btCollisionObject* o, double within, double& phi, Vec3& normal) {
    return signed_distance(o->getCollisionShape(), o->getWorldTransform(), particles.x.col(i), within, phi, normal) &&
           phi < within;
  };
  // The objects that may pinch: with contact response, their boxes grown by the reach meeting the
  // free nodes' box.
  w.near.clear();
  if (m_pinching) {
    Eigen::AlignedBox3d nodes;
    for (Index i = 0; i < n; ++i)
      if (particles.kind[i] == ParticleKind::free) nodes.extend(Vec3(particles.x.col(i)));
    for (int o = 0; o < objects.size() && !nodes.isEmpty(); ++o) {
      if (!objects[o]->hasContactResponse() || !objects[o]->getCollisionShape()) continue;
      btVector3 lo, hi;
      objects[o]->getCollisionShape()->getAabb(objects[o]->getWorldTransform(), lo, hi);
      Eigen::AlignedBox3d box(to_eigen(lo), to_eigen(hi));
      box.min().array() -= keep_reach;
      box.max().array() += keep_reach;
      if (box.intersects(nodes)) w.near.push_back({o, box});
    }
  }
  if (w.near.size() < 2 && m_pinches.empty()) return;  // nothing to keep, nothing to find
  // Existing pinches: kept while the node is free, its duplicates are still soft-bound to it, both
  // objects are still in the world (found by address: a removed one may be gone) and both objects
  // and both duplicates are near it.
  w.kept.clear();
  w.removed.clear();
  w.pinched.assign(static_cast<std::size_t>(n), 0);
  if (!m_pinches.empty()) {
    w.present.assign(objects.size(), nullptr);
    for (int o = 0; o < objects.size(); ++o) w.present[static_cast<std::size_t>(o)] = objects[o];
    std::sort(w.present.begin(), w.present.end(), std::less<const btCollisionObject*>());
    const auto in_world = [&](const btCollisionObject* o) {
      return std::binary_search(w.present.begin(), w.present.end(), o, std::less<const btCollisionObject*>());
    };
    const SoftBindings& soft = m_system.soft_bindings();
    w.target_of.assign(static_cast<std::size_t>(n), -1);
    for (Index k = 0; k < soft.size(); ++k)
      w.target_of[static_cast<std::size_t>(soft.particle[static_cast<std::size_t>(k)])] =
          soft.target[static_cast<std::size_t>(k)];
    for (const Pinch& p : m_pinches) {
      double phi;
      Vec3 normal;
      const bool keep = m_pinching && pinchable(p.node) && in_world(p.object[0]) && in_world(p.object[1]) &&
                        w.target_of[static_cast<std::size_t>(p.duplicate[0])] == p.node &&
                        w.target_of[static_cast<std::size_t>(p.duplicate[1])] == p.node &&
                        near_node(p.node, p.object[0], keep_reach, phi, normal) &&
                        near_node(p.node, p.object[1], keep_reach, phi, normal) &&
                        (particles.x.col(p.duplicate[0]) - particles.x.col(p.node)).norm() < keep_reach &&
                        (particles.x.col(p.duplicate[1]) - particles.x.col(p.node)).norm() < keep_reach;
      if (keep) {
        w.kept.push_back(p);
        w.pinched[static_cast<std::size_t>(p.node)] = 1;
        continue;
      }
      for (const Index d : p.duplicate)
        if (d < n && particles.kind[d] != ParticleKind::removed) w.removed.push_back(d);
    }
  }
  // New pinches, in node order.
  w.added.clear();
  if (w.near.size() >= 2) {
    for (Index i = 0; i < n; ++i) {
      if (w.pinched[static_cast<std::size_t>(i)] || !pinchable(i)) continue;
      const Vec3 x = particles.x.col(i);
      w.hits.clear();
      for (const PinchScratch::Near& candidate : w.near) {
        if (!candidate.box.contains(x)) continue;
        const btCollisionObject* o = objects[candidate.object];
        const btBroadphaseProxy* proxy = o->getBroadphaseHandle();
        if (proxy && !geometry.collides(i, static_cast<std::uint32_t>(proxy->m_collisionFilterGroup),
                                        static_cast<std::uint32_t>(proxy->m_collisionFilterMask)))
          continue;
        PinchScratch::Hit hit{o, 0.0, Vec3::Zero()};
        if (near_node(i, o, reach, hit.phi, hit.normal)) w.hits.push_back(hit);
      }
      double best = kInfinity;
      Pinch pinch;
      for (std::size_t a = 0; a < w.hits.size(); ++a)
        for (std::size_t b = a + 1; b < w.hits.size(); ++b)
          if (w.hits[a].normal.dot(w.hits[b].normal) < -0.5 && w.hits[a].phi + w.hits[b].phi < best) {
            best = w.hits[a].phi + w.hits[b].phi;
            pinch.object[0] = w.hits[a].object;
            pinch.object[1] = w.hits[b].object;
          }
      if (best == kInfinity) continue;
      pinch.node = i;
      w.added.push_back(pinch);
    }
  }
  if (!w.removed.empty()) m_system.remove_particles(w.removed);
  for (Pinch& p : w.added) {
    const Index node = p.node;
    for (Index& d : p.duplicate) {
      d = m_system.add_particle(m_system.particles().x.col(node), m_system.particles().v.col(node),
                                m_system.particles().mass[node]);
      m_system.set_collision_filter(d, geometry.group[static_cast<std::size_t>(node)],
                                    geometry.mask[static_cast<std::size_t>(node)]);
      SoftBindingSettings binding;
      binding.particle = d;
      binding.target = node;
      binding.stiffness = m_pinch_stiffness;
      m_system.add_soft_binding(binding);
    }
    w.kept.push_back(p);
  }
  std::sort(w.kept.begin(), w.kept.end(), [](const Pinch& a, const Pinch& b) { return a.node < b.node; });
  std::swap(m_pinches, w.kept);
  // The collision filters: each duplicate meets its own object only, the node passes both.
  w.only.clear();
  w.passes.clear();
  for (const Pinch& p : m_pinches)
    for (int k = 0; k < 2; ++k) {
      w.only.emplace_back(p.duplicate[k], p.object[k]);
      w.passes.emplace_back(p.node, p.object[k]);
    }
  m_collisions->set_pinches(w.only, w.passes);
}

void Coupling::find_tied_particles() {
  const HardBindings& hard = m_system.hard_bindings();
  const BindingSprings& springs = m_system.binding_springs();
  m_tied.clear();
  if (springs.size() > 0) {
    m_point_body.assign(static_cast<std::size_t>(m_system.particles().size()), -1);
    for (Index k = 0; k < hard.rigid_count(); ++k)
      m_point_body[static_cast<std::size_t>(hard.rigid_particle(k))] = hard.rigid_body(k);
    for (Index s = 0; s < springs.size(); ++s) {
      if (springs.removed(s) || !springs.active(s)) continue;
      const Index a = springs.a(s), b = springs.b(s);
      const Index body_a = m_point_body[static_cast<std::size_t>(a)];
      const Index body_b = m_point_body[static_cast<std::size_t>(b)];
      if (body_b >= 0 && body_a < 0) m_tied.emplace_back(a, body_b);
      if (body_a >= 0 && body_b < 0) m_tied.emplace_back(b, body_a);
    }
    std::sort(m_tied.begin(), m_tied.end());
    m_tied.erase(std::unique(m_tied.begin(), m_tied.end()), m_tied.end());
  }
  m_collisions->set_tied(m_tied);
}

// Section 5, in order:
//   1. copy each Bullet body's state into its rigid-body particle, with the total force and torque
//      Bullet has gathered on it (gravity, the application's forces) and its joints' equality rows;
//   2-5. the Newmark step with the rigid-body particles as 6-DOF parents; collisions for deformables only;
//   6. copy momentum only back: each body ends with the step's velocity plus the changes Bullet makes
//      after it (contacts, joint corrections), and wakes up; Bullet's own force impulse is taken out of
//      what it is handed, since the step has integrated that force already;
//   7. Bullet then integrates and collides the rigid bodies itself (the rest of its internal tick).
// Step 6 is split around step 7 so that Bullet moves each body along the Newmark position update
// (x^{n+1} = x^n + dt v~^{n+1/2}, section 3.3 step 2) and ends the tick with the Newmark velocity
// v^{n+1}: handing v^{n+1} to Bullet's position update instead (x += dt v^{n+1}) is unstable for stiff
// binding springs between rigid bodies, whose v^{n+1} flips sign every step. Bullet's own velocity
// changes in step 7 (contacts, constraints) are kept on top.
StepStats Coupling::tick(double dt) {
  // The world and its bodies as they are now: an application may change them between ticks.
  if (m_use_world_gravity) m_system.set_gravity(to_eigen(m_world->getGravity()));
  follow_world();
  if (m_body_contacts) {
    // Bullet's contact manifolds at the bodies' present poses (Bullet finds them again after this
    // callback, at the same poses): the last tick's are a tick old, and miss the contacts begun since.
    bool coupled = false;
    for (std::size_t b = 0; b < m_bodies.size() && !coupled; ++b)
      coupled = m_bodies[b] && !m_system.rigid_bodies().kinematic[static_cast<Index>(b)];
    if (coupled) m_world->performDiscreteCollisionDetection();
    join_touching_bodies();
  }
  // A set-up the application ran itself (System::finalize) merged masses into the particles: their
  // frames, where Bullet's bodies still are, say where the merged frames sit.
  if (m_system.set_ups() != m_set_ups_seen) adopt_set_up();
  copy_state_in();
  follow_teleports();
  if (m_collisions) update_pinches();
  update_sprinkles(dt);
  if (m_system.needs_set_up()) set_up();
  copy_joints_in(dt);
  if (m_system.asleep()) wake_on_approach(dt);
  if (m_collisions) find_tied_particles();
  // A tick that throws leaves the state of its start: the deformables and rigid-body particles as
  // they were, no collision impulse handed over, and Bullet's gathered forces cleared (the exception
  // leaves stepSimulation before Bullet's own clearForces, and the next call would add gravity again).
  m_tick_start_x = m_system.particles().x;
  m_tick_start_v = m_system.particles().v;
  m_tick_start_bodies = m_system.rigid_bodies();
  if (m_collisions)
    m_collisions->set_motion(
        [this](Index b, const Vec3& x, const Quat& q) {
          // Bullet's frame on the merged body (as in hand_over_position_velocity): q q_rel^-1, x - R d.
          const Quat turn = q * m_merged_turn[static_cast<std::size_t>(b)].conjugate();
          const Vec3 centre = x - turn * Vec3(m_merged_offset.col(b));
          return btTransform(
              btQuaternion(btScalar(turn.x()), btScalar(turn.y()), btScalar(turn.z()), btScalar(turn.w())),
              to_bullet(centre));
        },
        m_system.time());
  try {
    m_last = m_system.advance(dt);  // substeps when the tick exceeds the elastic forces' stable step
  } catch (...) {
    m_system.particles().x = m_tick_start_x;
    m_system.particles().v = m_tick_start_v;
    m_system.rigid_bodies() = m_tick_start_bodies;
    if (m_collisions) m_collisions->discard_pending_impulses();
    m_world->clearForces();
    throw;
  }
  m_total += m_last;
  if (m_collisions) {
    if (m_last.asleep) m_collisions->forget_contacts();  // the end of the tick holds none of them
    m_collisions->apply_pending_impulses();
  }
  // Asleep, the step left the bodies where they were copied in, at rest: they are handed a zero motion
  // and end the tick at rest (plus whatever Bullet itself does to them).
  hand_over_position_velocity(dt);
  return m_last;
}

// A sleeping system runs no step 3, so nothing stops a body that moves into the deformables: a body
// that may reach them within this tick wakes the system first. Reach: the bodies' AABBs, grown by how
// far their surface can move over the tick (speed, plus gravity's gain, plus spin times the bounding
// radius, times dt), against the box of the sleeping particles grown by the collision thickness.
// Dynamic bodies count while Bullet keeps them active (a body Bullet has put to sleep stays still
// until something wakes it, and then it wakes the deformables in turn), kinematic ones while they
// have a velocity; static objects never, nor coupled bodies, whose motion the system's own wake test
// sees (System::advance). Collision filters are not consulted: a needless wake costs one frame's step.
void Coupling::wake_on_approach(double dt) {
  if (!m_collisions) return;  // the deformables meet no Bullet object
  Eigen::AlignedBox3d sleeping = m_system.sleeping_bounds();
  if (sleeping.isEmpty()) return;
  const Vec3 pad = Vec3::Constant(m_collisions->thickness());
  sleeping.min() -= pad;
  sleeping.max() += pad;
  const double g = to_eigen(m_world->getGravity()).norm();
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  for (int o = 0; o < objects.size(); ++o) {
    const btCollisionObject* object = objects[o];
    if (object->isStaticObject() || m_rigid_particles.count(object)) continue;
    const btRigidBody* body = btRigidBody::upcast(object);
    Vec3 v = Vec3::Zero(), w = Vec3::Zero();
    if (body) {
      v = to_eigen(body->getLinearVelocity());
      w = to_eigen(body->getAngularVelocity());
    }
    if (object->isKinematicObject() ? v.isZero(0.0) && w.isZero(0.0) : !object->isActive()) continue;
    const btCollisionShape* shape = object->getCollisionShape();
    btVector3 lo, hi, centre;
    btScalar radius;
    shape->getAabb(object->getWorldTransform(), lo, hi);
    shape->getBoundingSphere(centre, radius);
    const double falls = object->isKinematicObject() ? 0.0 : g * dt;
    const Vec3 reach = Vec3::Constant((v.norm() + falls + w.norm() * static_cast<double>(radius)) * dt);
    const Eigen::AlignedBox3d moving(Vec3(to_eigen(lo) - reach), Vec3(to_eigen(hi) + reach));
    if (moving.intersects(sleeping)) {
      m_system.wake();
      return;
    }
  }
}

void Coupling::copy_state_in() {
  RigidBodyParticles& bodies = m_system.rigid_bodies();
  const Index count = static_cast<Index>(m_bodies.size());
  if (m_v_in.cols() != count) {
    for (Vectors3* a : {&m_v_in, &m_w_in, &m_x_in, &m_v_next, &m_w_next, &m_v_position, &m_w_position})
      a->setZero(3, count);
    m_q_in.assign(static_cast<std::size_t>(count), Quat::Identity());
  }
  for (Index b = 0; b < count; ++b) {
    const btRigidBody* body = m_bodies[static_cast<std::size_t>(b)];
    if (!body) continue;  // sinew's own or released: the step alone moves it
    // A kinematic body jumps to its new pose when stepSimulation starts and reports the velocity that
    // covers that motion over the whole call. Its particle keeps its own pose and moves with that
    // velocity tick by tick, so the cloth on it sweeps smoothly and meets the new pose at the end of the
    // call, exactly where Bullet has the body. A static body stays where it is put, whatever velocity it
    // was left with when it was made static.
    const bool is_static = bodies.kinematic[b] && !body->isKinematicObject();
    const btTransform& frame = body->getCenterOfMassTransform();
    const Vec3 v = is_static ? Vec3::Zero() : to_eigen(body->getLinearVelocity());
    const Vec3 w = is_static ? Vec3::Zero() : to_eigen(body->getAngularVelocity());
    if (!bodies.kinematic[b] || is_static) {
      m_x_in.col(b) = to_eigen(frame.getOrigin());
      m_q_in[static_cast<std::size_t>(b)] = to_eigen(frame.getRotation());
    } else {
      m_x_in.col(b) = bodies.x.col(b);
      m_q_in[static_cast<std::size_t>(b)] = bodies.q[b];
    }
    m_v_in.col(b) = v;
    m_w_in.col(b) = w;
    // The merged body (x' = c + R d, q' = q q_rel, v' = v + w x R d) stands on Bullet's frame.
    const Vec3 e = m_q_in[static_cast<std::size_t>(b)] * Vec3(m_merged_offset.col(b));
    if (!bodies.kinematic[b] || is_static) {
      bodies.x.col(b) = m_x_in.col(b) + e;
      bodies.q[b] = m_q_in[static_cast<std::size_t>(b)] * m_merged_turn[static_cast<std::size_t>(b)];
    }
    bodies.v.col(b) = v + w.cross(e);
    bodies.w.col(b) = w;
    // Gravity and the application's forces, which Bullet gathered before this tick: the step carries
    // them, so the deformables feel the body accelerate as it will. Bullet applies them at its centre
    // of mass; gravity, Bullet's body's weight (merged mass times g), acts at the merged centre, the
    // rest at Bullet's, a lever -e from the merged centre.
    if (!bodies.kinematic[b]) {
      const Vec3 force = to_eigen(body->getTotalForce());
      const Vec3 weight = body->isActive()
                              ? Vec3(to_eigen(body->getGravity()) / static_cast<double>(body->getInvMass()))
                              : Vec3::Zero();
      bodies.force.col(b) = force;
      bodies.torque.col(b) = to_eigen(body->getTotalTorque()) - e.cross(force - weight);
    }
  }
}

void Coupling::hand_over_position_velocity(double dt) {
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  for (std::size_t b = 0; b < m_bodies.size(); ++b) {
    const auto i = static_cast<Index>(b);
    if (!m_bodies[b] || bodies.kinematic[i]) continue;
    btRigidBody* body = m_bodies[b];
    // Bullet's frame on the merged body as the step left it: q = q' q_rel^-1, c = x' - R d.
    const Quat q = bodies.q[i] * m_merged_turn[b].conjugate();
    const Vec3 e = q * Vec3(m_merged_offset.col(i));
    const Vec3 w = bodies.w.col(i);
    m_v_next.col(i) = Vec3(bodies.v.col(i)) - w.cross(e);
    m_w_next.col(i) = w;
    // The motion of the step's frame over dt, as a twist Bullet's integrator reproduces.
    m_v_position.col(i) = (Vec3(bodies.x.col(i)) - e - Vec3(m_x_in.col(i))) / dt;
    const Eigen::AngleAxisd turn(q * m_q_in[b].conjugate());
    m_w_position.col(i) = turn.angle() * turn.axis() / dt;
    // Collision impulses on the body are in the step's twist already (CollisionContext::apply_body_impulse).
    hand_over(body, m_v_position.col(i), m_w_position.col(i), dt);
    body->activate(true);
  }
  m_handed_over = true;
}

// A coupled body moves in the step as if free unless the step knows its joints, and Bullet's solver
// then pulls it back onto them after the deformables have moved: a stiff binding spring on such a body
// would meet its end displaced by about (joint reaction / m) dt^2. So the equality rows of every
// enabled joint that touches a coupled body are read from Bullet (the Jacobians its own solver gets
// from getInfo2, at the tick's start) and held by both solves of the step. Limit and motor rows,
// which Bullet bounds, and soft rows (cfm > 0) stay Bullet's alone; so does Baumgarte's position
// correction (the rows keep the joint's relative velocity at zero). Bodies outside the coupling
// count as moving with their velocities at the tick's start.
void Coupling::copy_joints_in(double dt) {
  m_joint_rows.clear();
  auto index_of = [&](const btRigidBody* body) -> Index {
    const auto found = m_rigid_particles.find(body);
    return found == m_rigid_particles.end() ? -1 : found->second;
  };
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  const btContactSolverInfo& solver = m_world->getSolverInfo();
  for (int c = 0; c < m_world->getNumConstraints(); ++c) {
    btTypedConstraint* joint = m_world->getConstraint(c);
    // A breakable joint's rows are bounded by its threshold: Bullet alone decides when it breaks.
    if (!joint->isEnabled() || joint->getBreakingImpulseThreshold() < SIMD_INFINITY) continue;
    const btRigidBody& body_a = joint->getRigidBodyA();
    const btRigidBody& body_b = joint->getRigidBodyB();
    const Index a = index_of(&body_a), b = index_of(&body_b);
    if ((a < 0 || bodies.kinematic[a]) && (b < 0 || bodies.kinematic[b])) continue;
    btTypedConstraint::btConstraintInfo1 info1;
    joint->getInfo1(&info1);
    const int rows = info1.m_numConstraintRows;
    if (rows <= 0) continue;
    const btTypedConstraint::btConstraintInfo2 info2 = joint_info2(*joint, rows, solver, dt, m_joint_buffer);
    const Vec6 twist_a =
        (Vec6() << to_eigen(body_a.getLinearVelocity()), to_eigen(body_a.getAngularVelocity())).finished();
    const Vec6 twist_b =
        (Vec6() << to_eigen(body_b.getLinearVelocity()), to_eigen(body_b.getAngularVelocity())).finished();
    for (int r = 0; r < rows; ++r) {
      if (!is_equality_row(info2, r, solver.m_globalCfm)) continue;
      JointRow row = joint_row(info2, r, a, b, twist_a, twist_b);
      // Bullet's rows act on the twist of its centre c; the step's twist is the merged centre's x':
      // J_v . v_c + J_w . w = J_v . v' + (J_w + (c - x') x J_v) . w.
      auto to_merged = [&](Index body, Vec6& j) {
        if (body < 0) return;
        const Vec3 lever = Vec3(m_x_in.col(body)) - Vec3(bodies.x.col(body));
        j.tail<3>() += lever.cross(Vec3(j.head<3>()));
      };
      to_merged(row.body_a, row.j_a);
      to_merged(row.body_b, row.j_b);
      if (row.j_a.isZero(0.0) && row.j_b.isZero(0.0)) continue;
      m_joint_rows.push_back(row);
    }
  }
  add_contact_rows(dt);
  m_system.set_joint_rows(m_joint_rows);
}

// A contact Bullet resolved after the step would move a coupled body off the step's update by
// (impulse / m) dt, where its binding springs and joints did not expect it (a net of 0.1 kg rods on
// stiff springs catching a 5 kg ball gained energy from it at every landing). The step holds them
// instead (JointRow::unilateral), so both sides of a contact must be in the step or prescribed: a
// dynamic body touching a coupled dynamic body joins the coupling, which a body with a locked rotation
// axis (rigid-body particles have none) cannot; Bullet alone resolves its contacts.
void Coupling::join_touching_bodies() {
  if (!m_body_contacts) return;
  btDispatcher* dispatcher = m_world->getDispatcher();
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  auto coupled_dynamic = [&](const btCollisionObject* o) {
    const auto found = m_rigid_particles.find(o);
    return found != m_rigid_particles.end() && !bodies.kinematic[found->second];
  };
  auto joinable = [&](const btCollisionObject* o) {
    const btRigidBody* body = btRigidBody::upcast(o);
    if (!body || m_rigid_particles.count(o) || body->isStaticOrKinematicObject() || !(body->getInvMass() > 0))
      return false;
    const btVector3 inverse = body->getInvInertiaDiagLocal();
    return inverse.x() > 0 && inverse.y() > 0 && inverse.z() > 0;
  };
  for (int m = 0; m < dispatcher->getNumManifolds(); ++m) {
    const btPersistentManifold* manifold = dispatcher->getManifoldByIndexInternal(m);
    if (manifold->getNumContacts() == 0) continue;
    const btCollisionObject* a = manifold->getBody0();
    const btCollisionObject* b = manifold->getBody1();
    if (!dispatcher->needsResponse(a, b)) continue;
    if (coupled_dynamic(a) && joinable(b)) {
      rigid_particle(const_cast<btRigidBody*>(btRigidBody::upcast(b)));
    } else if (coupled_dynamic(b) && joinable(a)) {
      rigid_particle(const_cast<btRigidBody*>(btRigidBody::upcast(a)));
    }
  }
}

// Each point of Bullet's contact manifolds on a coupled dynamic body, as a contact row: the manifold
// (found at the bodies' present poses, see tick) holds a point on each body and the normal from body 1
// to body 0; the gap is their separation along it. Levers are from the merged centres
// (the particles' x), which the rows' twists are. The other body, when it is not coupled (static,
// kinematic, or a body that could not join), moves with its velocity: its point's normal speed goes
// into the target. An overlap is pushed out as Bullet's solver would (its contact ERP over the tick,
// for overlaps shallower than the split-impulse threshold, which Bullet pushes out by position alone).
void Coupling::add_contact_rows(double dt) {
  if (!m_body_contacts) return;
  btDispatcher* dispatcher = m_world->getDispatcher();
  const btContactSolverInfo& solver = m_world->getSolverInfo();
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  auto index_of = [&](const btCollisionObject* o) -> Index {
    const auto found = m_rigid_particles.find(o);
    return found == m_rigid_particles.end() ? -1 : found->second;
  };
  for (int m = 0; m < dispatcher->getNumManifolds(); ++m) {
    const btPersistentManifold* manifold = dispatcher->getManifoldByIndexInternal(m);
    if (manifold->getNumContacts() == 0) continue;
    const btCollisionObject* o[2] = {manifold->getBody0(), manifold->getBody1()};
    Index index[2] = {index_of(o[0]), index_of(o[1])};
    const bool dynamic[2] = {index[0] >= 0 && !bodies.kinematic[index[0]],
                             index[1] >= 0 && !bodies.kinematic[index[1]]};
    if (!dynamic[0] && !dynamic[1]) continue;
    if (!dispatcher->needsResponse(o[0], o[1])) continue;
    const int a = dynamic[0] ? 0 : 1, b = 1 - a;  // row.body_a: a coupled dynamic body
    for (int k = 0; k < manifold->getNumContacts(); ++k) {
      const btManifoldPoint& point = manifold->getContactPoint(k);
      const Vec3 world[2] = {to_eigen(point.getPositionWorldOnA()), to_eigen(point.getPositionWorldOnB())};
      const Vec3 at_a = world[a], at_b = world[b];
      const Vec3 n = (a == 0 ? 1.0 : -1.0) * to_eigen(point.m_normalWorldOnB);  // from b towards a
      JointRow row;
      row.unilateral = true;
      row.body_a = index[a];
      row.j_a << n, (at_a - Vec3(bodies.x.col(index[a]))).cross(n);
      row.gap = n.dot(at_a - at_b);
      row.friction = static_cast<double>(point.m_combinedFriction);
      row.point = 0.5 * (at_a + at_b);
      if (index[b] >= 0) {
        row.body_b = index[b];
        row.j_b << -n, -(at_b - Vec3(bodies.x.col(index[b]))).cross(n);
      } else if (const btRigidBody* other = btRigidBody::upcast(o[b]); other && !other->isStaticObject()) {
        const btVector3 lever = to_bullet(at_b) - other->getCenterOfMassPosition();
        row.target = n.dot(to_eigen(other->getVelocityInLocalPoint(lever)));
      }
      const bool split =
          solver.m_splitImpulse && row.gap < static_cast<double>(solver.m_splitImpulsePenetrationThreshold);
      if (row.gap < 0.0 && !split) row.target += -row.gap * static_cast<double>(solver.m_erp) / dt;
      m_joint_rows.push_back(row);
    }
  }
}

// Bullet's solver adds the body's external impulse (total force and torque, which the Newmark step
// has already integrated) and, with the gyroscopic flags, its own gyroscopic change of w (the step's
// rotation already has one) before it solves the joints and moves the body. Those are subtracted here,
// so that a body no joint or contact touches moves exactly along the step's position update; a stiff
// binding spring on it then meets its end where the step left it. The gyroscopic change depends on
// the w handed over, hence the fixed-point iteration (it contracts by about dt |w| per pass). Bullet's
// linear and angular damping (0 unless the application sets it) still act on what is handed over,
// before the solver: such a body ends d dt^2 |v| or so away from the step's update.
void Coupling::hand_over(btRigidBody* body, const Vec3& v, const Vec3& w, double dt) {
  const btScalar h = btScalar(dt);
  const btVector3 dv = body->getTotalForce() * (body->getInvMass() * h);
  const btVector3 dw_torque = body->getInvInertiaTensorWorld() * body->getTotalTorque() * h;
  body->setLinearVelocity(to_bullet(v) - dv);
  const int flags = body->getFlags();
  const int gyroscopic = BT_ENABLE_GYROSCOPIC_FORCE_EXPLICIT | BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_WORLD |
                         BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY;
  btVector3 handed = to_bullet(w) - dw_torque;
  body->setAngularVelocity(handed);
  if (!(flags & gyroscopic)) return;
  const btScalar max_gyroscopic = m_world->getSolverInfo().m_maxGyroscopicForce;
  for (int pass = 0; pass < 4; ++pass) {
    btVector3 dw_gyro(0, 0, 0);
    if (flags & BT_ENABLE_GYROSCOPIC_FORCE_EXPLICIT)
      dw_gyro -= body->getInvInertiaTensorWorld() * body->computeGyroscopicForceExplicit(max_gyroscopic) * h;
    if (flags & BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_WORLD) dw_gyro += body->computeGyroscopicImpulseImplicit_World(h);
    if (flags & BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY) dw_gyro += body->computeGyroscopicImpulseImplicit_Body(h);
    handed = to_bullet(w) - dw_torque - dw_gyro;
    body->setAngularVelocity(handed);
  }
}

// Bullet's solver stops each contact's approach at the velocity the body moves with over the tick, the
// step's v^{n+1/2} plus Bullet's changes; the body then ends the tick with v^{n+1}, which adds the
// step's second half: for a body resting on the ground, half a tick of gravity. It read g dt / 2 of
// sinking while its height held to 1e-12 m, and carried it into the next tick. So the contacts Bullet
// resolved in this tick (every point that pushed, in the islands of coupled dynamic bodies) hold the
// end-of-tick velocities too, as sinew's step-4 constraints hold particles on static surfaces: a few
// Gauss-Seidel passes over those points, in the dispatcher's order, remove any approach beyond what
// Bullet itself allows (a point still apart by d may close at d / dt) by an equal and opposite impulse
// on the two bodies, and tangential slip up to the point's friction times that impulse. A contact that
// separates at the end of the tick is left alone.
//
// Particles against dynamic bodies are held in the same passes. A particle on a static surface is held
// by step 4 (a velocity constraint); against a dynamic body step 4 has none, and whatever pulls the
// particle into the body (a binding spring whose end is on the body's surface) gives it an end-of-step
// velocity into the body that only the next step's projection took away: the node tied to the top of
// the hello sphere by a 1e4 N/m spring read 13 m/s while it moved at 0.15 m/s, and the spring's force,
// -k dx - c dv, read 2 N where k dx is 100 N. Each is held as step 3 holds it (its approach removed with
// step 3's friction), against the body's final velocity, the body taking the opposite impulse.
//
// A coupled body takes its impulses as the merged body it is (mass, inertia and centre of its particle),
// so that momentum is kept exactly; other bodies as Bullet has them.
Coupling::BodyView Coupling::body_view(btRigidBody* body, bool at_tick_start) const {
  BodyView view;
  view.body = body;
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  const auto found = m_rigid_particles.find(body);
  view.particle = found == m_rigid_particles.end() || bodies.kinematic[found->second] ? -1 : found->second;
  const btTransform& frame = body->getCenterOfMassTransform();
  if (view.particle < 0) {
    view.centre = to_eigen(frame.getOrigin());
    view.inverse_mass = static_cast<double>(body->getInvMass());
    // Bullet's per-axis locks (setLinearFactor, setAngularFactor) scale what an impulse changes, as
    // its applyImpulse does: a body locked to one axis is pushed along that axis only.
    view.linear_factor = to_eigen(body->getLinearFactor());
    const Vec3 angular_factor = to_eigen(body->getAngularFactor());
    const btMatrix3x3& i = body->getInvInertiaTensorWorld();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) view.inverse_inertia(r, c) = angular_factor[r] * static_cast<double>(i[r][c]);
  } else {
    const Index b = view.particle;
    view.offset = to_eigen(frame.getRotation()) * Vec3(m_merged_offset.col(b));
    // The contact points Bullet found are where its collision detection saw the bodies, at the tick's
    // start: levers from the centre there, as Bullet's solver took them (from the centre the body has
    // now, a sphere rolling at 0.3 m/s read a sinking of w dt |v| ~ 3e-4 m/s).
    view.centre = at_tick_start
                      ? Vec3(Vec3(m_x_in.col(b)) + m_q_in[static_cast<std::size_t>(b)] * Vec3(m_merged_offset.col(b)))
                      : Vec3(to_eigen(frame.getOrigin()) + view.offset);
    view.inverse_mass = 1.0 / bodies.mass[b];
    view.inverse_inertia = bodies.world_inverse_inertia(b);
  }
  return view;
}

Vec3 Coupling::BodyView::velocity(const Vec3& lever) const {
  const Vec3 w = to_eigen(body->getAngularVelocity());
  return to_eigen(body->getLinearVelocity()) + w.cross(offset + lever);
}

double Coupling::BodyView::inverse_mass_along(const Vec3& lever, const Vec3& u) const {
  const Vec3 t = lever.cross(u);
  // u is a unit vector: u . u = 1 for a body with no locked axis.
  const double free = linear_factor == Vec3::Ones() ? 1.0 : u.dot(linear_factor.cwiseProduct(u));
  return inverse_mass * free + t.dot(inverse_inertia * t);
}

void Coupling::BodyView::push(const Vec3& lever, const Vec3& j) const {
  const Vec3 w = to_eigen(body->getAngularVelocity()) + inverse_inertia * lever.cross(j);
  // The centre's velocity changes by j / m; Bullet's centre, offset from it, moves with it and w.
  const Vec3 v_centre = velocity(Vec3::Zero()) + inverse_mass * linear_factor.cwiseProduct(j);
  body->setLinearVelocity(to_bullet(v_centre - w.cross(offset)));
  body->setAngularVelocity(to_bullet(w));
}

void Coupling::hold_contacts_at_tick_end(double dt) {
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  m_islands.clear();
  for (std::size_t b = 0; b < m_bodies.size(); ++b)
    if (m_bodies[b] && !bodies.kinematic[static_cast<Index>(b)]) m_islands.push_back(m_bodies[b]->getIslandTag());
  auto in_coupled_island = [&](const btCollisionObject* o) {
    return o->getIslandTag() >= 0 &&
           std::find(m_islands.begin(), m_islands.end(), o->getIslandTag()) != m_islands.end();
  };
  m_end_contacts.clear();
  btDispatcher* dispatcher = m_world->getDispatcher();
  for (int m = 0; m < dispatcher->getNumManifolds(); ++m) {
    btPersistentManifold* manifold = dispatcher->getManifoldByIndexInternal(m);
    auto* a = const_cast<btRigidBody*>(btRigidBody::upcast(manifold->getBody0()));
    auto* b = const_cast<btRigidBody*>(btRigidBody::upcast(manifold->getBody1()));
    if (!a || !b || !(in_coupled_island(a) || in_coupled_island(b))) continue;
    for (int k = 0; k < manifold->getNumContacts(); ++k) {
      btManifoldPoint& point = manifold->getContactPoint(k);
      // With body_contacts the step held them and Bullet applied (about) nothing: every point counts
      // (a point still apart may close, so holding it costs nothing).
      if (m_body_contacts || point.getAppliedImpulse() > btScalar(0))
        m_end_contacts.push_back({&point, a, b, 0.0, Vec3::Zero()});
    }
  }
  const int passes = m_end_contacts.empty() ? 1 : 8;
  for (int pass = 0; pass < passes; ++pass) {
    for (EndContact& c : m_end_contacts) {
      const btManifoldPoint& point = *c.point;
      const BodyView a = body_view(c.a, true), b = body_view(c.b, true);
      const Vec3 n = to_eigen(point.m_normalWorldOnB);  // from b towards a
      const Vec3 ra = to_eigen(point.getPositionWorldOnA()) - a.centre;
      const Vec3 rb = to_eigen(point.getPositionWorldOnB()) - b.centre;
      auto inverse_mass = [&](const Vec3& u) { return a.inverse_mass_along(ra, u) + b.inverse_mass_along(rb, u); };
      auto relative_velocity = [&] { return Vec3(a.velocity(ra) - b.velocity(rb)); };
      auto push = [&](const Vec3& j) {
        a.push(ra, j);
        b.push(rb, -j);
      };
      // Normal: the accumulated impulse stays a push (>= 0).
      const double allowed = -std::max(0.0, static_cast<double>(point.getDistance())) / dt;
      const double k_n = inverse_mass(n);
      if (!(k_n > 0.0)) continue;
      const double vn = n.dot(relative_velocity());
      const double jn = std::max(c.normal - (vn - allowed) / k_n, 0.0) - c.normal;
      c.normal += jn;
      if (jn != 0.0) push(jn * n);
      // Friction: the accumulated tangential impulse within the friction disc of the normal one.
      Vec3 v_t = relative_velocity();
      v_t -= n.dot(v_t) * n;
      const double slip = v_t.norm();
      if (!(slip > 0.0)) continue;
      const double k_t = inverse_mass(v_t / slip);
      Vec3 friction = c.friction - v_t / k_t;
      const double limit = static_cast<double>(point.m_combinedFriction) * c.normal;
      if (friction.norm() > limit) friction *= limit / friction.norm();
      const Vec3 jt = friction - c.friction;
      c.friction = friction;
      push(jt);
    }
    if (!m_collisions) continue;
    Particles& particles = m_system.particles();
    for (const BulletCollisions::DynamicContact& contact : m_collisions->dynamic_contacts()) {
      const Index i = contact.particle;
      if (!is_dynamic(particles.kind[i])) continue;
      const BodyView body = body_view(contact.body, false);
      const Vec3 lever = Vec3(particles.x.col(i)) - body.centre;
      const Vec3 v_old = particles.v.col(i);
      const double mass = particles.mass[i];
      Vec3 v_new;
      if (mass > 0.0 && body.particle < 0) {
        // As step 3 takes it: a body Bullet alone moves as a body of its own mass (inelastic_impulse).
        const Mat3 K = Mat3::Identity() / mass +
                       body_point_inverse_mass(body.inverse_mass, body.linear_factor, body.inverse_inertia, lever);
        v_new =
            v_old + inelastic_impulse(v_old - body.velocity(lever), contact.normal, m_collisions->friction(), K) / mass;
      } else {
        v_new = stop_approach(v_old, body.velocity(lever), contact.normal, m_collisions->friction());
      }
      if (v_new == v_old) continue;
      particles.v.col(i) = v_new;
      body.push(lever, -particles.mass[i] * (v_new - v_old));
    }
  }
}

void Coupling::take_back_momentum() {
  if (!m_handed_over) return;
  m_handed_over = false;
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  for (std::size_t b = 0; b < m_bodies.size(); ++b) {
    const auto i = static_cast<Index>(b);
    if (!m_bodies[b] || bodies.kinematic[i]) continue;
    btRigidBody* body = m_bodies[b];
    // v^{n+1} from the Newmark step plus whatever Bullet changed in its own part of the tick.
    const Vec3 bullet_dv = to_eigen(body->getLinearVelocity()) - m_v_position.col(i);
    const Vec3 bullet_dw = to_eigen(body->getAngularVelocity()) - m_w_position.col(i);
    body->setLinearVelocity(to_bullet(m_v_next.col(i) + bullet_dv));
    body->setAngularVelocity(to_bullet(m_w_next.col(i) + bullet_dw));
  }
}

}  // namespace sinew::bullet
