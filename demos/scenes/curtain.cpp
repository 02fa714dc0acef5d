#include "bullet_scenes.hpp"

#include <cmath>
#include <numbers>

namespace sinew::scenes {
namespace {

// A torus approximated by capsules around a circle of radius R in the body's y-z plane (axis x);
// tube radius r. Principal inertia of a thin torus: I_axis = m (R^2 + 3/4 r^2), I_diameter =
// m (R^2/2 + 5/8 r^2).
btCollisionShape* ring_shape(BulletWorld& w, double R, double r, int segments) {
  auto ring = std::make_unique<btCompoundShape>();
  const double step = 2.0 * std::numbers::pi / segments;
  const double chord = 2.0 * R * std::sin(0.5 * step);
  btCollisionShape* capsule = w.keep(std::make_unique<btCapsuleShapeX>(btScalar(r), btScalar(chord)));
  for (int i = 0; i < segments; ++i) {
    const double a = (i + 0.5) * step;
    // A capsule along x, turned to lie tangent to the circle in the y-z plane.
    const btQuaternion turn(btVector3(0, 0, 1), btScalar(std::numbers::pi / 2));
    const btQuaternion around(btVector3(1, 0, 0), btScalar(a));
    ring->addChildShape(at(btVector3(0, btScalar(R * std::cos(a)), btScalar(R * std::sin(a))), around * turn), capsule);
  }
  return w.keep(std::move(ring));
}

// A cloth curtain hung by its top edge from ten rigid rings on a static rod; the rings slide along the
// rod by Bullet's own contact, and a kinematic handle draws the free edge open and closed. Bodies, in
// order: the rod, the ten rings, the handle, the two finials (tests/test_demos.cpp reads them so).
//
// The main demo (.ci/demo), so it must run in real time. The springs enter sinew's solves
// (implicit_elasticity), so they no longer limit its step: with bending explicit, whose stable step at
// this spacing is about a 1/240 s tick, sinew takes one step per Bullet tick; explicit, the springs'
// stable step asked for substeps inside each tick (about 40 ms a frame on the 2-core machine). Bending implicit too
// would let the ticks grow, but doubles each CG product (implicit bending was 35% of the frame,
// springs 17%), so four ticks with explicit bending are cheaper. Block Jacobi to 1e-4 m/s, as the
// benchmark's implicit settings: far below the step's own error.
class Curtain final : public BulletScene {
 public:
  Curtain() : BulletScene(btVector3(0, -9.81, 0)) {
    const double rod_y = 2.1, rod_r = 0.015, ring_R = 0.04, ring_r = 0.006, ring_mass = 0.05;
    btRigidBody* rod = m_world.add_body(m_world.keep(std::make_unique<btCylinderShapeX>(
                                            btVector3(btScalar(kRodHalfLength), btScalar(rod_r), btScalar(rod_r)))),
                                        0.0, at(btVector3(0, btScalar(rod_y), 0)));
    rod->setFriction(0.15);
    btCollisionShape* ring = ring_shape(m_world, ring_R, ring_r, 16);
    const double ring_y = rod_y + rod_r - (ring_R - ring_r);  // resting on the rod
    const btVector3 ring_inertia(btScalar(ring_mass * (ring_R * ring_R + 0.75 * ring_r * ring_r)),
                                 btScalar(ring_mass * (0.5 * ring_R * ring_R + 0.625 * ring_r * ring_r)),
                                 btScalar(ring_mass * (0.5 * ring_R * ring_R + 0.625 * ring_r * ring_r)));
    ClothGridSettings c;
    c.nx = 37;
    c.ny = 37;
    c.width = 1.8;
    c.height = 1.8;
    c.mass = 0.5;
    c.origin = Vec3(-0.9, ring_y - ring_R, 0.0);
    m_cloth = add_cloth_grid(system(), c);
    StepSettings& step = system().step_settings();
    step.implicit_elasticity = true;
    step.cg_tolerance = 1e-4;
    add_surface("curtain", m_cloth.triangles);
    for (int i = 0; i < 10; ++i) {
      btRigidBody* body =
          m_world.add_body(ring, ring_mass, at(btVector3(btScalar(-0.9 + 0.2 * i), btScalar(ring_y), 0)), ring_inertia);
      body->setFriction(0.15);
      body->setActivationState(DISABLE_DEACTIVATION);
      m_rings.push_back(body);
      coupling().bind_here(m_cloth.node(4 * i, 0), body);  // the ring's lowest point
    }
    // The handle: a kinematic body beside the free edge, tied to the last ring's cloth node.
    btCollisionShape* knob = m_world.keep(std::make_unique<btSphereShape>(0.02));
    m_handle = m_world.add_body(knob, 0.0, at(btVector3(0.95, btScalar(ring_y - ring_R), 0.0)), btVector3(0, 0, 0),
                                btBroadphaseProxy::DefaultFilter, 0);  // touches nothing
    m_handle->setCollisionFlags(m_handle->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    m_handle->setActivationState(DISABLE_DEACTIVATION);
    const Index grip = system().add_particle(to_eigen(m_handle->getWorldTransform().getOrigin()), Vec3::Zero(), 0.0);
    coupling().bind_here(grip, m_handle);
    system().add_binding_spring({grip, m_cloth.node(36, 0), 2e3, 1.0});
    m_handle_y = ring_y - ring_R;
    // Finials: a ball at each end of the rod, wider than a ring's hole (0.05 m against 0.034 m), as on
    // a real curtain rod. Without them the rings, pushed along by the folding cloth, slid off the rod's
    // end at frame 226.
    btCollisionShape* finial = m_world.keep(std::make_unique<btSphereShape>(btScalar(kFinialRadius)));
    for (double end : {-kRodHalfLength, kRodHalfLength})
      m_world.add_body(finial, 0.0, at(btVector3(btScalar(end), btScalar(rod_y), 0)))->setFriction(0.15);
  }
  void before_frame(double t) override {
    // Drawn from x = 0.95 to -0.35 and back every 8 s (closing first).
    const double x = 0.3 + 0.65 * std::cos(2.0 * std::numbers::pi * t / 8.0);
    m_handle->getMotionState()->setWorldTransform(at(btVector3(btScalar(x), btScalar(m_handle_y), 0)));
  }
  const std::vector<btRigidBody*>& rings() const { return m_rings; }

 private:
  static constexpr double kRodHalfLength = 1.3, kFinialRadius = 0.05;  // [m]
  ClothGrid m_cloth;
  std::vector<btRigidBody*> m_rings;
  btRigidBody* m_handle = nullptr;
  double m_handle_y = 0.0;
};

SINEW_REGISTER_SCENE(bullet_scene<Curtain>({.name = "curtain",
                                            .description = "figure 15: a cloth curtain on ten rings sliding along a "
                                                           "rod, drawn closed and open by a handle (the main demo)",
                                            .gallery_frame = 150}));

}  // namespace
}  // namespace sinew::scenes
