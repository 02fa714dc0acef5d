#include "bullet_scenes.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Issue 21's scene for what the plugin is for: flesh on bones. An arm hangs from a fixed shoulder:
// two Bullet capsules (upper arm 1 kg, forearm 0.6 kg) joined by hinges about z, the shoulder's to the
// world and the elbow's between the bones, with a motor Bullet drives. The flesh is one capsule of
// soft material around both (a closed surface embedded in a BCC lattice, add_embedded_volume); the
// lattice's nodes near each bone's axis are hard-bound to that bone (section 5's rigid frames), those
// around the elbow are free, so the flesh there bends as the joint turns. The bones carry the bound
// flesh's mass (Bullet's bodies are handed it) and the free flesh hangs from them two-way.
//
// For 1.5 s the arm hangs passive (the motor off) and settles; then the elbow's motor bends the
// forearm up to kFlexAngle and holds it. Both hinges' equality rows are held inside sinew's step (the
// motor and the limits are Bullet's). One Bullet tick a frame.
class Limb final : public BulletScene {
 public:
  Limb() : BulletScene(btVector3(0, -9.81, 0)) {
    const double upper_half = 0.13, fore_half = 0.11;
    btCollisionShape* upper_shape = m_world.keep(std::make_unique<btCapsuleShape>(0.015f, btScalar(2 * upper_half)));
    btCollisionShape* fore_shape = m_world.keep(std::make_unique<btCapsuleShape>(0.012f, btScalar(2 * fore_half)));
    // The bones and the flesh never collide (the flesh surrounds them): the bones are in their own
    // collision group, the flesh's particles leave it out of their mask.
    const int bones = btBroadphaseProxy::CharacterFilter;
    m_upper = m_world.add_body(upper_shape, 1.0, at(btVector3(0, btScalar(kUpperCentre), 0)), btVector3(0, 0, 0), bones,
                               btBroadphaseProxy::AllFilter);
    m_fore = m_world.add_body(fore_shape, 0.6, at(btVector3(0, btScalar(kForeCentre), 0)), btVector3(0, 0, 0), bones,
                              btBroadphaseProxy::AllFilter);
    for (btRigidBody* b : {m_upper, m_fore}) b->setActivationState(DISABLE_DEACTIVATION);
    auto shoulder = std::make_unique<btHingeConstraint>(*m_upper, btVector3(0, 0.15f, 0), btVector3(0, 0, 1));
    m_world.add_constraint(std::move(shoulder));
    auto elbow = std::make_unique<btHingeConstraint>(*m_upper, *m_fore, btVector3(0, -0.15f, 0), btVector3(0, 0.13f, 0),
                                                     btVector3(0, 0, 1), btVector3(0, 0, 1));
    elbow->setLimit(btScalar(-0.1), btScalar(2.0));
    // The motor is Bullet's: its impulse, bending the flesh, is large, and Bullet's solver balances it
    // with the hinge's own rows by iterating. At its default 10 iterations the answer leaves the
    // elbow's rows violated and the bones drift apart at the elbow by 5.5 mm over 1.5 s of bending
    // (the step's rows then close 20% of the gap a tick); at 50, by a few micrometres.
    m_world.world().getSolverInfo().m_numIterations = 50;
    m_elbow = static_cast<btHingeConstraint*>(m_world.add_constraint(std::move(elbow)));

    const ClosedSurface arm = capsule_surface(Vec3(0, kHand, 0), Vec3(0, kShoulder - 0.02, 0), kRadius, 24, 24, 6);
    VolumeMaterial material;
    material.density = 1000.0;
    material.young_modulus = 3e4;
    material.poisson_ratio = 0.3;
    material.damping = 0.01;
    material.implicit = true;
    m_flesh = add_embedded_volume(system(), arm.vertices, arm.triangles, kSpacing, material);
    for (const Index i : m_flesh.lattice) {
      system().set_collision_filter(i, kDefaultCollisionGroup, kAllCollisionGroups & ~std::uint32_t(bones));
      m_flesh_mass += system().particles().mass[i];
    }
    for (const Index i : m_flesh.surface)
      system().set_collision_filter(i, kDefaultCollisionGroup, kAllCollisionGroups & ~std::uint32_t(bones));
    // Bind the nodes within reach of a bone's axis, over a stretch centred on the bone, to it; those
    // around the elbow stay free. Centred, the bound flesh leaves the merged centre of mass near
    // Bullet's: what Bullet solves alone (the motor) sees the merged mass at Bullet's centre, exact
    // only where the two coincide (plugin/README.md, "Mass bound to a body").
    const double reach = 0.015 + 0.75 * kSpacing;
    for (const Index i : m_flesh.lattice) {
      const Vec3 x = system().particles().x.col(i);
      if (std::hypot(x.x(), x.z()) > reach) continue;
      // Each bone's stretch ends kFreeAroundElbow from the elbow and reaches as far the other way.
      if (std::abs(x.y() - kUpperCentre) < kUpperCentre - (kElbow + kFreeAroundElbow)) {
        coupling().bind_here(i, m_upper);
        ++m_bound[0];
      } else if (std::abs(x.y() - kForeCentre) < (kElbow - kFreeAroundElbow) - kForeCentre) {
        coupling().bind_here(i, m_fore);
        ++m_bound[1];
      }
    }
    add_surface("flesh", embedded_skin(m_flesh, arm.triangles));
  }

  int default_substeps() const override { return 1; }

  void before_frame(double time) override {
    if (time < kRelax) return;
    // A proportional servo on the elbow's angle through Bullet's motor: the target velocity closes
    // the error in about 0.25 s, limited to kFlexSpeed.
    const double error = kFlexAngle - m_elbow->getHingeAngle();
    const double speed = std::clamp(4.0 * error, -kFlexSpeed, kFlexSpeed);
    m_elbow->enableAngularMotor(true, btScalar(speed), btScalar(kMotorImpulse));
  }

  std::string json_fields() override {
    const Index tets = static_cast<Index>(m_flesh.embedding.tets.size());
    const PhaseTimes& ms = coupling().total_stats().ms;
    const double frames = std::max(1.0, m_time * 60.0);
    char text[768];
    std::snprintf(text, sizeof text,
                  "\"tets\": %ld, \"lattice_nodes\": %zu, \"surface_vertices\": %zu, \"bound_upper\": %d, "
                  "\"bound_fore\": %d, \"flesh_mass\": %.6g, \"bullet_mass\": %.6g, \"free_flesh_mass\": %.6g, "
                  "\"elbow_angle\": %.4g, \"ms_step1\": %.3g, \"ms_step2\": %.3g, \"ms_step3\": %.3g, "
                  "\"ms_step4\": %.3g, \"ms_step5\": %.3g, \"ms_forces\": %.3g, \"ms_cg\": %.3g, \"ms_step\": %.3g, ",
                  static_cast<long>(tets), m_flesh.lattice.size(), m_flesh.surface.size(), m_bound[0], m_bound[1],
                  m_flesh_mass, bullet_mass(), free_flesh_mass(), m_elbow->getHingeAngle(),
                  ms.implicit_half_velocity / frames, ms.advance_positions / frames, ms.process_collisions / frames,
                  ms.backward_euler_velocity / frames, ms.extrapolate_velocity / frames, ms.forces / frames,
                  ms.cg / frames, ms.total / frames);
    return text;
  }

  /// The mass Bullet's bones carry: their own and the bound flesh's, handed to them at the set-up [kg].
  double bullet_mass() const { return 1.0 / m_upper->getInvMass() + 1.0 / m_fore->getInvMass(); }
  /// The mass of the flesh's free (unbound) nodes [kg].
  double free_flesh_mass() {
    double m = 0.0;
    for (const Index i : m_flesh.lattice)
      if (system().particles().kind[i] == ParticleKind::free) m += system().particles().mass[i];
    return m;
  }

  static constexpr double kShoulder = 1.0, kElbow = 0.70, kHand = 0.44, kRadius = 0.05;
  static constexpr double kUpperCentre = kShoulder - 0.15, kForeCentre = kElbow - 0.13;
  static constexpr double kSpacing = 0.02, kFreeAroundElbow = 0.03;
  static constexpr double kRelax = 1.5, kFlexAngle = 1.2, kFlexSpeed = 1.5, kMotorImpulse = 0.5;

 private:
  btRigidBody* m_upper = nullptr;
  btRigidBody* m_fore = nullptr;
  btHingeConstraint* m_elbow = nullptr;
  EmbeddedVolume m_flesh;
  double m_flesh_mass = 0.0;
  int m_bound[2] = {0, 0};
};

SINEW_REGISTER_SCENE({.name = "limb",
                      .description = "flesh on bones: a soft arm embedded around two Bullet bones joined by "
                                     "hinges, hanging, then bent at the elbow by Bullet's motor",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Limb>(); },
                      .gallery_frame = 180});

}  // namespace
}  // namespace sinew::scenes
