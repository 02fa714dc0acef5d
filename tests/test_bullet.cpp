// The Bullet plugin's exchange (Sifakis et al. 2007, section 5): copy state in, momentum out.
#include "bullet_scenes.hpp"
#include "intersections.hpp"
#include "sinew/builders.hpp"
#include "sinew/bullet/collisions.hpp"
#include "sinew/bullet/convert.hpp"
#include "sinew/bullet/coupling.hpp"

#include <BulletDynamics/Featherstone/btMultiBodyConstraintSolver.h>
#include <BulletDynamics/Featherstone/btMultiBodyDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>
#include <gtest/gtest.h>

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace sinew {
namespace {

// A plain Bullet world, as an application would set it up: the scenes' own (demos/scenes/bullet_scenes.hpp).
using scenes::BulletWorld;

// A box body kept awake (the exchange is tested on bodies Bullet would otherwise put to sleep).
btRigidBody* add_box(BulletWorld& w, const btVector3& half, double mass, const btTransform& at) {
  btRigidBody* body = w.add_body(w.keep(std::make_unique<btBoxShape>(half)), mass, at);
  body->setActivationState(DISABLE_DEACTIVATION);
  return body;
}

// A body's kinetic energy (spin in its principal axes, where its inertia is diagonal) plus its weight's
// potential energy at g = 9.81 m/s^2 along -y.
double body_energy(const btRigidBody* b) {
  const Vec3 w = bullet::to_eigen(b->getAngularVelocity() * b->getCenterOfMassTransform().getBasis());
  const Vec3 inverse = bullet::to_eigen(b->getInvInertiaDiagLocal());
  const double m = 1.0 / static_cast<double>(b->getInvMass());
  double e = 0.5 * m * bullet::to_eigen(b->getLinearVelocity()).squaredNorm() +
             m * 9.81 * static_cast<double>(b->getCenterOfMassPosition().y());
  for (int a = 0; a < 3; ++a) e += 0.5 * w[a] * w[a] / inverse[a];
  return e;
}

// The lowest point of a body's collision shape (its box's bottom) [m].
double lowest_point(const btRigidBody* b) {
  btVector3 lo, hi;
  b->getCollisionShape()->getAabb(b->getWorldTransform(), lo, hi);
  return static_cast<double>(lo.y());
}

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
  bw.world().setInternalTickCallback(app_pre_tick, &g_app_ticks, true);
  g_app_ticks = 0;
  {
    bullet::Coupling coupling(&bw.world());
    scenes::add_cloth_grid(coupling.system(), small_cloth(Vec3(0, 1, 0)));
    const Vec3 start = coupling.system().particles().x.col(0);
    bw.world().stepSimulation(btScalar(1.0 / 60), 10, btScalar(1.0 / 240));  // four internal ticks
    EXPECT_EQ(g_app_ticks, 4);
    EXPECT_EQ(bw.world().getWorldUserInfo(), &g_app_ticks);
    EXPECT_NEAR(coupling.last_stats().dt, 1.0 / 240, 1e-15);
    // Free fall of the whole cloth for 1/60 s at the world's gravity, through four coupled ticks.
    EXPECT_NEAR(coupling.system().particles().x(1, 0) - start.y(), -0.5 * 9.81 / 3600.0, 1e-12);
  }
  bw.world().stepSimulation(btScalar(1.0 / 60), 10, btScalar(1.0 / 240));  // detached: only the app runs
  EXPECT_EQ(g_app_ticks, 8);
}

// No gravity, no ground: a spinning Bullet box carrying a cloth (partly hard-bound, partly tied by
// binding springs). Momentum leaves the deformables only as the impulse handed to Bullet, so the
// total (Bullet body plus cloth) is conserved through the copy-in / copy-out exchange.
TEST(BulletCoupling, IsolatedCoupledSystemConservesLinearMomentumThroughTheExchange) {
  BulletWorld bw(btVector3(0, 0, 0));
  btTransform at = scenes::at(btVector3(0, 0.5, 0));
  btRigidBody* box = add_box(bw, btVector3(0.3, 0.05, 0.2), 1.0, at);
  box->setLinearVelocity(btVector3(0.2, 0.1, 0));
  box->setAngularVelocity(btVector3(0, 2.0, 0.5));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.45, 0)));
  // Each bound point where it is on the box, in Bullet's frame of the box.
  std::vector<std::pair<Index, Vec3>> on_box;
  auto bind_here = [&](Index p) {
    coupling.bind_here(p, box);
    on_box.emplace_back(p, bullet::to_eigen(at.invXform(bullet::to_bullet(s.particles().x.col(p)))));
  };
  for (int i = 0; i < 3; ++i) bind_here(cloth.node(i, 0));
  for (int i = 3; i < 6; ++i) {
    const Index point = s.add_particle(s.particles().x.col(cloth.node(i, 0)), Vec3::Zero(), 0.0);
    bind_here(point);
    s.add_binding_spring({cloth.node(i, 0), point, 1e4, 1.0});
  }
  s.step_settings().cg_tolerance = 1e-13;
  auto total_momentum = [&] {
    // The cloth's free nodes (the system's momentum, less its copy of the box with the nodes bound to
    // it) plus Bullet's box, which carries those nodes: its mass times its centre of mass's velocity.
    const Vec3 cloth_p = s.linear_momentum() - s.rigid_bodies().mass[0] * Vec3(s.rigid_bodies().v.col(0));
    const btVector3 lever = bullet::to_bullet(coupling.centre_of_mass(box)) - box->getCenterOfMassPosition();
    return Vec3(cloth_p + (1.0 / box->getInvMass()) * bullet::to_eigen(box->getVelocityInLocalPoint(lever)));
  };
  bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const Vec3 p0 = total_momentum();
  double worst = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    worst = std::max(worst, (total_momentum() - p0).norm());
  }
  EXPECT_LT(worst, 1e-10);
  EXPECT_GT((box->getLinearVelocity() - btVector3(0.2, 0.1, 0)).length(), 1e-3);  // the cloth did push it
  EXPECT_LT(s.max_hard_binding_drift(), 1e-12);
  // After each tick the bound points sit on the frame Bullet integrated, not on sinew's prediction.
  const btTransform& frame = box->getCenterOfMassTransform();
  for (const auto& [p, local] : on_box) {
    const Vec3 expected = bullet::to_eigen(frame * bullet::to_bullet(local));
    EXPECT_LT((s.particles().x.col(p) - expected).norm(), 1e-12) << "particle " << p;
  }
}

// Gravity stays Bullet's for rigid bodies and sinew's for deformables: a box and the cloth hanging
// from it by binding springs, falling freely, gain exactly (M + m) g t of momentum, not (2M + m) g t.
TEST(BulletCoupling, GravityIsNotAppliedTwice) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = scenes::at(btVector3(0, 1.0, 0));
  btRigidBody* box = add_box(bw, btVector3(0.3, 0.05, 0.05), 2.0, at);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.95, 0)));
  for (int i = 0; i < 6; ++i) {
    const Index point = s.add_particle(s.particles().x.col(cloth.node(i, 0)), Vec3::Zero(), 0.0);
    coupling.bind_here(point, box);
    s.add_binding_spring({cloth.node(i, 0), point, 1e4, 1.0});
  }
  s.step_settings().cg_tolerance = 1e-13;
  const int ticks = 120;
  for (int i = 0; i < ticks; ++i) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const double t = ticks / 240.0;
  const double cloth_mass = 0.2, box_mass = 2.0;
  const Vec3 cloth_p = s.linear_momentum() - box_mass * Vec3(s.rigid_bodies().v.col(0));
  const double total = cloth_p.y() + box_mass * box->getLinearVelocity().y();
  EXPECT_NEAR(total, -(box_mass + cloth_mass) * 9.81 * t, 1e-9);
}

// A cloth on a body spinning at 50 rad/s: the centripetal load is large (|w|^2 r = 625 m/s^2 at
// 0.25 m) and the frame turns 0.2 rad per tick, yet the cloth stays attached and finite.
TEST(BulletCoupling, ClothOnFastSpinningBodyStaysAttached) {
  BulletWorld bw(btVector3(0, 0, 0));
  btTransform at = btTransform::getIdentity();
  btRigidBody* hub = add_box(bw, btVector3(0.1, 0.1, 0.1), 2.0, at);
  hub->setAngularVelocity(btVector3(0, 50, 0));
  bullet::CouplingSettings settings;
  settings.collisions = false;  // the cloth starts inside the hub's collision margin; not the point here
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(0.0, 0.05, -0.25));
  c.across = Vec3::UnitZ();
  c.down = Vec3::UnitX();        // a flag in the x-z plane, its inner edge along the hub
  c.stretch_stiffness = 5000.0;  // stiff enough that the centrifugal load (~25 N at the root) stretches it little
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (int i = 0; i < 6; i += 2) coupling.bind_here(cloth.node(i, 0), hub);
  for (int i = 1; i < 6; i += 2) {
    const Index point = s.add_particle(s.particles().x.col(cloth.node(i, 0)), Vec3::Zero(), 0.0);
    coupling.bind_here(point, hub);
    s.add_binding_spring({cloth.node(i, 0), point, 1e5, 1.0});
  }
  for (Index n : cloth.nodes) {
    const Vec3 x = s.particles().x.col(n);
    s.particles().v.col(n) = Vec3(0, 50, 0).cross(x);  // co-rotating start
  }
  double stretch = 0.0, drift = 0.0;
  for (int tick = 0; tick < 240; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    stretch = std::max(stretch, s.binding_springs().max_stretch(s.particles().x));
    drift = std::max(drift, s.max_hard_binding_drift());
  }
  EXPECT_TRUE(s.particles().x.allFinite());
  EXPECT_LT(stretch, 0.02);
  EXPECT_LT(drift, 1e-12);
  // The flag keeps its size: outer corners hypot(0.5, 0.25) = 0.56 m from the hub's centre, plus
  // stretch. (The hub itself drifts: the co-rotating start gives the system net momentum.)
  const btVector3 centre = hub->getCenterOfMassPosition();
  double reach = 0.0;
  for (Index n : cloth.nodes)
    reach = std::max(reach, std::hypot(s.particles().x(0, n) - centre.x(), s.particles().x(2, n) - centre.z()));
  EXPECT_LT(reach, 0.65);
  EXPECT_GT(reach, 0.5);
}

// A static body and a kinematic one animated by the application: the cloth bound to them follows
// their frames exactly, and they are never pushed.
TEST(BulletCoupling, ClothFollowsStaticAndKinematicParentsExactly) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = scenes::at(btVector3(0, 1.0, 0));
  btRigidBody* rod = add_box(bw, btVector3(0.4, 0.02, 0.02), 0.0, at);
  rod->setCollisionFlags(rod->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.98, 0)));
  for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), rod);
  btTransform pin_at;
  pin_at.setIdentity();
  pin_at.setOrigin(btVector3(0.5, 0.5, 0));
  btRigidBody* pin = add_box(bw, btVector3(0.02, 0.02, 0.02), 0.0, pin_at);  // static
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
    bw.world().stepSimulation(btScalar(1.0 / 60), 8, btScalar(1.0 / 240));
  }
  const btTransform& frame = rod->getCenterOfMassTransform();
  for (Index k = 0; k < s.hard_bindings().rigid_count(); ++k) {
    if (s.hard_bindings().rigid_body(k) != coupling.rigid_particle(rod)) continue;
    const Vec3 local = s.hard_bindings().rigid_offset_body(k);
    const Vec3 expected = bullet::to_eigen(frame * bullet::to_bullet(local));
    const Vec3 x = s.particles().x.col(s.hard_bindings().rigid_particle(k));
    EXPECT_NEAR((x - expected).norm(), 0.0, 1e-9) << "binding " << k;
  }
  EXPECT_LT(s.max_hard_binding_drift(), 1e-12);
  EXPECT_EQ(s.particles().x.col(corner), pinned);  // the static parent never moves, nor does its point
}

// A point inside a triangle of the cloth tied to a static body by a binding spring (Coupling::attach):
// once the cloth hangs at rest, statics says the spring carries the cloth's whole weight, and a
// zero-rest-length spring of stiffness k is then stretched by m g / k.
TEST(BulletCoupling, PointInsideATriangleHangsTheClothByABindingSpring) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = scenes::at(btVector3(0, 1.2, 0));
  btRigidBody* hook = add_box(bw, btVector3(0.02, 0.02, 0.02), 0.0, at);  // static
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 1.0, 0));
  c.stretch_damping = 0.5;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  const std::array<Index, 3> parents = {cloth.node(2, 0), cloth.node(3, 0), cloth.node(2, 1)};
  // Half way across the top row, above the cloth's centre of mass, so it hangs without swinging.
  const std::array<double, 3> weights = {0.3, 0.5, 0.2};
  const Index point = s.add_embedded_point(parents, weights);
  const Vec3 start = s.particles().x.col(point);
  const double k = 2e4;
  const Index spring = coupling.attach(point, hook, start - Vec3(0, 1.2, 0), k);
  EXPECT_THROW(s.add_embedded_point(parents, std::array<double, 3>{0.4, 0.4, 0.3}), Error);  // sums to 1.1
  for (int frame = 0; frame < 240; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 8, btScalar(1.0 / 240));
  const double weight = c.mass * 9.81;
  const Vec3 force = s.binding_spring_force(spring);  // on the cloth's point
  EXPECT_NEAR(force.y(), weight, 0.01 * weight);
  EXPECT_LT(std::hypot(force.x(), force.z()), 0.01 * weight);
  EXPECT_NEAR((s.particles().x.col(point) - start).norm(), weight / k, 0.02 * weight / k);
  Vec3 embedded = Vec3::Zero();
  for (int i = 0; i < 3; ++i) embedded += weights[i] * s.particles().x.col(parents[i]);
  EXPECT_LT((s.particles().x.col(point) - embedded).norm(), 1e-12);
}

// Removing bindings at run time in a Bullet scene: a cloth held by a rod (hard bindings on its top row)
// and by a binding spring to a hook is let go between two stepSimulation calls. From then on only
// gravity acts on it from outside, so its centre of mass follows y = y0 + v0 t - g t^2 / 2 exactly.
TEST(BulletCoupling, RemovingBindingsAtRunTimeReleasesTheCloth) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = scenes::at(btVector3(0, 1.05, 0));  // clear of the cloth by more than the collision thickness
  btRigidBody* rod = add_box(bw, btVector3(0.4, 0.01, 0.01), 0.0, at);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 1.0, 0)));
  for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), rod);
  const Index spring = coupling.attach(cloth.node(2, 5), rod, Vec3(0, -0.65, 0), 1e3);
  auto centre = [&] {
    Vec3 mx = Vec3::Zero(), mv = Vec3::Zero();
    double m = 0.0;
    for (Index p : cloth.nodes) {
      const double mp = s.input_mass()[p];
      mx += mp * s.particles().x.col(p), mv += mp * s.particles().v.col(p), m += mp;
    }
    return std::pair<Vec3, Vec3>(mx / m, mv / m);
  };
  for (int frame = 0; frame < 30; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 8, btScalar(1.0 / 240));
  EXPECT_GT(s.particles().x.row(1).minCoeff(), 0.3);  // held
  for (int i = 0; i < 6; ++i) EXPECT_TRUE(s.unbind(cloth.node(i, 0)));
  s.set_binding_spring_active(spring, false);
  const auto [x0, v0] = centre();
  const int frames = 30;
  for (int frame = 0; frame < frames; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 8, btScalar(1.0 / 240));
  const double t = frames / 60.0;
  const auto [x1, v1] = centre();
  EXPECT_NEAR(x1.y(), x0.y() + v0.y() * t - 0.5 * 9.81 * t * t, 1e-8);
  EXPECT_NEAR(v1.y(), v0.y() - 9.81 * t, 1e-8);
  EXPECT_NEAR(x1.x(), x0.x() + v0.x() * t, 1e-8);
  EXPECT_NEAR(s.binding_spring_force(spring).norm(), 0.0, 0.0);
}

// The centre of mass of a set of particles, and its velocity, from the masses they were created with.
std::pair<Vec3, Vec3> centre_of(const System& s, const std::vector<Index>& nodes) {
  Vec3 mx = Vec3::Zero(), mv = Vec3::Zero();
  double m = 0.0;
  for (Index p : nodes) {
    const double mp = s.input_mass()[p];
    mx += mp * s.particles().x.col(p), mv += mp * s.particles().v.col(p), m += mp;
  }
  return {mx / m, mv / m};
}

// A body the application takes away: removed from the world (and then deleted, before the next tick)
// or released with Coupling::remove. A falling box carries a cloth by its top row (hard-bound) and by a
// binding spring; once the box is gone only gravity acts on the cloth, so its centre of mass follows
// y = y0 + v0 t - g t^2 / 2 exactly. The bound nodes are free again with their own mass, the body point
// and its spring are gone, and the deleted box is never read (the sanitizer build runs this test).
// Before, sinew kept integrating the box's particle (weightless once out of the world, or read from
// freed memory) with the cloth still on it.
TEST(BulletCoupling, ABodyTakenAwayReleasesWhatWasBoundToIt) {
  for (const bool deleted : {true, false}) {
    const std::string how = deleted ? "removed from the world and deleted" : "Coupling::remove";
    BulletWorld bw(btVector3(0, -9.81, 0));
    btBoxShape shape(btVector3(0.3, 0.05, 0.05));
    btVector3 inertia;
    shape.calculateLocalInertia(2, inertia);
    auto box = std::make_unique<btRigidBody>(btRigidBody::btRigidBodyConstructionInfo(2, nullptr, &shape, inertia));
    box->setWorldTransform(scenes::at(btVector3(0, 1.0, 0)));
    box->setActivationState(DISABLE_DEACTIVATION);
    bw.world().addRigidBody(box.get());
    bullet::CouplingSettings settings;
    settings.collisions = false;  // only gravity and the cloth's own forces: free fall is exact
    bullet::Coupling coupling(&bw.world(), settings);
    System& s = coupling.system();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.95, 0)));
    for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), box.get());
    const Index spring = coupling.attach(cloth.node(2, 5), box.get(), Vec3(0, -0.6, 0), 1e3);
    const Index body_point = s.binding_springs().b(spring);
    s.step_settings().cg_tolerance = 1e-13;
    for (int frame = 0; frame < 10; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    if (deleted) {
      bw.world().removeRigidBody(box.get());
      box.reset();
    } else {
      coupling.remove(box.get());
      EXPECT_THROW(coupling.remove(box.get()), Error) << "released already";
    }
    const auto [x0, v0] = centre_of(s, cloth.nodes);
    const int frames = 30;
    const double box_vy = deleted ? 0.0 : double(box->getLinearVelocity().y());
    for (int frame = 0; frame < frames; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    const double t = frames / 60.0;
    const auto [x1, v1] = centre_of(s, cloth.nodes);
    EXPECT_NEAR(x1.y(), x0.y() + v0.y() * t - 0.5 * 9.81 * t * t, 1e-9) << how;
    EXPECT_NEAR(v1.y(), v0.y() - 9.81 * t, 1e-9) << how;
    EXPECT_NEAR(x1.x(), x0.x() + v0.x() * t, 1e-9) << how;
    for (int i = 0; i < 6; ++i) {
      const Index node = cloth.node(i, 0);
      EXPECT_EQ(s.particles().kind[node], ParticleKind::free) << how << ", node " << node;
      EXPECT_EQ(s.particles().mass[node], s.input_mass()[node]) << how << ", node " << node;
    }
    EXPECT_EQ(s.particles().kind[body_point], ParticleKind::removed) << how;
    EXPECT_TRUE(s.binding_springs().removed(spring)) << how;
    EXPECT_EQ(coupling.body(0), nullptr) << how;
    if (!deleted) {
      // A plain Bullet body again: it falls at g, untouched by the cloth.
      EXPECT_NEAR(box->getLinearVelocity().y(), box_vy - 9.81 * t, 1e-9) << how;
      bw.world().removeRigidBody(box.get());
    }
  }
}

// A coupled body the application makes static (mass 0) between ticks stops in Bullet; its rigid-body
// particle must stop too. Before, sinew kept integrating it under the weight of the cloth hanging from
// it and handed Bullet a velocity that grew without bound (2 m/s after 2 s) on a body that did not
// move. Made dynamic again, it falls with the cloth: total momentum grows by exactly the weight of
// everything sinew counts. A kinematic flag is followed the same way.
TEST(BulletCoupling, ABodyMadeStaticOrKinematicBetweenTicksIsFollowed) {
  for (const int flag : {int(btCollisionObject::CF_STATIC_OBJECT), int(btCollisionObject::CF_KINEMATIC_OBJECT)}) {
    const std::string how = flag == btCollisionObject::CF_STATIC_OBJECT ? "static" : "kinematic";
    BulletWorld bw(btVector3(0, -9.81, 0));
    btRigidBody* box = add_box(bw, btVector3(0.3, 0.05, 0.05), 2.0, scenes::at(btVector3(0, 1.0, 0)));
    const btVector3 inertia(btScalar(1) / box->getInvInertiaDiagLocal().x(),
                            btScalar(1) / box->getInvInertiaDiagLocal().y(),
                            btScalar(1) / box->getInvInertiaDiagLocal().z());
    bullet::CouplingSettings settings;
    settings.collisions = false;
    bullet::Coupling coupling(&bw.world(), settings);
    System& s = coupling.system();
    scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.95, 0));
    c.stretch_damping = 0.5;
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
    std::vector<Vec3> on_box;  // the bound nodes in Bullet's frame of the box
    for (int i = 0; i < 6; ++i) {
      coupling.bind_here(cloth.node(i, 0), box);
      const btTransform& frame = box->getCenterOfMassTransform();
      on_box.push_back(bullet::to_eigen(frame.invXform(bullet::to_bullet(s.particles().x.col(cloth.node(i, 0))))));
    }
    s.step_settings().cg_tolerance = 1e-13;
    for (int frame = 0; frame < 10; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    // Stopped where it is.
    if (flag == btCollisionObject::CF_STATIC_OBJECT) {
      box->setMassProps(0, btVector3(0, 0, 0));
    } else {
      // Animated through its motion state from now on: held where it is.
      box->setCollisionFlags(box->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      box->getMotionState()->setWorldTransform(box->getCenterOfMassTransform());
    }
    box->setLinearVelocity(btVector3(0, 0, 0));
    box->setAngularVelocity(btVector3(0, 0, 0));
    const btTransform held = box->getCenterOfMassTransform();
    for (int frame = 0; frame < 120; ++frame) {
      bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
      ASSERT_EQ(bullet::to_eigen(box->getLinearVelocity()), Vec3::Zero()) << how << ", frame " << frame;
      ASSERT_EQ(bullet::to_eigen(box->getAngularVelocity()), Vec3::Zero()) << how << ", frame " << frame;
    }
    EXPECT_TRUE(s.rigid_bodies().kinematic[0]) << how;
    EXPECT_EQ(s.rigid_bodies().v.col(0), Vec3::Zero()) << how;
    EXPECT_EQ(bullet::to_eigen(box->getCenterOfMassPosition()), bullet::to_eigen(held.getOrigin())) << how;
    for (int i = 0; i < 6; ++i) {
      const Vec3 expected = bullet::to_eigen(held * bullet::to_bullet(on_box[static_cast<std::size_t>(i)]));
      EXPECT_LT((s.particles().x.col(cloth.node(i, 0)) - expected).norm(), 1e-12) << how;
    }
    // Dynamic again: everything falls.
    if (flag == btCollisionObject::CF_STATIC_OBJECT) {
      box->setMassProps(2, inertia);
    } else {
      box->setCollisionFlags(box->getCollisionFlags() & ~btCollisionObject::CF_KINEMATIC_OBJECT);
    }
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    EXPECT_FALSE(s.rigid_bodies().kinematic[0]) << how;
    const Vec3 p0 = s.linear_momentum();
    const int ticks = 60;
    for (int tick = 0; tick < ticks; ++tick) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    double counted = 0.0;
    for (Index i = 0; i < s.particles().size(); ++i)
      if (s.particles().kind[i] == ParticleKind::free) counted += s.particles().mass[i];
    counted += s.rigid_bodies().mass[0];
    EXPECT_NEAR(s.linear_momentum().y() - p0.y(), -counted * 9.81 * ticks / 240.0, 1e-9) << how;
    EXPECT_LT(box->getCenterOfMassPosition().y(), held.getOrigin().y() - 0.01) << how;
    // The particle is the box with the nodes bound to it, standing on Bullet's box.
    const btVector3 lever = bullet::to_bullet(coupling.centre_of_mass(box)) - box->getCenterOfMassPosition();
    EXPECT_LT((s.rigid_bodies().x.col(0) - coupling.centre_of_mass(box)).norm(), 1e-12) << how;
    EXPECT_LT((s.rigid_bodies().v.col(0) - bullet::to_eigen(box->getVelocityInLocalPoint(lever))).norm(), 1e-12) << how;
  }
}

// Binding to a body that is not in the coupling's world is refused, naming the body: Bullet would
// never integrate it while sinew integrated its particle.
TEST(BulletCoupling, ABodyOutsideTheWorldIsRefused) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  BulletWorld other(btVector3(0, -9.81, 0));
  btRigidBody* elsewhere = add_box(other, btVector3(0.1, 0.1, 0.1), 1.0, scenes::at(btVector3(0, 1, 0)));
  btBoxShape shape(btVector3(0.1, 0.1, 0.1));
  btRigidBody never_added(btRigidBody::btRigidBodyConstructionInfo(1, nullptr, &shape, btVector3(1, 1, 1)));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const Index node = s.add_particle(Vec3::Zero(), Vec3::Zero(), 0.1);
  for (btRigidBody* body : {&never_added, elsewhere}) {
    try {
      coupling.bind(node, body, Vec3::Zero());
      ADD_FAILURE() << "bound to a body outside the world";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("is not in the coupling's world"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(s.rigid_bodies().size(), 0);
  EXPECT_EQ(s.hard_bindings().rigid_count(), 0);
}

// A rigid body added to the coupled system directly (System::add_rigid_body) is sinew's own: it falls
// at sinew's gravity, g t^2 / 2, and Bullet bodies coupled after it keep their own states. Before, the
// coupling's list of Bullet bodies and the system's rigid bodies fell out of step, and the own body
// was given the next Bullet body's state.
TEST(BulletCoupling, ARigidBodyAddedToTheSystemDirectlyIsSinewsOwn) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btRigidBody* first = add_box(bw, btVector3(0.1, 0.1, 0.1), 0.0, scenes::at(btVector3(-1, 1, 0)));
  btRigidBody* second = add_box(bw, btVector3(0.1, 0.1, 0.1), 1.0, scenes::at(btVector3(1, 3, 0)));
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  EXPECT_EQ(coupling.rigid_particle(first), 0);
  RigidBodySettings own;
  own.x = Vec3(0, 5, 0);
  const Index own_index = s.add_rigid_body(own);
  EXPECT_EQ(own_index, 1);
  EXPECT_EQ(coupling.rigid_particle(second), 2);
  EXPECT_EQ(coupling.body(1), nullptr);
  EXPECT_EQ(coupling.body(2), second);
  const int ticks = 120;
  for (int tick = 0; tick < ticks; ++tick) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const double t = ticks / 240.0;
  EXPECT_NEAR(s.rigid_bodies().x(1, own_index), 5.0 - 0.5 * 9.81 * t * t, 1e-9);
  EXPECT_NEAR(s.rigid_bodies().v(1, own_index), -9.81 * t, 1e-9);
  EXPECT_EQ(s.rigid_bodies().x.col(2), bullet::to_eigen(second->getCenterOfMassPosition()));
  EXPECT_EQ(s.rigid_bodies().x.col(0), bullet::to_eigen(first->getCenterOfMassPosition()));
}

// What the application reads between stepSimulation calls is the end-of-tick state. Bodies resting on
// what holds them read the velocity they move with: a sphere on the ground and a box on a 20 degree
// slope whose friction (0.8 > tan 20) holds it. Bullet's contacts stop the approach at the velocity a
// body moves with over the tick, the step's half-step velocity; the step's second half then added half
// a tick of gravity, and they read g dt / 2 = 0.02 m/s of sinking (the box, of sliding too) while
// their positions held to round-off. Here the reading and the motion over the last tick agree.
TEST(BulletCoupling, ARestingBodyReadsTheVelocityItMovesWith) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0,
              scenes::at(btVector3(0, 0, 0)));
  const btQuaternion tilt(btVector3(0, 0, 1), btScalar(20 * SIMD_PI / 180));
  btRigidBody* slope = add_box(bw, btVector3(1, 0.1, 1), 0.0, scenes::at(btVector3(3, 1, 0), tilt));
  slope->setFriction(0.8);
  btRigidBody* sphere =
      bw.add_body(bw.keep(std::make_unique<btSphereShape>(0.3)), 1.0, scenes::at(btVector3(0, 0.3, 0)));
  sphere->setActivationState(DISABLE_DEACTIVATION);
  const btVector3 on_slope = scenes::at(btVector3(3, 1, 0), tilt) * btVector3(0, 0.2, 0);
  btRigidBody* box = add_box(bw, btVector3(0.1, 0.1, 0.1), 1.0, scenes::at(on_slope, tilt));
  box->setFriction(0.8);
  bullet::Coupling coupling(&bw.world());
  coupling.rigid_particle(sphere);
  coupling.rigid_particle(box);
  const double dt = 1.0 / 240;
  for (int tick = 0; tick < 240; ++tick) bw.world().stepSimulation(btScalar(dt), 1, btScalar(dt));
  for (btRigidBody* body : {sphere, box}) {
    const std::string name = body == sphere ? "sphere" : "box";
    const Vec3 x0 = bullet::to_eigen(body->getCenterOfMassPosition());
    bw.world().stepSimulation(btScalar(dt), 1, btScalar(dt));
    const Vec3 moved = (bullet::to_eigen(body->getCenterOfMassPosition()) - x0) / dt;
    const Vec3 v = bullet::to_eigen(body->getLinearVelocity());
    // To what Bullet's iterative contact and friction solve leaves (about 1e-5 m/s on the box).
    EXPECT_LT(moved.norm(), 1e-4) << name << " rests";
    EXPECT_LT((v - moved).norm(), 1e-4) << name << " reads v = " << v.transpose();
    EXPECT_LT(bullet::to_eigen(body->getAngularVelocity()).norm(), 1e-3) << name;
  }
}

// The cloth of the README's hello scene (demos/hello.cpp): 1.2 m, 15 x 15 nodes, 0.2 kg, flat 1 cm
// above the top of a 0.3 m sphere centred at (0, 2, 0).
ClothGrid add_hello_cloth(System& s) {
  ClothGridSettings grid;
  grid.nx = grid.ny = 15;
  grid.width = grid.height = 1.2;
  grid.mass = 0.2;
  grid.origin = {-0.6, 2.31, -0.6};
  grid.down = {0, 0, 1};
  return add_cloth_grid(s, grid);
}

// The README's hello scene (demos/hello.cpp): a cloth tied at its centre to the top of a 1 kg sphere by
// a 1e4 N/m binding spring, at rest on the ground after 3 s. The tied node does not collide with the
// sphere it is tied to (Coupling::find_tied_particles), so it sits on the spring's end, which carries
// what the cloth around it pulls. Between ticks the node reads the velocity it moves with and the spring
// reads k times its stretch; the sphere reads no sinking; the spring's end on the sphere sits on the
// sphere's final frame, moving with its final twist. Before, the node read |v| = 13 m/s while it moved
// at 0.15 m/s (step 4 pulled it into the sphere, and only the next step's projection took that out),
// the spring read 2 N, and the sphere read g dt / 2 of sinking.
TEST(BulletCoupling, HelloSceneReadsTheStateItIsIn) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0,
              scenes::at(btVector3(0, 0, 0)));
  btSphereShape ball(0.3);
  btVector3 inertia;
  ball.calculateLocalInertia(1, inertia);
  btRigidBody* sphere = bw.add_body(&ball, 1.0, scenes::at(btVector3(0, 2, 0)), inertia);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const ClothGrid cloth = add_hello_cloth(s);
  const double k = 1e4;
  const Vec3 local(0, 0.3, 0);
  const Index spring = coupling.attach(cloth.node(7, 7), sphere, local, k);
  const Index node = s.binding_springs().a(spring), end = s.binding_springs().b(spring);
  for (int frame = 0; frame < 180; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
  const double dt = 1.0 / 240;
  double worst_node = 0.0, worst_force = 0.0, worst_sinking = 0.0, worst_end = 0.0;
  for (int tick = 0; tick < 8; ++tick) {
    const Vec3 x0 = s.particles().x.col(node);
    bw.world().stepSimulation(btScalar(dt), 1, btScalar(dt));
    const Vec3 moved = (s.particles().x.col(node) - x0) / dt;
    worst_node = std::max(worst_node, (Vec3(s.particles().v.col(node)) - moved).norm());

    const Vec3 stretch = s.particles().x.col(node) - s.particles().x.col(end);
    const Vec3 f = s.binding_spring_force(spring);
    const double weight = 0.2 * 9.81;  // the cloth's: what the spring carries at most, at rest
    worst_force = std::max(worst_force, (f + k * stretch).norm() / std::max(k * stretch.norm(), weight));
    worst_sinking = std::max(worst_sinking, std::abs(double(sphere->getLinearVelocity().y())));
    const btTransform& frame = sphere->getCenterOfMassTransform();
    const Vec3 r = bullet::to_eigen(frame.getBasis() * bullet::to_bullet(local));
    const Vec3 v_end =
        bullet::to_eigen(sphere->getLinearVelocity()) + bullet::to_eigen(sphere->getAngularVelocity()).cross(r);
    worst_end = std::max({worst_end, (Vec3(s.particles().x.col(end)) - bullet::to_eigen(frame.getOrigin()) - r).norm(),
                          (Vec3(s.particles().v.col(end)) - v_end).norm()});
    EXPECT_LT(stretch.norm(), 1e-3) << "m: the node sits on the spring's end";
  }
  EXPECT_LT(worst_node, 0.01) << "m/s between the node's reading and its motion";
  EXPECT_LT(worst_force, 0.02) << "of k times the stretch (or of the cloth's weight)";
  EXPECT_LT(worst_sinking, 1e-9) << "m/s";
  EXPECT_LT(worst_end, 1e-12);
  EXPECT_NEAR(sphere->getCenterOfMassPosition().y(), 0.3, 1e-9);
}

// A cloth tied by its centre to a point on a body, everything falling freely: no force does work, so
// the visible energy (kinetic, gravity, elastic and the binding spring's) keeps its start. The tie's end
// sits on the body's surface or inside it, where the collision thickness would hold the node out: with
// the node colliding with its own body the projection did work on the stretched spring at every step,
// and the README's hello scene (tie on a sphere's top) gained 2.2 J in 20 frames at one step per tick,
// 0.04 J at five. The family: sphere and box, tie on the surface at 1 and 4 Bullet ticks per frame, and
// 5 cm inside the sphere at 4, the scheme sinew chooses. Bound: 1e-3 of the kinetic energy the fall
// gives (14 J). Not held yet, where the cloth around the node wraps onto the falling body: a tie 5 cm
// inside the sphere at one 1/60 s tick (the energy swings by 3 J) and 5 cm inside the box at 4 ticks
// (+0.04 J), contact of cloth with fast bodies that the contact work has to take up.
struct TiedCase {
  bool box;
  double depth;  // of the tie below the top surface [m]
  int ticks;
};
class TiedClothInFreeFall : public ::testing::TestWithParam<TiedCase> {};

TEST_P(TiedClothInFreeFall, GainsNoEnergy) {
  const TiedCase p = GetParam();
  BulletWorld bw(btVector3(0, -9.81, 0));
  std::unique_ptr<btCollisionShape> shape;
  if (p.box) shape = std::make_unique<btBoxShape>(btVector3(0.3, 0.3, 0.3));
  else shape = std::make_unique<btSphereShape>(0.3);
  btVector3 inertia;
  shape->calculateLocalInertia(1, inertia);
  btRigidBody* body = bw.add_body(shape.get(), 1.0, scenes::at(btVector3(0, 2, 0)), inertia);
  body->setActivationState(DISABLE_DEACTIVATION);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const ClothGrid cloth = add_hello_cloth(s);
  coupling.attach(cloth.node(7, 7), body, Vec3(0, 0.3 - p.depth, 0), 1e4);
  const auto energy = [&] {  // as BulletScene::total_energy: the body's is Bullet's
    double e = s.potential_energy() + bw.rigid_energy();
    for (Index i = 0; i < s.particles().size(); ++i)
      if (s.particles().kind[i] == ParticleKind::free)
        e += 0.5 * s.particles().mass[i] * s.particles().v.col(i).squaredNorm();
    return e;
  };
  double start = 0.0, worst = 0.0;
  for (int frame = 1; frame <= 30; ++frame) {  // 0.5 s: the body falls 1.2 m and meets nothing
    bw.world().stepSimulation(btScalar(1.0 / 60), p.ticks, btScalar(1.0 / (60.0 * p.ticks)));
    if (frame == 1) start = energy();  // after the first tick has set the system up
    worst = std::max(worst, energy() - start);
  }
  EXPECT_LT(worst, 0.014) << "J above the start (" << start << " J)";
  EXPECT_GT(body->getCenterOfMassPosition().y(), 0.5) << "still falling freely";
}

INSTANTIATE_TEST_SUITE_P(BulletCoupling, TiedClothInFreeFall,
                         ::testing::Values(TiedCase{false, 0.0, 1}, TiedCase{false, 0.0, 4}, TiedCase{false, 0.05, 4},
                                           TiedCase{true, 0.0, 1}, TiedCase{true, 0.0, 4}));

// The mass of points hard-bound to a body is the body's (section 2, m = W^T m_bar). A 10 x 10 cloth
// moving at 1 m/s, without gravity, is bound by a corner to a box at rest: the corner's momentum goes
// into the box at set-up, and from then on the total linear and angular momentum of cloth and box stay
// what they were before the binding, to the CG tolerance. Bullet's box has the merged mass, and its
// mass times the velocity of centre_of_mass(box) is the merged body's momentum. Before, the corner's
// mass and momentum were dropped (4e-3 of the total).
TEST(BulletCoupling, ClothBoundByACornerGivesItsMomentumToTheBody) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* box = add_box(bw, btVector3(0.1, 0.1, 0.1), 1.0, scenes::at(btVector3(0, 0, 0)));
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(0.1, 0.1, 0.1));
  c.nx = c.ny = 10;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (Index node : cloth.nodes) s.particles().v.col(node) = Vec3(1.0, 0.0, 0.0);
  s.step_settings().cg_tolerance = 1e-13;
  Vec3 p0 = Vec3::Zero(), l0 = Vec3::Zero();
  for (Index node : cloth.nodes) {
    const double m = s.input_mass()[node];
    p0 += m * s.particles().v.col(node);
    l0 += m * Vec3(s.particles().x.col(node)).cross(Vec3(s.particles().v.col(node)));
  }
  const double corner_mass = s.input_mass()[cloth.node(0, 0)];
  coupling.bind_here(cloth.node(0, 0), box);
  double worst_p = 0.0, worst_l = 0.0, worst_bullet = 0.0;
  for (int tick = 0; tick < 100; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    worst_p = std::max(worst_p, (s.linear_momentum() - p0).norm());
    worst_l = std::max(worst_l, (s.angular_momentum() - l0).norm());
    // Bullet's side: the free nodes plus Bullet's mass times the merged centre's velocity.
    Vec3 p = Vec3::Zero();
    for (Index node : cloth.nodes)
      if (s.particles().kind[node] == ParticleKind::free) p += s.particles().mass[node] * s.particles().v.col(node);
    const btVector3 lever = bullet::to_bullet(coupling.centre_of_mass(box)) - box->getCenterOfMassPosition();
    p += (1.0 / box->getInvMass()) * bullet::to_eigen(box->getVelocityInLocalPoint(lever));
    worst_bullet = std::max(worst_bullet, (p - p0).norm());
  }
  EXPECT_NEAR(1.0 / box->getInvMass(), 1.0 + corner_mass, 1e-12);
  EXPECT_LT(worst_p, 1e-10) << "of " << p0.norm() << " kg m/s";
  EXPECT_LT(worst_bullet, 1e-10);
  // Angular momentum to the step's second order (the turning box, as in System's free-floating test):
  // the corner's own share, m x x v, is 3e-3 of it.
  EXPECT_LT(worst_l, 1e-4 * l0.norm()) << "of " << l0.norm() << " kg m^2/s";
  EXPECT_GT(bullet::to_eigen(box->getLinearVelocity()).norm(), 1e-3) << "the cloth pulled the box";
  // Released, the box gets its own mass back and the corner its own.
  coupling.remove(box);
  EXPECT_EQ(1.0 / box->getInvMass(), 1.0);
  bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  EXPECT_EQ(s.particles().mass[cloth.node(0, 0)], corner_mass);
}

// A 0.1 kg box hung from a fixed point by a point-to-point joint carries a 0.2 kg cloth by its top row.
// Once the cloth hangs at rest the joint carries the weight of both, (m_box + m_cloth) g, of which the
// hard-bound row's share is the box's (its mass handed to Bullet). The joint is breakable, so Bullet's
// solver alone holds it and its feedback reads the force (an unbreakable joint's rows are held inside
// the step, which leaves Bullet nothing to report). Before, the joint read the weight less the bound
// row's, 8 % short.
TEST(BulletCoupling, AJointCarriesTheWeightOfTheMassBoundToItsBody) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btRigidBody* box = add_box(bw, btVector3(0.3, 0.02, 0.02), 0.1, scenes::at(btVector3(0, 1.0, 0)));
  btPoint2PointConstraint joint(*box, btVector3(0, 0.02, 0));
  joint.setBreakingImpulseThreshold(btScalar(1e30));
  btJointFeedback feedback;
  joint.setJointFeedback(&feedback);
  joint.enableFeedback(true);
  bw.world().addConstraint(&joint);
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.98, 0));
  c.stretch_damping = 0.5;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  double bound = 0.0;
  for (int i = 0; i < 6; ++i) {
    coupling.bind_here(cloth.node(i, 0), box);
    bound += s.input_mass()[cloth.node(i, 0)];
  }
  for (int tick = 0; tick < 960; ++tick) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  double force = 0.0;
  const int ticks = 240;
  for (int tick = 0; tick < ticks; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    force += feedback.m_appliedForceBodyA.y() / ticks;
  }
  const double weight = (0.1 + c.mass) * 9.81;
  EXPECT_GT(bound * 9.81, 0.05 * weight) << "the bound row is a fair share of the weight";
  EXPECT_NEAR(force, weight, 0.01 * weight);
  EXPECT_NEAR(1.0 / box->getInvMass(), 0.1 + bound, 1e-12);
  bw.world().removeConstraint(&joint);
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// Collision regression: a small cloth dropped on each kind of static shape comes to lie on it and
// never sinks into it (its particles keep a non-negative distance to the surface, i.e. no deeper
// than the collision thickness into the skin around it).
class ClothOnShape : public ::testing::TestWithParam<std::string> {};

std::unique_ptr<btCollisionShape> make_shape(const std::string& kind, btTransform& at,
                                             std::vector<std::unique_ptr<btCollisionShape>>& keep,
                                             std::unique_ptr<btTriangleMesh>& mesh) {
  at.setIdentity();
  if (kind == "plane") return std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0);
  if (kind == "box") {
    at.setOrigin(btVector3(0, -0.1, 0));
    return std::make_unique<btBoxShape>(btVector3(0.5, 0.1, 0.5));
  }
  if (kind == "sphere") {
    at.setOrigin(btVector3(0, -0.3, 0));
    return std::make_unique<btSphereShape>(0.3);
  }
  if (kind == "capsule") {
    at.setOrigin(btVector3(0, -0.1, 0));
    return std::make_unique<btCapsuleShapeX>(0.1, 0.6);
  }
  if (kind == "cylinder") {
    at.setOrigin(btVector3(0, -0.1, 0));
    return std::make_unique<btCylinderShape>(btVector3(0.3, 0.1, 0.3));
  }
  if (kind == "cone") {
    // A flat cone (10.6 degree slope, below the 16.7 degree friction angle): the sheet stays on its
    // apex instead of sliding off a steep one, which is physics, not a collision failure.
    at.setOrigin(btVector3(0, -0.075, 0));
    return std::make_unique<btConeShape>(0.8, 0.15);
  }
  if (kind == "convex_hull") {
    auto hull = std::make_unique<btConvexHullShape>();
    for (int i = 0; i < 8; ++i)
      hull->addPoint(btVector3(i & 1 ? 0.4 : -0.4, i & 2 ? 0.0 : -0.2, i & 4 ? 0.4 : -0.4), i == 7);
    hull->setMargin(0);
    return hull;
  }
  if (kind == "compound") {
    auto compound = std::make_unique<btCompoundShape>();
    keep.push_back(std::make_unique<btBoxShape>(btVector3(0.2, 0.1, 0.4)));
    btTransform left, right;
    left.setIdentity();
    right.setIdentity();
    left.setOrigin(btVector3(-0.2, -0.1, 0));
    right.setOrigin(btVector3(0.2, -0.1, 0.05));
    compound->addChildShape(left, keep.back().get());
    compound->addChildShape(right, keep.back().get());
    return compound;
  }
  // triangle mesh: a 2 m x 2 m square of two triangles at y = 0
  mesh = std::make_unique<btTriangleMesh>();
  mesh->addTriangle(btVector3(-1, 0, -1), btVector3(1, 0, -1), btVector3(1, 0, 1));
  mesh->addTriangle(btVector3(-1, 0, -1), btVector3(1, 0, 1), btVector3(-1, 0, 1));
  return std::make_unique<btBvhTriangleMeshShape>(mesh.get(), true);
}

TEST_P(ClothOnShape, RestsOnItWithoutPenetrating) {
  std::vector<std::unique_ptr<btCollisionShape>> parts;  // a compound's children, outliving the world
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at;
  std::unique_ptr<btTriangleMesh> mesh;
  std::unique_ptr<btCollisionShape> shape = make_shape(GetParam(), at, parts, mesh);
  btRigidBody ground(btRigidBody::btRigidBodyConstructionInfo(0, nullptr, shape.get()));
  ground.setWorldTransform(at);
  bw.world().addRigidBody(&ground);
  {
    bullet::CouplingSettings settings;
    settings.thickness = 0.01;
    bullet::Coupling coupling(&bw.world(), settings);
    System& s = coupling.system();
    scenes::ClothGridSettings c;
    c.nx = c.ny = 9;
    c.width = c.height = 0.6;
    c.mass = 0.1;
    c.origin = Vec3(-0.3, 0.15, -0.3);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();  // horizontal sheet
    c.stretch_stiffness = 30.0;
    c.stretch_damping = 0.02;
    c.bending_stiffness = 1e-5;
    scenes::add_cloth_grid(s, c);
    double lowest = kInfinity;
    for (int tick = 0; tick < 360; ++tick) {
      bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
      for (Index i = 0; i < s.particles().size(); ++i) {
        double phi;
        Vec3 n;
        if (bullet::signed_distance(shape.get(), at, s.particles().x.col(i), 1.0, phi, n))
          lowest = std::min(lowest, phi);
      }
    }
    EXPECT_GE(lowest, -1e-9) << GetParam();
    // It lies on the shape: the sheet's centre rests at the thickness from the surface, on top of it.
    const Vec3 centre = s.particles().x.col(4 * 9 + 4);
    double phi;
    Vec3 n;
    ASSERT_TRUE(bullet::signed_distance(shape.get(), at, centre, 1.0, phi, n));
    EXPECT_NEAR(phi, settings.thickness, 2e-3) << GetParam();
    EXPECT_GT(centre.y(), -0.01) << GetParam();
    EXPECT_TRUE(s.particles().x.allFinite());
  }
  bw.world().removeRigidBody(&ground);
}

INSTANTIATE_TEST_SUITE_P(EveryShape, ClothOnShape,
                         ::testing::Values("plane", "box", "sphere", "capsule", "cylinder", "cone", "convex_hull",
                                           "compound", "triangle_mesh"));

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// The coupling attaches to a Featherstone multibody world as well, with its ordinary rigid bodies as
// parents: a cloth hung from a free-falling box falls with it at g.
TEST(BulletCoupling, AttachesToAMultibodyWorld) {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher(&configuration);
  btDbvtBroadphase broadphase;
  btMultiBodyConstraintSolver solver;
  btMultiBodyDynamicsWorld world(&dispatcher, &broadphase, &solver, &configuration);
  world.setGravity(btVector3(0, -9.81, 0));
  btBoxShape shape(btVector3(0.3, 0.05, 0.05));
  btVector3 inertia;
  shape.calculateLocalInertia(1, inertia);
  btDefaultMotionState state(btTransform(btQuaternion::getIdentity(), btVector3(0, 1, 0)));
  btRigidBody box(btRigidBody::btRigidBodyConstructionInfo(1, &state, &shape, inertia));
  world.addRigidBody(&box);
  {
    bullet::CouplingSettings settings;
    settings.collisions = false;
    bullet::Coupling coupling(&world, settings);
    System& s = coupling.system();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 0.95, 0)));
    for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), &box);
    for (int i = 0; i < 60; ++i) world.stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    const double t = 0.25;
    EXPECT_NEAR(box.getCenterOfMassPosition().y(), 1.0 - 0.5 * 9.81 * t * t, 0.02);  // Bullet's symplectic Euler
    EXPECT_LT(s.max_hard_binding_drift(), 1e-12);
    EXPECT_TRUE(s.particles().x.allFinite());
  }
  world.removeRigidBody(&box);
}

// A cloth thrown at 5 m/s onto a 1 cm plate does not pass through it (0.02 m per tick > the plate).
TEST(BulletCoupling, FastClothDoesNotTunnelThroughAThinPlate) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = scenes::at(btVector3(0, 0.5, 0));
  add_box(bw, btVector3(0.6, 0.005, 0.6), 0.0, at);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.8, -0.25));
  c.down = Vec3::UnitZ();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (Index n : cloth.nodes) s.particles().v.col(n) = Vec3(0, -5, 0);
  for (int tick = 0; tick < 120; ++tick) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  EXPECT_GT(s.particles().x.row(1).minCoeff(), 0.5 + 0.005);  // every particle is still above the plate
}

// A 0.3 g node tied by a 1e10 N/m binding spring to a free-falling 50 g body. Bullet integrates the
// body's weight itself after the step; unless the step carries that weight and hands Bullet a velocity
// from which Bullet's own gravity impulse is taken out, Bullet moves the body g dt^2 (0.17 mm at
// 1/240 s) away from where the step left the spring's end, and the spring turns that into kilojoules.
// Both fall freely together: y = -g t^2 / 2, the spring carrying nothing but its ringing.
TEST(BulletCoupling, AStiffSpringOnAFreeFallingBodyFallsWithIt) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btTransform at = btTransform::getIdentity();
  btRigidBody* box = add_box(bw, btVector3(0.04, 0.04, 0.04), 0.05, at);
  bullet::CouplingSettings settings;
  settings.collisions = false;  // the node sits inside the box
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  const Index node = s.add_particle(Vec3::Zero(), Vec3::Zero(), 3e-4);
  coupling.attach(node, box, Vec3::Zero(), 1e10);
  for (int i = 0; i < 240; ++i) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const double fall = -0.5 * 9.81 * 1.0;
  EXPECT_NEAR(box->getCenterOfMassPosition().y(), fall, 1e-9);
  EXPECT_NEAR(s.particles().x(1, node), fall, 1e-9);
  EXPECT_NEAR(s.particles().v(1, node), -9.81, 1e-9);
}

// A ring on a Bullet slider along a static rod, with a node hanging 4 cm below its axis by a binding
// spring (a curtain's top row). The step holds the slider's rows, so Bullet has nothing left to correct:
// the ring stays exactly on the rod and the spring keeps its end where the step left it. An unaware step
// let the ring fall freely for a tick and Bullet then put it back on the rod, millimetres away from the
// node, which a stiff spring turns into an energy blow-up.
void run_node_on_a_slider_ring(double node_mass, double k, double& stretch, double& off_rod, double& along_rod,
                               double global_cfm = 0.0, double* gap = nullptr, double* relative_speed = nullptr,
                               bool settle = true, int from_frame = 0) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bw.world().getSolverInfo().m_globalCfm = btScalar(global_cfm);
  btTransform at = btTransform::getIdentity();
  btRigidBody* rod = add_box(bw, btVector3(1.0, 0.01, 0.01), 0.0, at);
  btRigidBody* ring = add_box(bw, btVector3(0.04, 0.04, 0.04), 0.05, at);
  ring->setLinearVelocity(btVector3(0.3, 0, 0));
  btSliderConstraint slider(*rod, *ring, btTransform::getIdentity(), btTransform::getIdentity(), true);
  slider.setLowerLinLimit(1);  // lower > upper: free along and about the rod
  slider.setUpperLinLimit(-1);
  slider.setLowerAngLimit(1);
  slider.setUpperAngLimit(-1);
  bw.world().addConstraint(&slider, true);
  bullet::CouplingSettings settings;
  settings.collisions = false;  // the node hangs inside the ring's box
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  const Vec3 lever(0, -0.04, 0);
  const Index node = s.add_particle(lever, Vec3(0.3, 0, 0.5), node_mass);
  const Index spring = coupling.attach(node, ring, lever, k);
  s.step_settings().settle_stiff_binding_springs = settle;
  stretch = off_rod = 0.0;
  if (gap) *gap = 0.0;
  if (relative_speed) *relative_speed = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
    if (frame < from_frame) continue;
    stretch = std::max(stretch, s.binding_spring_force(spring).norm() / k);
    // Where the spring's end on the ring is, and how fast it moves, on Bullet's final frame.
    const btTransform& frame_now = ring->getCenterOfMassTransform();
    const btVector3 point = frame_now * bullet::to_bullet(lever);
    const Vec3 point_velocity = bullet::to_eigen(ring->getVelocityInLocalPoint(point - frame_now.getOrigin()));
    if (gap) *gap = std::max(*gap, (s.particles().x.col(node) - bullet::to_eigen(point)).norm());
    if (relative_speed)
      *relative_speed = std::max(*relative_speed, (Vec3(s.particles().v.col(node)) - point_velocity).norm());
    const btVector3 c = ring->getCenterOfMassPosition();
    off_rod = std::max(off_rod, std::hypot(double(c.y()), double(c.z())));
  }
  along_rod = ring->getLinearVelocity().x();
  bw.world().removeConstraint(&slider);
}

TEST(BulletCoupling, AStiffSpringOnASliderRingHoldsWithTheSlider) {
  double stretch, off_rod, along_rod;
  run_node_on_a_slider_ring(3e-4, 1e10, stretch, off_rod, along_rod);
  EXPECT_LT(off_rod, 1e-9);
  EXPECT_LT(stretch, 1e-6);  // measured 1.9e-7: the spring's stiff mode ringing, not the weight's 3e-13 m
  EXPECT_NEAR(along_rod, 0.3, 1e-9) << "nothing acts along the rod";
}

// Bullet seeds the global CFM on a joint's first row only; a row is soft (Bullet's alone) when the joint
// gives it more than that. A small global CFM must not make the step drop the slider.
TEST(BulletCoupling, ASliderIsHeldWithAGlobalCfm) {
  double stretch, off_rod, along_rod;
  run_node_on_a_slider_ring(3e-4, 1e10, stretch, off_rod, along_rod, 1e-8);
  EXPECT_LT(off_rod, 1e-6);
  EXPECT_LT(stretch, 1e-6);
}

// One momentum path for collisions: a cloth thrown at a free dynamic box (no gravity) pushes it. When
// the box is a rigid-body particle of the system its impulses go through the step (the context's
// apply_body_impulse) and reach Bullet with the step's twist; when it is not, they are summed and
// handed to Bullet once per tick. Either way the box gains exactly what the cloth loses.
TEST(BulletCoupling, ClothHittingADynamicBodyConservesMomentumOnEitherPath) {
  for (const bool coupled : {true, false}) {
    BulletWorld bw(btVector3(0, 0, 0));
    btTransform at = scenes::at(btVector3(0, 0, 0));
    btRigidBody* box = add_box(bw, btVector3(0.5, 0.05, 0.5), 0.5, at);
    bullet::Coupling coupling(&bw.world());
    System& s = coupling.system();
    if (coupled) coupling.rigid_particle(box);
    scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.2, -0.25));
    c.down = Vec3::UnitZ();  // lying flat above the box
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
    for (Index node : cloth.nodes) s.particles().v.col(node) = Vec3(0.1, -2.0, 0.0);
    s.step_settings().cg_tolerance = 1e-13;  // the cloth's damping solves: momentum to round-off
    auto total_momentum = [&] {
      Vec3 p = Vec3::Zero();
      for (Index node : cloth.nodes) p += s.particles().mass[node] * s.particles().v.col(node);
      return Vec3(p + (1.0 / box->getInvMass()) * bullet::to_eigen(box->getLinearVelocity()));
    };
    s.finalize();
    const Vec3 p0 = total_momentum();
    double worst = 0.0;
    for (int frame = 0; frame < 30; ++frame) {
      bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
      worst = std::max(worst, (total_momentum() - p0).norm());
    }
    const std::string path = coupled ? "coupled" : "uncoupled";
    EXPECT_GT(coupling.deepest_penetration() + std::abs(box->getLinearVelocity().y()), 0.0) << path;
    EXPECT_LT(box->getLinearVelocity().y(), -0.1) << path << ": the cloth pushed the box";
    EXPECT_LT(worst, 1e-11) << path;
  }
}

// The pair inverse mass K at a lever r (body_point_inverse_mass, and BulletCollisions::
// bullet_point_inverse_mass reading the body) is how Bullet's body answers the two impulses sinew hands it
// for a contact there (applyCentralImpulse(j), applyTorqueImpulse(r x j)): dv(r) = K j, for a tilted
// body with partial linear and angular locks (Bullet scales the rows of I^-1 by the angular factor).
TEST(ContactImpulses, APointsInverseMassIsHowBulletsBodyAnswersAnImpulse) {
  BulletWorld bw(btVector3(0, 0, 0));
  const btTransform tilted(btQuaternion(btVector3(1, 2, 0.5).normalized(), 0.7), btVector3(0.3, 1, -0.2));
  btRigidBody* body = add_box(bw, btVector3(0.3, 0.05, 0.12), 2.0, tilted);
  const std::array<btVector3, 3> linear{btVector3(1, 1, 1), btVector3(1, 0, 1), btVector3(0.5, 1, 0)};
  const std::array<btVector3, 3> angular{btVector3(1, 1, 1), btVector3(0, 1, 0), btVector3(0.3, 1, 0.6)};
  const std::array<Vec3, 3> arms{Vec3(0.3, 0.05, -0.1), Vec3(-0.2, 0.1, 0.12), Vec3(0.01, -0.3, 0.2)};
  const std::array<Vec3, 2> impulses{Vec3(0.2, -1.0, 0.3), Vec3(-0.5, 0.1, 0.7)};
  for (std::size_t k = 0; k < linear.size(); ++k) {
    body->setLinearFactor(linear[k]);
    body->setAngularFactor(angular[k]);
    Mat3 inverse_inertia;  // I^-1 in world axes, its rows scaled by the angular factor
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        inverse_inertia(r, c) = angular[k][r] * static_cast<double>(body->getInvInertiaTensorWorld()[r][c]);
    for (const Vec3& r : arms) {
      const Mat3 K = bullet::body_point_inverse_mass(static_cast<double>(body->getInvMass()),
                                                     bullet::to_eigen(linear[k]), inverse_inertia, r);
      for (const Vec3& j : impulses) {
        body->setLinearVelocity(btVector3(0.1, -0.2, 0.3));
        body->setAngularVelocity(btVector3(-1, 0.5, 2));
        auto point_velocity = [&] { return bullet::to_eigen(body->getVelocityInLocalPoint(bullet::to_bullet(r))); };
        const Vec3 before = point_velocity();
        body->applyCentralImpulse(bullet::to_bullet(j));
        body->applyTorqueImpulse(bullet::to_bullet(r).cross(bullet::to_bullet(j)));
        EXPECT_LT((point_velocity() - before - K * j).norm(), 1e-12 * (K * j).norm() + 1e-15)
            << "locks " << k << ", lever " << r.transpose() << ", impulse " << j.transpose();
        // The step's own copy, read from the body.
        const Mat3 own = bullet::BulletCollisions::bullet_point_inverse_mass(body, bullet::to_bullet(r));
        EXPECT_LT((point_velocity() - before - own * j).norm(), 1e-12 * (K * j).norm() + 1e-15)
            << "bullet_point_inverse_mass, locks " << k;
      }
    }
  }
}

// The impulse between a point and a body of finite mass, on pair inverse masses K of a point and
// a body (symmetric: no partial locks): it never stops short of equal normal velocities before
// friction, its tangential part stays in Coulomb's cone mu j_n, it never adds kinetic energy
// (j . v_rel + j . K j / 2 <= 0), it is zero for a point that does not approach, and against an
// immovable body (K = I / m) it is stop_approach's change times m.
TEST(ContactImpulses, TheInelasticImpulseStopsTheApproachWithinCoulombsConeAndAddsNoEnergy) {
  const Mat3 tilt = Eigen::AngleAxisd(0.6, Vec3(0.3, 1, -0.4).normalized()).toRotationMatrix();
  const Mat3 inverse_inertia = tilt * Vec3(40, 7, 15).asDiagonal() * tilt.transpose();
  const double point_mass = 0.004;
  const std::array<Vec3, 4> velocities{Vec3(0.3, -1, 0.2), Vec3(2, -0.1, -1), Vec3(0, -0.5, 0), Vec3(0.5, 0.2, 0)};
  const Vec3 n = Vec3(0.1, 1, -0.2).normalized();
  for (const double body_mass : {0.01, 1.0, 1e3}) {
    for (const Vec3& r : {Vec3(0.2, -0.1, 0.05), Vec3(0, 0, 0)}) {
      const Mat3 K = Mat3::Identity() / point_mass +
                     bullet::body_point_inverse_mass(1.0 / body_mass, Vec3::Ones(), inverse_inertia, r);
      for (const double mu : {0.0, 0.3, 5.0}) {
        for (const Vec3& v : velocities) {
          const Vec3 j = bullet::inelastic_impulse(v, n, mu, K);
          if (!(n.dot(v) < 0.0)) {
            EXPECT_TRUE(j.isZero(0.0)) << "a point that does not approach";
            continue;
          }
          const double j_n = n.dot(j);
          EXPECT_GT(j_n, 0.0);
          const Vec3 j_t = j - j_n * n;
          EXPECT_LE(j_t.norm(), (mu + 1e-12) * j_n) << "outside the cone, mu " << mu;  // round-off in j_t
          const double gain = j.dot(v) + 0.5 * j.dot(K * j);
          EXPECT_LE(gain, 1e-12 * 0.5 * v.squaredNorm() / point_mass) << "mass " << body_mass << ", mu " << mu;
          // The normal part alone leaves the normal velocities equal.
          EXPECT_NEAR(n.dot(v + K * (j_n * n)), 0.0, 1e-12 * v.norm());
        }
      }
    }
  }
  // Against an immovable body: stop_approach's change of the point's velocity, times its mass.
  for (const double mu : {0.0, 0.3, 5.0})
    for (const Vec3& v : velocities) {
      const Vec3 v_body(0.1, -0.2, 0.05);
      const Vec3 j = bullet::inelastic_impulse(v - v_body, n, mu, Mat3::Identity() / point_mass);
      const Vec3 dv = bullet::stop_approach(v, v_body, n, mu) - v;
      EXPECT_LT((j - point_mass * dv).norm(), 1e-12 * point_mass * (1 + v.norm())) << "mu " << mu;
    }
}

// A light body Bullet alone moves landing on heavier particles: a 10 g box at 1 m/s onto a free cloth
// of 5.6 g nodes (no gravity). Each contact is an inelastic impact between a particle and the box as a
// body of its own mass, seeing the impulses of the contacts before it; stopping every particle's
// approach as if the box were immovable, the reactions summed onto its velocity at the step's start,
// raised the energy to 116 times the box's. The energy the user sees (kinetic of box and cloth, the
// cloth's elastic) never rises above the box's, and momentum is kept. (As a rigid-body particle of
// the system the box still meets each particle as if immovable: 5.5 times; see plugin/README.md.)
TEST(BulletCoupling, ALightBoxLandingOnHeavierParticlesGainsNoEnergy) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* box = add_box(bw, btVector3(0.1, 0.02, 0.1), 0.01, scenes::at(btVector3(0.01, 0.3, 0.02)));
  box->setLinearVelocity(btVector3(0, -1, 0));
  box->setActivationState(DISABLE_DEACTIVATION);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.2, -0.25));
  c.down = Vec3::UnitZ();  // lying flat under the box
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  s.step_settings().cg_tolerance = 1e-13;
  s.finalize();
  const double box_mass = 1.0 / static_cast<double>(box->getInvMass());
  auto box_energy = [&] {
    // The spin in the box's principal axes, where its inertia is diagonal.
    const Vec3 w = bullet::to_eigen(box->getAngularVelocity() * box->getCenterOfMassTransform().getBasis());
    const Vec3 inverse = bullet::to_eigen(box->getInvInertiaDiagLocal());
    double e = 0.5 * box_mass * bullet::to_eigen(box->getLinearVelocity()).squaredNorm();
    for (int k = 0; k < 3; ++k) e += 0.5 * w[k] * w[k] / inverse[k];
    return e;
  };
  auto momentum = [&] {
    Vec3 p = box_mass * bullet::to_eigen(box->getLinearVelocity());
    for (Index node : cloth.nodes) p += s.particles().mass[node] * s.particles().v.col(node);
    return p;
  };
  auto energy = [&] {
    double e = box_energy() + s.potential_energy();
    for (Index node : cloth.nodes) e += 0.5 * s.particles().mass[node] * s.particles().v.col(node).squaredNorm();
    return e;
  };
  const double e0 = energy();
  const Vec3 p0 = momentum();
  double highest = 0.0, worst_momentum = 0.0;
  for (int frame = 0; frame < 60; ++frame) {
    bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    highest = std::max(highest, energy());
    worst_momentum = std::max(worst_momentum, (momentum() - p0).norm());
  }
  EXPECT_GT(box->getLinearVelocity().y(), -0.9) << "the cloth slowed the box";
  EXPECT_LE(highest, e0 * (1 + 1e-6)) << "energy rose from " << e0 << " J to " << highest << " J";
  EXPECT_LT(worst_momentum, 1e-9);
}

// A box dropped on a cloth lying on the ground, at Bullet's default tick (one 1/60 s tick a frame):
// each node under the box is caught between the box and the ground, which Bullet keeps apart. Pushed
// out of one into the other at every step, the nodes threw the cloth about (a 5 kg box landing flat:
// diverged at step 74, nodes at 1600 m/s; a 1 kg box landing on an edge: the scene's energy 3.9 J ->
// 13.6 J). They follow the ground instead, squeezed under the box: the scene never gains energy, the
// box comes to rest on the ground and the cloth stays above it.
TEST(BulletCoupling, ABoxDroppedOnAClothOnTheGroundHoldsAtOneTick) {
  struct Case {
    double mass;
    btQuaternion tilt;
  };
  for (const Case& k : {Case{5.0, btQuaternion::getIdentity()}, Case{1.0, btQuaternion(0.1, 0.2, 0.0)}}) {
    BulletWorld bw(btVector3(0, -9.81, 0));
    add_box(bw, btVector3(5, 0.5, 5), 0.0, scenes::at(btVector3(0, -0.5, 0)));
    btRigidBody* box = add_box(bw, btVector3(0.15, 0.1, 0.15), k.mass, btTransform(k.tilt, btVector3(0.05, 0.4, 0.02)));
    bullet::Coupling coupling(&bw.world());
    System& s = coupling.system();
    scenes::ClothGridSettings c;  // a user's cloth: the builder's defaults
    c.nx = c.ny = 21;
    c.width = c.height = 1.0;
    c.mass = 0.2;
    c.origin = Vec3(-0.5, 0.011, -0.5);
    c.down = Vec3::UnitZ();
    scenes::add_cloth_grid(s, c);
    auto energy = [&] { return body_energy(box) + s.kinetic_energy() + s.potential_energy(); };
    // The reference: the energy at the last frame before the box comes within 3 cm of the cloth (Bullet's
    // free fall itself loses a little at each tick, which would hide a gain from the first frame's).
    double before = 0.0, highest = 0.0;
    for (int frame = 0; frame < 1000; ++frame) {
      ASSERT_NO_THROW(bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60))) << "frame " << frame;
      if (lowest_point(box) > 0.021 + 0.03) before = energy();
      else highest = std::max(highest, energy());
    }
    // The 1 kg box landing on its edge still rises 0.16% (6 mJ) above it for a moment (written down).
    EXPECT_LE(highest, before * (1 + 2e-3))
        << k.mass << " kg: energy rose from " << before << " J to " << highest << " J";
    std::cout << k.mass << " kg: energy before the landing " << before << " J, highest after " << highest
              << " J; the cloth's kinetic energy at the end " << s.kinetic_energy() << " J\n";
    EXPECT_NEAR(box->getCenterOfMassPosition().y(), 0.1, 0.01) << k.mass << " kg: the box rests on the ground";
    EXPECT_GT(s.particles().x.row(1).minCoeff(), 0.0) << k.mass << " kg: the cloth stays above the ground";
    // Zero for the 5 kg box (the cloth sleeps); not yet for the 1 kg one (0.031 J after 1000 frames): a
    // node wedged against the box's side near its foot keeps a reported speed of 5 m/s while it barely
    // moves (written down).
    EXPECT_LT(s.kinetic_energy(), 0.05) << k.mass << " kg: the cloth is nearly at rest";
  }
}

// The same cloth on a 20 kg dynamic table, a box dropped on it: the nodes caught between the two
// bodies are pushed out of the nearer, as before (following the table instead, the corner and edge
// pass pushed the cloth's faces out of the box into the table at every step and the cloth diverged at
// 4 ticks a frame with either box). Energy never above its start at 4 ticks a frame.
TEST(BulletCoupling, ABoxDroppedOnAClothOnADynamicTableHoldsAtFourTicks) {
  for (const double mass : {1.0, 5.0}) {
    BulletWorld bw(btVector3(0, -9.81, 0));
    add_box(bw, btVector3(5, 0.5, 5), 0.0, scenes::at(btVector3(0, -0.5, 0)));
    btRigidBody* table = add_box(bw, btVector3(0.6, 0.1, 0.6), 20.0, scenes::at(btVector3(0, 0.1, 0)));
    btRigidBody* box = add_box(bw, btVector3(0.15, 0.1, 0.15), mass,
                               btTransform(btQuaternion(0.1, 0.2, 0.0), btVector3(0.05, 0.6, 0.02)));
    bullet::Coupling coupling(&bw.world());
    System& s = coupling.system();
    scenes::ClothGridSettings c;
    c.nx = c.ny = 21;
    c.width = c.height = 1.0;
    c.mass = 0.2;
    c.origin = Vec3(-0.5, 0.211, -0.5);
    c.down = Vec3::UnitZ();
    scenes::add_cloth_grid(s, c);
    auto energy = [&] { return body_energy(box) + body_energy(table) + s.kinetic_energy() + s.potential_energy(); };
    double before = 0.0, highest = 0.0;  // as in the test above
    for (int frame = 0; frame < 180; ++frame) {
      ASSERT_NO_THROW(bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240))) << "frame " << frame;
      if (lowest_point(box) > 0.221 + 0.03) before = energy();
      else highest = std::max(highest, energy());
    }
    EXPECT_LE(highest, before * (1 + 1e-3))
        << mass << " kg: energy rose from " << before << " J to " << highest << " J";
    EXPECT_NEAR(box->getCenterOfMassPosition().y(), 0.3, 0.01) << mass << " kg: the box rests on the table";
  }
}

// A cloth dropped on a crate that stands against a static wall: the nodes that land on the crate's top
// within the thickness of the wall are inside a body Bullet alone moves and touch a static object, but
// they came in through the top, which does not face the wall: they are pushed out through the top,
// and none ends inside the crate. (A guard for the caught-node rule; the looser rule of 63f8320, which
// did not ask how a node came in, passes it too.)
TEST(BulletCoupling, AClothDroppedOnACrateAgainstAWallStaysOnTheCrate) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  add_box(bw, btVector3(5, 0.5, 5), 0.0, scenes::at(btVector3(0, -0.5, 0)));
  add_box(bw, btVector3(0.05, 1.0, 1.0), 0.0, scenes::at(btVector3(0.35, 1.0, 0)));  // wall face at x = 0.3
  btRigidBody* crate = add_box(bw, btVector3(0.2, 0.15, 0.2), 2.0, scenes::at(btVector3(0.1, 0.15, 0)));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c;
  c.nx = c.ny = 15;
  c.width = c.height = 0.3;
  c.mass = 0.05;
  c.origin = Vec3(-0.005, 0.6, -0.15);  // on the crate's top, its last column 5 mm from the wall's face
  c.down = Vec3::UnitZ();
  scenes::add_cloth_grid(s, c);
  double deepest = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    ASSERT_NO_THROW(bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60))) << "frame " << frame;
    for (Index i = 0; i < s.particles().size(); ++i) {
      double phi;
      Vec3 n;
      if (bullet::signed_distance(crate->getCollisionShape(), crate->getCenterOfMassTransform(), s.particles().x.col(i),
                                  1.0, phi, n))
        deepest = std::max(deepest, -phi);
    }
  }
  std::cout << "deepest node inside the crate " << deepest << " m\n";
  EXPECT_LT(deepest, 0.01) << "a node sank into the crate";
  EXPECT_GT(s.particles().x.row(1).maxCoeff(), 0.3) << "the cloth lies on the crate";
}

// Per-particle collision filters follow Bullet's convention: a particle meets an object only when each
// one's group is in the other's mask. A cloth whose mask leaves out static objects falls through a
// static ground that a default cloth rests on.
TEST(BulletCoupling, CollisionFiltersFollowBulletsGroupsAndMasks) {
  for (const bool filtered : {false, true}) {
    BulletWorld bw(btVector3(0, -9.81, 0));
    btTransform at = scenes::at(btVector3(0, -0.05, 0));
    bw.add_body(bw.keep(std::make_unique<btBoxShape>(btVector3(2, 0.05, 2))), 0.0, at, btVector3(0, 0, 0),
                btBroadphaseProxy::StaticFilter, btBroadphaseProxy::AllFilter ^ btBroadphaseProxy::StaticFilter);
    bullet::Coupling coupling(&bw.world());
    System& s = coupling.system();
    scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.1, -0.25));
    c.down = Vec3::UnitZ();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
    if (filtered)
      for (Index node : cloth.nodes)
        s.set_collision_filter(node, btBroadphaseProxy::DefaultFilter,
                               btBroadphaseProxy::AllFilter ^ btBroadphaseProxy::StaticFilter);
    for (int frame = 0; frame < 60; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    const double lowest = s.particles().x.row(1).minCoeff();
    if (filtered) {
      EXPECT_LT(lowest, -1.0) << "the filtered cloth fell through the ground";
    } else {
      EXPECT_GT(lowest, 0.0) << "the default cloth rests on the ground";
    }
  }
}

// The world as the application changes it between ticks: gravity is read at every tick (a cloth falls
// again once gravity is switched back on), and an object with CF_NO_CONTACT_RESPONSE, which Bullet
// reports contacts for but resolves none, does not stop the cloth either.
TEST(BulletCoupling, FollowsTheWorldsGravityAndContactResponseFlags) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* sensor = add_box(bw, btVector3(2, 0.05, 2), 0.0, scenes::at(btVector3(0, -0.05, 0)));
  sensor->setCollisionFlags(sensor->getCollisionFlags() | btCollisionObject::CF_NO_CONTACT_RESPONSE);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.5, -0.25));
  c.down = Vec3::UnitZ();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (int frame = 0; frame < 30; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
  EXPECT_NEAR(s.particles().x(1, cloth.node(0, 0)), 0.5, 1e-12) << "no gravity: the cloth stays";
  bw.world().setGravity(btVector3(0, -9.81, 0));
  for (int frame = 0; frame < 60; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
  EXPECT_LT(s.particles().x.row(1).maxCoeff(), -1.0) << "it fell through the sensor box";
}

// A tick that throws leaves the world usable: the cloth where it was before the call, and Bullet's
// gathered forces cleared, so the next call does not apply gravity twice (a free-falling sphere gains
// exactly g dt per frame after the failed call, as before it).
TEST(BulletCoupling, AFailedTickLeavesTheStateOfItsStartAndTheWorldUsable) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btRigidBody* sphere = bw.add_body(bw.keep(std::make_unique<btSphereShape>(0.2)), 1.0, scenes::at(btVector3(3, 5, 0)));
  sphere->setActivationState(DISABLE_DEACTIVATION);
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::add_cloth_grid(s, small_cloth(Vec3(-0.25, 1.0, 0)));
  bool fail_now = false;
  s.add_collision_source(make_collision_source("failing", [&](CollisionContext&) {
    if (fail_now) fail("the source failed");
  }));
  for (int frame = 0; frame < 5; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
  const std::uint64_t cloth_before = s.state_hash();
  const double vy_before = sphere->getLinearVelocity().y();
  fail_now = true;
  EXPECT_THROW(bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60)), Error);
  EXPECT_EQ(s.state_hash(), cloth_before);
  fail_now = false;
  bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
  EXPECT_NEAR(sphere->getLinearVelocity().y() - vy_before, -9.81 / 60, 1e-9) << "gravity once";
  EXPECT_TRUE(s.particles().x.allFinite());
}

// A node heavier than its ring (0.1 kg on 0.05 kg, whose rotation about the rod it then dominates) on a
// spring of 1e10 N/m at the ring's 4 cm lever, at one 1/60 s tick: the spring holds the node on its
// point along the arc the ring turns through (the step moves bound points along their chords).
TEST(BulletCoupling, AStiffSpringHoldsANodeHeavierThanItsRing) {
  double stretch, off_rod, along_rod, gap, relative_speed;
  run_node_on_a_slider_ring(0.1, 1e10, stretch, off_rod, along_rod, 0.0, &gap, &relative_speed);
  // Within a micrometre, as the light node on the same ring (measured: 4e-10 m after a tick, growing by
  // about 3e-10 m a tick to 4e-8 m after 2 s whatever the CG tolerance; m g / k is 1e-10 m).
  EXPECT_LT(gap, 1e-6);
  EXPECT_LT(off_rod, 1e-9);
}

// In the same scene the ends' velocities at the end of each tick agree too. The step's end velocity
// v^{n+1} = 2 v~^{n+1/2} - v~^n keeps a stiff mode's velocity error and flips its sign each step (the
// trapezoidal rule damps nothing at k dt^2 / m >> 1), so without StepSettings::
// settle_stiff_binding_springs the ends kept the 0.5 m/s the node started with relative to its point,
// alternating in sign (the ring's spin read 18, 0.8, 16, 3 rad/s ...), and the spring's force reading
// was 1.3e4 N where the weight is 1 N. Settled, the relative speed falls below 1e-3 m/s within a few
// ticks (the slider's projection and the settling alternate) and the reading is the weight's.
TEST(BulletCoupling, AStiffSpringsEndsMoveTogetherAtTheEndOfEachTick) {
  for (const bool settle : {false, true}) {
    double stretch, off_rod, along_rod, gap, relative_speed;
    run_node_on_a_slider_ring(0.1, 1e10, stretch, off_rod, along_rod, 0.0, &gap, &relative_speed, settle, 10);
    if (!settle) {
      EXPECT_GT(relative_speed, 0.1) << "the ringing this guards against is gone without the settling";
      continue;
    }
    EXPECT_LT(relative_speed, 1e-3);
    EXPECT_LT(stretch, 1e-6);
  }
}

// A cloth bound to a hub spun far faster than a tick resolves: Bullet turns a body by at most pi/4
// per step, so the step turns the hub's particle and the points on it by no more (it used to take
// the full dt |w|, and past |w| dt = pi handed Bullet a turn the other way: 800 rad/s at 1/240 s
// exploded, energy x 3e42 at 1e4 rad/s). The cloth stays on its frame, finite and within reach.
class SpinningHub : public ::testing::TestWithParam<double> {};

TEST_P(SpinningHub, ClothFollowsWhateverTurnBulletMakes) {
  const double spin = GetParam();
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* hub = add_box(bw, btVector3(0.1, 0.1, 0.1), 2.0, btTransform::getIdentity());
  hub->setAngularVelocity(btVector3(0, btScalar(spin), 0));
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(0.0, 0.05, -0.25));
  c.across = Vec3::UnitZ();
  c.down = Vec3::UnitX();
  c.stretch_stiffness = 5e4;  // the hub turns pi/4 per tick (188 rad/s): a centripetal load of 2e4 m/s^2
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (int i = 0; i < 6; ++i) coupling.bind_here(cloth.node(i, 0), hub);
  double drift = 0.0, reach = 0.0;
  for (int tick = 0; tick < 120; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    drift = std::max(drift, s.max_hard_binding_drift());
    const btVector3 centre = hub->getCenterOfMassPosition();
    for (Index n : cloth.nodes) reach = std::max(reach, (s.particles().x.col(n) - bullet::to_eigen(centre)).norm());
  }
  EXPECT_TRUE(s.particles().x.allFinite() && s.particles().v.allFinite()) << spin << " rad/s";
  // The points on the hub are where Bullet has it, to round-off (the step hands over its own turn).
  EXPECT_LT(drift, 1e-9) << spin << " rad/s";
  // Outer corners start hypot(0.5, 0.25) = 0.56 m out; whipped round at 188 rad/s (2e4 m/s^2 at the
  // tip) the flag stretches (to 1.07 m at 1e4 rad/s, where the hub keeps its spin longest), it does
  // not fly off.
  EXPECT_LT(reach, 1.5) << spin << " rad/s";
}

INSTANTIATE_TEST_SUITE_P(RadPerSecond, SpinningHub, ::testing::Values(100.0, 700.0, 800.0, 1e4));

// The issue's chain through the plugin: 20 capsules of 0.1 kg joined only by binding springs between
// points on neighbouring bodies, the first hung from a static body, released horizontal, one 1/60 s
// tick per frame. The joints used to pass 1 mm by frame 14 and reach 1e43 m; they hold within 1 mm
// (or what the chain's weight stretches a soft one by), and the chain's visible energy (Bullet's kinetic plus gravity)
// never rises above its start. `touching`: the first capsule also rests against its support, a contact Bullet resolves
// after the step, which the step does not know; Bullet then moves that capsule off the step's update (7e-6 m in the
// first tick, growing) and the joints open by centimetres. That case is still open (issue 19: contacts of coupled
// bodies in the step), and disabled. It also conflicts by construction: the first joint sits at the capsule's tip, on
// the support's face, so the capsule's rounded end enters the support as the rod turns about the joint (by up to its
// radius, 1 cm, at a quarter turn). A solve that held the contact and the joint exactly would still open the joint by
// that much, so its 1 mm bound cannot hold; a chain draped over a ledge tests the contacts without the conflict.
void run_capsule_chain(double k, bool touching) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  const double length = 0.1, radius = 0.01;
  btCollisionShape* capsule =
      bw.keep(std::make_unique<btCapsuleShapeX>(btScalar(radius), btScalar(length - 2 * radius)));
  btRigidBody* support = add_box(bw, btVector3(0.02, 0.02, 0.02), 0.0, scenes::at(btVector3(-0.02, 0, 0)));
  const int links = 20, group = 2;
  const int mask = touching ? btBroadphaseProxy::AllFilter ^ group : 0;
  std::vector<btRigidBody*> rods;
  for (int i = 0; i < links; ++i) {
    btRigidBody* rod = bw.add_body(capsule, 0.1, scenes::at(btVector3(btScalar((i + 0.5) * length), 0, 0)),
                                   btVector3(0, 0, 0), group, mask);
    rod->setActivationState(DISABLE_DEACTIVATION);
    rods.push_back(rod);
  }
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  coupling.attach(coupling.add_body_point(support, Vec3(0.02, 0, 0)), rods[0], Vec3(-0.5 * length, 0, 0), k);
  for (int i = 1; i < links; ++i)
    coupling.attach(coupling.add_body_point(rods[i - 1], Vec3(0.5 * length, 0, 0)), rods[i], Vec3(-0.5 * length, 0, 0),
                    k);
  const double start = bw.rigid_energy();
  double gain = -kInfinity, gap = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    bw.world().stepSimulation(btScalar(1.0 / 60), 1, btScalar(1.0 / 60));
    gain = std::max(gain, bw.rigid_energy() - start);
    gap = std::max(gap, s.binding_springs().max_stretch(s.particles().x));
  }
  // The chain's m g L is 20 x 0.1 x 9.81 x 1 m ~ 20 J; a trace of it is allowed.
  EXPECT_LT(gain, 2e-3) << "k = " << k;
  // The first joint carries the chain's weight W = 19.6 N: statically W / k, swinging a few times it.
  EXPECT_LT(gap, std::max(1e-3, 5.0 * 20 * 0.1 * 9.81 / k)) << "k = " << k;
}

class CapsuleChain : public ::testing::TestWithParam<double> {};

TEST_P(CapsuleChain, HoldsAtOneTickPerFrame) { run_capsule_chain(GetParam(), false); }

TEST_P(CapsuleChain, DISABLED_HoldsAtOneTickPerFrameAgainstItsSupport) { run_capsule_chain(GetParam(), true); }

INSTANTIATE_TEST_SUITE_P(Stiffness, CapsuleChain, ::testing::Values(1e3, 1e6, 1e9, 1e12));

// ---- Teleports: the application moves a coupled body between ticks ------------------------------------

// What an application does to put a body somewhere else at once: its frame, Bullet's interpolation
// frame (so that Bullet sees no sweep) and its motion state, all moved by `move` (world to world).
void teleport(btRigidBody* body, const btTransform& move) {
  const btTransform to = move * body->getWorldTransform();
  body->setWorldTransform(to);
  body->setInterpolationWorldTransform(to);
  if (body->getMotionState()) body->getMotionState()->setWorldTransform(to);
}

// A 10x10 cloth hanging from a spinning box by its top row: hard-bound, or tied by binding springs
// (k 1e4), to a dynamic or static box. Gravity along -y, no collisions (the top row starts on the
// box's face).
struct HangingCloth {
  enum class Tie { hard, spring };
  BulletWorld bw{btVector3(0, -9.81, 0)};
  btRigidBody* box = nullptr;
  std::unique_ptr<bullet::Coupling> coupling;
  scenes::ClothGrid cloth;

  HangingCloth(Tie tie, bool dynamic, bool kinematic = false) {
    box = add_box(bw, btVector3(0.5, 0.05, 0.05), dynamic ? 2.0 : 0.0, scenes::at(btVector3(0, 1.0, 0)));
    if (kinematic) {
      // Bullet animates a kinematic body only if it was one when added to the world.
      bw.world().removeRigidBody(box);
      box->setCollisionFlags((box->getCollisionFlags() & ~btCollisionObject::CF_STATIC_OBJECT) |
                             btCollisionObject::CF_KINEMATIC_OBJECT);
      bw.world().addRigidBody(box);
    }
    if (dynamic) {
      box->setLinearVelocity(btVector3(0.3, 0.0, 0.1));
      box->setAngularVelocity(btVector3(0, 2.0, 0));
    }
    bullet::CouplingSettings settings;
    settings.collisions = false;
    coupling = std::make_unique<bullet::Coupling>(&bw.world(), settings);
    System& s = coupling->system();
    s.step_settings().cg_tolerance = 1e-12;
    s.step_settings().automatic = false;
    scenes::ClothGridSettings c = small_cloth(Vec3(-0.45, 0.95, 0));
    c.nx = c.ny = 10;
    c.width = c.height = 0.9;
    c.stretch_stiffness = 500.0;
    cloth = scenes::add_cloth_grid(s, c);
    if (!kinematic) {  // swinging round the box's axis: a motion to carry
      for (Index n : cloth.nodes) s.particles().v.col(n) = Vec3(0, 2.0, 0).cross(Vec3(s.particles().x.col(n)));
    }
    const btTransform& frame = box->getCenterOfMassTransform();
    for (int i = 0; i < 10; ++i) {
      const Index n = cloth.node(i, 0);
      if (tie == Tie::hard) {
        coupling->bind_here(n, box);
      } else {
        coupling->attach(n, box, bullet::to_eigen(frame.invXform(bullet::to_bullet(s.particles().x.col(n)))), 1e4);
      }
    }
  }
  System& system() { return coupling->system(); }
  void frame() { bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240)); }
  // Kinetic energy of the cloth's nodes (the box's, with the mass bound to it, is Bullet's).
  double cloth_kinetic_energy() {
    double e = 0.0;
    for (Index n : cloth.nodes)
      if (system().particles().kind[n] != ParticleKind::hard_bound)
        e += 0.5 * system().particles().mass[n] * system().particles().v.col(n).squaredNorm();
    return e;
  }
  // The fastest node relative to the box's centre of mass.
  double max_cloth_speed() {
    const Vec3 v_box = bullet::to_eigen(box->getLinearVelocity());
    double speed = 0.0;
    for (Index n : cloth.nodes) speed = std::max(speed, (Vec3(system().particles().v.col(n)) - v_box).norm());
    return speed;
  }
};

// The physics does not care where the scene is: with gravity along the turn's axis, the run whose box
// the application moves by a rigid transform T (turning its velocities with it) must be the run left
// alone, moved by T, to the solves' round-off: every node at T x, moving with R v, the cloth's kinetic
// energy the same. (Before, the bound row jumped 100 m with the box and the rest of the cloth stayed:
// a frame later the cloth moved at 4e4 m/s, 1.4e7 J of kinetic energy where the run left alone had 1 J.)
void run_carried_by_teleport(HangingCloth::Tie tie, bool dynamic) {
  const std::string what = std::string(tie == HangingCloth::Tie::hard ? "hard-bound" : "tied by springs") +
                           (dynamic ? ", dynamic box" : ", static box");
  HangingCloth left_alone(tie, dynamic), moved(tie, dynamic);
  const btTransform move(btQuaternion(btVector3(0, 1, 0), btScalar(0.5 * 3.14159265358979323846)),
                         btVector3(100, 0, -40));
  const Mat3 R = bullet::to_eigen(move.getRotation()).toRotationMatrix();
  const Vec3 t = bullet::to_eigen(move.getOrigin());
  for (int frame = 0; frame < 20; ++frame) {
    left_alone.frame();
    moved.frame();
  }
  const double energy_before = moved.cloth_kinetic_energy();
  ASSERT_GT(energy_before, 1e-3) << what;  // the cloth is swinging: a velocity to carry
  teleport(moved.box, move);
  // The application turns the box's velocities with it (set between ticks: taken in as they are).
  moved.box->setLinearVelocity(move.getBasis() * moved.box->getLinearVelocity());
  moved.box->setAngularVelocity(move.getBasis() * moved.box->getAngularVelocity());
  auto compare = [&](int frame, double tolerance) {
    const System& a = left_alone.system();
    const System& b = moved.system();
    double dx = 0.0, dv = 0.0;
    for (Index n : moved.cloth.nodes) {
      dx = std::max(dx, (Vec3(b.particles().x.col(n)) - (R * a.particles().x.col(n) + t)).norm());
      dv = std::max(dv, (Vec3(b.particles().v.col(n)) - R * a.particles().v.col(n)).norm());
    }
    const btTransform expected_box = move * left_alone.box->getCenterOfMassTransform();
    const double box_off =
        (bullet::to_eigen(moved.box->getCenterOfMassPosition()) - bullet::to_eigen(expected_box.getOrigin())).norm();
    EXPECT_LT(box_off, tolerance) << what << ", frame " << frame;
    EXPECT_LT(dx, tolerance) << what << ", frame " << frame;
    EXPECT_LT(dv, tolerance) << what << ", frame " << frame;
    EXPECT_NEAR(moved.cloth_kinetic_energy(), left_alone.cloth_kinetic_energy(),
                tolerance * (1.0 + left_alone.cloth_kinetic_energy()))
        << what << ", frame " << frame;
  };
  left_alone.frame();
  moved.frame();
  compare(21, 1e-8);
  for (int frame = 22; frame < 60; ++frame) {
    left_alone.frame();
    moved.frame();
  }
  compare(60, 1e-6);
  // A few hundred frames on: finite and as lively as the cloth left alone.
  // (The two runs part by round-off, which the swinging cloth amplifies: compared by how fast the cloth
  // moves relative to its box, the free fall taken out.)
  double fastest = 0.0, fastest_alone = 0.0;
  for (int frame = 60; frame < 200; ++frame) {
    left_alone.frame();
    moved.frame();
    fastest = std::max(fastest, moved.max_cloth_speed());
    fastest_alone = std::max(fastest_alone, left_alone.max_cloth_speed());
  }
  EXPECT_TRUE(moved.system().particles().x.allFinite() && moved.system().particles().v.allFinite()) << what;
  EXPECT_LT(fastest, 2.0 * fastest_alone + 0.1) << what;
}

TEST(Teleport, ClothHardBoundToADynamicBodyIsCarriedWithIt) { run_carried_by_teleport(HangingCloth::Tie::hard, true); }

TEST(Teleport, ClothTiedToADynamicBodyBySpringsIsCarriedWithIt) {
  run_carried_by_teleport(HangingCloth::Tie::spring, true);
}

TEST(Teleport, ClothOnAStaticBodyIsCarriedWithIt) {
  run_carried_by_teleport(HangingCloth::Tie::hard, false);
  run_carried_by_teleport(HangingCloth::Tie::spring, false);
}

// A kinematic body animated through its motion state moves between ticks as Bullet moves it, and that
// is prescribed motion, not a teleport: the cloth bound to it sweeps with it (its bound row on the
// body, the rest trailing behind and taking up the motion), it is not carried rigidly.
TEST(Teleport, AKinematicBodyAnimatedByItsMotionStateSweepsTheCloth) {
  HangingCloth scene(HangingCloth::Tie::hard, false, true);
  btRigidBody* rod = scene.box;
  System& s = scene.system();
  for (int frame = 0; frame < 30; ++frame) scene.frame();  // settle
  // Each node where it is in the rod's frame, and the cloth's centre.
  auto in_rod_frame = [&] {
    Vectors3 local(3, static_cast<Index>(scene.cloth.nodes.size()));
    for (std::size_t k = 0; k < scene.cloth.nodes.size(); ++k)
      local.col(static_cast<Index>(k)) = bullet::to_eigen(
          rod->getCenterOfMassTransform().invXform(bullet::to_bullet(Vec3(s.particles().x.col(scene.cloth.nodes[k])))));
    return local;
  };
  auto centre = [&] {
    Vec3 sum = Vec3::Zero();
    for (Index n : scene.cloth.nodes) sum += s.particles().x.col(n);
    return Vec3(sum / static_cast<double>(scene.cloth.nodes.size()));
  };
  const Vectors3 local_before = in_rod_frame();
  const Vec3 centre_before = centre();
  btTransform to = rod->getCenterOfMassTransform();
  const int frames = 6;
  const double speed = 3.0;  // [m/s] along x
  for (int frame = 0; frame < frames; ++frame) {
    to.setOrigin(to.getOrigin() + btVector3(btScalar(speed / 60.0), 0, 0));
    rod->getMotionState()->setWorldTransform(to);
    scene.frame();
    // The bound row is on the rod where Bullet has it at the end of every frame.
    const btTransform& frame_now = rod->getCenterOfMassTransform();
    for (Index k = 0; k < s.hard_bindings().rigid_count(); ++k) {
      const Vec3 expected =
          bullet::to_eigen(frame_now * bullet::to_bullet(Vec3(s.hard_bindings().rigid_offset_body(k))));
      EXPECT_LT((Vec3(s.particles().x.col(s.hard_bindings().rigid_particle(k))) - expected).norm(), 1e-9);
    }
  }
  const double moved = speed * frames / 60.0;
  EXPECT_NEAR(rod->getCenterOfMassPosition().x(), moved, 1e-9);
  // The cloth came along, pulled by its bound row (its centre moved the same way, by a fair part of the
  // rod's move), but not as a rigid piece: it changed shape on the rod by centimetres.
  const double came = centre().x() - centre_before.x();
  EXPECT_GT(came, 0.2 * moved);
  EXPECT_LT(came, 2.0 * moved);
  EXPECT_GT((in_rod_frame() - local_before).colwise().norm().maxCoeff(), 0.01);
  EXPECT_TRUE(s.particles().x.allFinite() && s.particles().v.allFinite());
}

// A cloth tied to two bodies, one of which the application moves 100 m (turning it a quarter turn): no
// rigid transform carries both ties, so the cloth stays and its ties to the moved body, a binding
// spring (k 1e4) or its hard-bound column, are stretched by the move. What follows is bounded by the
// energy that stretch gave: no gravity, and the implicit, critically damped springs and the cloth's
// damping only take energy away.
void run_tied_to_a_moved_and_a_still_body(bool hard_on_moved, bool still_is_dynamic, int frames) {
  const std::string what = std::string(hard_on_moved ? "hard-bound" : "tied by a spring") + " to the moved body, " +
                           (still_is_dynamic ? "still body dynamic" : "still body static");
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* moved = add_box(bw, btVector3(0.05, 0.05, 0.05), 2.0, scenes::at(btVector3(-0.5, 1.0, 0)));
  btRigidBody* still =
      add_box(bw, btVector3(0.05, 0.05, 0.05), still_is_dynamic ? 2.0 : 0.0, scenes::at(btVector3(0.5, 1.0, 0)));
  bullet::CouplingSettings settings;
  settings.collisions = false;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.45, 0.95, 0));
  c.nx = c.ny = 10;
  c.width = c.height = 0.9;
  c.stretch_stiffness = 500.0;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  auto local = [&](btRigidBody* body, Index n) {
    return bullet::to_eigen(body->getCenterOfMassTransform().invXform(bullet::to_bullet(Vec3(s.particles().x.col(n)))));
  };
  std::vector<Index> on_moved;  // the particles that go with the moved body: bound nodes or spring ends
  for (int j = 0; j < 3; ++j) {
    const Index left = cloth.node(0, j), right = cloth.node(9, j);
    if (hard_on_moved) {
      coupling.bind_here(left, moved);
      on_moved.push_back(left);
    } else {
      const Index spring = coupling.attach(left, moved, local(moved, left), 1e4);
      on_moved.push_back(s.binding_springs().b(spring));
    }
    coupling.attach(right, still, local(still, right), 1e4);
  }
  auto energy = [&] { return s.kinetic_energy() + s.potential_energy(); };
  for (int frame = 0; frame < 10; ++frame) bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
  const btTransform move(btQuaternion(btVector3(0, 0, 1), btScalar(0.5 * 3.14159265358979323846)),
                         btVector3(100, 0, 0));
  // The energy the move gives: the elastic and spring energy with those particles moved with the body.
  const double before = energy();
  const Vectors3 x_before = s.particles().x;
  for (Index p : on_moved)
    s.particles().x.col(p) = bullet::to_eigen(move * bullet::to_bullet(Vec3(s.particles().x.col(p))));
  const double given = energy() - before;
  s.particles().x = x_before;
  teleport(moved, move);
  double worst = -kInfinity;
  for (int frame = 0; frame < frames; ++frame) {
    bw.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    ASSERT_TRUE(s.particles().x.allFinite() && s.particles().v.allFinite()) << what << ", frame " << frame;
    worst = std::max(worst, energy());
  }
  EXPECT_GT(given, 1e6) << what;  // k/2 (100 m)^2 a stretched spring or edge, about
  EXPECT_LE(worst, before + given * (1.0 + 1e-6)) << what;
}

TEST(Teleport, ClothTiedToAMovedBodyAndAStaticOneStaysBounded) {
  run_tied_to_a_moved_and_a_still_body(false, false, 120);
  run_tied_to_a_moved_and_a_still_body(true, false, 120);
}

// Between two dynamic boxes of 2 kg the stretch's 1e8 J spins both at 3000-4500 rad/s: explicit frames
// then take substeps that turn them at most System::kMaxExplicitTurn (at the stable count, 2.8 rad a
// substep, the energy grew 1.45 times a frame), implicit ones are bounded by the turn.
TEST(Teleport, ClothTiedToAMovedBodyAndAStillDynamicOneStaysBounded) {
  run_tied_to_a_moved_and_a_still_body(false, true, 240);
}

// ---- the scheme System::advance chooses, and collisions at the bodies' step poses ----------------

namespace spinning {

// A cloth hard-bound by its top row to a Bullet box spinning (and tumbling) in the air, no gravity,
// nothing else: a passive scene, so the visible energy (the box with the bound mass, the cloth's
// motion and its elastic energy) never rises above its value after the first frame.
struct Run {
  double worst_gain = 0.0;  // largest E(frame) - E(1) [J]
  double start = 0.0;       // E(1)
  int implicit_ticks = 0;
  double work = 0.0;  // per frame: substeps (force evaluations) plus CG iterations, the cost counted
  std::string hash;
  Vectors3 x;  // the particles at the end
};

struct Options {
  int n = 20;
  int ticks = 1;
  double spin = 10.0;
  bool recipe = false;  // plugin/README.md's large-step recipe: implicit springs and bending, multigrid
  bool collisions = true;
  bool automatic = true;
  double relative_tolerance = StepSettings{}.relative_tolerance;
  int frames = 120;
};

Run run(const Options& o) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* box = add_box(bw, btVector3(0.6, 0.05, 0.05), 1.0, scenes::at(btVector3(0, 2, 0)));
  box->setAngularVelocity(btVector3(0, btScalar(o.spin), btScalar(0.3 * o.spin)));
  bullet::CouplingSettings settings;
  settings.collisions = o.collisions;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  scenes::ClothGridSettings grid;
  grid.nx = grid.ny = o.n;
  grid.width = grid.height = 1.2;
  grid.mass = 0.3;
  grid.origin = Vec3(-0.6, 1.95, 0.0);
  grid.bending_implicit = o.recipe;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, grid);
  for (int i = 0; i < o.n; ++i) coupling.bind_here(cloth.node(i, 0), box);
  s.step_settings().implicit_elasticity = s.step_settings().multigrid = o.recipe;
  s.step_settings().automatic = o.automatic;
  s.step_settings().relative_tolerance = o.relative_tolerance;
  const auto energy = [&] { return s.kinetic_energy() + s.potential_energy(); };
  const btScalar tick = btScalar(1.0 / (60.0 * o.ticks));
  Run r;
  for (int frame = 1; frame <= o.frames; ++frame) {
    for (int t = 0; t < o.ticks; ++t) {
      bw.world().stepSimulation(tick, 1, tick);
      const StepStats& stats = coupling.last_stats();
      r.implicit_ticks += stats.implicit_elasticity ? 1 : 0;
      if (frame > 1)
        r.work += stats.substeps + stats.cg_iterations_step1 + stats.cg_iterations_step3 + stats.cg_iterations_step4;
    }
    if (frame == 1) r.start = energy();
    r.worst_gain = std::max(r.worst_gain, energy() - r.start);
    if (!s.particles().x.allFinite()) {
      r.worst_gain = kInfinity;
      break;
    }
  }
  r.work /= o.frames - 1;
  r.hash = std::to_string(s.state_hash());
  r.x = s.particles().x;
  return r;
}

// The scene run with System::advance's choice off, then on.
std::pair<Run, Run> run_fixed_and_chosen(Options o) {
  o.automatic = false;
  Run fixed = run(o);
  o.automatic = true;
  return {std::move(fixed), run(o)};
}

}  // namespace spinning

// With substeps inside a tick the body turns between them; collisions that met it at Bullet's pose
// of the tick's start projected the cloth out of where the box had been (at 30 rad/s, 23 substeps
// per 1/60 s tick: +14 J in a scene of 58 J). Met where each step puts it, the scene loses energy.
TEST(BulletCollisions, ACollidingClothOnASpinningBoxGainsNoEnergyAcrossSubsteps) {
  spinning::Options o;
  o.spin = 30.0;
  o.automatic = false;  // explicit elasticity: 23 substeps per tick
  const spinning::Run r = spinning::run(o);
  EXPECT_LT(r.worst_gain, 1e-9 * r.start) << "of " << r.start << " J";
}

// Step 3 finds each particle's objects through a tree of their boxes (btDbvt), refitted every step and
// rebuilt when the world's objects change: a box moved under a falling particle catches it, one moved
// away or removed and replaced by another (the same object count) no longer does, the new one does.
TEST(BulletCollisions, TheObjectTreeFollowsBodiesMovedRemovedAndAdded) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* a = add_box(bw, btVector3(0.1, 0.1, 0.1), 0.0, scenes::at(btVector3(0, 0, 0)));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  s.step_settings().sleep = false;
  const double top = 0.1 + bullet::CouplingSettings{}.thickness;
  const auto drop = [&](double x) { return s.add_particle(Vec3(x, 0.2, 0), Vec3(0, -1, 0), 0.01); };
  const auto ticks = [&](int n) {
    for (int t = 0; t < n; ++t) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  };
  const Index p0 = drop(0.0);
  ticks(60);  // 0.25 s: 0.25 m of fall, stopped by the box after 0.09 m of it
  EXPECT_NEAR(s.particles().x(1, p0), top, 1e-9);
  // Moved under another falling particle: it catches that one; the first (given its speed again)
  // falls past where the box was.
  a->setWorldTransform(scenes::at(btVector3(3, 0, 0)));
  s.particles().v.col(p0) = Vec3(0, -1, 0);
  const Index p1 = drop(3.0);
  ticks(60);
  EXPECT_LT(s.particles().x(1, p0), -0.1);
  EXPECT_NEAR(s.particles().x(1, p1), top, 1e-9);
  // Removed, and another box added under a third particle (the world holds as many objects as before).
  bw.world().removeRigidBody(a);
  btRigidBody* b = add_box(bw, btVector3(0.1, 0.1, 0.1), 0.0, scenes::at(btVector3(5, 0, 0)));
  ASSERT_EQ(bw.world().getNumCollisionObjects(), 1);
  s.particles().v.col(p1) = Vec3(0, -1, 0);
  const Index p2 = drop(5.0);
  ticks(60);
  EXPECT_LT(s.particles().x(1, p1), -0.1);
  EXPECT_NEAR(s.particles().x(1, p2), top, 1e-9);
  bw.world().removeRigidBody(b);
  bw.world().addRigidBody(a);  // the world's destructor removes both
  bw.world().addRigidBody(b);
}

// Thin and fast bodies: a 2 mm plate moving at 20 m/s passes 8 cm per 1/240 s tick, forty times its
// thickness, so a test of the step's ends alone leaves every particle it meets behind it. The
// continuous test (BulletCollisions::crossed) finds the crossing and keeps them ahead of it.
TEST(BulletCollisions, AThinPlateMovingFastPushesTheParticlesItMeets) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* plate = add_box(bw, btVector3(0.2, 0.001, 0.2), 1000.0, scenes::at(btVector3(0, 0.05, 0)));
  plate->setLinearVelocity(btVector3(0, -20, 0));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  std::vector<Index> row;
  for (int k = 0; k < 9; ++k)
    row.push_back(s.add_particle(Vec3(-0.16 + 0.04 * k, 0, 0.03 * (k % 3)), Vec3::Zero(), 0.001));
  for (int t = 0; t < 12; ++t) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    const double face = double(plate->getCenterOfMassPosition().y()) - 0.001;
    for (const Index i : row)
      ASSERT_LT(s.particles().x(1, i), face) << "tick " << t << ": particle " << i << " is behind the plate";
  }
  // Carried at the plate's speed (1 mm/s of it lost to the plate's 1000 kg taking their momentum).
  for (const Index i : row) EXPECT_NEAR(s.particles().v(1, i), double(plate->getLinearVelocity().y()), 1e-2);
}

// A blade 2 mm thick spinning at 10 turns a second about its centre through a ring of particles at
// 0.2 m (12.6 m/s there, 5 cm a tick: more than the 2.2 cm the blade and the thickness on both its
// faces span): a particle it meets stays on its leading face (in the blade's frame, on the side it
// turns towards) instead of being crossed.
TEST(BulletCollisions, ASpinningBladeSweepsParticlesInsteadOfCrossingThem) {
  BulletWorld bw(btVector3(0, 0, 0));
  btRigidBody* blade = add_box(bw, btVector3(0.3, 0.05, 0.001), 1000.0, scenes::at(btVector3(0, 0, 0)));
  const double spin = 20.0 * M_PI;
  blade->setAngularVelocity(btVector3(0, btScalar(spin), 0));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  std::vector<Index> ring;
  for (int k = 0; k < 24; ++k) {
    const double a = 2.0 * M_PI * (k + 0.5) / 24;
    ring.push_back(s.add_particle(Vec3(0.2 * std::cos(a), 0, 0.2 * std::sin(a)), Vec3::Zero(), 0.001));
  }
  for (int t = 0; t < 60; ++t) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  // A quarter of a second: two and a half turns. Turning about +y, a point at local x > 0 moves
  // towards local -z.
  const btTransform frame = blade->getCenterOfMassTransform();
  int swept = 0;
  for (const Index i : ring) {
    const btVector3 local = frame.invXform(bullet::to_bullet(Vec3(s.particles().x.col(i))));
    if (std::abs(double(local.x())) > 0.3 || std::abs(double(local.y())) > 0.05) continue;  // flung off the tip
    ++swept;
    EXPECT_LT(double(local.x() * local.z()), 0.0) << "particle " << i << " is behind the blade";
    EXPECT_GE(std::abs(double(local.z())), 0.001 + 0.5 * bullet::CouplingSettings{}.thickness) << "particle " << i;
  }
  EXPECT_GT(swept, 0) << "no particle stayed on the blade: the test tests nothing";
}

// A paddle 1 m long turning about its end at 180 rad/s (0.75 rad a 1/240 s tick, under Bullet's
// clamp of pi/4), from 0.375 rad before a particle to 0.375 rad past it: the particle at 0.99 m lies
// outside the box of the paddle's two end poses (it reaches 0.95 m along x at both, padding
// included) but on the arc its tip sweeps, 3.5 cm further out. The swept box must hold the arc, so
// the particle is met and pushed ahead of the paddle's leading face instead of being passed.
TEST(BulletCollisions, APaddleTurningFastMeetsAParticleBeyondTheBoxOfItsEndPoses) {
  BulletWorld bw(btVector3(0, 0, 0));
  auto compound = std::make_unique<btCompoundShape>();
  btCollisionShape* blade = bw.keep(std::make_unique<btBoxShape>(btVector3(0.5, 0.05, 0.02)));
  btTransform child;
  child.setIdentity();
  child.setOrigin(btVector3(0.5, 0, 0));
  compound->addChildShape(child, blade);
  btCollisionShape* shape = bw.keep(std::move(compound));
  const double turn = 0.75;
  btTransform start(btQuaternion(btVector3(0, 1, 0), btScalar(-0.5 * turn)), btVector3(0, 0, 0));
  btRigidBody* paddle = bw.add_body(shape, 1000.0, start);
  paddle->setActivationState(DISABLE_DEACTIVATION);
  paddle->setAngularVelocity(btVector3(0, btScalar(240.0 * turn), 0));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const Index p = s.add_particle(Vec3(0.99, 0, 0), Vec3::Zero(), 0.001);
  // Turning about +y, a point at local x > 0 moves towards local -z: before the tick the particle is
  // ahead of the paddle (local z < 0).
  ASSERT_LT(double(paddle->getCenterOfMassTransform().invXform(btVector3(0.99, 0, 0)).z()), 0.0);
  bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
  const btTransform frame = paddle->getCenterOfMassTransform();
  ASSERT_NEAR(double(frame.getRotation().getAngle()), 0.5 * turn, 1e-3) << "Bullet turned the paddle otherwise";
  const btVector3 local = frame.invXform(bullet::to_bullet(Vec3(s.particles().x.col(p))));
  EXPECT_LE(double(local.z()), -0.02 - 0.5 * bullet::CouplingSettings{}.thickness)
      << "the particle is at local (" << local.x() << ", " << local.y() << ", " << local.z() << ")";
}

// A cloth lying on a box that moves down at 6 m/s (no gravity; the cloth slightly faster, so it
// presses on the face): each step must meet the face where the box is at the step's end, not where
// it was when the tick started (|v| dt = 2.5 cm higher at 1/240 s). Both for a body the coupling has
// as a rigid-body particle (its step frames) and for a plain Bullet body (moved on with its velocity).
TEST(BulletCollisions, AClothRidingADescendingBoxStaysOnItsFace) {
  for (const bool particle : {false, true}) {
    BulletWorld bw(btVector3(0, 0, 0));
    btRigidBody* box = add_box(bw, btVector3(1, 0.1, 1), 100.0, scenes::at(btVector3(0, 0, 0)));
    box->setLinearVelocity(btVector3(0, -6, 0));
    bullet::Coupling coupling(&bw.world());
    System& s = coupling.system();
    if (particle) coupling.rigid_particle(box);
    const double thickness = 0.01;
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, [&] {
      scenes::ClothGridSettings c = small_cloth(Vec3(-0.25, 0.1 + thickness, -0.25));
      c.down = Vec3::UnitZ();
      return c;
    }());
    for (Index node : cloth.nodes) s.particles().v.col(node) = Vec3(0, -6.2, 0);
    double worst = 0.0;
    for (int tick = 0; tick < 48; ++tick) {
      bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
      if (tick < 8) continue;  // landing
      const double face = double(box->getCenterOfMassPosition().y()) + 0.1;
      for (Index node : cloth.nodes) worst = std::max(worst, s.particles().x(1, node) - face - thickness);
    }
    // The cloth's sag over a tick is (0.2 m/s) / 240; the box's travel, 2.5 cm, must not show.
    EXPECT_LT(worst, 2e-3) << (particle ? "rigid-body particle" : "plain Bullet body");
  }
}

// plugin/README.md's recipe for large steps (implicit springs and bending, multigrid) at one 1/60 s
// tick: the solves linearise the springs where each step starts, and springs that turn within it are
// pulled along stale directions. Run as set, that feeds the spinning cloth (checked below, so the
// case stays a hard one); System::advance bounds the turn's missed work per substep and holds it.
TEST(AutomaticScheme, TheLargeStepRecipeOnASpinningBoxGainsNoEnergy) {
  spinning::Options o;
  o.recipe = true;
  for (const int n : {20, 40}) {
    o.n = n;
    o.frames = n == 20 ? 60 : 20;
    const auto [as_set, bounded] = spinning::run_fixed_and_chosen(o);
    EXPECT_GT(as_set.worst_gain, 0.05 * as_set.start) << n << " x " << n << ": the hard case is no longer hard";
    EXPECT_LT(bounded.worst_gain, 1e-9 * bounded.start) << n << " x " << n << " of " << bounded.start << " J";
  }
}

// A 40 x 40 cloth on a spinning box at 1/240 s ticks needs 12 explicit substeps per tick; the
// implicit scheme does a tick in one or two at less cost, counted as force evaluations plus CG
// iterations (deterministic, unlike a clock), and keeps the scene passive.
TEST(AutomaticScheme, ChoosesImplicitElasticityWhereExplicitNeedsManySubstepsAndCostsLess) {
  spinning::Options o;
  o.n = 40;
  o.ticks = 4;
  o.frames = 30;
  const auto [explicit_run, chosen] = spinning::run_fixed_and_chosen(o);
  EXPECT_EQ(explicit_run.implicit_ticks, 0);
  EXPECT_GT(chosen.implicit_ticks, 4 * o.frames / 2);
  EXPECT_LT(chosen.work, 0.8 * explicit_run.work) << "explicit " << explicit_run.work;
  EXPECT_LT(chosen.worst_gain, 1e-9 * chosen.start);
  EXPECT_LT(explicit_run.worst_gain, 1e-9 * explicit_run.start);
}

// Where explicit elasticity needs at most System::kCheapExplicitSubsteps substeps the choice is the
// settings as they are: with relative_tolerance = 0 (the solves at cg_tolerance) the same bits as with
// the choice off; with the default, solves stopped at kExplicitToleranceFactor * relative_tolerance of
// a substep's velocity change (1e-4 of it) move the cloth by far less than a millimetre over 30
// frames, and the passive scene still gains nothing.
TEST(AutomaticScheme, LeavesACheapExplicitSceneAsSetButForItsSolvesTolerance) {
  spinning::Options o;
  o.n = 6;
  o.ticks = 4;
  o.frames = 30;
  o.relative_tolerance = 0.0;
  const auto [off, on] = spinning::run_fixed_and_chosen(o);
  EXPECT_EQ(on.implicit_ticks, 0);
  EXPECT_EQ(on.hash, off.hash);
  o.relative_tolerance = StepSettings{}.relative_tolerance;
  const spinning::Run loose = spinning::run(o);
  EXPECT_EQ(loose.implicit_ticks, 0);
  EXPECT_NE(loose.hash, off.hash) << "the default tolerance changed nothing: the test no longer tests it";
  const double rms = std::sqrt((loose.x - off.x).colwise().squaredNorm().mean());
  std::cout << "RMS difference " << rms << " m, gain " << loose.worst_gain << " J of " << loose.start << "\n";
  EXPECT_LT(rms, 1e-3);
  EXPECT_LT(loose.worst_gain, 1e-9 * loose.start);
  EXPECT_LT(loose.work, on.work);
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// ---- sleeping (StepSettings::sleep) through the coupling ------------------------------------------

constexpr double kSleepTick = 1.0 / 240;

// A 9 x 9 cloth dropped flat from 3 cm onto a static ground plane.
struct ClothOnGround {
  BulletWorld bw{btVector3(0, -9.81, 0)};
  std::unique_ptr<bullet::Coupling> coupling;
  explicit ClothOnGround(bool sleep) {
    bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0,
                scenes::at(btVector3(0, 0, 0)));
    coupling = std::make_unique<bullet::Coupling>(&bw.world());
    coupling->system().step_settings().sleep = sleep;
    scenes::ClothGridSettings c;
    c.nx = c.ny = 9;
    c.width = c.height = 0.6;
    c.mass = 0.1;
    c.origin = Vec3(-0.3, 0.03, -0.3);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();
    c.stretch_stiffness = 30.0;
    c.stretch_damping = 0.02;
    c.bending_stiffness = 1e-5;
    scenes::add_cloth_grid(coupling->system(), c);
  }
  System& system() { return coupling->system(); }
  void tick() { bw.world().stepSimulation(btScalar(kSleepTick), 1, btScalar(kSleepTick)); }
};

TEST(Sleeping, AClothAsleepOnTheGroundWakesForAFallingBoxThatItThenStopsAsItWouldAwake) {
  ClothOnGround a(true), b(false);
  int asleep_at = -1;
  for (int tick = 0; tick < 720; ++tick) {
    a.tick();
    b.tick();
    if (asleep_at < 0 && a.system().asleep()) asleep_at = tick;
  }
  ASSERT_GE(asleep_at, 0) << "not asleep after 3 s on the ground";
  EXPECT_TRUE(a.system().asleep()) << "the ground alone woke it";
  EXPECT_FALSE(b.system().asleep());
  // A box dropped from 40 cm onto the cloth's centre, in both worlds.
  auto drop = [](ClothOnGround& w) {
    btRigidBody* box = w.bw.add_body(w.bw.keep(std::make_unique<btBoxShape>(btVector3(0.05, 0.05, 0.05))), 0.2,
                                     scenes::at(btVector3(0.02, 0.4, 0.01)));
    return box;
  };
  btRigidBody* box_a = drop(a);
  btRigidBody* box_b = drop(b);
  int woke_at = -1;
  double height_at_wake = 0.0;
  for (int tick = 0; tick < 360; ++tick) {
    a.tick();
    b.tick();
    if (woke_at < 0 && !a.system().asleep()) {
      woke_at = tick;
      height_at_wake = static_cast<double>(box_a->getCenterOfMassPosition().y());
    }
  }
  ASSERT_GE(woke_at, 0) << "the falling box did not wake the cloth";
  EXPECT_GT(woke_at, 0) << "woken before the box came near";
  EXPECT_GT(height_at_wake - 0.05, 0.01) << "woken only once the box was in the cloth";
  const double ya = static_cast<double>(box_a->getCenterOfMassPosition().y());
  const double yb = static_cast<double>(box_b->getCenterOfMassPosition().y());
  EXPECT_NEAR(ya, yb, 1e-3);
  EXPECT_GT(ya, 0.05 - 1e-3);  // on the ground through the cloth, as awake
  // The woken cloth lies as the awake one does: the nodes under the box squeezed on the ground, the
  // others where the box's landing left them. (A cloth that slept through the landing would also lie
  // on the ground under the box: the comparison with the awake cloth is what tells them apart.)
  const double apart = (a.system().particles().x - b.system().particles().x).colwise().norm().maxCoeff();
  std::cout << "largest distance between the woken and the awake cloth's nodes " << apart << " m\n";
  EXPECT_LT(apart, 1e-3);
  const System& s = a.system();
  for (Index i = 0; i < s.particles().size(); ++i) {
    double phi;
    Vec3 n;
    ASSERT_TRUE(bullet::signed_distance(box_a->getCollisionShape(), box_a->getCenterOfMassTransform(),
                                        s.particles().x.col(i), 1.0, phi, n));
    if (phi < 0.0) {
      EXPECT_LT(s.particles().x(1, i), bullet::CouplingSettings{}.thickness + 1e-6)
          << "particle " << i << " in the box, off the ground";
    }
  }
  EXPECT_LT(bullet::to_eigen(box_a->getLinearVelocity()).norm(), 0.05) << "stopped";
}

TEST(Sleeping, AClothHungBetweenABarAndABoxWakesWhenTheBoxIsPushed) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  btRigidBody* bar = add_box(bw, btVector3(0.3, 0.02, 0.02), 0.0, scenes::at(btVector3(0, 1.02, 0)));
  btRigidBody* box = bw.add_body(bw.keep(std::make_unique<btBoxShape>(btVector3(0.05, 0.05, 0.05))), 0.05,
                                 scenes::at(btVector3(0, 0.55, 0)));
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.2, 1.0, 0.0));
  c.width = 0.4;
  c.height = 0.4;
  c.stretch_stiffness = 200.0;
  c.stretch_damping = 2.0;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
  for (int i = 0; i < cloth.nx; ++i) coupling.bind_here(cloth.node(i, 0), bar);
  coupling.bind_here(cloth.node(2, cloth.ny - 1), box);
  coupling.bind_here(cloth.node(3, cloth.ny - 1), box);
  auto tick = [&] { bw.world().stepSimulation(btScalar(kSleepTick), 1, btScalar(kSleepTick)); };
  int asleep_at = -1;
  for (int t = 0; t < 960 && asleep_at < 0; ++t) {
    tick();
    if (s.asleep()) asleep_at = t;
  }
  ASSERT_GE(asleep_at, 0) << "not asleep after 4 s";
  // Asleep, the box is held where it came to rest.
  const Vec3 rest = bullet::to_eigen(box->getCenterOfMassPosition());
  for (int t = 0; t < 120; ++t) {
    tick();
    ASSERT_TRUE(s.asleep()) << t;
  }
  EXPECT_LT((bullet::to_eigen(box->getCenterOfMassPosition()) - rest).norm(), 1e-6);
  box->applyCentralImpulse(btVector3(0.005, 0, 0));  // 0.1 m/s
  tick();
  EXPECT_FALSE(s.asleep());
  EXPECT_FALSE(coupling.last_stats().asleep);
  EXPECT_GT(coupling.last_stats().substeps, 0);
  for (int t = 0; t < 24; ++t) tick();
  EXPECT_GT(bullet::to_eigen(box->getCenterOfMassPosition()).x() - rest.x(), 1e-3) << "the push moved the box";
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// CouplingSettings::self_collisions in a Bullet world: a 20 x 20 cloth of 0.8 m dropped from 0.3 m
// onto a 0.3 m box on the ground, off centre (0.5 m of it beyond one edge), drapes over it and folds
// where it meets the ground. With the setting no pair of its triangles (neighbours aside) intersects
// at any tick's end (FCL's count, intersections.hpp); without it the folds cross (hundreds of pairs;
// centred, the folds lay side by side in some runs, and the case tested nothing). Frictionless, so
// the cloth slides off the box into folds (friction holds it where it lands, and may leave none).
TEST(BulletCoupling, SelfCollisionsKeepADrapedClothFromCrossingItself) {
  for (const bool self : {true, false}) {
    BulletWorld bw(btVector3(0, -9.81, 0));
    bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0,
                scenes::at(btVector3(0, 0, 0)));
    add_box(bw, btVector3(0.15, 0.15, 0.15), 0.0, scenes::at(btVector3(0, 0.15, 0)));
    bullet::CouplingSettings settings;
    settings.self_collisions = self;
    settings.friction = 0.0;
    bullet::Coupling coupling(&bw.world(), settings);
    System& s = coupling.system();
    scenes::ClothGridSettings c;
    c.nx = c.ny = 20;
    c.width = c.height = 0.8;
    c.mass = 0.2;
    c.stretch_stiffness = 500.0;
    c.origin = Vec3(-0.15, 0.6, -0.4);
    c.down = Vec3(0.0, 0.1, 1.0).normalized();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(s, c);
    intersections::SurfaceIntersections checker(cloth.triangles, s.particles().x);
    std::size_t worst = 0;
    for (int frame = 0; frame < 60; ++frame) {
      for (int tick = 0; tick < 4; ++tick) {
        bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
        worst = std::max(worst, checker.count(s.particles().x));
      }
    }
    if (self) {
      EXPECT_EQ(worst, 0u) << "the cloth crossed itself";
    } else {
      EXPECT_GT(worst, 0u) << "without self collisions the folds must cross: the test tests nothing";
    }
  }
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// A box edge between two cloth nodes. A static box turned 45 degrees about z makes a ridge along z at
// y = 0, longer than the cloth; a 4 x 4 cloth of 0.6 m (20 cm cells, its columns at x = -0.3, -0.1,
// 0.1, 0.3, none on the ridge) falls onto it and hangs over it. Particles alone let the nodes beside
// the ridge slide down its slopes while the faces between them pass over the ridge below it; with the
// body's edges tested against the cloth's edges (and its corners against the faces), the cloth's
// height above every point of the ridge under it keeps the thickness (measured: 1.0 cm with the
// features, -9.5 cm with particles alone).
double lowest_cloth_over_ridge(bool features) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  add_box(bw, btVector3(0.2, 0.2, 0.5), 0.0,
          btTransform(btQuaternion(btVector3(0, 0, 1), btScalar(M_PI / 4)), btVector3(0, btScalar(-0.2 * M_SQRT2), 0)));
  bullet::CouplingSettings settings;
  settings.feature_contacts = features;
  bullet::Coupling coupling(&bw.world(), settings);
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.3, 0.03, -0.3));
  c.nx = c.ny = 4;
  c.width = c.height = 0.6;
  c.down = Vec3::UnitZ();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(coupling.system(), c);
  const Vectors3& x = coupling.system().particles().x;
  double lowest = kInfinity;
  for (int tick = 0; tick < 240; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    // The cloth's height over the ridge point (0, 0, z): the triangle whose projection on y = 0 holds it.
    for (double z = -0.25; z <= 0.25; z += 0.01)
      for (const auto& t : cloth.triangles) {
        const Eigen::Vector2d p(0.0, z), a(x(0, t[0]), x(2, t[0])), b(x(0, t[1]), x(2, t[1])),
            d(x(0, t[2]), x(2, t[2]));
        const double area = (b - a).x() * (d - a).y() - (b - a).y() * (d - a).x();
        const double wb = ((p - a).x() * (d - a).y() - (p - a).y() * (d - a).x()) / area;
        const double wd = ((b - a).x() * (p - a).y() - (b - a).y() * (p - a).x()) / area;
        const double wa = 1.0 - wb - wd;
        if (wa < 0.0 || wb < 0.0 || wd < 0.0) continue;
        lowest = std::min(lowest, wa * x(1, t[0]) + wb * x(1, t[1]) + wd * x(1, t[2]));
      }
  }
  EXPECT_TRUE(x.allFinite());
  return lowest;
}

TEST(BulletCollisions, ABoxEdgeBetweenClothNodesDoesNotPokeThroughTheFace) {
  const double thickness = bullet::CouplingSettings{}.thickness;
  const double points_only = lowest_cloth_over_ridge(false);
  EXPECT_LT(points_only, -0.01) << "the case is not hard: particles alone keep the ridge under the cloth";
  EXPECT_GT(lowest_cloth_over_ridge(true), 0.9 * thickness);
}

// The same ridge on a dynamic box (1 kg, no gravity) thrown edge first at 2 m/s into a free cloth at
// rest: the edge meets the faces between the nodes, the cloth is carried off on the ridge, and the
// box takes the opposite of every impulse the cloth gets, through its rigid-body particle or summed
// and handed to Bullet: the total linear momentum stays 2 kg m/s to round-off.
TEST(BulletCollisions, ABoxEdgeThrownIntoAClothKeepsTheMomentum) {
  for (const bool particle : {false, true}) {
    BulletWorld bw(btVector3(0, 0, 0));
    btRigidBody* box = add_box(bw, btVector3(0.2, 0.2, 0.5), 1.0,
                               btTransform(btQuaternion(btVector3(0, 0, 1), btScalar(M_PI / 4)),
                                           btVector3(0, btScalar(-0.2 * M_SQRT2 - 0.05), 0)));
    box->setLinearVelocity(btVector3(0, 2, 0));
    box->setActivationState(DISABLE_DEACTIVATION);
    bullet::Coupling coupling(&bw.world());
    if (particle) coupling.rigid_particle(box);
    scenes::ClothGridSettings c = small_cloth(Vec3(-0.3, 0.0, -0.3));
    c.nx = c.ny = 4;
    c.width = c.height = 0.6;
    c.down = Vec3::UnitZ();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(coupling.system(), c);
    const System& s = coupling.system();
    const auto momentum = [&] {
      Vec3 p = double(box->getMass()) * bullet::to_eigen(box->getLinearVelocity());
      for (const Index i : cloth.nodes) p += s.particles().mass[i] * s.particles().v.col(i);
      return p;
    };
    const Vec3 start = momentum();
    for (int tick = 0; tick < 60; ++tick) bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    EXPECT_LT((momentum() - start).norm(), 1e-9 * start.norm()) << (particle ? "rigid-body particle" : "plain body");
    // The cloth is carried up with the ridge, its middle above the edge.
    double lowest = kInfinity;
    for (const Index i : cloth.nodes) lowest = std::min(lowest, s.particles().v(1, i));
    EXPECT_GT(lowest, 0.5) << (particle ? "rigid-body particle" : "plain body") << ": the cloth was not carried";
  }
}

// A convex hull ridge (a triangular prism, apex along z at y = 0, Bullet's default 4 cm margin
// rounding it) under the same cloth: its edges come from the hull, and the cloth keeps the thickness
// plus the margin over the apex. Then the hull's points are changed in place (the apex raised 3 cm,
// the body kinematic so its box follows): the corners and edges are made again from the points as
// they are now, and the cloth is lifted with the apex (a hull kept for the shape's address would
// leave the new apex poking through).
TEST(BulletCollisions, AHullRidgeKeepsItsMarginAndIsTestedAsItIsNow) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  auto hull = std::make_unique<btConvexHullShape>();
  for (const double z : {-0.5, 0.5}) {
    hull->addPoint(btVector3(-0.3, -0.3, btScalar(z)), false);
    hull->addPoint(btVector3(0.3, -0.3, btScalar(z)), false);
    hull->addPoint(btVector3(0, 0, btScalar(z)), false);
  }
  hull->recalcLocalAabb();
  btConvexHullShape* shape = hull.get();
  btRigidBody* ridge = bw.add_body(bw.keep(std::move(hull)), 0.0, scenes::at(btVector3(0, 0, 0)));
  ridge->setCollisionFlags(ridge->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
  ridge->setActivationState(DISABLE_DEACTIVATION);
  bullet::Coupling coupling(&bw.world());
  scenes::ClothGridSettings c = small_cloth(Vec3(-0.3, 0.08, -0.3));
  c.nx = c.ny = 4;
  c.width = c.height = 0.6;
  c.down = Vec3::UnitZ();
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(coupling.system(), c);
  const Vectors3& x = coupling.system().particles().x;
  // The cloth's lowest height over the apex line (0, apex, z), |z| <= 0.25.
  const auto lowest_over_apex = [&] {
    double lowest = kInfinity;
    for (double z = -0.25; z <= 0.25; z += 0.01)
      for (const auto& t : cloth.triangles) {
        const Eigen::Vector2d p(0.0, z), a(x(0, t[0]), x(2, t[0])), b(x(0, t[1]), x(2, t[1])),
            d(x(0, t[2]), x(2, t[2]));
        const double area = (b - a).x() * (d - a).y() - (b - a).y() * (d - a).x();
        const double wb = ((p - a).x() * (d - a).y() - (p - a).y() * (d - a).x()) / area;
        const double wd = ((b - a).x() * (p - a).y() - (b - a).y() * (p - a).x()) / area;
        const double wa = 1.0 - wb - wd;
        if (wa < 0.0 || wb < 0.0 || wd < 0.0) continue;
        lowest = std::min(lowest, wa * x(1, t[0]) + wb * x(1, t[1]) + wd * x(1, t[2]));
      }
    return lowest;
  };
  const double reach = bullet::CouplingSettings{}.thickness + double(shape->getMargin());
  double lowest = kInfinity;
  for (int tick = 0; tick < 240; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    lowest = std::min(lowest, lowest_over_apex());
  }
  EXPECT_GT(lowest, 0.9 * reach) << "over the hull's apex";
  // The apex raised 3 cm in place.
  for (int i = 0; i < shape->getNumPoints(); ++i)
    if (shape->getUnscaledPoints()[i].y() > btScalar(-0.1)) shape->getUnscaledPoints()[i].setY(btScalar(0.03));
  shape->recalcLocalAabb();
  lowest = kInfinity;
  for (int tick = 0; tick < 240; ++tick) {
    bw.world().stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
    if (tick >= 120) lowest = std::min(lowest, lowest_over_apex());
  }
  EXPECT_GT(lowest, 0.03 + 0.9 * reach) << "over the raised apex";
  EXPECT_TRUE(x.allFinite());
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// A vise: two plain dynamic Bullet boxes (0.2 kg, no gravity of their own, locked by Bullet's
// setLinearFactor and setAngularFactor to move along z only) pushed together by 2 N each across a
// hanging cloth, 1/240 s ticks. They meet face to face with no gap for the cloth's thickness on
// either side, which no position of a node between them can meet. With pinching (figure 10) the
// nodes between them hang between their duplicates: the jaws stay face to face, the cloth still,
// and the jaws' locked axes hold (the end-of-tick contact passes push a locked body as Bullet's
// applyImpulse would: along its free axes only). Without, each node is pushed out of the nearer box
// into the other at every step: the cloth jitters at metres a second, its centre 8 mm off the jaws' middle where the
// pinched one stays within 2 mm.
struct PressedBoxes {
  BulletWorld w{btVector3(0, -9.81, 0)};
  btRigidBody* box[2] = {nullptr, nullptr};
  std::unique_ptr<bullet::Coupling> coupling;
  scenes::ClothGrid cloth;
  explicit PressedBoxes(bool pinching) {
    btRigidBody* bar = add_box(w, btVector3(0.25, 0.01, 0.01), 0.0, scenes::at(btVector3(0, 1.011, 0)));
    for (int s = 0; s < 2; ++s) {
      box[s] = add_box(w, btVector3(0.05, 0.05, 0.05), 0.2, scenes::at(btVector3(0, 0.8, s ? 0.1 : -0.1)));
      box[s]->setGravity(btVector3(0, 0, 0));
      box[s]->setActivationState(DISABLE_DEACTIVATION);
      box[s]->setFriction(0.5);
      box[s]->setLinearFactor(btVector3(0, 0, 1));
      box[s]->setAngularFactor(btVector3(0, 0, 0));
    }
    bullet::CouplingSettings settings;
    settings.pinching = pinching;
    coupling = std::make_unique<bullet::Coupling>(&w.world(), settings);
    scenes::ClothGridSettings c;
    c.nx = c.ny = 17;
    c.width = c.height = 0.4;
    c.mass = 0.05;
    c.origin = Vec3(-0.2, 1.0, 0.0);
    cloth = scenes::add_cloth_grid(coupling->system(), c);
    for (int i = 0; i < cloth.nx; ++i) coupling->bind_here(cloth.node(i, 0), bar);
  }
  void frame() {
    box[0]->applyCentralForce(btVector3(0, 0, 2));
    box[1]->applyCentralForce(btVector3(0, 0, -2));
    w.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
  }
  double z(int s) const { return static_cast<double>(box[s]->getCenterOfMassPosition().z()); }
};

TEST(Pinching, AViseOfTwoDynamicBoxesClosedOnAClothHoldsIt) {
  PressedBoxes pinched(true), naive(false);
  double rms = 0.0, naive_rms = 0.0, gap = kInfinity, off_plane = 0.0, off_axis = 0.0, naive_off_plane = 0.0;
  for (int f = 1; f <= 120; ++f) {
    pinched.frame();
    naive.frame();
    gap = std::min(gap, pinched.z(1) - pinched.z(0));
    for (const btRigidBody* box : pinched.box) {
      const btVector3 c = box->getCenterOfMassPosition();
      off_axis = std::max(off_axis, std::hypot(static_cast<double>(c.x()), static_cast<double>(c.y()) - 0.8));
    }
    if (f <= 30) continue;  // closed at frame 6; the cloth settles
    rms = std::max(rms, scenes::velocity_rms(pinched.coupling->system()));
    naive_rms = std::max(naive_rms, scenes::velocity_rms(naive.coupling->system()));
    off_plane = std::max(off_plane, std::abs(pinched.coupling->system().particles().x(2, pinched.cloth.node(8, 8))));
    naive_off_plane = std::max(
        naive_off_plane,
        std::abs(naive.coupling->system().particles().x(2, naive.cloth.node(8, 8)) - 0.5 * (naive.z(0) + naive.z(1))));
  }
  EXPECT_GT(gap, 0.1 - 2e-3);  // face to face, no deeper than Bullet's own contacts go
  EXPECT_LT(off_axis, 1e-9);   // locked
  EXPECT_LT(rms, 0.05);
  EXPECT_LT(off_plane, 2e-3);
  EXPECT_GE(pinched.coupling->pinches().size(), 9u);
  EXPECT_GT(naive_rms, 1.0);
  EXPECT_GT(naive_off_plane, 5e-3);  // from the jaws' middle (8 mm)
}

// A 0.5 kg box dropped on a cloth lying on the ground (plane, 1/240 s ticks) rests on the ground
// through it: Bullet's box meets the plane with no room for the cloth's thickness on either side.
// With pinching the nodes under the box hang between their duplicates, still and above the ground;
// without, they follow the ground (a node caught between a body Bullet alone moves and a static
// object), squeezed under the box, and none goes into the ground; the cloth around the box still
// jitters at 0.7 m/s. Before that rule each node was pushed out of the nearer of the two, into the
// other, at every step: the cloth jittered at a metre a second, its lowest node 7 mm into the ground.
struct BoxOnClothOnGround {
  BulletWorld w{btVector3(0, -9.81, 0)};
  btRigidBody* box = nullptr;
  std::unique_ptr<bullet::Coupling> coupling;
  scenes::ClothGrid cloth;
  explicit BoxOnClothOnGround(bool pinching) {
    w.add_body(w.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0, scenes::at(btVector3(0, 0, 0)))
        ->setFriction(0.8);
    box = add_box(w, btVector3(0.05, 0.05, 0.05), 0.5, scenes::at(btVector3(0.02, 0.3, 0.01)));
    bullet::CouplingSettings settings;
    settings.pinching = pinching;
    coupling = std::make_unique<bullet::Coupling>(&w.world(), settings);
    scenes::ClothGridSettings c;
    c.nx = c.ny = 21;
    c.width = c.height = 0.5;
    c.mass = 0.1;
    c.origin = Vec3(-0.25, 0.011, -0.25);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();
    cloth = scenes::add_cloth_grid(coupling->system(), c);
  }
  double lowest() const {
    double y = kInfinity;
    for (const Index i : cloth.nodes) y = std::min(y, coupling->system().particles().x(1, i));
    return y;
  }
};

TEST(Pinching, ABoxRestingOnAClothOnTheGroundHoldsItStill) {
  BoxOnClothOnGround pinched(true), naive(false);
  double rms = 0.0, naive_rms = 0.0, lowest = kInfinity, naive_lowest = kInfinity;
  for (int f = 1; f <= 240; ++f) {
    for (BoxOnClothOnGround* s : {&pinched, &naive})
      s->w.world().stepSimulation(btScalar(1.0 / 60), 4, btScalar(1.0 / 240));
    if (f <= 120) continue;  // landed by frame 30
    rms += scenes::velocity_rms(pinched.coupling->system()) / 120.0;
    naive_rms += scenes::velocity_rms(naive.coupling->system()) / 120.0;
    lowest = std::min(lowest, pinched.lowest());
    naive_lowest = std::min(naive_lowest, naive.lowest());
  }
  EXPECT_NEAR(static_cast<double>(pinched.box->getCenterOfMassPosition().y()), 0.05, 1e-3);  // on the ground
  EXPECT_GE(pinched.coupling->pinches().size(), 9u);  // the nodes under a 10 cm box at 2.5 cm spacing
  EXPECT_LT(rms, 0.05);
  EXPECT_GT(lowest, 0.0);
  std::cout << "velocity RMS with pinching " << rms << " m/s, without " << naive_rms << " m/s; lowest node " << lowest
            << " m, without " << naive_lowest << " m\n";
  EXPECT_GT(naive_rms, 10 * rms);  // pinching still pays: 0.73 m/s without, 0.01 with
  EXPECT_GT(naive_lowest, 0.0);
}

// A pinch stiffness that is not a positive number is refused when the coupling is made, by name.
TEST(Pinching, ABadPinchStiffnessIsRefusedByName) {
  for (const double k : {0.0, -10.0, std::nan(""), kInfinity}) {
    BulletWorld w(btVector3(0, -9.81, 0));
    bullet::CouplingSettings settings;
    settings.pinching = true;
    settings.pinch_stiffness = k;
    try {
      bullet::Coupling coupling(&w.world(), settings);
      ADD_FAILURE() << "accepted pinch_stiffness " << k;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("pinch_stiffness"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// Sprinkled collision particles (section 2, figure 3): a coarse ball (a sphere surface of 642 vertices
// embedded in 10 cm lattice cells) whose surface vertices collide instead of its lattice's nodes.
struct SprinkledBall {
  scenes::ClosedSurface surface;
  EmbeddedVolume volume;
};
SprinkledBall coarse_ball(System& s, const Vec3& centre) {
  SprinkledBall b;
  b.surface = scenes::sphere_surface(3, 0.15, centre);
  VolumeMaterial material;
  material.density = 200.0;
  material.young_modulus = 3e4;
  material.damping = 0.02;
  b.volume = add_embedded_volume(s, b.surface.vertices, b.surface.triangles, 0.1, material);
  return b;
}

TEST(Sprinkle, BadSamplesAndSettingsAreRefusedByName) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bullet::Coupling coupling(&bw.world());
  const SprinkledBall ball = coarse_ball(coupling.system(), Vec3(0, 1, 0));
  const auto refused = [&](std::vector<Index> samples, const bullet::SprinkleSettings& settings, const char* says) {
    try {
      coupling.sprinkle(samples, settings);
      ADD_FAILURE() << "accepted: " << says;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
  };
  const Index node = ball.volume.lattice[0];
  refused({ball.volume.surface[0], node}, {}, ("sample " + std::to_string(node) + " is not hard-bound").c_str());
  refused({100000}, {}, "sample 100000 does not exist");
  refused({}, {}, "no samples");
  bullet::SprinkleSettings bad;
  bad.reach = std::nan("");
  refused(ball.volume.surface, bad, "reach nan");
  bad = {};
  bad.linger = -1.0;
  refused(ball.volume.surface, bad, "linger -1");
  EXPECT_EQ(coupling.sprinkled_count(coupling.sprinkle(ball.volume.surface, {})), 0);  // adaptive, nothing near

  BulletWorld plain(btVector3(0, -9.81, 0));
  bullet::CouplingSettings off;
  off.collisions = false;
  bullet::Coupling without(&plain.world(), off);
  const SprinkledBall other = coarse_ball(without.system(), Vec3(0, 1, 0));
  try {
    without.sprinkle(other.volume.surface, {});
    ADD_FAILURE() << "sprinkled with collisions off";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("collisions off"), std::string::npos) << e.what();
  }
}

// Adaptive sprinkling adds and removes particles at run time without changing what is simulated: a
// ball coasting in zero gravity past a static box (its surface passing 3 cm from the box, inside the
// 5 cm reach, never touching) gains collision particles on its near side and loses them once past, and
// its momentum and mass stay what they were, to round-off, throughout.
TEST(Sprinkle, ParticlesComeAndGoWithoutChangingMassOrMomentum) {
  BulletWorld bw(btVector3(0, 0, 0));
  add_box(bw, btVector3(0.1, 0.1, 0.1), 0.0, scenes::at(btVector3(0, 0.28, 0)));  // 3 cm above the ball's top
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const SprinkledBall ball = coarse_ball(s, Vec3(-0.6, 0, 0));
  for (const Index i : ball.volume.lattice) s.particles().v.col(i) = Vec3(1.0, 0, 0);
  bullet::SprinkleSettings settings;
  settings.linger = 0.05;
  const Index set = coupling.sprinkle(ball.volume.surface, settings);
  bw.world().stepSimulation(1.0 / 240, 1, 1.0 / 240);
  const Vec3 momentum = s.linear_momentum();
  const double mass = s.particles().mass.sum();
  Index most = 0, added_then_gone = 0;
  for (int tick = 0; tick < 300; ++tick) {
    bw.world().stepSimulation(1.0 / 240, 1, 1.0 / 240);
    const Index count = coupling.sprinkled_count(set);
    if (most > 0 && count == 0) added_then_gone = most;
    most = std::max(most, count);
    ASSERT_LT((s.linear_momentum() - momentum).norm(), 1e-12 * momentum.norm()) << "tick " << tick;
    // Soft particles carry their targets' effective masses beside the parents' (not counted twice in
    // the momentum); the parents' own masses are unchanged.
    double parents = 0.0;
    for (const Index i : ball.volume.lattice) parents += s.particles().mass[i];
    ASSERT_NEAR(parents, mass, 1e-12 * mass) << "tick " << tick;
  }
  EXPECT_GT(most, 10);                                     // the near side got collision particles
  EXPECT_LT(most, Index(ball.volume.surface.size()) / 3);  // and only the near side
  EXPECT_EQ(added_then_gone, most);                        // all gone once past
  for (const Index i : ball.volume.surface) EXPECT_LT(s.particles().x(1, i), 0.18 - 0.01 + 1e-9);  // nothing touched
}

// A ball sprinkled all over (static) rests on the ground on its embedded surface, not on the lattice's
// nodes (which lie up to a cell outside it and stop colliding): every surface vertex ends the
// collision thickness off the ground to a tenth of it, the nodes below it go through, and the
// surface is at rest. Resolved one contact at a time (CollisionContext::synchronize, push_drift) and
// held in step 4 on their targets' stencils, the dozen samples a bottom tet holds share its correction;
// pushed together at the step's end, unheld, they left this surface jittering at 4 cm/s (and threw
// the pressed balls of the sprinkle scene about at metres a second).
TEST(Sprinkle, ABallRestsOnItsSprinkledSurface) {
  BulletWorld bw(btVector3(0, -9.81, 0));
  bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0, btTransform::getIdentity());
  bullet::Coupling coupling(&bw.world());
  System& s = coupling.system();
  const SprinkledBall ball = coarse_ball(s, Vec3(0, 0.16, 0));
  bullet::SprinkleSettings settings;
  settings.adaptive = false;
  const Index set = coupling.sprinkle(ball.volume.surface, settings);
  EXPECT_EQ(coupling.sprinkled_count(set), Index(ball.volume.surface.size()));
  for (int tick = 0; tick < 360; ++tick) bw.world().stepSimulation(1.0 / 240, 1, 1.0 / 240);
  const double thickness = 0.01;
  double lowest = kInfinity, lowest_node = kInfinity, speed2 = 0.0;
  for (const Index i : ball.volume.surface) {
    lowest = std::min(lowest, s.particles().x(1, i));
    speed2 += s.particles().v.col(i).squaredNorm();
  }
  for (const Index i : ball.volume.lattice) lowest_node = std::min(lowest_node, s.particles().x(1, i));
  EXPECT_NEAR(lowest, thickness, 0.1 * thickness);
  EXPECT_LT(lowest_node, 0.0);
  EXPECT_LT(std::sqrt(speed2 / double(ball.volume.surface.size())), 0.01);

  // A sample the application removes loses its collision particle at the next tick.
  const Index gone = ball.volume.surface[5];
  const Index particle = coupling.sprinkled(set)[5];
  s.remove_particles(std::vector<Index>{gone});
  bw.world().stepSimulation(1.0 / 240, 1, 1.0 / 240);
  EXPECT_EQ(coupling.sprinkled(set)[5], -1);
  EXPECT_EQ(s.particles().kind[particle], ParticleKind::removed);
  EXPECT_EQ(coupling.sprinkled_count(set), Index(ball.volume.surface.size()) - 1);
}

}  // namespace
}  // namespace sinew
