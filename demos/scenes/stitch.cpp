#include "bullet_scenes.hpp"

#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Figure 8: deformable bodies stitched together by binding springs between embedded points. Three
// pairs of soft blocks (each 0.2 x 0.1 x 0.2 m, a box surface embedded in a BCC lattice of 4.5 cm cells):
// the upper block of each hangs from a static Bullet bar by its top face (Coupling::attach), the lower
// one hangs from the upper by 25 binding springs (eq. 5, zero rest length, implicit in the step)
// between the vertices of the two faces that meet, points embedded in each block's lattice. The
// stitches are soft (30 N/m, the gap opens by centimetres), medium (1e3 N/m) and stiff (1e8 N/m, the
// faces coincide to the solver's tolerance with no smaller step). At rest the stitches carry the
// lower block's weight: their mean stretch is m g / (n k) whatever the blocks' elasticity, which
// the JSON line reports beside the measured gaps.
class Stitch final : public BulletScene {
 public:
  Stitch() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* bar = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.12, 0.01, 0.12)));
    VolumeMaterial material;
    material.density = 500.0;
    material.young_modulus = 5e4;
    material.poisson_ratio = 0.3;
    material.damping = 0.02;
    for (int p = 0; p < 3; ++p) {
      Pair& pair = m_pairs[static_cast<std::size_t>(p)];
      pair.stiffness = kStiffness[p];
      const double x = (p - 1) * 0.4;
      const ClosedSurface upper = box_surface(Vec3(x - 0.1, kSeam, -0.1), Vec3(x + 0.1, kSeam + 0.1, 0.1), 4);
      const ClosedSurface lower = box_surface(Vec3(x - 0.1, kSeam - 0.1, -0.1), Vec3(x + 0.1, kSeam, 0.1), 4);
      const EmbeddedVolume up = add_embedded_volume(system(), upper.vertices, upper.triangles, kSpacing, material);
      const EmbeddedVolume down = add_embedded_volume(system(), lower.vertices, lower.triangles, kSpacing, material);
      btRigidBody* hanger = m_world.add_body(bar, 0.0, at(btVector3(btScalar(x), btScalar(kSeam + 0.111), 0)));
      // The lattice's nodes reach a cell above the block's top face, into the bar: the bar holds the
      // block by its springs alone and meets nothing.
      hanger->setCollisionFlags(hanger->getCollisionFlags() | btCollisionObject::CF_NO_CONTACT_RESPONSE);
      const btTransform frame = hanger->getCenterOfMassTransform();
      for (Index v = 0; v < upper.vertices.cols(); ++v)
        if (upper.vertices(1, v) > kSeam + 0.1 - 1e-12) {
          const Vec3 world = upper.vertices.col(v);
          coupling().attach(up.surface[static_cast<std::size_t>(v)], hanger,
                            bullet::to_eigen(frame.invXform(bullet::to_bullet(world))), 1e5);
        }
      // The stitches: each vertex of the lower block's top face to the upper block's vertex there.
      for (Index a = 0; a < upper.vertices.cols(); ++a) {
        if (std::abs(upper.vertices(1, a) - kSeam) > 1e-12) continue;
        for (Index b = 0; b < lower.vertices.cols(); ++b)
          if ((lower.vertices.col(b) - upper.vertices.col(a)).norm() < 1e-12) {
            BindingSpringSettings spring;
            spring.a = up.surface[static_cast<std::size_t>(a)];
            spring.b = down.surface[static_cast<std::size_t>(b)];
            spring.stiffness = pair.stiffness;
            pair.stitches.push_back(system().add_binding_spring(spring));
          }
      }
      for (const Index i : down.lattice) pair.lower_mass += system().particles().mass[i];
      add_surface("upper", embedded_skin(up, upper.triangles));
      add_surface("lower", embedded_skin(down, lower.triangles));
    }
  }
  std::string json_fields() override {
    std::string out;
    const char* names[3] = {"soft", "medium", "stiff"};
    for (std::size_t p = 0; p < m_pairs.size(); ++p) {
      const Pair& pair = m_pairs[p];
      char text[256];
      std::snprintf(text, sizeof text, "\"gap_%s\": %.4g, \"gap_%s_predicted\": %.4g, \"gap_%s_largest\": %.4g, ",
                    names[p], mean_stretch(pair), names[p], predicted_stretch(pair), names[p], largest_gap(pair));
      out += text;
    }
    char text[64];
    std::snprintf(text, sizeof text, "\"stitches\": %zu, ", m_pairs[0].stitches.size());
    return out + text;
  }

  /// A pair of blocks and the stitches between them.
  struct Pair {
    double stiffness = 0.0;
    std::vector<Index> stitches;  ///< binding springs
    double lower_mass = 0.0;      ///< [kg]
  };
  const Pair& pair(int p) const { return m_pairs[static_cast<std::size_t>(p)]; }
  /// The stitches' mean vertical stretch, upper end above lower [m].
  double mean_stretch(const Pair& pair) const {
    const System& s = m_coupling->system();
    double sum = 0.0;
    for (const Index k : pair.stitches)
      sum += s.particles().x(1, s.binding_springs().a(k)) - s.particles().x(1, s.binding_springs().b(k));
    return sum / double(pair.stitches.size());
  }
  /// What carrying the lower block's weight at rest takes: m g / (n k) [m].
  double predicted_stretch(const Pair& pair) const {
    return pair.lower_mass * 9.81 / (double(pair.stitches.size()) * pair.stiffness);
  }
  /// The widest stitch: the largest distance between its ends [m].
  double largest_gap(const Pair& pair) const {
    const System& s = m_coupling->system();
    double widest = 0.0;
    for (const Index k : pair.stitches)
      widest = std::max(
          widest,
          (s.particles().x.col(s.binding_springs().a(k)) - s.particles().x.col(s.binding_springs().b(k))).norm());
    return widest;
  }

  static constexpr double kSeam = 1.0, kSpacing = 0.045;
  static constexpr double kStiffness[3] = {30.0, 1e3, 1e8};

 private:
  std::array<Pair, 3> m_pairs;
};

SINEW_REGISTER_SCENE({.name = "stitch",
                      .description = "figure 8: soft blocks hanging from blocks by binding springs between "
                                     "embedded points, soft, medium and stiff",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Stitch>(); },
                      .gallery_frame = 120});

}  // namespace
}  // namespace sinew::scenes
