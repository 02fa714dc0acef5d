#include "sinew/bullet/coupling.hpp"

#include "sinew/bullet/collisions.hpp"
#include "sinew/bullet/convert.hpp"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
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

}  // namespace

Coupling::Coupling(btDynamicsWorld* world, const CouplingSettings& settings) : m_world(world) {
  if (!world) fail("bullet coupling: world is null");
  SystemSettings system = settings.system;
  system.absorb_bound_mass_into_rigid_bodies = false;
  if (settings.use_world_gravity) system.gravity = to_eigen(world->getGravity());
  m_use_world_gravity = settings.use_world_gravity;
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
        world, CollisionSettings{settings.thickness, settings.friction}, &m_rigid_particles);
    m_collisions = collisions.get();
    m_system.add_collision_source(std::move(collisions));
  }
  m_app_pre_tick = TickCallbackAccess::pre_tick(*world);
  m_app_post_tick = TickCallbackAccess::post_tick(*world);
  world->setInternalTickCallback(&Coupling::pre_tick, world->getWorldUserInfo(), true);
  world->setInternalTickCallback(&Coupling::post_tick, world->getWorldUserInfo(), false);
}

Coupling::~Coupling() {
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
  m_bodies.push_back(body);
  m_seen_inverse_mass.push_back(body->getInvMass());
  m_seen_inverse_inertia.push_back(body->getInvInertiaDiagLocal());
  m_rigid_particles.emplace(body, b);
  return b;
}

void Coupling::add_own_body_slots() {
  const auto count = static_cast<std::size_t>(m_system.rigid_bodies().size());
  if (m_bodies.size() >= count) return;
  m_bodies.resize(count, nullptr);
  m_seen_inverse_mass.resize(count, btScalar(0));
  m_seen_inverse_inertia.resize(count, btVector3(0, 0, 0));
}

void Coupling::remove(btRigidBody* body) {
  const auto found = body ? m_rigid_particles.find(body) : m_rigid_particles.end();
  if (found == m_rigid_particles.end())
    fail("Coupling::remove: rigid body ", static_cast<const void*>(body), " is not coupled");
  release(found->second);
}

void Coupling::release(Index b) {
  // Points with a mass of their own go free with it; massless ones (body points, and points embedded
  // among them that set-up has not yet resolved onto the body) have nothing left to follow.
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
  for (bool grew = true; grew;) {
    grew = false;
    for (Index k = 0; k < linear.size(); ++k) {
      const Index p = linear.particle(k);
      if (is_removed[static_cast<std::size_t>(p)] || mass[p] > 0.0) continue;
      for (Index parent : linear.parents(k))
        if (is_removed[static_cast<std::size_t>(parent)]) {
          removed.push_back(p);
          is_removed[static_cast<std::size_t>(p)] = 1;
          grew = true;
          break;
        }
    }
  }
  // The particle stays (indices keep their meaning) as a kinematic body at rest that nothing uses.
  m_system.set_rigid_body_mass(b, true);
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
  const bool changed =
      body->getInvMass() != m_seen_inverse_mass[i] || body->getInvInertiaDiagLocal() != m_seen_inverse_inertia[i];
  if (prescribed == static_cast<bool>(bodies.kinematic[b]) && !changed) return;
  m_seen_inverse_mass[i] = body->getInvMass();
  m_seen_inverse_inertia[i] = body->getInvInertiaDiagLocal();
  if (prescribed) {
    if (bodies.kinematic[b]) return;
    m_system.set_rigid_body_mass(b, true);
    // From here it moves as Bullet moves it (copy_state_in): from its pose now.
    const btTransform& frame = body->getCenterOfMassTransform();
    bodies.x.col(b) = to_eigen(frame.getOrigin());
    bodies.q[b] = to_eigen(frame.getRotation());
    return;
  }
  const btVector3 inverse = body->getInvInertiaDiagLocal();
  Vec3 inertia;
  for (int d = 0; d < 3; ++d) {
    if (!(inverse[d] > btScalar(0)))
      fail("bullet coupling: rigid body ", b, " has a locked rotation axis (inverse inertia ", d,
           " is 0), which rigid-body particles do not support yet");
    inertia[d] = 1.0 / static_cast<double>(inverse[d]);
  }
  m_system.set_rigid_body_mass(b, false, 1.0 / static_cast<double>(body->getInvMass()), inertia);
}

Index Coupling::bind(Index particle, btRigidBody* body, const Vec3& local) {
  return m_system.bind_rigid(particle, rigid_particle(body), local);
}

Index Coupling::bind_here(Index particle, btRigidBody* body) {
  return m_system.bind_rigid_here(particle, rigid_particle(body));
}

Index Coupling::add_body_point(btRigidBody* body, const Vec3& local) {
  const Index b = rigid_particle(body);
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  const Vec3 r = bodies.q[b] * local;
  const Vec3 v = bodies.v.col(b) + bodies.w.col(b).cross(r);
  const Index point = m_system.add_particle(bodies.x.col(b) + r, v, 0.0);
  m_system.bind_rigid(point, b, local);
  return point;
}

Index Coupling::attach(Index point, btRigidBody* body, const Vec3& local, double stiffness, double damping_ratio) {
  const Index end = add_body_point(body, local);
  return m_system.add_binding_spring({point, end, stiffness, damping_ratio});
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
  copy_state_in();
  copy_joints_in(dt);
  // A tick that throws leaves the state of its start: the deformables and rigid-body particles as
  // they were, no collision impulse handed over, and Bullet's gathered forces cleared (the exception
  // leaves stepSimulation before Bullet's own clearForces, and the next call would add gravity again).
  m_tick_start_x = m_system.particles().x;
  m_tick_start_v = m_system.particles().v;
  m_tick_start_bodies = m_system.rigid_bodies();
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
  if (m_collisions) m_collisions->apply_pending_impulses();
  hand_over_position_velocity(dt);
  return m_last;
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
    if (!bodies.kinematic[b] || is_static) {
      const btTransform& frame = body->getCenterOfMassTransform();
      bodies.x.col(b) = to_eigen(frame.getOrigin());
      bodies.q[b] = to_eigen(frame.getRotation());
    }
    bodies.v.col(b) = is_static ? Vec3::Zero() : to_eigen(body->getLinearVelocity());
    bodies.w.col(b) = is_static ? Vec3::Zero() : to_eigen(body->getAngularVelocity());
    // Gravity and the application's forces, which Bullet gathered before this tick: the step carries
    // them, so the deformables feel the body accelerate as it will.
    if (!bodies.kinematic[b]) {
      bodies.force.col(b) = to_eigen(body->getTotalForce());
      bodies.torque.col(b) = to_eigen(body->getTotalTorque());
    }
    m_x_in.col(b) = bodies.x.col(b);
    m_q_in[b] = bodies.q[b];
    m_v_in.col(b) = bodies.v.col(b);
    m_w_in.col(b) = bodies.w.col(b);
  }
}

void Coupling::hand_over_position_velocity(double dt) {
  const RigidBodyParticles& bodies = m_system.rigid_bodies();
  for (std::size_t b = 0; b < m_bodies.size(); ++b) {
    const auto i = static_cast<Index>(b);
    if (!m_bodies[b] || bodies.kinematic[i]) continue;
    btRigidBody* body = m_bodies[b];
    m_v_next.col(i) = bodies.v.col(i);
    m_w_next.col(i) = bodies.w.col(i);
    // The motion of the step's frame over dt, as a twist Bullet's integrator reproduces.
    m_v_position.col(i) = (bodies.x.col(i) - m_x_in.col(i)) / dt;
    const Eigen::AngleAxisd turn(bodies.q[i] * m_q_in[b].conjugate());
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
      const JointRow row = joint_row(info2, r, a, b, twist_a, twist_b);
      if (row.j_a.isZero(0.0) && row.j_b.isZero(0.0)) continue;
      m_joint_rows.push_back(row);
    }
  }
  m_system.set_joint_rows(m_joint_rows);
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
// on the two bodies (Bullet's masses, applyImpulse), and tangential slip up to the point's friction
// times that impulse. A contact that separates at the end of the tick is left alone. The particles
// the step found against dynamic bodies are held the same way (BulletCollisions::hold_dynamic_contacts),
// in the same passes.
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
      if (point.getAppliedImpulse() > btScalar(0)) m_end_contacts.push_back({&point, a, b, 0.0, Vec3::Zero()});
    }
  }
  // The contact points are where the tick's collision detection found them, with the centres of mass
  // there: a coupled body's lever is taken from its centre at the tick's start, as Bullet's solver
  // took it (from the centre the body has now, a sphere rolling at 0.3 m/s would read a sinking of
  // w dt |v| ~ 3e-4 m/s); other bodies use the centre they have now.
  auto centre_seen = [&](const btRigidBody* body) {
    const auto found = m_rigid_particles.find(body);
    if (found == m_rigid_particles.end() || bodies.kinematic[found->second]) return body->getCenterOfMassPosition();
    return to_bullet(m_x_in.col(found->second));
  };
  // The particles' contacts with dynamic bodies alternate with the bodies' own (each moves the other:
  // a node on a sphere that the ground stops follows it down no further).
  constexpr int kPasses = 8;
  const int passes = m_end_contacts.empty() ? 1 : kPasses;
  for (int pass = 0; pass < passes; ++pass) {
    for (EndContact& c : m_end_contacts) {
      const btManifoldPoint& point = *c.point;
      const Vec3 n = to_eigen(point.m_normalWorldOnB);  // from b towards a
      const btVector3 ra = point.getPositionWorldOnA() - centre_seen(c.a);
      const btVector3 rb = point.getPositionWorldOnB() - centre_seen(c.b);
      // Inverse effective mass of the two bodies at the point along a unit direction d.
      auto inverse_mass = [&](const Vec3& d) {
        const btVector3 u = to_bullet(d);
        const btVector3 ta = ra.cross(u), tb = rb.cross(u);
        return static_cast<double>(c.a->getInvMass() + c.b->getInvMass() +
                                   ta.dot(c.a->getInvInertiaTensorWorld() * ta) +
                                   tb.dot(c.b->getInvInertiaTensorWorld() * tb));
      };
      auto relative_velocity = [&] {
        return to_eigen(c.a->getVelocityInLocalPoint(ra) - c.b->getVelocityInLocalPoint(rb));
      };
      auto push = [&](const Vec3& j) {
        c.a->applyImpulse(to_bullet(j), ra);
        c.b->applyImpulse(to_bullet(-j), rb);
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
    if (m_collisions) m_collisions->hold_dynamic_contacts(m_system.particles());
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
