#include "bullet_scenes.hpp"
#include "fibered.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace sinew::scenes {
namespace {

// Figure 10 of Liu et al. 2012: a leaf stalk snaps when its fiber breaks. The stalk is a soft meshfree
// matrix (3 x 3 x 22 particles 8 mm apart, E = 50 kPa: alone it could not hold itself up) rising from a
// pot and curving over along an arc, with one fiber drawn along its middle whose rest shape is that
// curve (ElasticRods' rest turning angles). The pot is a dynamic Bullet box on the ground; the
// stalk's two lowest layers are hard-bound to the pot's frame (Coupling::bind_here: section 5, the
// stalk's weight and swing reach the pot through W^T), the rest meets the pot and the ground as
// particles. At kBreakTime the fiber breaks a third of the way up (ElasticRods::break_fiber): the
// bending energy is discontinuous there, the matrix alone cannot carry the stalk's far part, and the
// stalk kinks and droops.
class Stalk final : public BulletScene {
 public:
  Stalk() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    btCollisionShape* pot = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.03f, 0.04f, 0.05f)));
    m_pot = m_world.add_body(pot, 2.0, at(btVector3(0, 0.04f, 0)));
    m_pot->setFriction(0.8);
    m_pot->setActivationState(DISABLE_DEACTIVATION);
    m_pot_start = to_eigen(m_pot->getCenterOfMassPosition());

    const double s = kSpacing, radius = 0.15;
    const Vec3 root(0.03, 0.08 + bullet::CouplingSettings{}.thickness + 0.002, 0.0);
    // The centre line: up from the root, turning toward +x along an arc of `radius`.
    const auto centre = [&](double arc) {
      const double t = arc / radius;
      return Vec3(root.x() + radius * (1.0 - std::cos(t)), root.y() + radius * std::sin(t), 0.0);
    };
    const auto across = [&](double arc) {
      const double t = arc / radius;
      return Vec3(std::cos(t), -std::sin(t), 0.0);
    };
    FiberedLatticeSettings lattice{.nx = 3,
                                   .ny = 3,
                                   .nz = kLayers,
                                   .particle_mass = 1000.0 * s * s * s,
                                   .particle_volume = s * s * s,
                                   .matrix = {.support_radius = 2.5 * s,
                                              .young_modulus = 5e4,
                                              .poisson_ratio = 0.3,
                                              .beta = 0.01,
                                              .hourglass = 0.1,
                                              .implicit = true}};
    Vectors3 fiber(3, kLayers);
    for (int k = 0; k < kLayers; ++k) fiber.col(k) = centre(k * s);
    m_stalk = add_fibered_lattice(
        system(), lattice,
        [&](int i, int j, int k) {
          return Vec3(centre(k * s) + (i - 1) * s * across(k * s) + Vec3(0, 0, (j - 1) * s));
        },
        {fiber},
        {.stretch_stiffness = 200.0, .bending_stiffness = 0.05, .beta = 0.01, .lambda = 0.5, .implicit = true});
    for (int k = 0; k < 2; ++k)
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) coupling().bind_here(m_stalk.at(i, j, k), m_pot);
    add_surface("stalk", m_stalk.skin());
    m_tip_start = tip().y();
  }

  void advance(double frame_dt, int substeps) override {
    if (!m_broken && m_time + 0.5 * frame_dt >= kBreakTime) {
      // The fiber's edge a third of the way up goes; the two pieces keep every other term.
      m_stalk.fibers.force->break_fiber(0, static_cast<std::size_t>(kLayers / 3));
      m_broken = true;
      m_tip_before = tip().y();
      m_energy_at_break = total_energy();
    }
    BulletScene::advance(frame_dt, substeps);
    const double energy = total_energy();
    // From the first frame's end on: the bound masses are merged into their bodies there.
    if (m_energy_start != m_energy_start) m_energy_start = energy;
    (m_broken ? m_energy_max_after : m_energy_max_before) =
        std::max(m_broken ? m_energy_max_after : m_energy_max_before, energy);
    if (m_broken) m_tip_lowest_after = std::min(m_tip_lowest_after, tip().y());
    m_drift = std::max(m_drift, hard_binding_drift());
  }

  std::string json_fields() override {
    char text[640];
    const Vec3 pot = to_eigen(m_pot->getCenterOfMassPosition());
    std::snprintf(
        text, sizeof text,
        "\"material_particles\": %zu, \"structure_particles\": %lld, \"tip_height_start\": %.4f, "
        "\"tip_height_before_break\": %.4f, \"tip_height_lowest_after\": %.4f, \"tip_height\": %.4f, "
        "\"pot_moved\": %.5f, \"binding_drift\": %.2e, \"energy_first_frame\": %.5f, \"energy_max_before_break\": "
        "%.5f, \"energy_at_break\": %.5f, \"energy_max_after_break\": %.5f, ",
        m_stalk.material.size(), static_cast<long long>(m_stalk.structure_particles()), m_tip_start, m_tip_before,
        m_broken ? m_tip_lowest_after : std::numeric_limits<double>::quiet_NaN(), tip().y(), (pot - m_pot_start).norm(),
        m_drift, m_energy_start, m_energy_max_before,
        m_broken ? m_energy_at_break : std::numeric_limits<double>::quiet_NaN(),
        m_broken ? m_energy_max_after : std::numeric_limits<double>::quiet_NaN());
    return text;
  }

  static constexpr double kSpacing = 0.008, kBreakTime = 1.0;
  static constexpr int kLayers = 22;

 private:
  Vec3 tip() { return m_stalk.layer_centre(system().particles().x, kLayers - 1); }

  btRigidBody* m_pot = nullptr;
  Vec3 m_pot_start = Vec3::Zero();
  FiberedLattice m_stalk;
  bool m_broken = false;
  double m_tip_start = 0.0;
  double m_tip_before = std::numeric_limits<double>::quiet_NaN(), m_tip_lowest_after = kInfinity;
  double m_drift = 0.0;
  double m_energy_start = std::numeric_limits<double>::quiet_NaN(), m_energy_max_before = -kInfinity,
         m_energy_at_break = 0.0, m_energy_max_after = -kInfinity;
};

SINEW_REGISTER_SCENE(bullet_scene<Stalk>(
    {.name = "stalk",
     .description = "figure 10 of the fibers paper: a curved meshfree stalk held up by its fiber, rooted in a Bullet "
                    "pot, snaps and droops when the fiber breaks",
     .gallery_frame = 120}));

}  // namespace
}  // namespace sinew::scenes
