#include "bullet_scenes.hpp"
#include "fnv_hash.hpp"

#include <BulletCollision/CollisionShapes/btShapeHull.h>

#include <map>

namespace sinew::scenes {

// ---- BulletWorld --------------------------------------------------------------------------------------

BulletWorld::BulletWorld(const btVector3& gravity)
    : m_configuration(std::make_unique<btDefaultCollisionConfiguration>()),
      m_dispatcher(std::make_unique<btCollisionDispatcher>(m_configuration.get())),
      m_broadphase(std::make_unique<btDbvtBroadphase>()),
      m_solver(std::make_unique<btSequentialImpulseConstraintSolver>()),
      m_world(std::make_unique<btDiscreteDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(),
                                                        m_configuration.get())) {
  m_world->setGravity(gravity);
}

BulletWorld::~BulletWorld() {
  for (auto& c : m_constraints) m_world->removeConstraint(c.get());
  for (auto& b : m_bodies) m_world->removeRigidBody(b.get());
}

btCollisionShape* BulletWorld::keep(std::unique_ptr<btCollisionShape> shape) {
  m_shapes.push_back(std::move(shape));
  return m_shapes.back().get();
}

btRigidBody* BulletWorld::add_body(btCollisionShape* shape, double mass, const btTransform& at, btVector3 inertia,
                                   int group, int mask) {
  if (mass > 0 && inertia.isZero()) shape->calculateLocalInertia(btScalar(mass), inertia);
  m_states.push_back(std::make_unique<btDefaultMotionState>(at));
  m_bodies.push_back(std::make_unique<btRigidBody>(
      btRigidBody::btRigidBodyConstructionInfo(btScalar(mass), m_states.back().get(), shape, inertia)));
  m_world->addRigidBody(m_bodies.back().get(), group, mask);
  m_body_list.push_back(m_bodies.back().get());
  return m_bodies.back().get();
}

btTypedConstraint* BulletWorld::add_constraint(std::unique_ptr<btTypedConstraint> constraint) {
  m_constraints.push_back(std::move(constraint));
  m_world->addConstraint(m_constraints.back().get());
  return m_constraints.back().get();
}

double BulletWorld::rigid_energy() const {
  double e = 0.0;
  const Vec3 g = to_eigen(m_world->getGravity());
  for (const btRigidBody* b : m_body_list) {
    if (b->getInvMass() == btScalar(0)) continue;
    const double m = 1.0 / static_cast<double>(b->getInvMass());
    const Vec3 v = to_eigen(b->getLinearVelocity());
    const Vec3 w_local = to_eigen(b->getAngularVelocity() * b->getCenterOfMassTransform().getBasis());
    const Vec3 inverse = to_eigen(b->getInvInertiaDiagLocal());
    double rotational = 0.0;
    for (int i = 0; i < 3; ++i)
      if (inverse[i] > 0) rotational += w_local[i] * w_local[i] / inverse[i];
    e += 0.5 * m * v.squaredNorm() + 0.5 * rotational - m * g.dot(to_eigen(b->getCenterOfMassPosition()));
  }
  return e;
}

// ---- BulletScene ------------------------------------------------------------------------------------

BulletScene::BulletScene(const btVector3& gravity, const bullet::CouplingSettings& settings) : m_world(gravity) {
  m_coupling = std::make_unique<bullet::Coupling>(&m_world.world(), settings);
}

void BulletScene::advance(double frame_dt, int substeps) {
  before_frame(m_time);
  m_world.world().stepSimulation(btScalar(frame_dt), substeps, btScalar(frame_dt / substeps));
  m_time += frame_dt;
}

SceneMeasures BulletScene::measure() {
  SceneMeasures m;
  m.particles = system().particles().size();
  m.rigid_bodies = static_cast<Index>(m_world.bodies().size());
  m.hard_binding_drift = hard_binding_drift();
  m.binding_spring_stretch = system().binding_springs().max_stretch(system().particles().x);
  m.deepest_penetration = m_coupling->deepest_penetration();
  m.energy = total_energy();
  m.velocity_rms = velocity_rms(system());
  return m;
}

std::uint64_t BulletScene::state_hash() {
  FnvHash h;
  h.mix(system().state_hash());
  for (const btRigidBody* body : m_world.bodies()) {
    const btTransform& t = body->getWorldTransform();
    for (int i = 0; i < 3; ++i) {
      h.mix(double(t.getOrigin()[i]));
      h.mix(double(body->getLinearVelocity()[i]));
      h.mix(double(body->getAngularVelocity()[i]));
      for (int j = 0; j < 3; ++j) h.mix(double(t.getBasis()[i][j]));
    }
  }
  return h.h;
}

double BulletScene::hard_binding_drift() {
  System& s = system();
  double drift = 0.0;
  const HardBindings& hard = s.hard_bindings();
  for (Index k = 0; k < hard.rigid_count(); ++k) {
    const btRigidBody* body = m_coupling->body(hard.rigid_body(k));
    if (!body) continue;  // sinew's own body, or one released: max_hard_binding_drift covers it
    // Kinematic parents follow their own swept pose inside a frame; they meet Bullet's at its end.
    const btTransform& frame = body->getCenterOfMassTransform();
    const Vec3 expected = to_eigen(frame * to_bullet(m_coupling->body_offset(k)));
    drift = std::max(drift, (s.particles().x.col(hard.rigid_particle(k)) - expected).norm());
  }
  return std::max(drift, s.max_hard_binding_drift());
}

double BulletScene::total_energy() {
  System& s = system();
  double e = s.potential_energy() + m_world.rigid_energy();
  for (Index i = 0; i < s.particles().size(); ++i)
    if (s.particles().kind[i] == ParticleKind::free)
      e += 0.5 * s.particles().mass[i] * s.particles().v.col(i).squaredNorm();
  return e;
}

namespace {

// Appends a collision shape at a pose as triangles: convex shapes through their hull, compounds by
// child, concave shapes by their triangles, a static plane as a 20 m square.
struct TriangleSink : btTriangleCallback {
  BulletScene::Surface* out;
  btTransform frame;
  void processTriangle(btVector3* t, int, int) override {
    const Index base = out->vertices.cols();
    out->vertices.conservativeResize(3, base + 3);
    for (int k = 0; k < 3; ++k) out->vertices.col(base + k) = to_eigen(frame * t[k]);
    out->triangles.push_back({base, base + 1, base + 2});
  }
};

void triangulate(const btCollisionShape* shape, const btTransform& frame, BulletScene::Surface& out) {
  if (shape->getShapeType() == COMPOUND_SHAPE_PROXYTYPE) {
    const auto* compound = static_cast<const btCompoundShape*>(shape);
    for (int i = 0; i < compound->getNumChildShapes(); ++i)
      triangulate(compound->getChildShape(i), frame * compound->getChildTransform(i), out);
    return;
  }
  if (shape->getShapeType() == STATIC_PLANE_PROXYTYPE) {
    const auto* plane = static_cast<const btStaticPlaneShape*>(shape);
    const btVector3 n = plane->getPlaneNormal();
    btVector3 u, w;
    btPlaneSpace1(n, u, w);
    const btVector3 c = n * plane->getPlaneConstant();
    btVector3 corners[4] = {c + 10 * (u + w), c + 10 * (u - w), c - 10 * (u + w), c - 10 * (u - w)};
    TriangleSink sink;
    sink.out = &out;
    sink.frame = frame;
    btVector3 a[3] = {corners[0], corners[1], corners[2]}, b[3] = {corners[0], corners[2], corners[3]};
    sink.processTriangle(a, 0, 0);
    sink.processTriangle(b, 0, 1);
    return;
  }
  if (shape->isConvex()) {
    btShapeHull hull(static_cast<const btConvexShape*>(shape));
    hull.buildHull(shape->getMargin());
    const Index base = out.vertices.cols();
    out.vertices.conservativeResize(3, base + hull.numVertices());
    for (int v = 0; v < hull.numVertices(); ++v)
      out.vertices.col(base + v) = to_eigen(frame * hull.getVertexPointer()[v]);
    for (int t = 0; t + 2 < hull.numIndices(); t += 3)
      out.triangles.push_back({base + hull.getIndexPointer()[t], base + hull.getIndexPointer()[t + 1],
                               base + hull.getIndexPointer()[t + 2]});
    return;
  }
  if (shape->isConcave()) {
    TriangleSink sink;
    sink.out = &out;
    sink.frame = frame;
    const btVector3 big(1e4, 1e4, 1e4);
    static_cast<const btConcaveShape*>(shape)->processAllTriangles(&sink, -big, big);
  }
}

}  // namespace

std::vector<BulletScene::Surface> BulletScene::surfaces() {
  std::vector<Surface> out;
  const Vectors3& x = system().particles().x;
  for (std::size_t s = 0; s < m_surface_triangles.size(); ++s) {
    Surface surface;
    surface.name = m_surface_names[s];
    std::map<Index, Index> local;  // particle -> vertex, in particle order (deterministic)
    for (const auto& t : m_surface_triangles[s])
      for (Index p : t) local.emplace(p, 0);
    surface.vertices.resize(3, static_cast<Index>(local.size()));
    Index next = 0;
    for (auto& [particle, vertex] : local) {
      vertex = next;
      surface.vertices.col(next++) = x.col(particle);
    }
    for (const auto& t : m_surface_triangles[s]) surface.triangles.push_back({local[t[0]], local[t[1]], local[t[2]]});
    out.push_back(std::move(surface));
  }
  for (std::size_t b = 0; b < m_world.bodies().size(); ++b) {
    const btRigidBody* body = m_world.bodies()[b];
    Surface surface;
    surface.name = "body" + std::to_string(b);
    surface.vertices.resize(3, 0);
    triangulate(body->getCollisionShape(), body->getWorldTransform(), surface);
    if (!surface.triangles.empty()) out.push_back(std::move(surface));
  }
  return out;
}

std::vector<std::string> bullet_scene_names() {
  std::vector<std::string> names;
  for (const SceneInfo& s : registered_scenes())
    if (s.kind == SceneKind::bullet) names.push_back(s.name);
  return names;
}

std::unique_ptr<BulletScene> make_bullet_scene(const std::string& name) {
  if (find_scene(name).kind != SceneKind::bullet)
    fail("scene '", name, "' is a ", to_string(find_scene(name).kind), " scene, not a Bullet scene");
  std::unique_ptr<Scene> scene = make_scene(name);
  auto* bullet = dynamic_cast<BulletScene*>(scene.get());
  if (!bullet) fail("scene '", name, "' is registered as a Bullet scene but its factory built something else");
  scene.release();
  return std::unique_ptr<BulletScene>(bullet);
}

}  // namespace sinew::scenes
