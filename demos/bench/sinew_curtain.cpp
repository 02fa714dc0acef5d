#include "sinew_curtain.hpp"

#include "sinew/builders.hpp"
#include "sinew/bullet/convert.hpp"
#include "sinew/bullet/coupling.hpp"

#include <btBulletDynamicsCommon.h>

#include <cmath>
#include <sstream>

namespace sinew::bench {

namespace {

class SinewCurtain final : public SinewCurtainRun {
 public:
  SinewCurtain(const CurtainSpec& spec, const SinewSettings& settings)
      : m_spec(spec), m_settings(settings), m_pivots(bound_pivots(spec)) {
    if (!(std::isfinite(settings.cg_tolerance) && settings.cg_tolerance > 0))
      fail("sinew curtain: cg_tolerance = ", settings.cg_tolerance, ", must be positive");
    if (!(settings.cfl > 0 && settings.cfl <= 1)) fail("sinew curtain: cfl = ", settings.cfl, ", must be in (0, 1]");
    if (!(std::isfinite(settings.binding_spring_stiffness) && settings.binding_spring_stiffness >= 0))
      fail("sinew curtain: binding_spring_stiffness = ", settings.binding_spring_stiffness,
           " N/m, must be finite and >= 0");
    if (!(std::isfinite(settings.binding_spring_damping_ratio) && settings.binding_spring_damping_ratio >= 0))
      fail("sinew curtain: binding_spring_damping_ratio = ", settings.binding_spring_damping_ratio,
           ", must be finite and >= 0");
    m_configuration = std::make_unique<btDefaultCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    m_solver = std::make_unique<btSequentialImpulseConstraintSolver>();
    m_world = std::make_unique<btDiscreteDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(),
                                                        m_configuration.get());
    m_world->setGravity(btVector3(0, btScalar(-spec.gravity), 0));
    m_rings = std::make_unique<RodAndRings>(*m_world, spec);
    // Per-tick statistics: a post-tick callback installed before the coupling, which chains it.
    m_world->setInternalTickCallback(&SinewCurtain::after_tick, this, false);

    bullet::CouplingSettings coupling;
    coupling.collisions = false;  // the benchmark measures the binding, not contact (as for the peers)
    m_coupling = std::make_unique<bullet::Coupling>(m_world.get(), coupling);
    System& system = m_coupling->system();

    ClothGridSettings grid = cloth_grid_of(spec);
    grid.bending_implicit = spec.bending_implicit;
    grid.origin = node_rest_position(spec, 0, 0);
    grid.across = Vec3::UnitX();
    grid.down = -Vec3::UnitY();
    m_cloth = add_cloth_grid(system, grid);
    for (Index node : m_cloth.nodes) system.particles().v.col(node) = spec.initial_velocity;
    // The grid places node (i, j) at origin + i dx across + j dx down, which rounds differently from
    // node_rest_position: put every node exactly where the spec (and the peers) put it. The forces took
    // their rest state from the grid's positions, which differ by an ulp at most.
    for (int j = 0; j < spec.n; ++j)
      for (int i = 0; i < spec.n; ++i) system.particles().x.col(m_cloth.node(i, j)) = node_rest_position(spec, i, j);
    for (const BoundPivot& p : m_pivots) {
      const Index node = m_cloth.node(p.node, 0);
      if (settings.binding_spring_stiffness > 0) {
        // The node keeps its mass and DOFs; attachment() then measures the springs' stretch.
        m_coupling->attach(node, &m_rings->ring(p.ring), p.local, settings.binding_spring_stiffness,
                           settings.binding_spring_damping_ratio);
      } else {
        m_bound_mass += system.input_mass()[node];
        m_coupling->bind(node, &m_rings->ring(p.ring), p.local);
      }
    }

    StepSettings& step = system.step_settings();
    step.implicit_elasticity = settings.implicit_elasticity;
    step.multigrid = settings.multigrid;
    step.cg_tolerance = settings.cg_tolerance;
    step.cfl = settings.cfl;
    step.threads = settings.threads;
    step.newton_iterations = settings.newton_iterations;
    step.automatic = false;  // each named setting runs as it says; System::advance's own choice is not one of them
    system.finalize();
  }

  ~SinewCurtain() override {
    m_coupling.reset();  // restores the world's callbacks before the world goes
    m_rings.reset();
  }

  std::string system() const override {
    if (m_settings.multigrid) return "sinew-multigrid";
    if (m_settings.implicit_elasticity) return m_spec.bending_implicit ? "sinew-implicit-bending" : "sinew-implicit";
    return "sinew";
  }

  void advance(double frame_dt, int steps) override {
    if (!(std::isfinite(frame_dt) && frame_dt > 0)) fail(system(), ": frame_dt = ", frame_dt, " s, must be positive");
    if (steps < 1) fail(system(), ": steps = ", steps, ", needs at least 1");
    m_world->stepSimulation(btScalar(frame_dt), steps, btScalar(frame_dt / steps));
  }

  System& deformable_system() override { return m_coupling->system(); }

  Vectors3 nodes() const override {
    const Vectors3& x = m_coupling->system().particles().x;
    Vectors3 out(3, static_cast<Index>(m_cloth.nodes.size()));
    for (std::size_t k = 0; k < m_cloth.nodes.size(); ++k) out.col(static_cast<Index>(k)) = x.col(m_cloth.nodes[k]);
    return out;
  }

  AttachmentError attachment() const override { return attachment_error(*m_rings, nodes(), m_pivots); }

  // A ring carrying hard-bound nodes is the merged body of its rigid-body particle (the nodes' mass is
  // the ring's, at the merged centre of mass, with the merged inertia): its momentum and energy are
  // that body's. Rings without a particle are measured as Bullet has them.
  double momentum_along_rod() const override {
    const System& s = m_coupling->system();
    const RigidBodyParticles& bodies = s.rigid_bodies();
    double p = 0.0;
    for (int k = 0; k < m_rings->count(); ++k) {
      const Index b = particle_of(k);
      if (b >= 0) {
        p += bodies.mass[b] * merged_velocity(k).x();
      } else if (m_rings->ring(k).getInvMass() > 0) {
        p += m_rings->ring(k).getLinearVelocity().x() / m_rings->ring(k).getInvMass();
      }
    }
    for (Index node : m_cloth.nodes)
      if (s.particles().kind[node] == ParticleKind::free) p += s.particles().mass[node] * s.particles().v(0, node);
    return p;
  }

  double energy() const override {
    System& s = m_coupling->system();
    // potential_energy: elastic plus the free particles' gravity; the rings' gravity is Bullet's.
    double e = m_rings->energy(m_spec.gravity) + s.potential_energy();
    const RigidBodyParticles& bodies = s.rigid_bodies();
    for (int k = 0; k < m_rings->count(); ++k) {
      const Index b = particle_of(k);
      if (b < 0) continue;
      const btRigidBody& ring = m_rings->ring(k);  // replace Bullet's view of it by the merged body
      const btVector3 w_body = ring.getWorldTransform().getBasis().transpose() * ring.getAngularVelocity();
      double spin = 0.0;
      for (int a = 0; a < 3; ++a) spin += w_body[a] * w_body[a] / ring.getInvInertiaDiagLocal()[a];
      e -= 0.5 * ring.getLinearVelocity().length2() / ring.getInvMass() + 0.5 * spin +
           m_spec.gravity * ring.getWorldTransform().getOrigin().y() / ring.getInvMass();
      const Vec3 w = bullet::to_eigen(ring.getAngularVelocity());
      e += 0.5 * bodies.mass[b] * merged_velocity(k).squaredNorm() + 0.5 * w.dot(bodies.world_inertia(b) * w) +
           bodies.mass[b] * m_spec.gravity * m_coupling->centre_of_mass(&ring).y();
    }
    for (Index node : m_cloth.nodes)
      if (s.particles().kind[node] == ParticleKind::free)
        e += 0.5 * s.particles().mass[node] * s.particles().v.col(node).squaredNorm();
    return e;
  }

  /// The velocity of ring k's merged centre of mass, from Bullet's state (the particle's is the last
  /// tick's: the benchmark sets velocities before the first).
  Vec3 merged_velocity(int k) const {
    const btRigidBody& ring = m_rings->ring(k);
    const btVector3 lever = bullet::to_bullet(m_coupling->centre_of_mass(&ring)) - ring.getCenterOfMassPosition();
    return bullet::to_eigen(ring.getVelocityInLocalPoint(lever));
  }

  /// The dynamic rigid-body particle standing for ring k, or -1.
  Index particle_of(int k) const {
    const RigidBodyParticles& bodies = m_coupling->system().rigid_bodies();
    for (Index b = 0; b < bodies.size(); ++b)
      if (m_coupling->body(b) == &m_rings->ring(k) && !bodies.kinematic[b]) return b;
    return -1;
  }

  double binding_spring_energy() const override {
    const System& s = m_coupling->system();
    return s.binding_springs().potential_energy(s.particles().x);
  }

  bool healthy() const override {
    const System& s = m_coupling->system();
    for (Index node : m_cloth.nodes) {
      const Vec3 x = s.particles().x.col(node), v = s.particles().v.col(node);
      if (!all_finite(x) || !all_finite(v) || !(x.norm() <= kFarAway)) return false;
    }
    return m_rings->healthy();
  }

  std::string mismatch() const override {
    std::ostringstream out;
    if (m_settings.binding_spring_stiffness > 0)
      out << "bound nodes tied by binding springs (k = " << m_settings.binding_spring_stiffness
          << " N/m, damping ratio " << m_settings.binding_spring_damping_ratio << ") instead of hard bindings";
    else
      out << "the bound nodes' " << m_bound_mass * 1e3
          << " g is the rings' (merged into their mass and inertia, which Bullet is handed; the peers keep it on the "
             "nodes)";
    return out.str();
  }

  const StepStats& total_stats() const override { return m_total; }

 private:
  static void after_tick(btDynamicsWorld* world, btScalar) {
    auto* self = static_cast<SinewCurtain*>(world->getWorldUserInfo());
    self->m_total += self->m_coupling->last_stats();
  }

  CurtainSpec m_spec;
  SinewSettings m_settings;
  std::vector<BoundPivot> m_pivots;
  std::unique_ptr<btDefaultCollisionConfiguration> m_configuration;
  std::unique_ptr<btCollisionDispatcher> m_dispatcher;
  std::unique_ptr<btDbvtBroadphase> m_broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> m_solver;
  std::unique_ptr<btDiscreteDynamicsWorld> m_world;
  std::unique_ptr<RodAndRings> m_rings;
  std::unique_ptr<bullet::Coupling> m_coupling;
  ClothGrid m_cloth;
  double m_bound_mass = 0.0;
  StepStats m_total;
};

}  // namespace

std::unique_ptr<SinewCurtainRun> make_sinew_curtain(const CurtainSpec& spec, const SinewSettings& settings) {
  return std::make_unique<SinewCurtain>(spec, settings);
}

}  // namespace sinew::bench
