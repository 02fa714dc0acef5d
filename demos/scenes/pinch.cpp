#include "bullet_scenes.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace sinew::scenes {
namespace {

// Figure 10: a cloth pinched between two Bullet spheres driven together. A 0.6 m cloth hangs from a
// static bar by its top row; two kinematic spheres (radius 0.1 m) close on its middle from either
// side until they overlap each other by 2 cm (0.75 s, eased), hold, and at 1.5 s the bar lets go
// (Coupling::remove), so the cloth hangs from the pinch alone; at 4 s the spheres part again (0.75 s)
// and let it fall. With pinching (CouplingSettings::
// pinching, on here) each pinched node gets two soft-bound duplicates, one colliding with each
// sphere, and hangs between them on their binding springs, held by their friction. `pinch/naive`
// runs the same scene with pinching off: each node is pushed out of the nearer sphere, that is into
// the other one, and the cloth slides out of the grip.
class Pinch final : public BulletScene {
 public:
  explicit Pinch(bool pinching) : BulletScene(btVector3(0, -9.81, 0), settings(pinching)) {
    btCollisionShape* bar = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.35, 0.01, 0.01)));
    m_bar = m_world.add_body(bar, 0.0, at(btVector3(0, btScalar(kTop + 0.011), 0)));
    btCollisionShape* ball = m_world.keep(std::make_unique<btSphereShape>(btScalar(kRadius)));
    for (int side = 0; side < 2; ++side) {
      m_sphere[side] = m_world.add_body(ball, 0.0, pose(side, 0.0));
      m_sphere[side]->setCollisionFlags(m_sphere[side]->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      m_sphere[side]->setActivationState(DISABLE_DEACTIVATION);
      m_sphere[side]->setFriction(1.0);
    }
    ClothGridSettings c;
    c.nx = c.ny = 25;
    c.width = c.height = 0.6;
    c.mass = 0.1;
    c.origin = Vec3(-0.3, kTop, 0.0);
    m_cloth = add_cloth_grid(system(), c);
    add_surface("cloth", m_cloth.triangles);
    for (int i = 0; i < m_cloth.nx; ++i) coupling().bind_here(m_cloth.node(i, 0), m_bar);
  }
  void before_frame(double t) override {
    for (int side = 0; side < 2; ++side) m_sphere[side]->getMotionState()->setWorldTransform(pose(side, t));
    if (t >= kLetGo && m_bar) {
      coupling().remove(m_bar);
      m_bar = nullptr;
    }
  }
  const ClothGrid& cloth() const { return m_cloth; }

  static constexpr double kTop = 1.3, kRadius = 0.1, kStart = 0.25, kEnd = 0.09, kClose = 0.75, kLetGo = 1.5,
                          kOpen = 4.0;

 private:
  static bullet::CouplingSettings settings(bool pinching) {
    bullet::CouplingSettings s;
    s.pinching = pinching;
    return s;
  }
  // Sphere `side` (0 at -z, 1 at +z) at time t: centres at the middle of the cloth, closing from
  // kStart to kEnd from the cloth's plane over kClose seconds (cosine ease), and opening again from
  // kOpen.
  static btTransform pose(int side, double t) {
    const double s = t < kOpen ? std::min(t / kClose, 1.0) : std::max(1.0 - (t - kOpen) / kClose, 0.0);
    const double z = kStart + (kEnd - kStart) * 0.5 * (1.0 - std::cos(std::numbers::pi * s));
    return at(btVector3(0, btScalar(kTop - 0.3), btScalar(side == 0 ? -z : z)));
  }

  btRigidBody* m_bar = nullptr;
  btRigidBody* m_sphere[2] = {nullptr, nullptr};
  ClothGrid m_cloth;
};

SINEW_REGISTER_SCENE({.name = "pinch",
                      .description = "figure 10: a hanging cloth pinched between two spheres driven together, "
                                     "then let go from its bar (soft-bound duplicates hold it)",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Pinch>(true); },
                      .gallery_frame = 150});
SINEW_REGISTER_SCENE({.name = "pinch/naive",
                      .description = "the pinch scene with CouplingSettings::pinching off: one particle per node, "
                                     "pushed out of the nearer sphere",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Pinch>(false); }});

}  // namespace
}  // namespace sinew::scenes
