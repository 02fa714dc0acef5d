#include "bullet_scenes.hpp"

#include "sinew/ccd.hpp"
#include "sinew/forces/triangle_membrane.hpp"
#include "sinew/lattice.hpp"
#include "sinew/refinement.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

namespace sinew::scenes {
namespace {

// Figure 7: sub-element elasticity through soft bindings. Two coarse balls (a sphere surface of 320
// triangles, vertices about 4 cm apart, embedded in a BCC lattice of 10 cm cells) rest on the ground,
// tied down by their lowest nodes; a kinematic Bullet sphere of 2.5 cm radius comes down on each top
// after kWait, presses until its centre is kPress below the settled top, holds, and goes back up.
//   left   the lattice's nodes collide with it, nothing else: it goes in between them;
//   right  the surface is red-refined twice where the probe comes (figure 4: triangles within kFine
//          of its path, then within kFiner), every refined vertex is a hard-bound target on the coarse
//          surface (the original vertices embedded in the tets, the midpoints bound to the ends of
//          the edges they halve), and each target has a soft-bound particle tied to it by a binding
//          spring (section 3.2) that inherits the tets' elastic accelerations (f_s = m_s a_target).
//          The soft particles, not the nodes, meet the probe: they drift from their targets by the
//          dent, far finer than a tet, and the springs pull the tets along; once the probe leaves,
//          the springs bring them back.
// Refined statically around the probe's known path (the scene models only what it needs); the paper
// refines as bodies come near.
class SubElement final : public BulletScene {
 public:
  SubElement() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    btCollisionShape* pin = m_world.keep(std::make_unique<btSphereShape>(btScalar(0.01)));
    btRigidBody* anchor = m_world.add_body(pin, 0.0, at(btVector3(0, -1, 0)));
    anchor->setCollisionFlags(anchor->getCollisionFlags() | btCollisionObject::CF_NO_CONTACT_RESPONSE);
    btCollisionShape* probe = m_world.keep(std::make_unique<btSphereShape>(btScalar(kProbeRadius)));
    VolumeMaterial material;
    material.density = 200.0;
    material.young_modulus = 3e4;
    material.poisson_ratio = 0.3;
    material.damping = 0.02;
    for (int b = 0; b < 3; ++b) {
      Ball& ball = m_balls[static_cast<std::size_t>(b)];
      ball.x = (b - 1) * 0.45;
      ball.surface = sphere_surface(2, kRadius, Vec3(ball.x, kRadius, 0));
      ball.volume = add_embedded_volume(system(), ball.surface.vertices, ball.surface.triangles, kSpacing, material);
      // Held up by the nodes below the surface, up to a cell below it: put it there from the start.
      double lowest = kInfinity;
      for (const Index i : ball.volume.lattice) lowest = std::min(lowest, system().particles().x(1, i));
      for (const Index i : ball.volume.lattice) system().particles().x(1, i) -= lowest - 0.011;
      for (const Index i : ball.volume.surface) system().particles().x(1, i) -= lowest - 0.011;
      for (Index v = 0; v < ball.surface.vertices.cols(); ++v) ball.surface.vertices(1, v) -= lowest - 0.011;
      double lowest_node = kInfinity;
      for (const Index i : ball.volume.lattice) lowest_node = std::min(lowest_node, system().particles().x(1, i));
      for (const Index i : ball.volume.lattice)
        if (system().particles().x(1, i) < lowest_node + 0.25 * kSpacing)
          coupling().attach(i, anchor, system().particles().x.col(i) - Vec3(0, -1, 0), kTie);
      ball.top = -kInfinity;
      for (Index v = 0; v < ball.surface.vertices.cols(); ++v)
        ball.top = std::max(ball.top, ball.surface.vertices(1, v));
      if (b == 1) add_soft_surface(ball);
      if (b == 2) start_adaptive(ball);
      if (ball.soft.empty()) ball.skin = embedded_skin(ball.volume, ball.surface.triangles);
      ball.drawn = static_cast<Index>(m_surface_triangles.size());
      add_surface(b == 0   ? "nodes only"
                  : b == 1 ? "soft-bound surface refined once"
                           : "soft-bound surface refined as the probe comes",
                  ball.skin);
      ball.probe = m_world.add_body(probe, 0.0, probe_pose(ball, 0.0), btVector3(0, 0, 0), kProbeGroup,
                                    btBroadphaseProxy::AllFilter);
      ball.probe->setCollisionFlags(ball.probe->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      ball.probe->setActivationState(DISABLE_DEACTIVATION);
    }
  }

  void before_frame(double t) override {
    if (t >= kWait && !m_settled) {
      m_settled = true;
      for (Ball& ball : m_balls) {
        ball.top = -kInfinity;
        for (const Index i : ball.volume.surface) ball.top = std::max(ball.top, system().particles().x(1, i));
      }
    }
    for (const Ball& ball : m_balls) ball.probe->getMotionState()->setWorldTransform(probe_pose(ball, t));
  }

  void advance(double frame_dt, int substeps) override {
    refine_near_probe(m_balls[2]);
    BulletScene::advance(frame_dt, substeps);
    for (Ball& ball : m_balls) {
      ball.deepest = std::max(ball.deepest, depth(ball));
      ball.most_drift = std::max(ball.most_drift, drift(ball));
    }
  }

  std::string json_fields() override {
    const Ball& nodes = m_balls[0];
    const Ball& soft = m_balls[1];
    const Ball& adaptive = m_balls[2];
    char text[768];
    std::snprintf(text, sizeof text,
                  "\"lattice_nodes\": %zu, \"tets\": %zu, \"coarse_triangles\": %zu, \"refined_triangles\": %zu, "
                  "\"soft_particles\": %zu, \"deepest_nodes_only\": %.4f, \"deepest_soft\": %.4f, "
                  "\"soft_drift_max\": %.4f, \"soft_drift_now\": %.3g, \"adaptive_refined_triangles\": %zu, "
                  "\"adaptive_soft_particles\": %zu, \"adaptive_refinements\": %d, \"deepest_adaptive\": %.4f, "
                  "\"adaptive_drift_max\": %.4f, \"adaptive_drift_now\": %.3g, ",
                  nodes.volume.lattice.size(), nodes.volume.embedding.tets.size(), nodes.surface.triangles.size(),
                  soft.skin.size(), soft.soft.size(), nodes.deepest, soft.deepest, soft.most_drift, drift(soft),
                  adaptive.skin.size(), adaptive.soft.size(), adaptive.refinements, adaptive.deepest,
                  adaptive.most_drift, drift(adaptive));
    return text;
  }

  static constexpr double kRadius = 0.15, kSpacing = 0.1, kProbeRadius = 0.025, kSpeed = 0.25, kPress = 0.03,
                          kStartAbove = 0.03, kWait = 0.5, kHold = 1.0, kTie = 2e3, kFine = 0.09, kFiner = 0.05,
                          kSoftStiffness = 20.0, kOff = 0.025, kSkinMu = 50.0;
  static constexpr int kProbeGroup = btBroadphaseProxy::CharacterFilter;

 private:
  struct Ball {
    double x = 0.0, top = 0.0;
    ClosedSurface surface;
    EmbeddedVolume volume;
    std::vector<Index> target;             // per refined vertex (right ball): its target
    std::vector<Index> soft, soft_target;  // the soft particles and their targets
    std::vector<std::array<Index, 3>> skin;
    btRigidBody* probe = nullptr;
    double deepest = -kInfinity, most_drift = 0.0;
    Index drawn = -1;  // its surface among the scene's drawn ones
    // The adaptive ball: its surface as refined so far, a soft particle per vertex (-1: none yet),
    // the membrane among them, and how many rounds refined it.
    RefinedTriangles mesh;
    std::vector<Index> soft_of;
    TriangleMembrane* membrane = nullptr;
    int refinements = 0;
  };

  // The third ball starts coarse: its surface's vertices are their own targets (the embedded ones),
  // no soft particle yet; refine_near_probe adds them where the probe comes.
  void start_adaptive(Ball& ball) {
    ball.mesh = unrefined(ball.surface.vertices, ball.surface.triangles);
    ball.target = ball.volume.surface;
    ball.soft_of.assign(ball.target.size(), -1);
    const std::uint32_t probe = static_cast<std::uint32_t>(kProbeGroup);
    for (const Index i : ball.volume.lattice)
      system().set_collision_filter(i, kDefaultCollisionGroup, kAllCollisionGroups & ~probe);
  }

  // Before each frame: the adaptive ball's triangles whose centre is within kFine of the probe's
  // centre are split once, those within kFiner of it twice (red refinement, figure 4); new midpoints
  // become targets bound to the ends of the edges they halve, every vertex of a split triangle gets a
  // soft particle on a binding spring (at its target, or between the soft particles at the ends of
  // the edge it halves), and the membrane among the soft particles is made again over the refined
  // part, its rest shape the refined surface at rest. Refinement is kept once made.
  void refine_near_probe(Ball& ball) {
    const Vectors3& x = system().particles().x;
    const Vec3 centre = to_eigen(ball.probe->getWorldTransform().getOrigin());
    bool changed = false;
    for (int level = 0; level < 2; ++level) {
      const double reach = level == 0 ? kFine : kFiner;
      std::vector<Index> chosen;
      for (std::size_t t = 0; t < ball.mesh.triangles.size(); ++t) {
        if (ball.mesh.level[t] != level) continue;
        Vec3 c = Vec3::Zero();
        for (const Index v : ball.mesh.triangles[t]) c += x.col(ball.target[static_cast<std::size_t>(v)]) / 3.0;
        if ((c - centre).norm() < reach) chosen.push_back(static_cast<Index>(t));
      }
      if (chosen.empty()) continue;
      const Index before = ball.mesh.vertices.cols();
      ball.mesh = red_refine(ball.mesh, chosen);
      for (const auto& [edge, middle] : ball.mesh.midpoint) {
        if (middle < before) continue;
        const Index a = ball.target[static_cast<std::size_t>(edge.first)],
                    b = ball.target[static_cast<std::size_t>(edge.second)];
        const Index m = system().add_particle(
            0.5 * (x.col(a) + x.col(b)), 0.5 * (system().particles().v.col(a) + system().particles().v.col(b)), 0.0);
        const Index parents[2] = {a, b};
        const double weights[2] = {0.5, 0.5};
        system().bind_linear(m, parents, weights);
        ball.target.resize(std::max(ball.target.size(), static_cast<std::size_t>(middle) + 1), -1);
        ball.target[static_cast<std::size_t>(middle)] = m;
      }
      ball.soft_of.resize(ball.target.size(), -1);
      changed = true;
      ++ball.refinements;
    }
    if (!changed) return;
    const std::uint32_t probe = static_cast<std::uint32_t>(kProbeGroup);
    std::map<Index, std::pair<Index, Index>> edge_of;
    for (const auto& [edge, middle] : ball.mesh.midpoint) edge_of.emplace(middle, edge);
    for (std::size_t t = 0; t < ball.mesh.triangles.size(); ++t) {
      if (ball.mesh.level[t] == 0) continue;
      for (const Index v : ball.mesh.triangles[t]) {
        if (ball.soft_of[static_cast<std::size_t>(v)] >= 0) continue;
        const Index target = ball.target[static_cast<std::size_t>(v)];
        // A midpoint of an edge whose ends are soft already starts between them (the soft surface
        // keeps its shape where it is split); any other vertex starts at its target.
        Vec3 at = system().particles().x.col(target), velocity = system().particles().v.col(target);
        if (const auto ends = edge_of.find(v); ends != edge_of.end()) {
          const Index a = ball.soft_of[static_cast<std::size_t>(ends->second.first)],
                      b = ball.soft_of[static_cast<std::size_t>(ends->second.second)];
          if (a >= 0 && b >= 0) {
            at = 0.5 * (system().particles().x.col(a) + system().particles().x.col(b));
            velocity = 0.5 * (system().particles().v.col(a) + system().particles().v.col(b));
          }
        }
        const Index s = system().add_particle(at, velocity, 0.0);
        SoftBindingSettings binding;
        binding.particle = s;
        binding.target = target;
        binding.stiffness = kSoftStiffness;
        system().add_soft_binding(binding);
        system().set_collision_filter(s, kDefaultCollisionGroup, probe);
        ball.soft_of[static_cast<std::size_t>(v)] = s;
        ball.soft.push_back(s);
        ball.soft_target.push_back(target);
      }
    }
    if (ball.membrane != nullptr) system().remove_force(*ball.membrane);
    Vectors3 rest = system().particles().x;
    std::vector<std::array<Index, 3>> membrane_triangles;
    ball.skin.clear();
    for (const auto& tri : ball.mesh.triangles) {
      std::array<Index, 3> drawn{};
      bool all_soft = true;
      for (int k = 0; k < 3; ++k) {
        const auto v = static_cast<std::size_t>(tri[static_cast<std::size_t>(k)]);
        const Index s = ball.soft_of[v];
        all_soft = all_soft && s >= 0;
        drawn[static_cast<std::size_t>(k)] = s >= 0 ? s : ball.target[v];
        if (s >= 0) rest.col(s) = ball.mesh.vertices.col(static_cast<Index>(v));
      }
      ball.skin.push_back(drawn);
      if (all_soft) membrane_triangles.push_back(drawn);
    }
    TriangleMembraneSettings membrane;
    membrane.mu = kSkinMu;
    membrane.lambda = kSkinMu;
    ball.membrane = &system().add_force(std::make_unique<TriangleMembrane>(membrane_triangles, rest, membrane));
    m_surface_triangles[static_cast<std::size_t>(ball.drawn)] = ball.skin;
  }

  const System& system_const() const { return m_coupling->system(); }

  // The right ball's collision surface: refined around the probe's path, a target per vertex, a soft
  // particle tied to each. The lattice's nodes stop meeting the probe (its collision group is out of
  // their mask); they still rest on the ground.
  void add_soft_surface(Ball& ball) {
    const double reaches[2] = {kFine, kFiner};
    const RefinedTriangles mesh =
        refine_near(unrefined(ball.surface.vertices, ball.surface.triangles), reaches, [&](const Vec3& c) {
          return c.y() > ball.top - kRadius ? std::hypot(c.x() - (ball.x + kOff), c.z() - kOff) : kInfinity;
        });
    const Index coarse = ball.surface.vertices.cols();
    ball.target.assign(static_cast<std::size_t>(mesh.vertices.cols()), -1);
    for (Index v = 0; v < coarse; ++v)
      ball.target[static_cast<std::size_t>(v)] = ball.volume.surface[static_cast<std::size_t>(v)];
    for (Index v = coarse; v < mesh.vertices.cols(); ++v)
      ball.target[static_cast<std::size_t>(v)] = system().add_particle(mesh.vertices.col(v), Vec3::Zero(), 0.0);
    // Each midpoint on the edge it halves (chains flattened at set-up): on the coarse surface.
    for (const auto& [edge, middle] : mesh.midpoint) {
      const Index parents[2] = {ball.target[static_cast<std::size_t>(edge.first)],
                                ball.target[static_cast<std::size_t>(edge.second)]};
      const double weights[2] = {0.5, 0.5};
      system().bind_linear(ball.target[static_cast<std::size_t>(middle)], parents, weights);
    }
    const std::uint32_t probe = static_cast<std::uint32_t>(kProbeGroup);
    for (const Index i : ball.volume.lattice)
      system().set_collision_filter(i, kDefaultCollisionGroup, kAllCollisionGroups & ~probe);
    // Soft particles where the surface was refined: they meet the probe alone; elsewhere the surface
    // is drawn from its targets. The membrane among them makes the probe dent the copy instead of
    // parting its particles.
    SoftCopy copy = add_soft_copy(system(), mesh, ball.target, kSoftStiffness, probe, kSkinMu);
    ball.soft = std::move(copy.soft);
    ball.soft_target = std::move(copy.soft_target);
    ball.skin = std::move(copy.skin);
  }

  // Largest distance of a soft particle from its target now [m] (0 for the left ball).
  double drift(const Ball& ball) const {
    const Vectors3& x = system_const().particles().x;
    double most = 0.0;
    for (std::size_t k = 0; k < ball.soft.size(); ++k)
      most = std::max(most, (x.col(ball.soft[k]) - x.col(ball.soft_target[k])).norm());
    return most;
  }

  // How deep the probe is in the ball's drawn surface [m]: its radius less the distance from its
  // centre to the nearest triangle, signed by that triangle's outward side; negative while outside.
  double depth(const Ball& ball) const {
    const Vectors3& x = system_const().particles().x;
    const Vec3 c = to_eigen(ball.probe->getWorldTransform().getOrigin());
    double nearest = kInfinity, side = 1.0;
    for (const auto& t : ball.skin) {
      const Vec3 a = x.col(t[0]), b = x.col(t[1]), d = x.col(t[2]);
      const Vec3 p = closest_on_triangle(c, a, b, d);
      const double distance = (c - p).norm();
      if (distance < nearest) {
        nearest = distance;
        side = (c - p).dot((b - a).cross(d - a)) < 0.0 ? -1.0 : 1.0;
      }
    }
    return kProbeRadius - side * nearest;
  }

  // The probe over `ball` at time t: kStartAbove over the top at first, coming down at kSpeed after
  // kWait until its centre is kPress below the top, held for kHold, then going back up at kSpeed.
  // Its path is off the ball's axis by (2.5 cm, 2.5 cm): between the lattice's node columns.
  static btTransform probe_pose(const Ball& ball, double t) {
    const double start = ball.top + kStartAbove + kProbeRadius, bottom = ball.top - kPress;
    const double down = (start - bottom) / kSpeed, up_at = kWait + down + kHold;
    double y = std::max(bottom, start - kSpeed * std::max(0.0, t - kWait));
    if (t > up_at) y = std::min(start, bottom + kSpeed * (t - up_at));
    return at(btVector3(btScalar(ball.x + kOff), btScalar(y), btScalar(kOff)));
  }

  // Closest point on triangle (a, b, c) to p.
  static Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const std::array<double, 3> w = ccd::closest_on_triangle(p, a, b, c);
    return w[0] * a + w[1] * b + w[2] * c;
  }

  std::array<Ball, 3> m_balls;
  bool m_settled = false;
};

SINEW_REGISTER_SCENE({.name = "subelement",
                      .description = "figure 7: a small Bullet sphere pressed into two coarse balls: lattice nodes "
                                     "only, and a refined surface of soft-bound particles on binding springs",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<SubElement>(); },
                      .gallery_frame = 75});

}  // namespace
}  // namespace sinew::scenes
