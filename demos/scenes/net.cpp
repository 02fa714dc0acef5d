#include "bullet_scenes.hpp"

#include <cmath>

namespace sinew::scenes {
namespace {

// A net of rigid rods joined at their ends by implicit binding springs between hard-bound points on
// different bodies (point joints), its corners held, catching a heavy ball that Bullet drops into it.
class Net final : public BulletScene {
 public:
  Net() : BulletScene(btVector3(0, -9.81, 0)) {
    const int n = 6;  // joints per side
    const double spacing = 0.3, y = 1.0, rod_r = 0.015, rod_mass = 0.1;
    const double length = spacing - 2 * rod_r;
    const int rods = 4, everything = btBroadphaseProxy::AllFilter;
    btCollisionShape* along_x =
        m_world.keep(std::make_unique<btCapsuleShapeX>(btScalar(rod_r), btScalar(length - 2 * rod_r)));
    btCollisionShape* along_z =
        m_world.keep(std::make_unique<btCapsuleShapeZ>(btScalar(rod_r), btScalar(length - 2 * rod_r)));
    auto joint = [&](int i, int k) { return Vec3((i - 0.5 * (n - 1)) * spacing, y, (k - 0.5 * (n - 1)) * spacing); };
    // The points of each joint, joined in a chain by binding springs.
    std::vector<std::vector<Index>> at_joint(static_cast<std::size_t>(n * n));
    auto add_rod = [&](const Vec3& a, const Vec3& b, btCollisionShape* shape) {
      // Rods do not collide with each other (they overlap at the joints), only with the ball. Their
      // inertia is the transverse one about every axis: a thin rod's axial inertia is 1/500 of it, and
      // a glancing contact would spin it past what one step integrates well.
      const double transverse = rod_mass * length * length / 12.0;
      btRigidBody* rod = m_world.add_body(shape, rod_mass, at(to_bullet(0.5 * (a + b))),
                                          btVector3(btScalar(transverse), btScalar(transverse), btScalar(transverse)),
                                          rods, everything ^ rods);
      rod->setActivationState(DISABLE_DEACTIVATION);
      for (const Vec3& end : {a, b}) {
        const Index p = system().add_particle(end, Vec3::Zero(), 0.0);
        coupling().bind_here(p, rod);
        at_joint[static_cast<std::size_t>(std::lround((end.x() / spacing + 0.5 * (n - 1))) * n +
                                          std::lround(end.z() / spacing + 0.5 * (n - 1)))]
            .push_back(p);
      }
    };
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) {
        if (i + 1 < n) add_rod(joint(i, k), joint(i + 1, k), along_x);
        if (k + 1 < n) add_rod(joint(i, k), joint(i, k + 1), along_z);
      }
    for (std::size_t j = 0; j < at_joint.size(); ++j)
      for (std::size_t a = 1; a < at_joint[j].size(); ++a)
        system().add_binding_spring({at_joint[j][a - 1], at_joint[j][a], 2e5, 1.0});
    for (auto [i, k] : {std::pair{0, 0}, std::pair{0, n - 1}, std::pair{n - 1, 0}, std::pair{n - 1, n - 1}}) {
      const Index anchor = system().add_kinematic_particle(joint(i, k));
      system().add_binding_spring({anchor, at_joint[static_cast<std::size_t>(i * n + k)].front(), 2e5, 1.0});
    }
    btCollisionShape* ball = m_world.keep(std::make_unique<btSphereShape>(0.2));
    m_ball = m_world.add_body(ball, 5.0, at(btVector3(0.05, 2.0, -0.03)));
    m_ball->setActivationState(DISABLE_DEACTIVATION);
  }
  // Stiff point joints between light rods meet the ball's contacts. Solved by Bullet after the step,
  // which did not know them, they fed energy in at every landing (at 1/240 s ticks +4.7 J between
  // frames 200 and 300, and 127 J by frame 450 before the joints' ends were settled), and the scene
  // ran at 1/480 s ticks. The step holds them with the springs (CouplingSettings::body_contacts: the
  // ball joins the coupling when it first touches a rod), and the energy never rises above its start
  // at 8, 4, 2 or 1 ticks per frame (600 frames); the scene runs at the default 4.
  btRigidBody* ball() const { return m_ball; }

 private:
  btRigidBody* m_ball = nullptr;
};

SINEW_REGISTER_SCENE(bullet_scene<Net>(
    {.name = "net",
     .description =
         "figure 13: a net of rigid rods joined by binding springs, held at its corners, catching a 5 kg ball",
     .gallery_frame = 100}));

}  // namespace
}  // namespace sinew::scenes
