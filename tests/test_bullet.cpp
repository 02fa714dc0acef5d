// The Bullet plugin's exchange (Sifakis et al. 2007, section 5): copy state in, momentum out.
#include "cloth.hpp"
#include "sinew/bullet/coupling.hpp"

#include <btBulletDynamicsCommon.h>
#include <gtest/gtest.h>

#include <memory>

namespace sinew {
namespace {

// A plain Bullet world, as an application would set it up.
struct BulletWorld {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher{&configuration};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &configuration};
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btDefaultMotionState>> states;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  explicit BulletWorld(const btVector3& gravity) { world.setGravity(gravity); }
  ~BulletWorld() {
    for (auto& b : bodies) world.removeRigidBody(b.get());
  }
  btRigidBody* add_box(const btVector3& half, double mass, const btTransform& at) {
    shapes.push_back(std::make_unique<btBoxShape>(half));
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shapes.back()->calculateLocalInertia(btScalar(mass), inertia);
    states.push_back(std::make_unique<btDefaultMotionState>(at));
    bodies.push_back(std::make_unique<btRigidBody>(
        btRigidBody::btRigidBodyConstructionInfo(btScalar(mass), states.back().get(), shapes.back().get(), inertia)));
    bodies.back()->setActivationState(DISABLE_DEACTIVATION);
    world.addRigidBody(bodies.back().get());
    return bodies.back().get();
  }
};

scenes::ClothGridSettings small_cloth(const Vec3& origin) {
  scenes::ClothGridSettings c;
  c.nx = c.ny = 6;
  c.width = c.height = 0.5;
  c.mass = 0.2;
  c.origin = origin;
  c.stretch_stiffness = 50.0;
  c.stretch_damping = 0.05;
  return c;
}

int g_app_ticks = 0;
void app_pre_tick(btDynamicsWorld* world, btScalar) {
  if (world->getWorldUserInfo() == &g_app_ticks) ++g_app_ticks;
}

TEST(BulletCoupling, RunsEveryInternalTickAndChainsTheApplicationsCallback) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bw.world.setInternalTickCallback(app_pre_tick, &g_app_ticks, true);
  g_app_ticks = 0;
  {
    bullet::Coupling coupling(&bw.world);
    scenes::add_cloth_grid(coupling.system(), small_cloth(Vec3(0, 1, 0)));
    const Vec3 start = coupling.system().particles().x.col(0);
    bw.world.stepSimulation(btScalar(1.0 / 60), 10, btScalar(1.0 / 240));  // four internal ticks
    EXPECT_EQ(g_app_ticks, 4);
    EXPECT_EQ(bw.world.getWorldUserInfo(), &g_app_ticks);
    EXPECT_NEAR(coupling.last_stats().dt, 1.0 / 240, 1e-15);
    // Free fall of the whole cloth for 1/60 s at the world's gravity, through four coupled ticks.
    EXPECT_NEAR(coupling.system().particles().x(1, 0) - start.y(), -0.5 * 9.81 / 3600.0, 1e-12);
  }
  bw.world.stepSimulation(btScalar(1.0 / 60), 10, btScalar(1.0 / 240));  // detached: only the app runs
  EXPECT_EQ(g_app_ticks, 8);
}

// No gravity, no ground: a spinning Bullet box carrying a cloth (partly hard-bound, partly tied by
// binding springs). Momentum leaves the deformables only as the impulse handed to Bullet, so the
// total (Bullet body plus cloth) is conserved through the copy-in / copy-out exchange.
TEST(BulletCoupling, IsolatedCoupledSystemConservesLinearMomentumThroughTheExchange) {
  BulletWorld bw(btVector3(0, 0, 0));
  btTransform at;
  at.setIdentity();
  at.setOrigin(btVector3(0, 0.5, 0));
  btRigidBody* box = bw.add_box(btVector3(0.3, 0.05, 0.2), 1.0, at);
  box->setLinearVelocity(btVector3(0.2, 0.1, 0));
  box->setAngularVelocity(btVector3(0, 2.0, 0.5));
  bullet::Coupling coupling(&bw.world);
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.45, 0)));
  for (int i = 0; i < 3; ++i) coupling.bind_here(cloth.node(i, 0), box);
  for (int i = 3; i < 6; ++i) {
    const Index point = s.add_particle(s.particles().x.col(cloth.node(i, 0)), Vec3::Zero(), 0.0);
    coupling.bind_here(point, box);
    s.add_binding_spring({cloth.node(i, 0), point, 1e4, 1.0});
  }
  s.step_settings().cg_tolerance = 1e-13;
  auto total_momentum = [&] {
    // The cloth's momentum (the system's, less its copy of the box) plus Bullet's box.
    const Vec3 cloth_p = s.linear_momentum() - s.rigid_bodies().mass[0] * Vec3(s.rigid_bodies().v.col(0));
    const btVector3 v = box->getLinearVelocity();
    return Vec3(cloth_p + (1.0 / box->getInvMass()) * Vec3(v.x(), v.y(), v.z()));
  };
  bw.world.stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const Vec3 p0 = total_momentum();
  double worst = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    bw.world.stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    worst = std::max(worst, (total_momentum() - p0).norm());
  }
  EXPECT_LT(worst, 1e-10);
  EXPECT_GT((box->getLinearVelocity() - btVector3(0.2, 0.1, 0)).length(), 1e-3);  // the cloth did push it
  EXPECT_LT(s.max_hard_binding_drift(), 1e-12);
}

// Gravity stays Bullet's for rigid bodies and sinew's for deformables: a box and the cloth hanging
// from it by binding springs, falling freely, gain exactly (M + m) g t of momentum, not (2M + m) g t.
TEST(BulletCoupling, GravityIsNotAppliedTwice) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at;
  at.setIdentity();
  at.setOrigin(btVector3(0, 1.0, 0));
  btRigidBody* box = bw.add_box(btVector3(0.3, 0.05, 0.05), 2.0, at);
  bullet::Coupling coupling(&bw.world);
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.95, 0)));
  for (int i = 0; i < 6; ++i) {
    const Index point = s.add_particle(s.particles().x.col(cloth.node(i, 0)), Vec3::Zero(), 0.0);
    coupling.bind_here(point, box);
    s.add_binding_spring({cloth.node(i, 0), point, 1e4, 1.0});
  }
  s.step_settings().cg_tolerance = 1e-13;
  const int ticks = 120;
  for (int i = 0; i < ticks; ++i) bw.world.stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const double t = ticks / 240.0;
  const double cloth_mass = 0.2, box_mass = 2.0;
  const Vec3 cloth_p = s.linear_momentum() - box_mass * Vec3(s.rigid_bodies().v.col(0));
  const double total = cloth_p.y() + box_mass * box->getLinearVelocity().y();
  EXPECT_NEAR(total, -(box_mass + cloth_mass) * 9.81 * t, 1e-9);
}

// A static body and a kinematic one animated by the application: the cloth bound to them follows
// their frames exactly, and they are never pushed.
TEST(BulletCoupling, ClothFollowsStaticAndKinematicParentsExactly) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at;
  at.setIdentity();
  at.setOrigin(btVector3(0, 1.0, 0));
  btRigidBody* rod = bw.add_box(btVector3(0.4, 0.02, 0.02), 0.0, at);
  rod->setCollisionFlags(rod->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
  bullet::Coupling coupling(&bw.world);
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.98, 0)));
  for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), rod);
  btTransform pin_at;
  pin_at.setIdentity();
  pin_at.setOrigin(btVector3(0.5, 0.5, 0));
  btRigidBody* pin = bw.add_box(btVector3(0.02, 0.02, 0.02), 0.0, pin_at);  // static
  const Index corner = cloth.node(5, 5);
  const Vec3 pinned = s.particles().x.col(corner);
  coupling.bind_here(corner, pin);
  for (int frame = 0; frame < 60; ++frame) {
    // The application moves the kinematic rod through its motion state.
    btTransform next;
    next.setIdentity();
    next.setOrigin(btVector3(btScalar(0.3 * std::sin(0.1 * (frame + 1))), 1.0, 0));
    next.setRotation(btQuaternion(btVector3(0, 1, 0), btScalar(0.05 * (frame + 1))));
    rod->getMotionState()->setWorldTransform(next);
    bw.world.stepSimulation(btScalar(1.0 / 60), 8, btScalar(1.0 / 240));
  }
  const btTransform& frame = rod->getCenterOfMassTransform();
  for (Index k = 0; k < s.hard_bindings().rigid_count(); ++k) {
    if (s.hard_bindings().rigid_body(k) != coupling.rigid_particle(rod)) continue;
    const Vec3 local = s.hard_bindings().rigid_offset_body(k);
    const btVector3 expected = frame * btVector3(btScalar(local.x()), btScalar(local.y()), btScalar(local.z()));
    const Vec3 x = s.particles().x.col(s.hard_bindings().rigid_particle(k));
    EXPECT_NEAR((x - Vec3(expected.x(), expected.y(), expected.z())).norm(), 0.0, 1e-9) << "binding " << k;
  }
  EXPECT_LT(s.max_hard_binding_drift(), 1e-12);
  EXPECT_EQ(s.particles().x.col(corner), pinned);  // the static parent never moves, nor does its point
}

}  // namespace
}  // namespace sinew
