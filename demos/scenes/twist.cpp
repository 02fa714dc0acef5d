#include "bullet_scenes.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace sinew::scenes {
namespace {

// The standard self-contact stress test: a square cloth of 1 m held along two opposite edges by two
// rigid bars that turn in opposite directions about the axis between them, half a turn a second
// each, while they close in from 1 m to 0.6 m apart over the first two seconds; the cloth winds into
// a rope that presses against itself everywhere. The bars are kinematic Bullet bodies (the
// application moves them through their motion states, as Bullet's kinematic bodies are moved); each
// holds its edge's nodes by hard bindings on its frame (Coupling::bind_here). Gravity pulls; the
// contact is CouplingSettings::self_collisions. 32 x 32 nodes unless the program asks for more
// (--nx, --ny: the speed goal is 100 x 100).
class Twist final : public BulletScene {
 public:
  explicit Twist(const SceneParams& params) : BulletScene(btVector3(0, -9.81, 0), settings()) {
    btCollisionShape* bar = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.01, 0.01, 0.55)));
    for (int side = 0; side < 2; ++side) {
      m_bar[side] = m_world.add_body(bar, 0.0, pose(side, 0.0));
      m_bar[side]->setCollisionFlags(m_bar[side]->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      m_bar[side]->setActivationState(DISABLE_DEACTIVATION);
    }
    ClothGridSettings c;
    c.nx = params.nx > 0 ? params.nx : 32;
    c.ny = params.ny > 0 ? params.ny : 32;
    c.width = c.height = 2.0 * kHalfSpan;
    c.mass = 0.2;
    c.stretch_stiffness = 500.0;
    c.origin = Vec3(-kHalfSpan, kHeight, -kHalfSpan);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();
    m_cloth = add_cloth_grid(system(), c);
    add_surface("cloth", m_cloth.triangles);
    for (int j = 0; j < m_cloth.ny; ++j) {
      coupling().bind_here(m_cloth.node(0, j), m_bar[0]);
      coupling().bind_here(m_cloth.node(m_cloth.nx - 1, j), m_bar[1]);
    }
  }
  void before_frame(double t) override {
    for (int side = 0; side < 2; ++side) m_bar[side]->getMotionState()->setWorldTransform(pose(side, t));
  }

 private:
  static constexpr double kHalfSpan = 0.5, kHeight = 1.0, kClosing = 0.2, kClosingTime = 2.0;
  static bullet::CouplingSettings settings() {
    bullet::CouplingSettings s;
    s.self_collisions = true;
    return s;
  }
  // Bar `side` (0: at -x, turning positively about +x; 1: at +x, negatively) at time t.
  static btTransform pose(int side, double t) {
    const double sign = side == 0 ? -1.0 : 1.0;
    const double x = sign * (kHalfSpan - kClosing * std::min(t, kClosingTime) / kClosingTime);
    const double angle = -sign * std::numbers::pi * t;  // half a turn a second
    return at(btVector3(btScalar(x), btScalar(kHeight), 0), btQuaternion(btVector3(1, 0, 0), btScalar(angle)));
  }

  btRigidBody* m_bar[2] = {nullptr, nullptr};
  ClothGrid m_cloth;
};

SINEW_REGISTER_SCENE({.name = "twist",
                      .description = "a cloth held by two bars turning in opposite directions winds into a rope "
                                     "(self contact stress test; --nx, --ny)",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams& p) { return std::make_unique<Twist>(p); },
                      .gallery_frame = 150,
                      .takes_grid = true});

}  // namespace
}  // namespace sinew::scenes
