#include "bullet_scenes.hpp"
#include "fibered.hpp"

#include "sinew/fibers.hpp"

#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace sinew::scenes {
namespace {

// Figure 6 of Liu et al. 2012: the same short bar drawn with four fiber layouts, dropped on its end on
// Bullet's ground. Each bar is a meshfree matrix (MeshfreeCorotated) of 6 x 6 x 12 material particles
// 1.5 cm apart (9 x 9 x 18 cm; 1000 kg/m^3, E = 200 kPa), with four fibers (embed_fibers, lambda
// 0.5, EA twice the bar's own E A each, some bending stiffness) drawn:
//   plain     none;
//   vertical  along the bar's axis: it resists being squashed;
//   shear     tilted in one plane: squashing it shears it sideways;
//   twist     as helices half a turn round the axis: squashing it twists it.
// The matrix particles meet the ground themselves (friction 0.3); the fibers are bound to them. The
// JSON line also reports the largest non-affine residual any matrix particle reached and has now
// (the zero-energy modes' measure, MeshfreeCorotated::largest_non_affine_residual: the hourglass
// penalty holds it down).
class Bars final : public BulletScene {
 public:
  Bars() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    const char* names[4] = {"plain", "vertical", "shear", "twist"};
    for (int b = 0; b < 4; ++b) add_bar(b, names[b], (b - 1.5) * 0.25);
  }

  void advance(double frame_dt, int substeps) override {
    if (m_energy_start != m_energy_start) m_energy_start = m_energy_max = total_energy();
    BulletScene::advance(frame_dt, substeps);
    m_energy_max = std::max(m_energy_max, total_energy());
    for (Bar& bar : m_bars) {
      m_non_affine_max = std::max(m_non_affine_max, bar.matrix->largest_non_affine_residual(system().particles().x));
      bar.lowest_height = std::min(bar.lowest_height, height(bar));
      bar.largest_twist = std::max(bar.largest_twist, std::abs(twist(bar)));
      bar.largest_shear = std::max(bar.largest_shear, std::abs(shear(bar)));
    }
  }

  std::string json_fields() override {
    std::string text;
    for (const Bar& bar : m_bars) {
      char part[384];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"material_particles\": %zu, \"structure_particles\": %zu, \"squash_max\": %.4f, "
                    "\"twist_max_degrees\": %.3f, \"shear_max\": %.4f}, ",
                    bar.name, bar.material.size(), bar.structure, 1.0 - bar.lowest_height / kHeight,
                    bar.largest_twist * 180.0 / std::numbers::pi, bar.largest_shear / kHeight);
      text += part;
    }
    char part[256];
    double non_affine_now = 0.0;
    for (const Bar& bar : m_bars)
      non_affine_now = std::max(non_affine_now, bar.matrix->largest_non_affine_residual(system().particles().x));
    std::snprintf(part, sizeof part,
                  "\"non_affine_max\": %.2e, \"non_affine_now\": %.2e, \"energy_before\": %.5f, \"energy_max\": "
                  "%.5f, ",
                  m_non_affine_max, non_affine_now, m_energy_start, m_energy_max);
    return text + part;
  }

  static constexpr double kSpacing = 0.015, kYoung = 2e5, kDensity = 1000.0, kDrop = 0.1;
  static constexpr int kN = 6, kLayers = 12;
  static constexpr double kHeight = (kLayers - 1) * kSpacing;

 private:
  struct Bar {
    const char* name = "";
    std::vector<Index> material;  // (i, j, k) at k kN kN + j kN + i
    std::size_t structure = 0;
    MeshfreeCorotated* matrix = nullptr;
    Vec3 origin = Vec3::Zero();
    double lowest_height = kHeight, largest_twist = 0.0, largest_shear = 0.0;
  };
  Index at(const Bar& bar, int i, int j, int k) const {
    return bar.material[static_cast<std::size_t>((k * kN + j) * kN + i)];
  }
  Vec3 layer_centre(const Bar& bar, int k) const {
    Vec3 c = Vec3::Zero();
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i) c += system().particles().x.col(at(bar, i, j, k));
    return c / double(kN * kN);
  }
  Bar& bar_at(int b) { return m_bars[static_cast<std::size_t>(b)]; }
  System& system() const { return const_cast<Bars*>(this)->BulletScene::system(); }
  // The bar's height: its top layer's centre above its bottom layer's.
  double height(const Bar& bar) const { return (layer_centre(bar, kLayers - 1) - layer_centre(bar, 0)).norm(); }
  // The top layer's turn about the bar's axis relative to the bottom layer's (the direction of one
  // edge of each, projected across the axis).
  double twist(const Bar& bar) const {
    const auto edge = [&](int k) {
      Vec3 d = system().particles().x.col(at(bar, kN - 1, 0, k)) - system().particles().x.col(at(bar, 0, 0, k));
      return Eigen::Vector2d(d.x(), d.z());
    };
    const Eigen::Vector2d a = edge(0), b = edge(kLayers - 1);
    return std::atan2(a.x() * b.y() - a.y() * b.x(), a.dot(b));
  }
  // The top layer's centre displaced across the axis from above the bottom's.
  double shear(const Bar& bar) const {
    const Vec3 d = layer_centre(bar, kLayers - 1) - layer_centre(bar, 0);
    return std::hypot(d.x(), d.z());
  }

  void add_bar(int b, const char* name, double x0) {
    Bar& bar = m_bars.emplace_back();
    (void)b;
    bar.name = name;
    const double half = 0.5 * (kN - 1) * kSpacing;
    bar.origin = Vec3(x0 - half, kDrop + bullet::CouplingSettings{}.thickness, -half);
    System& s = system();
    const double volume = kSpacing * kSpacing * kSpacing;
    for (int k = 0; k < kLayers; ++k)
      for (int j = 0; j < kN; ++j)
        for (int i = 0; i < kN; ++i)
          bar.material.push_back(
              s.add_particle(bar.origin + kSpacing * Vec3(i, k, j), Vec3::Zero(), kDensity * volume));
    const double h = 2.5 * kSpacing;
    MeshfreeCorotated& matrix = s.add_force(std::make_unique<MeshfreeCorotated>(
        bar.material, s.particles().x, std::vector<double>(bar.material.size(), volume),
        MeshfreeCorotatedSettings{.support_radius = h,
                                  .young_modulus = kYoung,
                                  .poisson_ratio = 0.3,
                                  .beta = 0.01,
                                  .hourglass = 0.1,
                                  .implicit = true}));
    bar.matrix = &matrix;
    std::vector<Vectors3> lines = fibers(bar, std::string(name));
    if (!lines.empty()) {
      const double EA = 2.0 * kYoung * std::pow(kN * kSpacing, 2);
      const EmbeddedFibers embedded = embed_fibers(s, matrix, h, lines,
                                                   {.stretch_stiffness = EA,
                                                    .bending_stiffness = EA * kSpacing * kSpacing * 0.1,
                                                    .beta = 0.01,
                                                    .lambda = 0.5,
                                                    .implicit = true});
      for (const auto& fiber : embedded.fibers) bar.structure += fiber.size();
    }
    // The lattice's outer faces: the fibers scenes' lattice layout, (i, j, k) at (k kN + j) kN + i.
    FiberedLattice lattice;
    lattice.nx = lattice.ny = kN;
    lattice.nz = kLayers;
    lattice.material = bar.material;
    add_surface(std::string(name), lattice.skin());
  }

  // The layouts, in the bar's frame (x, z across, y up; u, w in [0, 1] across, t in [0, 1] up).
  std::vector<Vectors3> fibers(const Bar& bar, const std::string& layout) const {
    std::vector<Vectors3> lines;
    if (layout == "plain") return lines;
    const double side = (kN - 1) * kSpacing;
    const int points = kLayers;
    for (int f = 0; f < 4; ++f) {
      Vectors3 line(3, points);
      for (int p = 0; p < points; ++p) {
        const double t = double(p) / (points - 1);
        double u = 0.0, w = 0.0;
        if (layout == "vertical") {
          u = f % 2 ? 0.3 : 0.7;
          w = f / 2 ? 0.3 : 0.7;
        } else if (layout == "shear") {
          u = 0.15 + 0.7 * t;  // across the bar from one side to the other, in x
          w = 0.2 + 0.2 * f;
        } else {  // twist: helices half a turn round the axis
          const double angle = 0.5 * std::numbers::pi * f + std::numbers::pi * t;
          u = 0.5 + 0.32 * std::cos(angle);
          w = 0.5 + 0.32 * std::sin(angle);
        }
        line.col(p) = bar.origin + Vec3(u * side, t * kHeight, w * side);
      }
      lines.push_back(line);
    }
    return lines;
  }

  std::vector<Bar> m_bars;
  double m_energy_start = std::numeric_limits<double>::quiet_NaN(), m_energy_max = 0.0;  // [J]
  double m_non_affine_max = 0.0;  // MeshfreeCorotated::largest_non_affine_residual, over bars and frames
};

SINEW_REGISTER_SCENE(bullet_scene<Bars>(
    {.name = "bars",
     .description = "figure 6 of the fibers paper: a short meshfree bar dropped on its end with no fibers and with "
                    "vertical, shear and twist fiber layouts",
     .gallery_frame = 30}));

}  // namespace
}  // namespace sinew::scenes
