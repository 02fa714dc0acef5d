#include "stability.hpp"

#include "bullet_peers.hpp"
#include "sinew_curtain.hpp"

#include "sinew/builders.hpp"
#include "sinew/bullet/coupling.hpp"

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
#include <chrono>
#include <cmath>
#include <memory>
#include <sstream>

namespace sinew::bench {

namespace {

// ---- the drop scene -------------------------------------------------------------------------------
// The plate's top face is at y = plate_thickness / 2, its bottom face at -plate_thickness / 2; the cloth
// starts `height` above the top face, in the x-z plane, centred over the plate, every node falling at
// drop_speed. Node (i, j) rests at (-size/2 + i dx, top + height, -size/2 + j dx).

Vec3 drop_rest_position(const DropSpec& d, int i, int j) {
  const double dx = d.size / (d.n - 1);
  return Vec3(-0.5 * d.size + i * dx, 0.5 * d.plate_thickness + d.height, -0.5 * d.size + j * dx);
}

void validate(const DropSpec& d) {
  if (d.n < 2) fail("drop: n = ", d.n, ", needs at least 2 nodes per side");
  if (!(d.size > 0 && d.cloth_mass > 0 && d.plate_size > d.size && d.plate_thickness > 0 && d.height > 0 &&
        d.thickness > 0))
    fail("drop: size, cloth_mass, plate_thickness, height and thickness must be positive and plate_size > size (plate ",
         d.plate_size, " m, cloth ", d.size, " m)");
  if (!(std::isfinite(d.drop_speed) && d.drop_speed >= 0))
    fail("drop: drop_speed = ", d.drop_speed, " m/s, must be finite and >= 0");
}

// The static plate, in any Bullet world: a box that collides with everything.
struct Plate {
  std::unique_ptr<btBoxShape> shape;
  std::unique_ptr<btDefaultMotionState> state;
  std::unique_ptr<btRigidBody> body;
  btDynamicsWorld* world = nullptr;

  Plate(btDynamicsWorld& w, const DropSpec& d) : world(&w) {
    shape = std::make_unique<btBoxShape>(
        btVector3(btScalar(0.5 * d.plate_size), btScalar(0.5 * d.plate_thickness), btScalar(0.5 * d.plate_size)));
    // Bullet's box margin (0.04 m by default) is inside the extents for a box, but a margin larger than
    // the half thickness would round the plate's edges into it: keep it well below.
    shape->setMargin(btScalar(0.25 * d.plate_thickness));
    state = std::make_unique<btDefaultMotionState>(btTransform::getIdentity());
    body = std::make_unique<btRigidBody>(btRigidBody::btRigidBodyConstructionInfo(0, state.get(), shape.get()));
    body->setFriction(btScalar(d.friction));
    world->addRigidBody(body.get());
  }
  ~Plate() { world->removeRigidBody(body.get()); }
};

class SinewDrop final : public CurtainRun {
 public:
  /// multigrid: springs and bending implicit with the multigrid preconditioner ("sinew-multigrid").
  SinewDrop(const DropSpec& d, bool multigrid) : m_spec(d), m_multigrid(multigrid) {
    validate(d);
    m_configuration = std::make_unique<btDefaultCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    m_solver = std::make_unique<btSequentialImpulseConstraintSolver>();
    m_world = std::make_unique<btDiscreteDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(),
                                                        m_configuration.get());
    m_world->setGravity(btVector3(0, btScalar(-d.gravity), 0));
    m_plate = std::make_unique<Plate>(*m_world, d);

    bullet::CouplingSettings coupling;
    coupling.collisions = true;
    coupling.thickness = d.thickness;
    coupling.friction = d.friction;
    m_coupling = std::make_unique<bullet::Coupling>(m_world.get(), coupling);
    System& system = m_coupling->system();
    ClothGridSettings grid = cloth_grid_of(d);
    grid.bending_implicit = multigrid;
    grid.origin = drop_rest_position(d, 0, 0);
    grid.across = Vec3::UnitX();
    grid.down = Vec3::UnitZ();
    m_cloth = add_cloth_grid(system, grid);
    for (Index node : m_cloth.nodes) system.particles().v.col(node) = Vec3(0, -d.drop_speed, 0);
    system.step_settings().implicit_elasticity = multigrid;
    system.step_settings().multigrid = multigrid;
    system.step_settings().newton_iterations = multigrid ? 1 : 0;  // as the curtains' sinew-multigrid
    system.finalize();
  }
  ~SinewDrop() override {
    m_coupling.reset();
    m_plate.reset();
  }

  std::string system() const override { return m_multigrid ? "sinew-multigrid" : "sinew"; }
  void advance(double frame_dt, int steps) override {
    m_world->stepSimulation(btScalar(frame_dt), steps, btScalar(frame_dt / steps));
  }
  Vectors3 nodes() const override {
    Vectors3 out(3, static_cast<Index>(m_cloth.nodes.size()));
    for (std::size_t k = 0; k < m_cloth.nodes.size(); ++k)
      out.col(static_cast<Index>(k)) = m_coupling->system().particles().x.col(m_cloth.nodes[k]);
    return out;
  }
  AttachmentError attachment() const override { return {}; }
  double momentum_along_rod() const override {
    const Particles& p = m_coupling->system().particles();
    double px = 0.0;
    for (Index node : m_cloth.nodes) px += p.mass[node] * p.v(0, node);
    return px;
  }
  double energy() const override {
    System& s = m_coupling->system();
    double e = s.potential_energy();  // elastic + gravity relative to y = 0
    for (Index node : m_cloth.nodes) e += 0.5 * s.particles().mass[node] * s.particles().v.col(node).squaredNorm();
    return e;
  }
  bool healthy() const override {
    const Particles& p = m_coupling->system().particles();
    for (Index node : m_cloth.nodes)
      if (!all_finite(p.x.col(node)) || !all_finite(p.v.col(node)) || !(p.x.col(node).norm() <= kFarAway)) return false;
    return true;
  }
  std::string mismatch() const override {
    std::ostringstream out;
    out << "point contacts at thickness " << m_spec.thickness << " m, Coulomb friction " << m_spec.friction;
    return out.str();
  }

 private:
  DropSpec m_spec;
  bool m_multigrid = false;
  std::unique_ptr<btDefaultCollisionConfiguration> m_configuration;
  std::unique_ptr<btCollisionDispatcher> m_dispatcher;
  std::unique_ptr<btDbvtBroadphase> m_broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> m_solver;
  std::unique_ptr<btDiscreteDynamicsWorld> m_world;
  std::unique_ptr<Plate> m_plate;
  std::unique_ptr<bullet::Coupling> m_coupling;
  ClothGrid m_cloth;
};

// What both Bullet drops share: the cloth as a CreatePatch btSoftBody (node (i, j) at j * n + i; its
// diagonals may mirror sinew's, which does not matter for contact), its measurements, and the order of
// destruction.
class BulletDrop : public CurtainRun {
 public:
  ~BulletDrop() override {
    if (m_world && m_cloth) m_world->removeCollisionObject(m_cloth.get());
    m_plate.reset();
  }
  void advance(double frame_dt, int steps) override {
    m_world->stepSimulation(btScalar(frame_dt), steps, btScalar(frame_dt / steps));
  }
  Vectors3 nodes() const override {
    Vectors3 x(3, m_cloth->m_nodes.size());
    for (int k = 0; k < m_cloth->m_nodes.size(); ++k) x.col(k) = bullet::to_eigen(m_cloth->m_nodes[k].m_x);
    return x;
  }
  AttachmentError attachment() const override { return {}; }
  double momentum_along_rod() const override {
    double px = 0.0;
    for (int k = 0; k < m_cloth->m_nodes.size(); ++k) px += m_cloth->m_nodes[k].m_v.x() / m_cloth->m_nodes[k].m_im;
    return px;
  }
  double energy() const override {
    double e = elastic_energy();
    for (int k = 0; k < m_cloth->m_nodes.size(); ++k) {
      const btSoftBody::Node& n = m_cloth->m_nodes[k];
      const double m = 1.0 / n.m_im;
      e += 0.5 * m * n.m_v.length2() + m * m_spec.gravity * n.m_x.y();
    }
    return e;
  }
  bool healthy() const override {
    for (int k = 0; k < m_cloth->m_nodes.size(); ++k) {
      const btSoftBody::Node& n = m_cloth->m_nodes[k];
      if (!all_finite(n.m_x) || !all_finite(n.m_v) || !(n.m_x.length() <= kFarAway)) return false;
    }
    return true;
  }

 protected:
  explicit BulletDrop(const DropSpec& d) : m_spec(d) { validate(d); }
  virtual double elastic_energy() const { return 0.0; }

  // The cloth, not yet in the world.
  void build_cloth(btSoftBodyWorldInfo& info) {
    const int n = m_spec.n;
    m_cloth.reset(btSoftBodyHelpers::CreatePatch(info, bullet::to_bullet(drop_rest_position(m_spec, 0, 0)),
                                                 bullet::to_bullet(drop_rest_position(m_spec, n - 1, 0)),
                                                 bullet::to_bullet(drop_rest_position(m_spec, 0, n - 1)),
                                                 bullet::to_bullet(drop_rest_position(m_spec, n - 1, n - 1)), n, n, 0,
                                                 true));
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        btSoftBody::Node& nd = m_cloth->m_nodes[j * n + i];
        nd.m_x = nd.m_q = bullet::to_bullet(drop_rest_position(m_spec, i, j));
        nd.m_v = nd.m_vn = btVector3(0, btScalar(-m_spec.drop_speed), 0);
      }
    m_cloth->resetLinkRestLengths();
    m_cloth->updateBounds();
    m_cloth->setTotalMass(btScalar(m_spec.cloth_mass), true);
    m_cloth->setActivationState(DISABLE_DEACTIVATION);
    // The soft body's collision margin is its contact thickness: sinew's.
    m_cloth->getCollisionShape()->setMargin(btScalar(m_spec.thickness));
    m_cloth->m_cfg.kDF = btScalar(m_spec.friction);
  }

  DropSpec m_spec;
  std::unique_ptr<btCollisionConfiguration> m_configuration;
  std::unique_ptr<btCollisionDispatcher> m_dispatcher;
  std::unique_ptr<btBroadphaseInterface> m_broadphase;
  std::unique_ptr<btDeformableBodySolver> m_deformable_solver;
  std::unique_ptr<btConstraintSolver> m_solver;
  std::unique_ptr<btDynamicsWorld> m_world;
  std::unique_ptr<Plate> m_plate;
  std::vector<std::unique_ptr<btDeformableLagrangianForce>> m_forces;
  std::unique_ptr<btSoftBody> m_cloth;
};

// Classic: the soft body's rigid contacts (fCollision::SDF_RS, Bullet's default) against the plate's
// sparse signed-distance field, solved with the links in its position sweeps.
class ClassicDrop final : public BulletDrop {
 public:
  explicit ClassicDrop(const DropSpec& d) : BulletDrop(d) {
    const ClassicSettings settings;  // the curtain's: 10 sweeps, kLST 1, kDP 0
    m_configuration = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    m_solver = std::make_unique<btSequentialImpulseConstraintSolver>();
    auto world = std::make_unique<btSoftRigidDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(),
                                                            m_configuration.get());
    const btVector3 g(0, btScalar(-d.gravity), 0);
    world->setGravity(g);
    world->getWorldInfo().m_gravity = g;
    btSoftRigidDynamicsWorld& soft_world = *world;
    m_world = std::move(world);
    m_plate = std::make_unique<Plate>(*m_world, d);
    build_cloth(soft_world.getWorldInfo());
    m_cloth->m_cfg.piterations = settings.piterations;
    m_cloth->m_cfg.kDP = btScalar(settings.damping);
    m_cloth->m_cfg.collisions = btSoftBody::fCollision::SDF_RS;
    m_cloth->m_materials[0]->m_kLST = btScalar(settings.link_stiffness);
    soft_world.addSoftBody(m_cloth.get());
  }
  std::string system() const override { return "bullet-classic"; }
  std::string mismatch() const override {
    return "rigid contacts through the plate's sparse SDF (SDF_RS), margin = thickness; PBD links (kLST 1, 10 sweeps)";
  }
};

// Deformable: its own rigid-deformable contacts (SDF_RD node contacts and SDF_RDF face contacts), solved
// as projections inside its implicit step.
class DeformableDrop final : public BulletDrop {
 public:
  explicit DeformableDrop(const DropSpec& d) : BulletDrop(d) {
    const DeformableSettings settings;  // the curtain's: implicit, projection, 10 PGS sweeps
    m_configuration = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>();
    m_dispatcher = std::make_unique<btCollisionDispatcher>(m_configuration.get());
    m_broadphase = std::make_unique<btDbvtBroadphase>();
    m_deformable_solver = std::make_unique<btDeformableBodySolver>();
    auto solver = std::make_unique<btDeformableMultiBodyConstraintSolver>();
    solver->setDeformableSolver(m_deformable_solver.get());
    auto world = std::make_unique<btDeformableMultiBodyDynamicsWorld>(
        m_dispatcher.get(), m_broadphase.get(), solver.get(), m_configuration.get(), m_deformable_solver.get());
    m_solver = std::move(solver);
    const btVector3 g(0, btScalar(-d.gravity), 0);
    world->setGravity(g);
    world->getWorldInfo().m_gravity = g;
    world->setImplicit(settings.implicit);
    world->setUseProjection(settings.use_projection);
    world->getSolverInfo().m_numIterations = settings.solver_iterations;
    btDeformableMultiBodyDynamicsWorld& deformable_world = *world;
    m_world = std::move(world);
    m_plate = std::make_unique<Plate>(*m_world, d);
    build_cloth(deformable_world.getWorldInfo());
    // As Bullet's ClothFriction demo sets them: full contact hardness, node and face contacts.
    m_cloth->m_cfg.kCHR = 1;
    m_cloth->m_cfg.kKHR = 1;
    m_cloth->m_cfg.collisions = btSoftBody::fCollision::SDF_RD | btSoftBody::fCollision::SDF_RDF;
    deformable_world.addSoftBody(m_cloth.get());
    m_forces.push_back(std::make_unique<btDeformableMassSpringForce>(btScalar(d.stretch_stiffness),
                                                                     btScalar(d.stretch_damping), true));
    deformable_world.addForce(m_cloth.get(), m_forces.back().get());
    m_forces.push_back(std::make_unique<btDeformableGravityForce>(g));
    deformable_world.addForce(m_cloth.get(), m_forces.back().get());
  }
  std::string system() const override { return "bullet-deformable"; }
  std::string mismatch() const override {
    return "SDF_RD node + SDF_RDF face contacts, margin = thickness; no bending";
  }

 private:
  double elastic_energy() const override {
    double e = 0.0;
    for (int l = 0; l < m_cloth->m_links.size(); ++l) {
      const btSoftBody::Link& link = m_cloth->m_links[l];
      const double stretch = (link.m_n[1]->m_x - link.m_n[0]->m_x).length() - link.m_rl;
      e += 0.5 * m_spec.stretch_stiffness * stretch * stretch;
    }
    return e;
  }
};

// ---- running ----------------------------------------------------------------------------------------

}  // namespace

std::unique_ptr<CurtainRun> make_stability_run(const StabilityCase& c, const std::string& system) {
  if (c.drop) {
    if (system == "sinew" || system == "sinew-multigrid")
      return std::make_unique<SinewDrop>(c.drop_spec, system == "sinew-multigrid");
    if (system == "bullet-classic") return std::make_unique<ClassicDrop>(c.drop_spec);
    if (system == "bullet-deformable") return std::make_unique<DeformableDrop>(c.drop_spec);
  } else {
    if (system == "sinew" || system == "sinew-multigrid") {
      SinewSettings settings;
      settings.binding_spring_stiffness = c.binding_spring_stiffness;
      CurtainSpec spec = c.curtain;
      if (system == "sinew-multigrid") {
        // The large-step setting: springs and bending implicit, the multigrid preconditioner.
        settings.implicit_elasticity = settings.multigrid = true;
        settings.cg_tolerance = 1e-7;
        // One Newton iteration on step 1: with a single linearisation, one 1/24 s step per frame
        // gains energy up to the scene's whole scale (StepSettings::newton_iterations).
        settings.newton_iterations = 1;
        spec.bending_implicit = true;
      }
      return make_sinew_curtain(spec, settings);
    }
    if (system == "bullet-classic") return make_classic_curtain(c.curtain);
    if (system == "bullet-deformable") return make_deformable_curtain(c.curtain);
  }
  fail("stability: unknown system \"", system, "\" (sinew, sinew-multigrid, bullet-classic, bullet-deformable)");
}

namespace {

// The energy the cloth brings into the scene (see StabilityResult::energy_gain) [J].
double energy_scale(const StabilityCase& c) {
  if (c.drop) {
    const DropSpec& d = c.drop_spec;
    return d.cloth_mass * (d.gravity * d.height + 0.5 * d.drop_speed * d.drop_speed);
  }
  const CurtainSpec& s = c.curtain;
  const double spin = 0.5 * ring_inertia(s).x() * s.ring_spin * s.ring_spin * s.rings;
  return s.cloth_mass * (s.gravity * s.size + 0.5 * s.initial_velocity.squaredNorm()) + spin;
}

// Why a run is unhealthy, read from its nodes first (the rings are only checked by healthy()).
std::string unhealthy_reason(const CurtainRun& run) {
  const Vectors3 x = run.nodes();
  for (Index k = 0; k < x.cols(); ++k)
    if (!all_finite(x.col(k))) return "non-finite";
  for (Index k = 0; k < x.cols(); ++k)
    if (!(x.col(k).norm() <= kFarAway)) return "left 1 km";
  return "non-finite velocity or ring";
}

double worst(double a, double b) { return std::isnan(b) ? kInfinity : std::max(a, b); }

}  // namespace

std::vector<StabilityCase> stability_cases() {
  // Two seconds of simulated time each at the benchmark's 1/60 s frames of 4 ticks. 40 x 40 costs sinew
  // about 20 ms a tick (explicit springs substep inside a tick), so only bind_all, which is about many
  // bindings on one top row, runs at 40 x 40; the others stress masses, stiffness, rates or parents,
  // which 20 x 20 shows as well at a quarter of the cost, keeping the whole suite on sinew under a minute.
  std::vector<StabilityCase> cases;
  auto curtain = [&](const std::string& name, const std::string& what, int n) -> StabilityCase& {
    StabilityCase c;
    c.name = name;
    c.what = what;
    c.curtain.n = n;
    cases.push_back(c);
    return cases.back();
  };
  curtain("bind_all", "every top-row node (40) bound, 4 per ring", 40).curtain.bind_all = true;
  {
    StabilityCase& c = curtain("light_rings", "5 g rings under a 0.5 kg cloth (the cloth weighs 100 rings)", 20);
    c.curtain.ring_mass = 0.005;
  }
  {
    StabilityCase& c = curtain("heavy_rings", "10 kg rings under a 5 g cloth (a ring weighs 2000 cloths)", 20);
    c.curtain.ring_mass = 10.0;
    c.curtain.cloth_mass = 0.005;
  }
  curtain("stiff_cloth", "k = 500 N/m per edge at 20 x 20", 20).curtain.stretch_stiffness = 500.0;
  {
    StabilityCase& c =
        curtain("stiff_binding_springs_1_24",
                "sinew: binding springs k = 1e12 N/m instead of hard bindings; 1/24 s frames of ONE tick "
                "(the peers' anchors are not springs: they run their usual anchors at that step)",
                20);
    c.binding_spring_stiffness = 1e12;
    c.frame_dt = 1.0 / 24.0;
    c.steps = 1;
    c.frames = 48;
    // The same springs on static rings: no Bullet joint moves a spring's rigid end after sinew's step, so
    // this isolates the implicit spring itself from the exchange with Bullet's constraint solver.
    StabilityCase fixed = c;
    fixed.name = "stiff_binding_springs_1_24_static";
    fixed.what = "as stiff_binding_springs_1_24, on static rings";
    fixed.curtain.parent = RingParent::fixed;
    cases.push_back(fixed);
  }
  curtain("spin_100", "rings spun up impulsively to 100 rad/s about the rod, then free on their sliders", 20)
      .curtain.ring_spin = 100.0;
  {
    StabilityCase c;
    c.name = "fast_drop_on_thin_plate";
    c.what = "free 20 x 20 cloth, 1 m, 0.5 kg, hitting a 1 cm static plate at about 10 m/s (4 cm a tick)";
    c.drop = true;
    cases.push_back(c);
  }
  curtain("parents_kinematic", "kinematic rings (CF_KINEMATIC_OBJECT) sliding at 0.2 m/s along the rod", 20)
      .curtain.parent = RingParent::kinematic;
  curtain("parents_static", "static rings (mass 0)", 20).curtain.parent = RingParent::fixed;
  curtain("parents_sleeping", "dynamic rings asleep (ISLAND_SLEEPING) at the start, deactivation allowed", 20)
      .curtain.parent = RingParent::sleeping;
  return cases;
}

StabilityCase stability_case(const std::string& name) {
  for (const StabilityCase& c : stability_cases())
    if (c.name == name) return c;
  fail("stability: no case called \"", name, "\"");
}

std::vector<std::string> stability_systems() {
  return {"sinew", "sinew-multigrid", "bullet-classic", "bullet-deformable"};
}

StabilityResult run_stability_case(const StabilityCase& c, const std::string& system) {
  StabilityResult r;
  r.case_name = c.name;
  r.system = system;
  r.energy_scale = energy_scale(c);
  r.energy_gain = -kInfinity;  // the largest gain seen; a passive scene's is negative
  const auto start = std::chrono::steady_clock::now();
  auto finish = [&](StabilityResult& result) -> StabilityResult& {
    result.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return result;
  };
  auto failed = [&](int frame, std::string reason) -> StabilityResult {
    r.survived = false;
    r.failed_frame = frame;
    r.reason = std::move(reason);
    return finish(r);
  };

  std::unique_ptr<CurtainRun> run;
  try {
    run = make_stability_run(c, system);
  } catch (const Error& e) {
    return failed(0, std::string("threw at set-up: ") + e.what());
  }
  r.note = run->mismatch();
  // A kinematic parent does work in the lab frame; in the frame moving with it the scene is passive.
  const double u = !c.drop && c.curtain.parent == RingParent::kinematic ? c.curtain.kinematic_speed : 0.0;
  const double e0 = run->energy() - run->binding_spring_energy(), p0 = run->momentum_along_rod();
  const double plate_bottom = -0.5 * c.drop_spec.plate_thickness, plate_half = 0.5 * c.drop_spec.plate_size;

  for (int f = 1; f <= c.frames; ++f) {
    try {
      run->advance(c.frame_dt, c.steps);
    } catch (const Error& e) {
      return failed(f, std::string("threw: ") + e.what());
    }
    r.frames = f;
    if (!run->healthy()) return failed(f, unhealthy_reason(*run));

    const double springs = run->binding_spring_energy();
    const double gain = (run->energy() - springs - u * (run->momentum_along_rod() - p0) - e0) / r.energy_scale;
    r.energy_gain = worst(r.energy_gain, gain);
    r.spring_energy = worst(r.spring_energy, springs / r.energy_scale);
    const AttachmentError a = run->attachment();
    r.max_drift = worst(r.max_drift, a.bound_node);
    r.max_drift_before_overwrite = worst(r.max_drift_before_overwrite, a.bound_node_before_overwrite);
    r.max_ring_joint = worst(r.max_ring_joint, a.ring_joint);
    if (c.drop) {
      const Vectors3 x = run->nodes();
      for (Index k = 0; k < x.cols(); ++k) {
        const Vec3 p = x.col(k);
        if (std::abs(p.x()) < plate_half && std::abs(p.z()) < plate_half)
          r.min_clearance = std::min(r.min_clearance, p.y() - plate_bottom);
      }
      if (r.min_clearance < 0.0) {
        r.tunnelled = true;
        return failed(f, "tunnelled through the plate");
      }
    }
    if (!(r.energy_gain <= c.blow_up_gain))
      return failed(f, std::isfinite(r.energy_gain) ? "energy blow-up" : "non-finite energy");
  }
  r.survived = true;
  if (!c.drop && c.curtain.parent == RingParent::sleeping) {
    // Surviving is not enough here: rings that never wake hold the cloth like static ones.
    const Vectors3 x = run->nodes();
    bool moved = false;
    // A micrometre: far above the rounding of a node written onto an unmoved ring's pivot, far below any
    // motion the sliding cloth gives a ring that is awake.
    for (const BoundPivot& p : bound_pivots(c.curtain))
      moved = moved || (x.col(p.node) - node_rest_position(c.curtain, p.node, 0)).norm() > 1e-6;
    if (!moved)
      r.note +=
          (r.note.empty() ? "" : "; ") + std::string("the rings never woke: no bound node ever left its rest position");
  }
  return finish(r);
}

std::vector<StabilityResult> run_stability_suite(const std::vector<std::string>& systems, std::FILE* progress) {
  std::vector<StabilityResult> results;
  for (const StabilityCase& c : stability_cases())
    for (const std::string& system : systems) {
      results.push_back(run_stability_case(c, system));
      if (progress) {
        const StabilityResult& r = results.back();
        std::fprintf(progress, "  %-34s %-18s %s%s (%.0f ms)\n", r.case_name.c_str(), r.system.c_str(),
                     r.survived ? "survived" : "FAILED ",
                     r.survived ? "" : (" at frame " + std::to_string(r.failed_frame) + ": " + r.reason).c_str(),
                     r.wall_ms);
        std::fflush(progress);
      }
    }
  return results;
}

void print_stability_table(std::FILE* out, const std::vector<StabilityResult>& results) {
  std::fprintf(out, "%-34s %-18s %-8s %6s %-28s %10s %10s %10s %10s %9s\n", "case", "system", "survived", "frame",
               "reason", "energy", "drift", "drift pre", "ring joint", "ms");
  std::fprintf(out, "%-34s %-18s %-8s %6s %-28s %10s %10s %10s %10s %9s\n", "", "", "", "", "", "gain", "[m]",
               "overwrite", "[m]", "");
  for (const StabilityResult& r : results) {
    const std::string reason = r.reason.size() > 28 ? r.reason.substr(0, 25) + "..." : r.reason;
    std::fprintf(out, "%-34s %-18s %-8s %6d %-28s %10.2e %10.2e %10.2e %10.2e %9.0f\n", r.case_name.c_str(),
                 r.system.c_str(),
                 !r.run       ? "not run"
                 : r.survived ? "yes"
                              : "NO",
                 r.failed_frame, reason.c_str(), r.energy_gain, r.max_drift, r.max_drift_before_overwrite,
                 r.max_ring_joint, r.wall_ms);
  }
  std::fprintf(
      out,
      "energy gain: max (E(t) - E(0)) / (energy the cloth brings), E in the frame of kinematic parents and without the "
      "binding springs' own energy; a passive scene can only lose energy.\ndrift: hard-binding drift, anchor error, or "
      "(stiff_binding_springs) the springs' "
      "stretch; the deformable world overwrites anchored nodes, 'drift pre' is its error before that.\n");
  for (const StabilityCase& c : stability_cases()) {
    std::fprintf(out, "%s: %s; %d frames of %.4g s, %d tick%s each\n", c.name.c_str(), c.what.c_str(), c.frames,
                 c.frame_dt, c.steps, c.steps == 1 ? "" : "s");
    for (const StabilityResult& r : results)
      if (r.case_name == c.name) {
        if (!r.note.empty()) std::fprintf(out, "    %s: %s\n", r.system.c_str(), r.note.c_str());
        if (r.spring_energy > 0.0)
          std::fprintf(out,
                       "    %s: the binding springs store at most %.2e of the energy scale (left out of the gain)\n",
                       r.system.c_str(), r.spring_energy);
        if (!r.survived && r.reason.size() > 28)
          std::fprintf(out, "    %s failed: %s\n", r.system.c_str(), r.reason.c_str());
        if (c.drop && r.run)
          std::fprintf(out, "    %s: lowest node %.4g m above the plate's bottom face%s\n", r.system.c_str(),
                       r.min_clearance, r.tunnelled ? " (tunnelled)" : "");
      }
  }
}

void write_stability_csv(std::FILE* out, const std::vector<StabilityResult>& results) {
  std::fprintf(out,
               "case,system,run,survived,failed_frame,frames,reason,energy_gain,energy_scale_J,max_drift_m,max_drift_"
               "before_overwrite_m,"
               "max_ring_joint_m,min_clearance_m,tunnelled,wall_ms,spring_energy\n");
  for (const StabilityResult& r : results) {
    std::string reason = r.reason;
    std::replace(reason.begin(), reason.end(), '"', '\'');
    std::fprintf(out, "%s,%s,%d,%d,%d,%d,\"%s\",%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%d,%.3f,%.6e\n", r.case_name.c_str(),
                 r.system.c_str(), r.run ? 1 : 0, r.survived ? 1 : 0, r.failed_frame, r.frames, reason.c_str(),
                 r.energy_gain, r.energy_scale, r.max_drift, r.max_drift_before_overwrite, r.max_ring_joint,
                 std::isfinite(r.min_clearance) ? r.min_clearance : -1.0, r.tunnelled ? 1 : 0, r.wall_ms,
                 r.spring_energy);
  }
}

}  // namespace sinew::bench
