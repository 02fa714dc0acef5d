#include "bullet_scenes.hpp"
#include "fibered.hpp"

#include <BulletDynamics/ConstraintSolver/btGeneric6DofConstraint.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace sinew::scenes {
namespace {

// Figure 7 of Liu et al. 2012: a long bar fixed on the floor by its end and pushed down by a heavy
// panel; the fibers drawn into it choose how it bends. Three bars side by side, each a meshfree
// matrix (MeshfreeCorotated) of 4 x 4 x 20 material particles 1.5 cm apart (6 x 30 cm; 1000 kg/m^3,
// E = 1 MPa), its two lowest layers hard-bound to Bullet's ground (Coupling::bind_here), with two
// fibers (lambda 0.5, EA twice the bar's own E A each) drawn up the bar in the x-y plane:
//   plain  none: the panel squashes it straight;
//   bow    bowed by kBow towards +x at mid-height, a half sine: it bends that way;
//   s      a full sine, towards +x in its lower half and -x in its upper: it bends into an S.
// A fiber drawn curved is at rest curved (its rest turning angles are the drawing's), so at rest
// nothing moves. Pressed, it keeps its length: its ends come closer only by bowing further, and the
// matrix around it goes with it.
//
// Each bar's top layer is hard-bound to its own dynamic Bullet panel (kPanelMass; the layer's mass is
// carried by the panel), which a Bullet joint (btGeneric6DofConstraint to the ground) keeps level and
// lets move along y only; sinew holds the joint's rows in its step. The panel's weight is taken off
// the bar at first by an upward force the application applies before every frame, kPanelMass g
// falling linearly to zero over kRamp seconds, so the bar is loaded slowly (108 N, about a fifth of
// a plain bar's Euler load with both ends clamped, 4 pi^2 E I / L^2 = 585 N over the 27 cm between
// its bound layers: the bend is the fibers' doing, not buckling).
class Press final : public BulletScene {
 public:
  Press() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_ground = m_world.add_body(ground, 0.0, btTransform::getIdentity());
    btCollisionShape* panel = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.05f, 0.01f, 0.05f)));
    const char* names[3] = {"plain", "bow", "s"};
    for (int b = 0; b < 3; ++b) add_bar(names[b], (b - 1) * 0.2, panel);
  }

  void before_frame(double time) override {
    m_lift = kPanelMass * 9.81 * std::max(0.0, 1.0 - time / kRamp);
    for (Bar& bar : m_bars) {
      bar.panel->applyCentralForce(btVector3(0, btScalar(m_lift), 0));
      bar.panel_y = bar.panel->getCenterOfMassPosition().y();
    }
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    for (Bar& bar : m_bars) {
      // The lift's work this frame: constant over the frame, along the panel's move.
      m_lift_work += m_lift * (bar.panel->getCenterOfMassPosition().y() - bar.panel_y);
    }
    // Counted from the first frame's end: the bound layers' masses are merged into the bodies there.
    if (std::isnan(m_energy_start)) {
      m_energy_start = total_energy();
      m_lift_work = 0.0;
    }
    m_gain = std::max(m_gain, total_energy() - m_lift_work - m_energy_start);
  }

  std::string json_fields() override {
    std::string text;
    for (const Bar& b : m_bars) {
      char part[384];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"structure_particles\": %lld, \"offset_quarter\": %.5f, \"offset_mid\": %.5f, "
                    "\"offset_three_quarters\": %.5f, \"squash\": %.4f, \"panel_speed\": %.5f}, ",
                    b.name, static_cast<long long>(b.body.structure_particles()), offset(b, (kLayers - 1) / 4),
                    offset(b, (kLayers - 1) / 2), offset(b, 3 * (kLayers - 1) / 4), squash(b),
                    b.panel->getLinearVelocity().length());
      text += part;
    }
    char part[160];
    std::snprintf(part, sizeof part, "\"energy_less_lift_work_gain_max\": %.3g, ", m_gain);
    return text + part;
  }

  /// Layer k's centre across the bar (x) from the bottom layer's: the bending the fibers guide [m].
  double offset(int bar, int k) const { return offset(m_bars[static_cast<std::size_t>(bar)], k); }
  /// How much shorter the bar is than at rest, a fraction of its height.
  double squash(int bar) const { return squash(m_bars[static_cast<std::size_t>(bar)]); }
  double panel_speed(int bar) const {
    return m_bars[static_cast<std::size_t>(bar)].panel->getLinearVelocity().length();
  }
  /// The most the energy (kinetic, gravity, elastic) less the lift's work rose above its start [J].
  double energy_gain() const { return m_gain; }
  double energy_start() const { return m_energy_start; }

  static constexpr double kSpacing = 0.015, kYoung = 1e6, kDensity = 1000.0, kBow = 0.015;
  static constexpr double kPanelMass = 11.0, kRamp = 1.0;  // [kg], [s]
  static constexpr int kN = 4, kLayers = 20;
  static constexpr double kHeight = (kLayers - 1) * kSpacing;

 private:
  struct Bar {
    const char* name = "";
    FiberedLattice body;
    btRigidBody* panel = nullptr;
    double panel_y = 0.0;  // at the frame's start
  };
  System& system() const { return const_cast<Press*>(this)->BulletScene::system(); }
  Vec3 layer(const Bar& bar, int k) const { return bar.body.layer_centre(system().particles().x, k); }
  double offset(const Bar& bar, int k) const { return layer(bar, k).x() - layer(bar, 0).x(); }
  double squash(const Bar& bar) const { return 1.0 - (layer(bar, kLayers - 1).y() - layer(bar, 0).y()) / kHeight; }

  void add_bar(const char* name, double x0, btCollisionShape* panel) {
    Bar& bar = m_bars.emplace_back();
    bar.name = name;
    const double s = kSpacing, half = 0.5 * (kN - 1) * s;
    const Vec3 origin(x0 - half, bullet::CouplingSettings{}.thickness, -half);
    FiberedLatticeSettings lattice{.nx = kN,
                                   .ny = kN,
                                   .nz = kLayers,
                                   .particle_mass = kDensity * s * s * s,
                                   .particle_volume = s * s * s,
                                   .matrix = {.support_radius = 2.5 * s,
                                              .young_modulus = kYoung,
                                              .poisson_ratio = 0.3,
                                              .beta = 0.01,
                                              .hourglass = 0.1,
                                              .implicit = true}};
    std::vector<Vectors3> lines;
    const std::string layout = name;
    if (layout != "plain") {
      for (int f = 0; f < 2; ++f) {
        Vectors3 line(3, kLayers);
        for (int p = 0; p < kLayers; ++p) {
          const double t = double(p) / (kLayers - 1);
          const double bow = kBow * std::sin((layout == "bow" ? 1.0 : 2.0) * std::numbers::pi * t);
          line.col(p) = Vec3(x0 + bow, origin.y() + t * kHeight, (f == 0 ? -0.5 : 0.5) * s);
        }
        lines.push_back(line);
      }
    }
    const double EA = 2.0 * kYoung * std::pow(kN * s, 2);
    bar.body = add_fibered_lattice(system(), lattice,
                                   [&](int i, int j, int k) -> Vec3 { return origin + s * Vec3(i, k, j); }, lines,
                                   {.stretch_stiffness = EA,
                                    .bending_stiffness = 0.01 * EA * s * s,
                                    .beta = 0.01,
                                    .lambda = 0.5,
                                    .implicit = true});
    add_surface(std::string(name), bar.body.skin());

    // The panel sits on the top layer, which is glued to it; the panels are in a group of their own
    // that the bars' particles leave out of their masks (the layer under the glued one is 1.5 cm below
    // the panel's face, within reach of the thickness once pressed).
    const int panels = btBroadphaseProxy::CharacterFilter;
    const double top = origin.y() + kHeight;
    bar.panel = m_world.add_body(panel, kPanelMass, at(btVector3(btScalar(x0), btScalar(top + 0.01), 0)),
                                 btVector3(0, 0, 0), panels, btBroadphaseProxy::AllFilter);
    bar.panel->setActivationState(DISABLE_DEACTIVATION);
    for (int k = 0; k < kLayers; ++k)
      for (int j = 0; j < kN; ++j)
        for (int i = 0; i < kN; ++i) {
          const Index p = bar.body.at(i, j, k);
          system().set_collision_filter(p, kDefaultCollisionGroup, kAllCollisionGroups & ~std::uint32_t(panels));
          if (k < 2) coupling().bind_here(p, m_ground);
          if (k == kLayers - 1) coupling().bind_here(p, bar.panel);
        }
    // Level, and free along y only: a 6-dof joint to the ground, its linear x and z and all three
    // angular axes locked (lower = upper), linear y free (lower > upper).
    btTransform in_panel = btTransform::getIdentity();
    btTransform in_ground = at(btVector3(btScalar(x0), btScalar(top + 0.01), 0));
    auto slide = std::make_unique<btGeneric6DofConstraint>(*m_ground, *bar.panel, in_ground, in_panel, true);
    slide->setLinearLowerLimit(btVector3(0, 1, 0));
    slide->setLinearUpperLimit(btVector3(0, -1, 0));
    slide->setAngularLowerLimit(btVector3(0, 0, 0));
    slide->setAngularUpperLimit(btVector3(0, 0, 0));
    m_world.add_constraint(std::move(slide));
  }

  btRigidBody* m_ground = nullptr;
  std::vector<Bar> m_bars;
  double m_lift = 0.0;       // [N] on each panel this frame
  double m_lift_work = 0.0;  // [J] done on the panels by the lift so far (negative: it holds them back)
  double m_energy_start = std::numeric_limits<double>::quiet_NaN();  // [J]
  double m_gain = -std::numeric_limits<double>::infinity();          // [J]
};

SINEW_REGISTER_SCENE(bullet_scene<Press>(
    {.name = "press",
     .description = "figure 7 of the fibers paper: long meshfree bars fixed on the floor and pressed by heavy "
                    "Bullet panels glued on their tops: straight with no fibers, bent by bowed fibers, into an S "
                    "by S-shaped ones",
     .gallery_frame = 150}));

}  // namespace
}  // namespace sinew::scenes
