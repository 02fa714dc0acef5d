#include "bullet_peers.hpp"

// GCC's optimiser reports btReducedVector's inline copies (pulled in by the deformable solver's
// headers) as maybe-uninitialized although they are system headers; the code is Bullet's, not ours.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <BulletSoftBody/btDeformableBodySolver.h>
#include <BulletSoftBody/btDeformableGravityForce.h>
#include <BulletSoftBody/btDeformableMassSpringForce.h>
#include <BulletSoftBody/btDeformableMultiBodyDynamicsWorld.h>
#pragma GCC diagnostic pop
#include <BulletSoftBody/btSoftBodyHelpers.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>
#include <BulletSoftBody/btSoftRigidDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>

#include "sinew/bullet/convert.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <sstream>

namespace sinew::bench {

namespace {

constexpr int kCollidesWithNothing = 0;  // broadphase mask: the cloth touches neither rod nor rings

// The patch's diagonals are sinew's only for even n (see BulletCurtain::build_cloth).
std::string mesh_mismatch(const CurtainSpec& spec) {
  return spec.n % 2 == 0 ? std::string() : "; odd n: the patch's diagonals are the mirror image of sinew's";
}

// What both Bullet peers share: the cloth as a btSoftBody made by btSoftBodyHelpers::CreatePatch, the
// rod and rings, the anchors' pivots and every measurement. The Bullet objects are members in the order
// they are built, so they are destroyed in reverse; the cloth leaves the world first.
class BulletCurtain : public CurtainRun {
 public:
  ~BulletCurtain() override {
    // removeCollisionObject is virtual: both soft-body worlds route a soft body to their removeSoftBody
    // (the deformable world also detaches it from its forces).
    if (m_world && m_cloth) m_world->removeCollisionObject(m_cloth.get());
  }

  void advance(double frame_dt, int steps) override {
    if (!(std::isfinite(frame_dt) && frame_dt > 0)) fail(system(), ": frame_dt = ", frame_dt, " s, must be positive");
    if (steps < 1) fail(system(), ": steps = ", steps, ", needs at least 1");
    // Bullet's fixed-step accumulator: frame_dt / steps divides frame_dt exactly when steps is a power of
    // two; otherwise a step may be carried over to the next frame, as in any Bullet application.
    m_world->stepSimulation(btScalar(frame_dt), steps, btScalar(frame_dt / steps));
  }

  Vectors3 nodes() const override {
    Vectors3 x(3, static_cast<Index>(m_bullet_index.size()));
    for (std::size_t k = 0; k < m_bullet_index.size(); ++k)
      x.col(static_cast<Index>(k)) = bullet::to_eigen(node(static_cast<int>(k)).m_x);
    return x;
  }

  AttachmentError attachment() const override { return attachment_error(*m_rings, nodes(), m_pivots); }

  double momentum_along_rod() const override {
    double p = m_rings->momentum_along_rod();
    for (int k = 0; k < node_count(); ++k) p += node(k).m_v.x() / node(k).m_im;
    return p;
  }

  double energy() const override {
    double e = m_rings->energy(m_spec.gravity) + elastic_energy();
    for (int k = 0; k < node_count(); ++k) {
      const btSoftBody::Node& n = node(k);
      const double m = 1.0 / n.m_im;
      e += 0.5 * m * n.m_v.length2() + m * m_spec.gravity * n.m_x.y();
    }
    return e;
  }

  bool healthy() const override {
    for (int k = 0; k < node_count(); ++k) {
      const btSoftBody::Node& n = node(k);
      if (!all_finite(n.m_x) || !all_finite(n.m_v) || !(n.m_x.length() <= kFarAway)) return false;
    }
    return m_rings->healthy();
  }

 protected:
  explicit BulletCurtain(const CurtainSpec& spec) : m_spec(spec), m_pivots(bound_pivots(spec)) {}

  int node_count() const { return static_cast<int>(m_bullet_index.size()); }
  // Node j * n + i of the interface.
  const btSoftBody::Node& node(int k) const { return m_cloth->m_nodes[m_bullet_index[static_cast<std::size_t>(k)]]; }
  int bullet_index(int k) const { return m_bullet_index[static_cast<std::size_t>(k)]; }

  // Elastic energy the model stores, if it has one [J].
  virtual double elastic_energy() const { return 0.0; }

  // The rigid part; the world's gravity must already be set.
  void build_rings() { m_rings = std::make_unique<RodAndRings>(*m_world, m_spec); }

  // The cloth, not yet in the world. CreatePatch numbers node (ix, iy) as iy * resx + ix, places it by
  // bilinear interpolation of the four corners, and splits quad (ix, iy) along (ix, iy)-(ix+1, iy+1) when
  // ix + iy is odd, along (ix+1, iy)-(ix, iy+1) when even (with gendiags, a link along that diagonal):
  // the mirror image of sinew's grid, which uses the first diagonal when i + j is even. Mirroring the
  // patch in x (ix = n - 1 - i, iy = j) turns the one into the other when n is even; for odd n no mirror
  // or flip does, and mismatch() says so.
  void build_cloth(btSoftBodyWorldInfo& info) {
    const int n = m_spec.n;
    const bool mirrored = n % 2 == 0;
    m_bullet_index.resize(static_cast<std::size_t>(n) * n);
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
        m_bullet_index[static_cast<std::size_t>(j * n + i)] = j * n + (mirrored ? n - 1 - i : i);
    const int left = mirrored ? n - 1 : 0, right = mirrored ? 0 : n - 1;
    m_cloth.reset(btSoftBodyHelpers::CreatePatch(info, bullet::to_bullet(node_rest_position(m_spec, left, 0)),
                                                 bullet::to_bullet(node_rest_position(m_spec, right, 0)),
                                                 bullet::to_bullet(node_rest_position(m_spec, left, n - 1)),
                                                 bullet::to_bullet(node_rest_position(m_spec, right, n - 1)), n, n, 0,
                                                 true));
    // Interpolation rounds differently from node_rest_position: put every node exactly where the spec
    // (and sinew) puts it, then take the links' rest lengths from there.
    const btVector3 v0 = bullet::to_bullet(m_spec.initial_velocity);
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        btSoftBody::Node& nd = m_cloth->m_nodes[bullet_index(j * n + i)];
        nd.m_x = nd.m_q = bullet::to_bullet(node_rest_position(m_spec, i, j));
        // m_vn is the deformable world's v_n: its implicit solve starts from it, not from m_v.
        nd.m_v = nd.m_vn = v0;
      }
    m_cloth->resetLinkRestLengths();
    m_cloth->updateBounds();
    // Lumped by area: each node gets a third of the mass of every triangle it belongs to (all triangles
    // of the grid have the same area), as add_cloth_mesh does.
    m_cloth->setTotalMass(btScalar(m_spec.cloth_mass), true);
    m_cloth->setActivationState(DISABLE_DEACTIVATION);
  }

  CurtainSpec m_spec;
  std::vector<BoundPivot> m_pivots;
  std::vector<int> m_bullet_index;  // interface node j * n + i -> btSoftBody node

  std::unique_ptr<btCollisionConfiguration> m_configuration;
  std::unique_ptr<btCollisionDispatcher> m_dispatcher;
  std::unique_ptr<btBroadphaseInterface> m_broadphase;
  std::unique_ptr<btDeformableBodySolver> m_deformable_solver;  // the deformable world's only
  std::unique_ptr<btConstraintSolver> m_solver;
  std::unique_ptr<btDynamicsWorld> m_world;
  std::unique_ptr<RodAndRings> m_rings;
  std::vector<std::unique_ptr<btDeformableLagrangianForce>> m_forces;
  std::unique_ptr<btSoftBody> m_cloth;
};

// ---- classic ------------------------------------------------------------------------------------

void check(const ClassicSettings& s) {
  if (s.piterations < 1) fail("classic: piterations = ", s.piterations, ", needs at least 1");
  if (!(s.anchor_hardness > 0 && s.anchor_hardness <= 1))
    fail("classic: anchor_hardness = ", s.anchor_hardness, ", must be in (0, 1]");
  if (!(s.link_stiffness > 0 && s.link_stiffness <= 1))
    fail("classic: link_stiffness = ", s.link_stiffness, ", must be in (0, 1]");
  if (!(s.damping >= 0 && s.damping < 1)) fail("classic: damping = ", s.damping, ", must be in [0, 1)");
}

class ClassicCurtain final : public BulletCurtain {
 public:
  ClassicCurtain(const CurtainSpec& spec, const ClassicSettings& settings) : BulletCurtain(spec), m_settings(settings) {
    check(settings);
    m_configuration = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    m_solver = std::make_unique<btSequentialImpulseConstraintSolver>();
    auto world = std::make_unique<btSoftRigidDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(),
                                                            m_configuration.get());
    const btVector3 g(0, btScalar(-spec.gravity), 0);
    world->setGravity(g);
    world->getWorldInfo().m_gravity = g;  // the soft bodies read gravity from here, not from the world
    btSoftRigidDynamicsWorld& soft_world = *world;
    m_world = std::move(world);
    build_rings();
    build_cloth(soft_world.getWorldInfo());

    btSoftBody::Config& cfg = m_cloth->m_cfg;
    cfg.piterations = settings.piterations;
    cfg.kAHR = btScalar(settings.anchor_hardness);
    cfg.kDP = btScalar(settings.damping);
    m_cloth->m_materials[0]->m_kLST = btScalar(settings.link_stiffness);  // CreatePatch's one material
    soft_world.addSoftBody(m_cloth.get(), btBroadphaseProxy::DefaultFilter, kCollidesWithNothing);
    for (const BoundPivot& p : m_pivots)
      m_cloth->appendAnchor(bullet_index(p.node), &m_rings->ring(p.ring), bullet::to_bullet(p.local), true);
  }

  std::string system() const override { return "bullet-classic"; }

  std::string mismatch() const override {
    std::ostringstream out;
    out << "links are position constraints (kLST = " << m_settings.link_stiffness << ", dimensionless, "
        << m_settings.piterations << " sweeps) instead of " << m_spec.stretch_stiffness
        << " N/m springs, with no elastic energy; no edge damping (kDP = " << m_settings.damping
        << " is a drag on absolute velocity); no bending" << mesh_mismatch(m_spec);
    return out.str();
  }

 private:
  ClassicSettings m_settings;
};

// ---- deformable ---------------------------------------------------------------------------------

void check(const DeformableSettings& s) {
  if (s.newton_iterations < 1) fail("deformable: newton_iterations = ", s.newton_iterations, ", needs at least 1");
  if (s.cg_max_iterations < 1) fail("deformable: cg_max_iterations = ", s.cg_max_iterations, ", needs at least 1");
  if (!(std::isfinite(s.cg_tolerance) && s.cg_tolerance >= 0))
    fail("deformable: cg_tolerance = ", s.cg_tolerance, ", must be finite and >= 0");
  if (s.solver_iterations < 1) fail("deformable: solver_iterations = ", s.solver_iterations, ", needs at least 1");
}

// btDeformableBodySolver with its protected Newton and CG limits set, and a look at the anchored nodes
// inside applyTransforms. That virtual is the last thing a step does to the cloth
// (btDeformableMultiBodyDynamicsWorld::integrateTransforms calls it right after integrating the rigid
// bodies): for every node x += h (v + v_split) and q = x, then every anchored node is overwritten,
// x = T_body p_local. So once it returns, an anchored node's q still holds where the step itself put it:
// the position before the overwrite, against the same, already integrated, ring transform.
class MeasuringDeformableSolver final : public btDeformableBodySolver {
 public:
  explicit MeasuringDeformableSolver(const DeformableSettings& s) {
    m_maxNewtonIterations = s.newton_iterations;
    m_cg.m_maxIterations = s.cg_max_iterations;
    m_cg.setTolerance(btScalar(s.cg_tolerance));
  }
  std::function<void()> after_transforms;

  void applyTransforms(btScalar timeStep) override {
    btDeformableBodySolver::applyTransforms(timeStep);
    if (after_transforms) after_transforms();
  }
};

class DeformableCurtain final : public BulletCurtain {
 public:
  DeformableCurtain(const CurtainSpec& spec, const DeformableSettings& settings)
      : BulletCurtain(spec), m_settings(settings) {
    check(settings);
    m_configuration = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    auto deformable = std::make_unique<MeasuringDeformableSolver>(settings);
    MeasuringDeformableSolver& measuring = *deformable;
    m_deformable_solver = std::move(deformable);
    auto solver = std::make_unique<btDeformableMultiBodyConstraintSolver>();
    solver->setDeformableSolver(m_deformable_solver.get());
    auto world = std::make_unique<btDeformableMultiBodyDynamicsWorld>(
        m_dispatcher.get(), m_broadphase.get(), solver.get(), m_configuration.get(), m_deformable_solver.get());
    m_solver = std::move(solver);
    const btVector3 g(0, btScalar(-spec.gravity), 0);
    world->setGravity(g);
    world->getWorldInfo().m_gravity = g;
    // The world hands these to its solver at the start of every step (reinitialize).
    world->setImplicit(settings.implicit);
    world->setUseProjection(settings.use_projection);
    world->setLineSearch(settings.line_search);
    world->getSolverInfo().m_numIterations = settings.solver_iterations;
    btDeformableMultiBodyDynamicsWorld& deformable_world = *world;
    m_world = std::move(world);
    build_rings();
    build_cloth(deformable_world.getWorldInfo());
    deformable_world.addSoftBody(m_cloth.get(), btBroadphaseProxy::DefaultFilter, kCollidesWithNothing);

    // The spec's spring: k along each edge on its length error, damping d on the rate of stretch along
    // the edge (conserve_angular = true projects the damping onto the edge). The patch has no bending
    // links, so the force's bending stiffness is never used.
    m_forces.push_back(std::make_unique<btDeformableMassSpringForce>(btScalar(spec.stretch_stiffness),
                                                                     btScalar(spec.stretch_damping), true));
    deformable_world.addForce(m_cloth.get(), m_forces.back().get());
    m_forces.push_back(std::make_unique<btDeformableGravityForce>(g));
    deformable_world.addForce(m_cloth.get(), m_forces.back().get());

    // appendDeformableAnchor takes no pivot: it stores the node's position in the body's frame now,
    // which is the pivot because the node sits at its rest position and the ring is unrotated. Masses
    // must be final here: the anchor caches its impulse matrix (node and ring effective mass) once.
    for (const BoundPivot& p : m_pivots) m_cloth->appendDeformableAnchor(bullet_index(p.node), &m_rings->ring(p.ring));

    measuring.after_transforms = [this] { m_before_overwrite = pre_overwrite_error(); };
  }

  std::string system() const override { return "bullet-deformable"; }

  AttachmentError attachment() const override {
    AttachmentError error = BulletCurtain::attachment();
    error.bound_node_before_overwrite = m_before_overwrite;
    return error;
  }

  std::string mismatch() const override {
    std::string line = "no bending (Bullet's bending springs resist a fold only at second order in its angle)";
    if (!m_settings.implicit) line += "; explicit elasticity";
    else if (!m_settings.use_projection) line += "; implicit without projection drops every force";
    return line + mesh_mismatch(m_spec);
  }

 private:
  // Sum over the links of k/2 (|x_b - x_a| - L)^2: btDeformableMassSpringForce's energy.
  double elastic_energy() const override {
    double e = 0.0;
    for (int l = 0; l < m_cloth->m_links.size(); ++l) {
      const btSoftBody::Link& link = m_cloth->m_links[l];
      const double stretch = (link.m_n[1]->m_x - link.m_n[0]->m_x).length() - link.m_rl;
      e += 0.5 * m_spec.stretch_stiffness * stretch * stretch;
    }
    return e;
  }

  // max |q_node - T_ring p_local| over the anchored nodes, inside applyTransforms (see above).
  double pre_overwrite_error() const {
    double worst = 0.0;
    for (const BoundPivot& p : m_pivots) {
      const double e = (bullet::to_eigen(node(p.node).m_q) - m_rings->world_point(p.ring, p.local)).norm();
      worst = std::isnan(e) ? kInfinity : std::max(worst, e);
    }
    return worst;
  }

  DeformableSettings m_settings;
  double m_before_overwrite = 0.0;
};

}  // namespace

std::unique_ptr<CurtainRun> make_classic_curtain(const CurtainSpec& spec, const ClassicSettings& settings) {
  return std::make_unique<ClassicCurtain>(spec, settings);
}

std::unique_ptr<CurtainRun> make_deformable_curtain(const CurtainSpec& spec, const DeformableSettings& settings) {
  return std::make_unique<DeformableCurtain>(spec, settings);
}

}  // namespace sinew::bench
