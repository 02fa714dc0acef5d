#include "bullet_scenes.hpp"

#include "sinew/ccd.hpp"
#include "sinew/lattice.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Figure 3: a coarse deformable ball pressed by a small kinematic sphere, three ways side by side.
// Each ball is a closed sphere surface (1280 triangles, 642 vertices about 2 cm apart) embedded in a
// BCC lattice of 10 cm cells (add_embedded_volume), resting on the ground; a Bullet sphere of radius
// 2.5 cm, smaller than the lattice's cells, comes down on its top at 0.25 m/s until its centre is
// kPress below the ball's undeformed top, and stays there.
//   left    the lattice's nodes collide, nothing else (the sphere passes between them);
//   middle  static sprinkling: every surface vertex has a collision particle, all the time;
//   right   adaptive sprinkling: a surface vertex has one only while a Bullet object is within reach.
// In both sprinkled balls the lattice's nodes stop colliding (SprinkleSettings::hosts_collide), so the
// balls rest on their surfaces. The scene reports, per ball, the deepest the sphere has gone into the
// embedded surface (its radius less the signed distance from its centre to the surface) and how many
// particles each part uses.
class Sprinkle final : public BulletScene {
 public:
  Sprinkle() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    // What the balls are tied to: a static body below the floor that meets nothing (a tie to the floor
    // itself would keep a ball from colliding with it).
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
      // Lifted by the lattice's margin on the left, where the nodes outside the surface hold it up.
      const double lift = b == 0 ? 0.0 : 0.011;
      ball.surface = sphere_surface(3, kRadius, Vec3(ball.x, kRadius + lift, 0));
      ball.volume = add_embedded_volume(system(), ball.surface.vertices, ball.surface.triangles, kSpacing, material);
      ball.top = 2.0 * kRadius + lift;
      if (b == 0) {
        // Held up by the nodes below the surface, which lie up to a cell below it: let it settle there
        // from the start, so the three probes meet balls at rest.
        double lowest = kInfinity;
        for (const Index i : ball.volume.lattice) lowest = std::min(lowest, system().particles().x(1, i));
        ball.top -= lowest - 0.011;
        for (const Index i : ball.volume.lattice) system().particles().x(1, i) -= lowest - 0.011;
        for (const Index i : ball.volume.surface) system().particles().x(1, i) -= lowest - 0.011;
      }
      // Tied down by the nodes of its lowest layer (binding springs to fixed points where they start),
      // so that a probe a little off its axis presses it instead of rolling it away.
      double lowest_node = kInfinity;
      for (const Index i : ball.volume.lattice) lowest_node = std::min(lowest_node, system().particles().x(1, i));
      for (const Index i : ball.volume.lattice)
        if (system().particles().x(1, i) < lowest_node + 0.25 * kSpacing)
          coupling().attach(i, anchor, system().particles().x.col(i) - Vec3(0, -1, 0), kTie);
      if (b > 0) {
        bullet::SprinkleSettings sprinkle;
        sprinkle.adaptive = b == 2;
        sprinkle.reach = 0.03;
        ball.sprinkle = coupling().sprinkle(ball.volume.surface, sprinkle);
      }
      if (b == 0) ball.aim = between_nodes(ball);
      else ball.aim = m_balls[0].aim - Vec3(m_balls[0].x, 0, 0) + Vec3(ball.x, 0, 0);
      ball.skin = embedded_skin(ball.volume, ball.surface.triangles);
      add_surface(kNames[b], ball.skin);
      ball.probe = m_world.add_body(probe, 0.0, probe_pose(ball, 0.0));
      ball.probe->setCollisionFlags(ball.probe->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      ball.probe->setActivationState(DISABLE_DEACTIVATION);
    }
  }
  void before_frame(double t) override {
    if (t >= kWait && !m_settled) {
      // The tops as the balls have settled under their weight: the probes press from there.
      m_settled = true;
      for (Ball& ball : m_balls) {
        ball.top = -kInfinity;
        for (const Index i : ball.volume.surface) ball.top = std::max(ball.top, system().particles().x(1, i));
      }
    }
    for (const Ball& ball : m_balls) ball.probe->getMotionState()->setWorldTransform(probe_pose(ball, t));
  }
  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    for (Ball& ball : m_balls) {
      ball.deepest = std::max(ball.deepest, depth(ball));
      if (ball.sprinkle >= 0) {
        const double count = double(coupling().sprinkled_count(ball.sprinkle));
        ball.most = std::max(ball.most, count);
        ball.sum += count;
      }
    }
    ++m_frames;
  }
  std::string json_fields() override {
    char text[768];
    const auto& [nodes, fixed, adaptive] = m_balls;
    std::snprintf(text, sizeof text,
                  "\"lattice_nodes\": %zu, \"surface_samples\": %zu, \"deepest_nodes_only\": %.4f, "
                  "\"deepest_static\": %.4f, \"deepest_adaptive\": %.4f, \"sprinkled_static\": %.0f, "
                  "\"sprinkled_adaptive_max\": %.0f, \"sprinkled_adaptive_mean\": %.1f, "
                  "\"surface_velocity_rms_nodes_only\": %.3g, \"surface_velocity_rms_static\": %.3g, "
                  "\"surface_velocity_rms_adaptive\": %.3g, ",
                  nodes.volume.lattice.size(), nodes.volume.surface.size(), nodes.deepest, fixed.deepest,
                  adaptive.deepest, fixed.most, adaptive.most, m_frames > 0 ? adaptive.sum / m_frames : 0.0,
                  surface_velocity_rms(nodes), surface_velocity_rms(fixed), surface_velocity_rms(adaptive));
    return text;
  }

  /// Ball 0 (nodes only), 1 (static sprinkling), 2 (adaptive).
  struct Ball {
    double x = 0.0, top = 0.0;
    Vec3 aim = Vec3::Zero();  ///< the probe's path: x and z of this point
    ClosedSurface surface;
    EmbeddedVolume volume;
    std::vector<std::array<Index, 3>> skin;
    Index sprinkle = -1;
    btRigidBody* probe = nullptr;
    double deepest = -kInfinity, most = 0.0, sum = 0.0;
  };
  const Ball& ball(int b) const { return m_balls[static_cast<std::size_t>(b)]; }

  /// Root mean square of the speeds of `ball`'s embedded surface now [m/s] (what is drawn).
  double surface_velocity_rms(const Ball& ball) const {
    double sum = 0.0;
    for (const Index i : ball.volume.surface) sum += system_const().particles().v.col(i).squaredNorm();
    return std::sqrt(sum / double(ball.volume.surface.size()));
  }
  /// How deep the probe of `ball` is in its embedded surface now [m]: the probe's radius less the
  /// signed distance from its centre to the surface (negative inside); negative while it is outside.
  double depth(const Ball& ball) const {
    const Vectors3& x = system_const().particles().x;
    Vectors3 vertices(3, static_cast<Index>(ball.volume.surface.size()));
    for (std::size_t k = 0; k < ball.volume.surface.size(); ++k)
      vertices.col(static_cast<Index>(k)) = x.col(ball.volume.surface[k]);
    const Vec3 c = to_eigen(ball.probe->getWorldTransform().getOrigin());
    double nearest = kInfinity;
    for (const auto& t : ball.surface.triangles)
      nearest = std::min(
          nearest, (c - closest_on_triangle(c, vertices.col(t[0]), vertices.col(t[1]), vertices.col(t[2]))).norm());
    const double signed_distance = SurfaceInside(vertices, ball.surface.triangles).inside(c) ? -nearest : nearest;
    return kProbeRadius - signed_distance;
  }

  static constexpr double kRadius = 0.15, kSpacing = 0.1, kProbeRadius = 0.025, kSpeed = 0.25, kPress = 0.03,
                          kStartAbove = 0.03, kWait = 0.5, kTie = 2e3;

 private:
  static constexpr const char* kNames[3] = {"nodes only", "static sprinkling", "adaptive sprinkling"};
  const System& system_const() const { return m_coupling->system(); }
  // The probe over `ball` at time t: its lowest point kStartAbove over the ball's top at t = 0, coming
  // down at kSpeed until its centre is kPress below the top.
  static btTransform probe_pose(const Ball& ball, double t) {
    const double start = ball.top + kStartAbove + kProbeRadius;
    const double y = std::max(ball.top - kPress, start - kSpeed * std::max(0.0, t - kWait));
    return at(btVector3(btScalar(ball.aim.x()), btScalar(y), btScalar(ball.aim.z())));
  }
  // Where the probe comes down: the point within 3 cm of the ball's axis (on a 5 mm grid) farthest,
  // across, from the lattice nodes in the ball's upper half, so the coarse lattice cannot catch it on
  // a node that happens to sit on its path (the case figure 3 is about).
  Vec3 between_nodes(const Ball& ball) const {
    const Vectors3& x = system_const().particles().x;
    double centre_y = 0.0;
    for (const Index i : ball.volume.lattice) centre_y += x(1, i) / double(ball.volume.lattice.size());
    Vec3 best(ball.x, 0, 0);
    double widest = -1.0;
    for (int a = -6; a <= 6; ++a)
      for (int c = -6; c <= 6; ++c) {
        const double px = ball.x + 0.005 * a, pz = 0.005 * c;
        double nearest = kInfinity;
        for (const Index i : ball.volume.lattice)
          if (x(1, i) > centre_y) nearest = std::min(nearest, std::hypot(x(0, i) - px, x(2, i) - pz));
        if (nearest > widest) {
          widest = nearest;
          best = Vec3(px, 0, pz);
        }
      }
    return best;
  }
  // Closest point on triangle (a, b, c) to p.
  static Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
    const std::array<double, 3> w = ccd::closest_on_triangle(p, a, b, c);
    return w[0] * a + w[1] * b + w[2] * c;
  }

  std::array<Ball, 3> m_balls;
  bool m_settled = false;
  int m_frames = 0;
};

SINEW_REGISTER_SCENE({.name = "sprinkle",
                      .description = "figure 3: a small Bullet sphere pressed into three coarse embedded balls: "
                                     "lattice nodes only, static and adaptive sprinkled collision particles",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Sprinkle>(); },
                      .gallery_frame = 60});

}  // namespace
}  // namespace sinew::scenes
