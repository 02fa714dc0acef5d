#include "bullet_scenes.hpp"
#include "fibered.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace sinew::scenes {
namespace {

// Figure 9 of Liu et al. 2012: a leaf sags under gravity. Three leaves held out level from a static
// Bullet twig by their bases (the first two rows hard-bound to it, Coupling::bind_here): each a
// meshfree sheet two particles thick, 7 wide and 14 long, 8 mm apart (600 kg/m^3), narrowing to its
// tip.
//   soft    E = 10 kPa and nothing else: it cannot hold itself up;
//   stiff   E = 200 kPa: it holds better, but bends as one piece;
//   veined  E = 10 kPa with veins drawn in (a midrib and four side veins, embed_fibers, EA 100 N,
//           EI 0.01 N m^2): the veins carry the leaf, the blade between them stays soft and droops
//           from them.
// Reported per leaf: the tip's sag and the blade's droop (how far its edges at mid-length hang below
// the midrib there).
class Leaf final : public BulletScene {
 public:
  Leaf() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* twig = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.01f, 0.01f, 0.25f)));
    m_twig = m_world.add_body(twig, 0.0, at(btVector3(-0.01f, 0.2f, 0)));
    const char* names[3] = {"soft", "stiff", "veined"};
    for (int b = 0; b < 3; ++b) add_leaf(names[b], (b - 1) * 0.09);
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    // From the first frame's end on, as the other fibers scenes.
    if (m_energy_start != m_energy_start) m_energy_start = m_energy_max = total_energy();
    m_energy_max = std::max(m_energy_max, total_energy());
  }

  std::string json_fields() override {
    std::string text;
    const Vectors3& x = system().particles().x;
    for (const Blade& leaf : m_leaves) {
      const Vec3 tip =
          0.5 * (x.col(leaf.body.at(kWide / 2, 0, kLong - 1)) + x.col(leaf.body.at(kWide / 2, 1, kLong - 1)));
      const int k = kLong / 2;
      const double midrib = 0.5 * (x(1, leaf.body.at(kWide / 2, 0, k)) + x(1, leaf.body.at(kWide / 2, 1, k)));
      const double edges = 0.25 * (x(1, leaf.body.at(0, 0, k)) + x(1, leaf.body.at(0, 1, k)) +
                                   x(1, leaf.body.at(kWide - 1, 0, k)) + x(1, leaf.body.at(kWide - 1, 1, k)));
      char part[320];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"material_particles\": %zu, \"structure_particles\": %lld, \"tip_sag\": %.5f, "
                    "\"blade_droop\": %.5f}, ",
                    leaf.name, leaf.body.material.size(), static_cast<long long>(leaf.body.structure_particles()),
                    leaf.tip_start - tip.y(), midrib - edges);
      text += part;
    }
    char part[160];
    std::snprintf(part, sizeof part, "\"binding_drift\": %.2e, \"energy_first_frame\": %.5f, \"energy_max\": %.5f, ",
                  hard_binding_drift(), m_energy_start, m_energy_max);
    return text + part;
  }

  static constexpr double kSpacing = 0.008;
  static constexpr int kWide = 7, kThick = 2, kLong = 14;

 private:
  struct Blade {
    const char* name = "";
    FiberedLattice body;
    double tip_start = 0.0;
  };

  void add_leaf(const char* name, double z0) {
    Blade& leaf = m_leaves.emplace_back();
    leaf.name = name;
    const double s = kSpacing;
    const Vec3 base(bullet::CouplingSettings{}.thickness + 0.002, 0.2, z0);
    // Half-width at layer k (in spacings): the leaf narrows from its middle to its tip and its base.
    const auto width = [](double k) { return 0.45 + 0.55 * std::sin(std::numbers::pi * (k + 1.0) / (kLong + 1.0)); };
    const auto place = [&](double i, double j, double k) {
      return Vec3(base + s * Vec3(k, j - 0.5 * (kThick - 1), (i - 0.5 * (kWide - 1)) * width(k)));
    };
    const std::string kind(name);
    std::vector<Vectors3> veins;
    if (kind == "veined") {
      Vectors3 midrib(3, kLong);
      for (int k = 0; k < kLong; ++k) midrib.col(k) = place(0.5 * (kWide - 1), 0.5 * (kThick - 1), k);
      veins.push_back(midrib);
      for (const int from : {3, 7})
        for (const double side : {-1.0, 1.0}) {
          Vectors3 vein(3, 4);
          for (int p = 0; p < 4; ++p)
            vein.col(p) = place(0.5 * (kWide - 1) + side * p, 0.5 * (kThick - 1), from + 0.8 * p);
          veins.push_back(vein);
        }
    }
    leaf.body = add_fibered_lattice(
        system(),
        {.nx = kWide,
         .ny = kThick,
         .nz = kLong,
         .particle_mass = 600.0 * s * s * s,
         .particle_volume = s * s * s,
         .matrix = {.support_radius = 2.5 * s,
                    .young_modulus = kind == "stiff" ? 2e5 : 1e4,
                    .poisson_ratio = 0.3,
                    .beta = 0.01,
                    .hourglass = 0.1,
                    .implicit = true}},
        [&](int i, int j, int k) { return place(i, j, k); }, veins,
        {.stretch_stiffness = 100.0, .bending_stiffness = 0.01, .beta = 0.01, .lambda = 0.5, .implicit = true});
    for (int k = 0; k < 2; ++k)
      for (int j = 0; j < kThick; ++j)
        for (int i = 0; i < kWide; ++i) coupling().bind_here(leaf.body.at(i, j, k), m_twig);
    add_surface(std::string(name), leaf.body.skin());
    const Vectors3& x = system().particles().x;
    leaf.tip_start = 0.5 * (x(1, leaf.body.at(kWide / 2, 0, kLong - 1)) + x(1, leaf.body.at(kWide / 2, 1, kLong - 1)));
  }

  btRigidBody* m_twig = nullptr;
  std::vector<Blade> m_leaves;
  double m_energy_start = std::numeric_limits<double>::quiet_NaN(), m_energy_max = 0.0;  // [J]
};

SINEW_REGISTER_SCENE(bullet_scene<Leaf>(
    {.name = "leaf",
     .description = "figure 9 of the fibers paper: three meshfree leaves held out from a Bullet twig sag under "
                    "gravity: too soft, too stiff, and soft with veins drawn in",
     .gallery_frame = 90}));

}  // namespace
}  // namespace sinew::scenes
