#include "bullet_scenes.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Figure 5: two elastic sheets meshed with T-junctions (refined_strip: 1 m x 0.5 m, 9 x 5 nodes,
// red-refined once in the middle 60% and twice in the middle 30%), each held at its left end by a
// static Bullet bar and at its right end by a kinematic bar that moves out by a third of the width
// over 2 s (quasistatically) and holds. The upper sheet's T-junctions are free nodes; the lower
// sheet's are hard-bound to the ends of the edges they lie on (bind_t_junctions). Under the stretch
// and their weight the sheets deform unevenly, and the upper one opens gaps at its T-junctions where
// the lower one stays closed. The JSON line adds each sheet's largest gap now and over the run.
class TJunction final : public BulletScene {
 public:
  TJunction() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* bar = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.01, 0.3, 0.02)));
    for (int k = 0; k < 2; ++k) {
      Sheet& sheet = m_sheets[static_cast<std::size_t>(k)];
      sheet.bound = k == 1;
      const double bottom = k == 0 ? 1.1 : 0.3;
      sheet.mesh = refined_strip(9, 5, kWidth, 0.5, Vec3(0, bottom, 0));
      ClothMaterial material;
      material.mass = 0.2;
      material.stretch_stiffness = 0.0;
      material.bending_stiffness = 0.0;
      material.membrane_mu = 200.0;
      material.membrane_lambda = 300.0;
      material.membrane_damping = 0.02;
      sheet.particles = add_cloth_mesh(system(), sheet.mesh.vertices, sheet.mesh.triangles, material);
      if (sheet.bound) bind_t_junctions(system(), sheet.mesh, sheet.particles);
      const btScalar middle = btScalar(bottom + 0.25);
      sheet.left = m_world.add_body(bar, 0.0, at(btVector3(-0.011f, middle, 0)));
      sheet.right = m_world.add_body(bar, 0.0, at(btVector3(btScalar(kWidth + 0.011), middle, 0)));
      sheet.right->setCollisionFlags(sheet.right->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      sheet.right->setActivationState(DISABLE_DEACTIVATION);
      for (Index v = 0; v < sheet.mesh.vertices.cols(); ++v) {
        const double x = sheet.mesh.vertices(0, v);
        if (x < 1e-12) coupling().bind_here(sheet.particles[static_cast<std::size_t>(v)], sheet.left);
        if (x > kWidth - 1e-12) coupling().bind_here(sheet.particles[static_cast<std::size_t>(v)], sheet.right);
      }
      std::vector<std::array<Index, 3>> skin;
      for (const auto& t : sheet.mesh.triangles)
        skin.push_back({sheet.particles[static_cast<std::size_t>(t[0])],
                        sheet.particles[static_cast<std::size_t>(t[1])],
                        sheet.particles[static_cast<std::size_t>(t[2])]});
      add_surface(sheet.bound ? "T-junctions bound" : "T-junctions free", std::move(skin));
    }
  }
  void before_frame(double t) override {
    const double out = kWidth / 3.0 * std::min(1.0, t / kPull);
    for (const Sheet& sheet : m_sheets) {
      btTransform pose = sheet.right->getWorldTransform();
      pose.setOrigin(btVector3(btScalar(kWidth + 0.011 + out), pose.getOrigin().y(), 0));
      sheet.right->getMotionState()->setWorldTransform(pose);
    }
  }
  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    for (Sheet& sheet : m_sheets) sheet.widest = std::max(sheet.widest, gap(sheet));
  }
  std::string json_fields() override {
    char text[320];
    const auto& [free, bound] = m_sheets;
    std::snprintf(text, sizeof text,
                  "\"t_junctions\": %zu, \"gap_free\": %.3g, \"gap_free_max\": %.3g, \"gap_bound\": %.3g, "
                  "\"gap_bound_max\": %.3g, ",
                  bound.mesh.t_junctions.size(), gap(free), free.widest, gap(bound), bound.widest);
    return text;
  }

  struct Sheet {
    bool bound = false;
    RefinedTriangles mesh;
    std::vector<Index> particles;
    btRigidBody *left = nullptr, *right = nullptr;
    double widest = 0.0;
  };
  /// The largest distance of a T-junction of `sheet` from the edge it lies on, now [m].
  double gap(const Sheet& sheet) const {
    const Vectors3& x = m_coupling->system().particles().x;
    Vectors3 at(3, sheet.mesh.vertices.cols());
    for (Index v = 0; v < at.cols(); ++v) at.col(v) = x.col(sheet.particles[static_cast<std::size_t>(v)]);
    return largest_t_junction_gap(sheet.mesh, at);
  }

  static constexpr double kWidth = 1.0, kPull = 2.0;

 private:
  std::array<Sheet, 2> m_sheets;
};

SINEW_REGISTER_SCENE({.name = "tjunction",
                      .description = "figure 5: two sheets meshed with T-junctions stretched by a third between "
                                     "Bullet bars, the T-junctions free (above) and hard-bound (below)",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<TJunction>(); },
                      .gallery_frame = 150});

}  // namespace
}  // namespace sinew::scenes
