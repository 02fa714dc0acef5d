#include "bullet_scenes.hpp"

#include "sinew/forces/triangle_membrane.hpp"
#include "sinew/lattice.hpp"
#include "sinew/plasticity.hpp"
#include "sinew/refinement.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace sinew::scenes {
namespace {

// Figure 9: sub-element plasticity. Three coarse blocks (45 x 17 x 45 cm, embedded in a BCC lattice
// of 10 cm cells: a stamp's arm is narrower than a cell) stand on the ground, held by ties at their
// lattice's lowest nodes. Each block's top face is duplicated, red-refined three times where a kinematic Bullet
// stamp (a cross of two 4 cm bars) comes, and every vertex of the copy is a massless target embedded
// in the tets (PlasticSurface::add_target); the vertices of the refined part carry soft-bound
// particles on binding springs (section 3.2) held together by a membrane, which alone meet the stamp.
// The stamp comes down kPress into each top, holds, and goes away up.
//   left    no yield: the top springs back (an elastic block);
//   middle  yield length 1 cm;  right  yield length 2 cm.
// When the stamp stretches a binding spring past the yield length, the target moves in material
// space until the spring is that long (PlasticSurface::yield, after every frame): the dent the stamp
// leaves is at most as deep as the soft particles were pressed (kPress and the contact thickness,
// less the block's own elastic give under the stamp), and at least that less the yield length.
class Stamp final : public BulletScene {
 public:
  Stamp() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    btCollisionShape* pin = m_world.keep(std::make_unique<btSphereShape>(btScalar(0.01)));
    btRigidBody* anchor = m_world.add_body(pin, 0.0, at(btVector3(0, -1, 0)));
    anchor->setCollisionFlags(anchor->getCollisionFlags() | btCollisionObject::CF_NO_CONTACT_RESPONSE);
    btCollisionShape* stamp = make_stamp_shape();
    VolumeMaterial material;
    material.density = 300.0;
    material.young_modulus = 2e5;
    material.poisson_ratio = 0.3;
    material.damping = 0.02;
    const double yields[3] = {0.0, 0.01, 0.02};
    for (std::size_t b = 0; b < m_blocks.size(); ++b) {
      Block& block = m_blocks[b];
      block.x = (static_cast<double>(b) - 1.0) * 0.55;
      block.yield_length = yields[b];
      block.surface = box_surface(Vec3(block.x - kHalf, 0.0, -kHalf), Vec3(block.x + kHalf, kHeight, kHalf), 6);
      block.volume = add_embedded_volume(system(), block.surface.vertices, block.surface.triangles, kSpacing, material);
      double lowest = kInfinity;
      for (const Index i : block.volume.lattice) lowest = std::min(lowest, system().particles().x(1, i));
      for (const Index i : block.volume.lattice)
        if (system().particles().x(1, i) < lowest + 0.25 * kSpacing)
          coupling().attach(i, anchor, system().particles().x.col(i) - Vec3(0, -1, 0), kTie);
      add_soft_top(block);
      add_surface(b == 0 ? "elastic (no yield)" : b == 1 ? "yield 1 cm" : "yield 2 cm", block.skin);
      block.stamp = m_world.add_body(stamp, 0.0, stamp_pose(block, 0.0), btVector3(0, 0, 0), kStampGroup,
                                     btBroadphaseProxy::AllFilter);
      block.stamp->setCollisionFlags(block.stamp->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
      block.stamp->setActivationState(DISABLE_DEACTIVATION);
    }
  }

  void before_frame(double t) override {
    if (t >= kWait && !m_settled) {
      // The tops have settled under gravity: the stamp presses from here, and the sag is the zero of
      // the elastic give.
      m_settled = true;
      for (Block& block : m_blocks) {
        block.top = top_height(block);
        block.sag = kHeight - block.top;
      }
      m_energy_before = total_energy();
      m_springs_before = system().binding_springs().potential_energy(system().particles().x);
    }
    for (const Block& block : m_blocks) block.stamp->getMotionState()->setWorldTransform(stamp_pose(block, t));
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    for (Block& block : m_blocks) {
      // Re-embedding changes no mass and no velocity: momentum and angular momentum stay as they were.
      const Vec3 P = system().linear_momentum(true), L = system().angular_momentum(true);
      const YieldStats stats = block.plastic->yield(system());
      m_momentum_jump = std::max(
          {m_momentum_jump, (system().linear_momentum(true) - P).norm(), (system().angular_momentum(true) - L).norm()});
      block.moves += stats.moved;
      block.stopped += stats.stopped;
      // The block's elastic give under the stamp while it holds: how far its deepest target sits
      // below its material place, less the sag under gravity.
      if (m_settled && time() <= kWait + travel() + kHold) {
        const auto [deepest, X] = deepest_target(block);
        block.give = std::max(block.give, X.y() - system().particles().x(1, deepest) - block.sag);
      }
    }
  }

  std::string json_fields() override {
    std::string text;
    const char* names[3] = {"elastic", "yield_1cm", "yield_2cm"};
    for (std::size_t b = 0; b < m_blocks.size(); ++b) {
      Block& block = m_blocks[b];
      // The soft particles are pressed kPress + the contact thickness below the top; a target ends at
      // most L_y from its soft particle, at least L_y less deep when right above it; the block's own
      // give under the stamp comes back.
      const double pressed = kPress + kThickness - block.give;
      char part[512];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"yield_length\": %.3f, \"targets\": %zu, \"soft_particles\": %zu, \"re_embeddings\": "
                    "%lld, \"stopped_at_material\": %lld, \"dent_material\": %.5f, \"dent_world\": %.5f, "
                    "\"elastic_give\": %.5f, \"dent_low\": %.5f, \"dent_high\": %.5f}, ",
                    names[b], block.yield_length, block.targets.size(), block.soft.size(),
                    static_cast<long long>(block.moves), static_cast<long long>(block.stopped), dent_material(block),
                    dent_world(block), block.give,
                    block.yield_length > 0.0 ? std::max(0.0, pressed - block.yield_length) : 0.0,
                    block.yield_length > 0.0 ? pressed : 0.0);
      text += part;
    }
    double membranes = 0.0;
    for (const Block& block : m_blocks) membranes += block.membrane->potential_energy(system().particles().x);
    char part[512];
    std::snprintf(part, sizeof part,
                  "\"lattice_nodes\": %zu, \"tets\": %zu, \"press\": %.3f, \"energy_before_press\": %.4f, "
                  "\"membrane_energy\": %.4f, \"binding_spring_energy_before_press\": %.4f, "
                  "\"binding_spring_energy\": %.4f, \"momentum_change_by_yield\": %.3g, ",
                  m_blocks[0].volume.lattice.size(), m_blocks[0].volume.embedding.tets.size(), kPress, m_energy_before,
                  membranes, m_springs_before, system().binding_springs().potential_energy(system().particles().x),
                  m_momentum_jump);
    return text + part;
  }

  static constexpr double kHalf = 0.225, kHeight = 0.17, kSpacing = 0.1, kTie = 4e3, kSoftStiffness = 40.0,
                          kSkinMu = 100.0, kPress = 0.03, kSpeed = 0.1, kStartAbove = 0.02, kWait = 0.5, kHold = 0.5,
                          kArm = 0.1, kArmWidth = 0.02, kArmHeight = 0.06, kReach1 = 0.06, kReach2 = 0.04,
                          kReach3 = 0.025, kNoYield = 1e3, kRise = 0.2, kAway = 0.3;
  static inline const double kThickness = bullet::CouplingSettings{}.thickness;
  static constexpr int kStampGroup = btBroadphaseProxy::CharacterFilter;

 private:
  struct Block {
    double x = 0.0, yield_length = 0.0, top = kHeight, sag = 0.0, give = 0.0;
    ClosedSurface surface;
    EmbeddedVolume volume;
    std::unique_ptr<PlasticSurface> plastic;
    std::vector<Index> targets;            // per vertex of the refined top
    std::vector<Index> soft, soft_target;  // soft particles and their targets
    std::vector<Index> coarse;             // targets at the coarse top's vertices away from the stamp
    std::vector<std::array<Index, 3>> skin;
    btRigidBody* stamp = nullptr;
    TriangleMembrane* membrane = nullptr;  // among the soft particles
    std::int64_t moves = 0, stopped = 0;
  };

  // A cross of two bars, kArm half-long, kArmWidth half-wide, under a plate: its lowest face at the
  // body's origin.
  btCollisionShape* make_stamp_shape() {
    auto* compound = static_cast<btCompoundShape*>(m_world.keep(std::make_unique<btCompoundShape>()));
    btCollisionShape* along_x = m_world.keep(
        std::make_unique<btBoxShape>(btVector3(btScalar(kArm), btScalar(kArmHeight / 2), btScalar(kArmWidth))));
    btCollisionShape* along_z = m_world.keep(
        std::make_unique<btBoxShape>(btVector3(btScalar(kArmWidth), btScalar(kArmHeight / 2), btScalar(kArm))));
    btCollisionShape* plate = m_world.keep(
        std::make_unique<btBoxShape>(btVector3(btScalar(kArm + 0.02), btScalar(0.01), btScalar(kArm + 0.02))));
    compound->addChildShape(at(btVector3(0, btScalar(kArmHeight / 2), 0)), along_x);
    compound->addChildShape(at(btVector3(0, btScalar(kArmHeight / 2), 0)), along_z);
    compound->addChildShape(at(btVector3(0, btScalar(kArmHeight + 0.01), 0)), plate);
    return compound;
  }

  // Distance from (x, z) to the cross's footprint, about the block's centre.
  double to_cross(const Block& block, double x, double z) const {
    const double u = std::abs(x - block.x), w = std::abs(z);
    const auto to_bar = [](double a, double b, double half_a, double half_b) {
      return std::hypot(std::max(0.0, a - half_a), std::max(0.0, b - half_b));
    };
    return std::min(to_bar(u, w, kArm, kArmWidth), to_bar(u, w, kArmWidth, kArm));
  }

  // The top face's copy: refined where the stamp comes, a target per vertex, a soft particle on a
  // binding spring at each vertex of the refined part, a membrane among those.
  void add_soft_top(Block& block) {
    std::vector<std::array<Index, 3>> sides, top;
    for (const auto& t : block.surface.triangles) {
      bool on_top = true;
      for (const Index v : t) on_top = on_top && block.surface.vertices(1, v) == kHeight;
      (on_top ? top : sides).push_back(t);
    }
    // The top's vertices, numbered afresh.
    std::vector<Index> renumber(static_cast<std::size_t>(block.surface.vertices.cols()), -1);
    std::vector<Index> used;
    for (auto& t : top)
      for (Index& v : t) {
        if (renumber[static_cast<std::size_t>(v)] < 0) {
          renumber[static_cast<std::size_t>(v)] = static_cast<Index>(used.size());
          used.push_back(v);
        }
        v = renumber[static_cast<std::size_t>(v)];
      }
    Vectors3 top_vertices(3, static_cast<Index>(used.size()));
    for (std::size_t k = 0; k < used.size(); ++k)
      top_vertices.col(static_cast<Index>(k)) = block.surface.vertices.col(used[k]);
    const double reaches[3] = {kReach1, kReach2, kReach3};
    const RefinedTriangles mesh = refine_near(unrefined(top_vertices, top), reaches,
                                              [&](const Vec3& c) { return to_cross(block, c.x(), c.z()); });
    // The lattice's nodes and the targets meet nothing (the ties hold the block; its lattice reaches
    // below the ground, where its lowest tets hold no material); the soft particles meet the stamp.
    const std::uint32_t stamp = static_cast<std::uint32_t>(kStampGroup);
    for (const Index i : block.volume.lattice) system().set_collision_filter(i, kDefaultCollisionGroup, 0);
    // The elastic block's targets are embedded the same way, with a yield length no spring reaches.
    block.plastic = std::make_unique<PlasticSurface>(
        block.volume.embedding.vertices, block.volume.embedding.tets, block.volume.lattice, block.surface.vertices,
        block.surface.triangles, block.yield_length > 0.0 ? block.yield_length : kNoYield);
    for (Index v = 0; v < mesh.vertices.cols(); ++v) {
      const Index t = block.plastic->add_target(system(), mesh.vertices.col(v));
      system().set_collision_filter(t, kDefaultCollisionGroup, 0);
      block.targets.push_back(t);
    }
    SoftCopy copy = add_soft_copy(system(), mesh, block.targets, kSoftStiffness, stamp, kSkinMu);
    for (std::size_t k = 0; k < copy.soft.size(); ++k) block.plastic->track(copy.soft[k], copy.soft_target[k]);
    // The top's height is read from the targets of the coarse top away from the stamp.
    for (Index v = 0; v < mesh.vertices.cols(); ++v) {
      const Index target = block.targets[static_cast<std::size_t>(v)];
      if (copy.drawn[static_cast<std::size_t>(v)] == target &&
          to_cross(block, mesh.vertices(0, v), mesh.vertices(2, v)) > 2.0 * kReach1)
        block.coarse.push_back(target);
    }
    block.soft = std::move(copy.soft);
    block.soft_target = std::move(copy.soft_target);
    block.skin = std::move(copy.skin);
    block.membrane = copy.membrane;
    for (const auto& t : embedded_skin(block.volume, sides)) block.skin.push_back(t);
  }
  // Mean height of the coarse top's targets away from the stamp [m].
  double top_height(const Block& block) const {
    double sum = 0.0;
    for (const Index t : block.coarse) sum += system_const().particles().x(1, t);
    return sum / static_cast<double>(block.coarse.size());
  }

  // The target (with a soft particle) whose material place is deepest, and that place.
  std::pair<Index, Vec3> deepest_target(const Block& block) const {
    std::pair<Index, Vec3> deepest{-1, Vec3::Constant(kInfinity)};
    for (const Index t : block.soft_target) {
      const Vec3 X = block.plastic->material_point(t);
      if (X.y() < deepest.second.y()) deepest = {t, X};
    }
    return deepest;
  }

  // The permanent dent: how far below the top face the deepest target's material place is [m].
  double dent_material(const Block& block) const { return kHeight - deepest_target(block).second.y(); }

  // The dent seen now: the top's height away from the stamp less the lowest soft particle's [m].
  double dent_world(const Block& block) const {
    double lowest = kInfinity;
    for (const Index s : block.soft) lowest = std::min(lowest, system_const().particles().x(1, s));
    return top_height(block) - lowest;
  }

  const System& system_const() const { return m_coupling->system(); }

  static double travel() { return (kStartAbove + kPress) / kSpeed; }

  // The stamp over `block` at time t: its face kStartAbove over the top at first, coming down at
  // kSpeed after kWait until it is kPress below the settled top, held for kHold, then going up at
  // kRise to kAway over its start (out of the picture's way).
  static btTransform stamp_pose(const Block& block, double t) {
    const double start = block.top + kStartAbove, bottom = block.top - kPress;
    const double up_at = kWait + travel() + kHold;
    double y = std::max(bottom, start - kSpeed * std::max(0.0, t - kWait));
    if (t > up_at) y = std::min(start + kAway, bottom + kRise * (t - up_at));
    return at(btVector3(btScalar(block.x), btScalar(y), 0));
  }

  std::array<Block, 3> m_blocks;
  bool m_settled = false;
  double m_energy_before = 0.0, m_springs_before = 0.0;  // [J] when the stamps start down
  double m_momentum_jump = 0.0;  // largest change of momentum or angular momentum across a yield
};

SINEW_REGISTER_SCENE({.name = "stamp",
                      .description = "figure 9: a Bullet stamp pressed into three coarse blocks whose refined, "
                                     "soft-bound top copies yield in material space (no yield, 1 cm, 2 cm)",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Stamp>(); },
                      .gallery_frame = 180});

}  // namespace
}  // namespace sinew::scenes
