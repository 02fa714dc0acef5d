#include "bullet_scenes.hpp"
#include "fibered.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace sinew::scenes {
namespace {

// Figure 8 of Liu et al. 2012: a plant swings after an initial impulse. Two plants side by side, each a
// stem of soft meshfree matrix (3 x 3 x 25 particles 8 mm apart, E = 30 kPa) rooted in a dynamic Bullet
// pot (its two lowest layers hard-bound to the pot's frame) and carrying a 40 g Bullet flower head
// (a sphere hard-bound to its top layer): both ends of the stem are Bullet bodies, coupled two-way.
//   plain    the matrix alone: too compliant to carry the head, it bends over;
//   fibered  fibers drawn up the stem, three in its lower half and one to the top (stiffer at the
//            bottom, as the paper's plant): it stands and swings.
// At the start every stem particle and the head move sideways in proportion to their height (1 m/s at
// the head): the impulse. Reported per plant: the head's largest swing and lowest height, and how far
// the stem's centre line ever stretched or shortened.
class Plant final : public BulletScene {
 public:
  Plant() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    const char* names[2] = {"plain", "fibered"};
    for (int p = 0; p < 2; ++p) add_plant(names[p], (0.5 - p) * 0.16);  // plain on the right, falling away
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    // From the first frame's end on: the bound masses are merged into their bodies there.
    if (m_energy_start != m_energy_start) m_energy_start = m_energy_max = total_energy();
    m_energy_max = std::max(m_energy_max, total_energy());
    for (Stem& stem : m_stems) {
      const Vec3 head = to_eigen(stem.head->getCenterOfMassPosition());
      stem.largest_swing = std::max(stem.largest_swing, std::abs(head.x() - stem.head_start.x()));
      stem.lowest_head = std::min(stem.lowest_head, head.y());
      const double stretch = centre_line_length(stem) / stem.rest_length - 1.0;
      stem.largest_stretch = std::max(stem.largest_stretch, std::abs(stretch));
    }
  }

  std::string json_fields() override {
    std::string text;
    for (const Stem& stem : m_stems) {
      char part[384];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"material_particles\": %zu, \"structure_particles\": %lld, \"swing_max\": %.4f, "
                    "\"head_lowest\": %.4f, \"head_start\": %.4f, \"stretch_max\": %.4f}, ",
                    stem.name, stem.body.material.size(), static_cast<long long>(stem.body.structure_particles()),
                    stem.largest_swing, stem.lowest_head, stem.head_start.y(), stem.largest_stretch);
      text += part;
    }
    char part[160];
    std::snprintf(part, sizeof part, "\"binding_drift\": %.2e, \"energy_first_frame\": %.5f, \"energy_max\": %.5f, ",
                  hard_binding_drift(), m_energy_start, m_energy_max);
    return text + part;
  }

  static constexpr double kSpacing = 0.008, kImpulse = 1.0;
  static constexpr int kLayers = 25;

 private:
  struct Stem {
    const char* name = "";
    FiberedLattice body;
    btRigidBody* pot = nullptr;
    btRigidBody* head = nullptr;
    Vec3 head_start = Vec3::Zero();
    double rest_length = 0.0, largest_swing = 0.0, lowest_head = kInfinity, largest_stretch = 0.0;
  };

  double centre_line_length(const Stem& stem) {
    const Vectors3& x = system().particles().x;
    double length = 0.0;
    for (int k = 1; k < kLayers; ++k)
      length += (stem.body.layer_centre(x, k) - stem.body.layer_centre(x, k - 1)).norm();
    return length;
  }

  void add_plant(const char* name, double x0) {
    Stem& stem = m_stems.emplace_back();
    stem.name = name;
    const double s = kSpacing, thickness = bullet::CouplingSettings{}.thickness;
    btCollisionShape* pot = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.05f, 0.04f, 0.05f)));
    stem.pot = m_world.add_body(pot, 2.0, at(btVector3(btScalar(x0), 0.04f, 0)));
    stem.pot->setFriction(0.8);
    const Vec3 root(x0 - s, 0.08 + thickness + 0.002, -s);
    const double height = (kLayers - 1) * s;
    std::vector<Vectors3> lines;
    if (std::string(name) == "fibered") {
      // Three fibers up the lower half, on a triangle round the axis, and one up the middle to the top.
      for (int f = 0; f < 3; ++f) {
        const double a = 2.0 * std::numbers::pi * f / 3.0;
        Vectors3 line(3, kLayers / 2 + 1);
        for (int k = 0; k <= kLayers / 2; ++k)
          line.col(k) = root + Vec3(s + 0.6 * s * std::cos(a), k * s, s + 0.6 * s * std::sin(a));
        lines.push_back(line);
      }
      Vectors3 line(3, kLayers);
      for (int k = 0; k < kLayers; ++k) line.col(k) = root + Vec3(s, k * s, s);
      lines.push_back(line);
    }
    stem.body = add_fibered_lattice(
        system(),
        {.nx = 3,
         .ny = 3,
         .nz = kLayers,
         .particle_mass = 1000.0 * s * s * s,
         .particle_volume = s * s * s,
         .matrix = {.support_radius = 2.5 * s,
                    .young_modulus = 3e4,
                    .poisson_ratio = 0.3,
                    .beta = 0.01,
                    .hourglass = 0.1,
                    .implicit = true}},
        [&](int i, int j, int k) { return Vec3(root + s * Vec3(i, k, j)); }, lines,
        {.stretch_stiffness = 100.0, .bending_stiffness = 0.02, .beta = 0.01, .lambda = 0.5, .implicit = true});
    for (int k = 0; k < 2; ++k)
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) coupling().bind_here(stem.body.at(i, j, k), stem.pot);
    // The head sits on the stem's top, its top layer bound to it (the head's collision group is left out of the stem's
    // mask).
    const double radius = 0.025;
    btCollisionShape* head = m_world.keep(std::make_unique<btSphereShape>(btScalar(radius)));
    const Vec3 top = root + Vec3(s, height, s);
    stem.head_start = top + Vec3(0, radius, 0);
    const int heads = btBroadphaseProxy::CharacterFilter;
    stem.head = m_world.add_body(head, 0.04, at(to_bullet(stem.head_start)), btVector3(0, 0, 0), heads,
                                 btBroadphaseProxy::AllFilter);
    for (const Index p : stem.body.material)
      system().set_collision_filter(p, kDefaultCollisionGroup, kAllCollisionGroups & ~std::uint32_t(heads));
    for (btRigidBody* body : {stem.pot, stem.head}) body->setActivationState(DISABLE_DEACTIVATION);
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) coupling().bind_here(stem.body.at(i, j, kLayers - 1), stem.head);
    add_surface(std::string(name), stem.body.skin());
    stem.rest_length = centre_line_length(stem);
    // The impulse: sideways, in proportion to the height above the root.
    Vectors3& v = system().particles().v;
    for (const Index p : stem.body.material)
      v.col(p) = Vec3(kImpulse * (system().particles().x(1, p) - root.y()) / (height + radius), 0, 0);
    stem.head->setLinearVelocity(btVector3(btScalar(kImpulse), 0, 0));
  }

  std::vector<Stem> m_stems;
  double m_energy_start = std::numeric_limits<double>::quiet_NaN(), m_energy_max = 0.0;  // [J]
};

SINEW_REGISTER_SCENE(bullet_scene<Plant>(
    {.name = "plant",
     .description = "figure 8 of the fibers paper: two meshfree stems rooted in Bullet pots and carrying Bullet "
                    "flower heads swing after an impulse: a plain one bends over, one with fibers drawn in stands",
     .gallery_frame = 60}));

}  // namespace
}  // namespace sinew::scenes
