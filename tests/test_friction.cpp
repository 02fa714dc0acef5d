// Coulomb friction between deformables and Bullet's static and kinematic bodies, against the
// analytic motion of a body sliding on a plane: deceleration mu g, stopping distance v0^2 / (2 mu g),
// sticking below the friction angle, x = a t^2 / 2 above it with a = g (sin theta - mu cos theta), and
// a cloth carried by a moving belt. A resting contact has no approach for step 3 to stop; its friction
// comes from the load step 4's projection carries (Newmark::apply_surface_friction) and, for the
// step's displacement, from the push step 3 gives (BulletCollisions::hold_by_friction).
#include "bullet_scenes.hpp"
#include "cloth.hpp"
#include "sinew/builders.hpp"
#include "sinew/bullet/convert.hpp"
#include "sinew/bullet/coupling.hpp"

#include <btBulletDynamicsCommon.h>
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

namespace sinew {
namespace {

constexpr double kG = 9.81;
constexpr double kTick = 1.0 / 240;

// A 0.5 m cloth of 10 x 10 nodes lying flat at the collision thickness on a static plane tilted by
// `slope` degrees (gravity turned instead of the plane: down-slope is +x).
struct ClothOnPlane {
  scenes::BulletWorld bw;
  std::unique_ptr<bullet::Coupling> coupling;
  scenes::ClothGrid cloth;

  ClothOnPlane(double slope_degrees, double mu, double v0, bool plane = true)
      : bw(btVector3(btScalar(kG * std::sin(slope_degrees * M_PI / 180)),
                     btScalar(-kG * std::cos(slope_degrees * M_PI / 180)), 0)) {
    if (plane)
      bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0,
                  btTransform::getIdentity());
    bullet::CouplingSettings settings;
    settings.friction = mu;
    coupling = std::make_unique<bullet::Coupling>(&bw.world(), settings);
    // Solved to a tolerance, not to the automatic scheme's RMS bound (whose accepted guesses leave
    // the nodes' speeds 1e-4 m/s apart): the figures below are exact to round-off.
    coupling->system().step_settings().automatic = false;
    coupling->system().step_settings().cg_tolerance = 1e-12;
    scenes::ClothGridSettings c;
    c.nx = c.ny = 10;
    c.width = c.height = 0.5;
    c.mass = 0.1;
    c.origin = {-0.25, settings.thickness, -0.25};
    c.down = {0, 0, 1};
    cloth = scenes::add_cloth_grid(coupling->system(), c);
    for (Index n : cloth.nodes) system().particles().v(0, n) = v0;
  }
  System& system() { return coupling->system(); }
  // Bullet's gravity as it holds it (single precision in Debian's build): the figures to compare with.
  Vec3 gravity() { return bullet::to_eigen(bw.world().getGravity()); }
  void tick() { bw.world().stepSimulation(btScalar(kTick), 1, btScalar(kTick)); }
  Vec3 mean(const Vectors3& of) {
    Vec3 m = Vec3::Zero();
    for (Index n : cloth.nodes) m += of.col(n);
    return m / double(cloth.nodes.size());
  }
  double slowest_fastest_gap() {  // the spread of the nodes' speeds along x
    double lo = kInfinity, hi = -kInfinity;
    for (Index n : cloth.nodes) {
      lo = std::min(lo, system().particles().v(0, n));
      hi = std::max(hi, system().particles().v(0, n));
    }
    return hi - lo;
  }
};

// Deceleration mu g exactly while it slides, then at rest for good, having slid v0^2 / (2 mu g):
// Newmark's trapezoid is exact for a constant deceleration, and the stop inside a step is where the
// step's end velocity would pass zero.
TEST(Friction, ASlidingClothStopsAtCoulombsDistance) {
  for (const double mu : {0.2, 0.5, 1.0}) {
    const double v0 = 1.0;
    ClothOnPlane scene(0.0, mu, v0);
    const double g = -scene.gravity().y();
    const double stop = v0 / (mu * g);
    const Vec3 x0 = scene.mean(scene.system().particles().x);
    double kinetic = kInfinity;
    int ticks = 0;
    for (; ticks * kTick < stop - kTick; ++ticks) {
      scene.tick();
      const double t = (ticks + 1) * kTick;
      const Vec3 v = scene.mean(scene.system().particles().v);
      ASSERT_NEAR(v.x(), v0 - mu * g * t, 1e-9) << "mu " << mu << ", t " << t;
      ASSERT_LT(scene.slowest_fastest_gap(), 1e-9) << "mu " << mu << ", t " << t;
      const double now = 0.5 * v.squaredNorm();
      ASSERT_LE(now, kinetic) << "mu " << mu << ", t " << t;
      kinetic = now;
    }
    for (int more = 0; more < 240; ++more) scene.tick();
    const Vec3 x1 = scene.mean(scene.system().particles().x);
    EXPECT_LT(scene.system().particles().v.cwiseAbs().maxCoeff(), 1e-12) << "mu " << mu;
    // Within the step that stops it: it ends the step at rest, having moved v dt / 2 in it at most.
    EXPECT_NEAR(x1.x() - x0.x(), v0 * v0 / (2.0 * mu * g), mu * g * kTick * kTick) << "mu " << mu;
    EXPECT_NEAR(x1.y(), x0.y(), 1e-12) << "mu " << mu;
    EXPECT_NEAR(x1.z(), x0.z(), 1e-12) << "mu " << mu;
    for (int more = 0; more < 240; ++more) scene.tick();
    EXPECT_EQ(scene.mean(scene.system().particles().x), x1) << "mu " << mu;
  }
}

// Below the friction angle (tan theta < mu) a cloth set down on a slope never moves, not even by the
// dt^2 g_t / 2 a step's prediction slides it; above it, it slides with a = g (sin - mu cos).
TEST(Friction, AClothOnASlopeSticksBelowTheFrictionAngleAndSlidesAbove) {
  const double mu = 0.3;  // friction angle 16.7 degrees
  for (const double slope : {5.0, 16.0}) {
    ClothOnPlane scene(slope, mu, 0.0);
    const Vectors3 x0 = scene.system().particles().x;
    for (int tick = 0; tick < 480; ++tick) scene.tick();
    EXPECT_LT((scene.system().particles().x - x0).cwiseAbs().maxCoeff(), 1e-12) << slope << " degrees";
    EXPECT_LT(scene.system().particles().v.cwiseAbs().maxCoeff(), 1e-12) << slope << " degrees";
  }
  for (const double slope : {18.0, 30.0}) {
    ClothOnPlane scene(slope, mu, 0.0);
    const Vec3 g = scene.gravity();
    const double a = g.x() + mu * g.y();
    const Vec3 x0 = scene.mean(scene.system().particles().x);
    const int ticks = 240;
    for (int tick = 0; tick < ticks; ++tick) scene.tick();
    const double t = ticks * kTick;
    EXPECT_NEAR(scene.mean(scene.system().particles().v).x(), a * t, 1e-9) << slope << " degrees";
    EXPECT_NEAR(scene.mean(scene.system().particles().x).x() - x0.x(), 0.5 * a * t * t, 1e-9) << slope << " degrees";
  }
}

// Without a coefficient nothing slows it: the slide keeps its speed to round-off.
TEST(Friction, AFrictionlessClothKeepsItsSpeed) {
  ClothOnPlane scene(0.0, 0.0, 1.0);
  for (int tick = 0; tick < 240; ++tick) scene.tick();
  EXPECT_NEAR(scene.mean(scene.system().particles().v).x(), 1.0, 1e-12);
}

// A kinematic belt moving at u under a cloth at rest: friction accelerates the cloth at mu g until it
// moves with the belt (the contact's surface velocity, not zero, is what friction drives it toward),
// then carries it without slip. Bullet reads the belt's velocity from its single-precision poses, to
// about 1e-6 m/s.
TEST(Friction, AMovingBeltCarriesAClothUpToItsSpeed) {
  const double mu = 0.4, u = 0.6;
  ClothOnPlane scene(0.0, mu, 0.0, false);
  btRigidBody* belt = scene.bw.add_body(scene.bw.keep(std::make_unique<btBoxShape>(btVector3(5, 0.1, 2))), 0.0,
                                        scenes::at(btVector3(0, -0.1, 0)));
  scene.bw.world().removeRigidBody(belt);  // Bullet animates a kinematic body only if added as one
  belt->setCollisionFlags((belt->getCollisionFlags() & ~btCollisionObject::CF_STATIC_OBJECT) |
                          btCollisionObject::CF_KINEMATIC_OBJECT);
  belt->setActivationState(DISABLE_DEACTIVATION);
  scene.bw.world().addRigidBody(belt);
  const double g = -scene.gravity().y();
  for (int tick = 1; tick <= 240; ++tick) {
    belt->getMotionState()->setWorldTransform(scenes::at(btVector3(btScalar(u * tick * kTick), -0.1, 0)));
    scene.tick();
    const double t = tick * kTick;
    const double expected = std::min(u, mu * g * t);
    ASSERT_NEAR(scene.mean(scene.system().particles().v).x(), expected, 1e-5) << "t " << t;
  }
  EXPECT_NEAR(scene.mean(scene.system().particles().x).y(), 0.01, 1e-9);
}

// A soft cube sliding on its sprinkled (synchronized soft-bound) surface, the surface embedded in a
// coarse lattice: the contacts hold the samples' targets' stencils, and friction acts there too. The
// cube's mean speed falls at mu g to within its wobble and it ends at rest near v0^2 / (2 mu g).
TEST(Friction, ASoftCubeSlidingOnItsSprinkledSurfaceStops) {
  const double mu = 0.5, v0 = 1.0;
  scenes::BulletWorld bw(btVector3(0, -kG, 0));
  bw.add_body(bw.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0)), 0.0, btTransform::getIdentity());
  bullet::CouplingSettings settings;
  settings.friction = mu;
  bullet::Coupling coupling(&bw.world(), settings);
  System& s = coupling.system();
  const scenes::ClosedSurface surface = scenes::box_surface(Vec3(-0.1, 0.01, -0.1), Vec3(0.1, 0.21, 0.1), 3);
  VolumeMaterial material;
  material.density = 200.0;
  material.young_modulus = 3e4;
  material.damping = 0.02;
  const EmbeddedVolume volume = add_embedded_volume(s, surface.vertices, surface.triangles, 0.1, material);
  bullet::SprinkleSettings sprinkle;
  sprinkle.adaptive = false;
  coupling.sprinkle(volume.surface, sprinkle);
  for (Index i = 0; i < s.particles().size(); ++i) s.particles().v(0, i) = v0;
  const auto momentum_x = [&] {
    double p = 0.0, m = 0.0;
    for (Index i : volume.lattice) {
      p += s.particles().mass[i] * s.particles().v(0, i);
      m += s.particles().mass[i];
    }
    return p / m;
  };
  const double stop = v0 / (mu * kG);
  double x0 = 0.0;
  for (Index i : volume.surface) x0 += s.particles().x(0, i) / double(volume.surface.size());
  int tick = 0;
  for (; tick * kTick < 0.5 * stop; ++tick) bw.world().stepSimulation(btScalar(kTick), 1, btScalar(kTick));
  EXPECT_NEAR(momentum_x(), v0 - mu * kG * tick * kTick, 0.1 * v0);
  for (; tick < 480; ++tick) bw.world().stepSimulation(btScalar(kTick), 1, btScalar(kTick));
  EXPECT_LT(std::abs(momentum_x()), 1e-3);
  double x1 = 0.0;
  for (Index i : volume.surface) x1 += s.particles().x(0, i) / double(volume.surface.size());
  EXPECT_NEAR(x1 - x0, v0 * v0 / (2.0 * mu * kG), 0.2 * v0 * v0 / (2.0 * mu * kG));
}

}  // namespace
}  // namespace sinew
