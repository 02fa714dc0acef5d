#include "bullet_scenes.hpp"

#include <cmath>

namespace sinew::scenes {
namespace {

// Issue 21's second Bullet scene: a soft ball squeezed between two Bullet panels that Bullet pushes
// together. The ball is a closed sphere surface (320 triangles) embedded in a BCC lattice of 4 cm
// cells (add_embedded_volume: the lattice carries the material's mass and elasticity, the surface is
// hard-bound to it by barycentric weights); it rests on the ground. Two dynamic panels (1 kg, locked
// by Bullet's linear and angular factors to slide along x only) stand on either side; a constant
// force of kPush newtons drives each towards the ball, applied through Bullet (applyCentralForce
// before every frame). The lattice's nodes collide with the panels, which take the opposite impulses,
// so the panels stop where the squeezed ball's contact forces balance the push.
class Squeeze final : public BulletScene {
 public:
  Squeeze() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    btCollisionShape* panel = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.01, 0.15, 0.15)));
    for (int side = 0; side < 2; ++side) {
      const double x = (side == 0 ? -1.0 : 1.0) * (kRadius + 0.01 + kStartGap);
      m_panel[side] = m_world.add_body(panel, 1.0, at(btVector3(btScalar(x), btScalar(0.155), 0)));
      m_panel[side]->setLinearFactor(btVector3(1, 0, 0));
      m_panel[side]->setAngularFactor(btVector3(0, 0, 0));
      m_panel[side]->setActivationState(DISABLE_DEACTIVATION);
      m_panel[side]->setFriction(0.5);  // its lower edge 5 mm above the ground: it slides on nothing
    }
    const ClosedSurface ball = sphere_surface(2, kRadius, Vec3(0, kRadius + 0.011, 0));
    VolumeMaterial material;
    material.density = 300.0;
    material.young_modulus = 5e3;
    material.poisson_ratio = 0.3;
    material.damping = 0.02;
    m_ball = add_embedded_volume(system(), ball.vertices, ball.triangles, kSpacing, material);
    add_surface("ball", embedded_skin(m_ball, ball.triangles));
  }
  void before_frame(double) override {
    for (int side = 0; side < 2; ++side)
      m_panel[side]->applyCentralForce(btVector3(btScalar(side == 0 ? kPush : -kPush), 0, 0));
  }
  const EmbeddedVolume& ball() const { return m_ball; }
  btRigidBody* panel(int side) const { return m_panel[side]; }

  static constexpr double kRadius = 0.12, kSpacing = 0.04, kStartGap = 0.03, kPush = 20.0;

 private:
  btRigidBody* m_panel[2] = {nullptr, nullptr};
  EmbeddedVolume m_ball;
};

SINEW_REGISTER_SCENE({.name = "squeeze",
                      .description = "a soft ball (a closed surface embedded in a BCC tet lattice) squeezed "
                                     "between two Bullet panels pushed together by 20 N",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Squeeze>(); },
                      .gallery_frame = 120});

}  // namespace
}  // namespace sinew::scenes
