#include "bullet_scenes.hpp"

#include <BulletCollision/CollisionShapes/btShapeHull.h>

#include <cmath>
#include <map>
#include <numbers>

namespace sinew::scenes {

namespace {

Vec3 to_eigen(const btVector3& v) { return Vec3(v.x(), v.y(), v.z()); }
btVector3 to_bullet(const Vec3& v) { return btVector3(btScalar(v.x()), btScalar(v.y()), btScalar(v.z())); }

btTransform at(const btVector3& origin, const btQuaternion& rotation = btQuaternion::getIdentity()) {
  return btTransform(rotation, origin);
}

// A torus approximated by capsules around a circle of radius R in the body's y-z plane (axis x);
// tube radius r. Principal inertia of a thin torus: I_axis = m (R^2 + 3/4 r^2), I_diameter =
// m (R^2/2 + 5/8 r^2).
btCollisionShape* ring_shape(BulletWorld& w, double R, double r, int segments) {
  auto ring = std::make_unique<btCompoundShape>();
  const double step = 2.0 * std::numbers::pi / segments;
  const double chord = 2.0 * R * std::sin(0.5 * step);
  btCollisionShape* capsule = w.keep(std::make_unique<btCapsuleShapeX>(btScalar(r), btScalar(chord)));
  for (int i = 0; i < segments; ++i) {
    const double a = (i + 0.5) * step;
    // A capsule along x, turned to lie tangent to the circle in the y-z plane.
    const btQuaternion turn(btVector3(0, 0, 1), btScalar(std::numbers::pi / 2));
    const btQuaternion around(btVector3(1, 0, 0), btScalar(a));
    ring->addChildShape(at(btVector3(0, btScalar(R * std::cos(a)), btScalar(R * std::sin(a))), around * turn), capsule);
  }
  return w.keep(std::move(ring));
}

// ---- curtain (figure 15) ------------------------------------------------------------------------
// A cloth curtain hung by its top edge from ten rigid rings on a static rod; the rings slide along the
// rod by Bullet's own contact, and a kinematic handle draws the free edge open and closed.
class Curtain final : public BulletScene {
 public:
  Curtain() : BulletScene(btVector3(0, -9.81, 0)) {
    const double rod_y = 2.1, rod_r = 0.015, ring_R = 0.04, ring_r = 0.006, ring_mass = 0.05;
    btRigidBody* rod = m_world.add_body(m_world.keep(std::make_unique<btCylinderShapeX>(btVector3(1.3, btScalar(rod_r), btScalar(rod_r)))),
                                        0.0, at(btVector3(0, btScalar(rod_y), 0)));
    rod->setFriction(0.15);
    btCollisionShape* ring = ring_shape(m_world, ring_R, ring_r, 16);
    const double ring_y = rod_y + rod_r - (ring_R - ring_r);  // resting on the rod
    const btVector3 ring_inertia(btScalar(ring_mass * (ring_R * ring_R + 0.75 * ring_r * ring_r)),
                                 btScalar(ring_mass * (0.5 * ring_R * ring_R + 0.625 * ring_r * ring_r)),
                                 btScalar(ring_mass * (0.5 * ring_R * ring_R + 0.625 * ring_r * ring_r)));
    ClothGridSettings c;
    c.nx = 37;
    c.ny = 37;
    c.width = 1.8;
    c.height = 1.8;
    c.mass = 0.5;
    c.origin = Vec3(-0.9, ring_y - ring_R, 0.0);
    m_cloth = add_cloth_grid(system(), c);
    add_surface("curtain", m_cloth.triangles);
    for (int i = 0; i < 10; ++i) {
      btRigidBody* body = m_world.add_body(ring, ring_mass, at(btVector3(btScalar(-0.9 + 0.2 * i), btScalar(ring_y), 0)), ring_inertia);
      body->setFriction(0.15);
      body->setActivationState(DISABLE_DEACTIVATION);
      m_rings.push_back(body);
      coupling().bind_here(m_cloth.node(4 * i, 0), body);  // the ring's lowest point
    }
    // The handle: a kinematic body beside the free edge, tied to the last ring's cloth node.
    btCollisionShape* knob = m_world.keep(std::make_unique<btSphereShape>(0.02));
    m_handle = m_world.add_body(knob, 0.0, at(btVector3(0.95, btScalar(ring_y - ring_R), 0.0)), btVector3(0, 0, 0),
                                btBroadphaseProxy::DefaultFilter, 0);  // touches nothing
    m_handle->setCollisionFlags(m_handle->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    m_handle->setActivationState(DISABLE_DEACTIVATION);
    const Index grip = system().add_particle(to_eigen(m_handle->getWorldTransform().getOrigin()), Vec3::Zero(), 0.0);
    coupling().bind_here(grip, m_handle);
    system().add_binding_spring({grip, m_cloth.node(36, 0), 2e3, 1.0});
    m_handle_y = ring_y - ring_R;
  }
  std::string name() const override { return "curtain"; }
  void before_frame(double t) override {
    // Drawn from x = 0.95 to -0.35 and back every 8 s (closing first).
    const double x = 0.3 + 0.65 * std::cos(2.0 * std::numbers::pi * t / 8.0);
    m_handle->getMotionState()->setWorldTransform(at(btVector3(btScalar(x), btScalar(m_handle_y), 0)));
  }
  const std::vector<btRigidBody*>& rings() const { return m_rings; }

 private:
  ClothGrid m_cloth;
  std::vector<btRigidBody*> m_rings;
  btRigidBody* m_handle = nullptr;
  double m_handle_y = 0.0;
};

// ---- hello ----------------------------------------------------------------------------------------
// The Bullet hello-world (a ground plane and a falling sphere) with a cloth bound to the sphere.
class Hello final : public BulletScene {
 public:
  Hello() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, at(btVector3(0, 0, 0)))->setFriction(0.8);
    btCollisionShape* ball = m_world.keep(std::make_unique<btSphereShape>(0.3));
    btRigidBody* sphere = m_world.add_body(ball, 1.0, at(btVector3(0, 2.0, 0)));
    sphere->setActivationState(DISABLE_DEACTIVATION);
    // The same cloth as the plain program demos/hello.cpp adds.
    ClothGridSettings c;
    c.nx = c.ny = 15;
    c.width = c.height = 1.2;
    c.mass = 0.2;
    c.origin = Vec3(-0.6, 2.31, -0.6);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();
    const ClothGrid cloth = add_cloth_grid(system(), c);
    add_surface("cloth", cloth.triangles);
    coupling().attach(cloth.node(7, 7), sphere, Vec3(0, 0.3, 0), 1e4);
  }
  std::string name() const override { return "hello"; }
};

// ---- net (figure 13) ------------------------------------------------------------------------------
// A net of rigid rods joined at their ends by implicit binding springs between hard-bound points on
// different bodies (point joints), its corners held, catching a heavy ball that Bullet drops into it.
class Net final : public BulletScene {
 public:
  Net() : BulletScene(btVector3(0, -9.81, 0)) {
    const int n = 6;                  // joints per side
    const double spacing = 0.3, y = 1.0, rod_r = 0.015, rod_mass = 0.1;
    const double length = spacing - 2 * rod_r;
    const int rods = 4, everything = btBroadphaseProxy::AllFilter;
    btCollisionShape* along_x = m_world.keep(std::make_unique<btCapsuleShapeX>(btScalar(rod_r), btScalar(length - 2 * rod_r)));
    btCollisionShape* along_z = m_world.keep(std::make_unique<btCapsuleShapeZ>(btScalar(rod_r), btScalar(length - 2 * rod_r)));
    auto joint = [&](int i, int k) { return Vec3((i - 0.5 * (n - 1)) * spacing, y, (k - 0.5 * (n - 1)) * spacing); };
    // The points of each joint, joined in a chain by binding springs.
    std::vector<std::vector<Index>> at_joint(static_cast<std::size_t>(n * n));
    auto add_rod = [&](const Vec3& a, const Vec3& b, btCollisionShape* shape) {
      // Rods do not collide with each other (they overlap at the joints), only with the ball. Their
      // inertia is the transverse one about every axis: a thin rod's axial inertia is 1/500 of it, and
      // a glancing contact would spin it past what one step integrates well.
      const double transverse = rod_mass * length * length / 12.0;
      btRigidBody* rod = m_world.add_body(shape, rod_mass, at(to_bullet(0.5 * (a + b))),
                                          btVector3(btScalar(transverse), btScalar(transverse), btScalar(transverse)), rods, everything ^ rods);
      rod->setActivationState(DISABLE_DEACTIVATION);
      for (const Vec3& end : {a, b}) {
        const Index p = system().add_particle(end, Vec3::Zero(), 0.0);
        coupling().bind_here(p, rod);
        at_joint[static_cast<std::size_t>(std::lround((end.x() / spacing + 0.5 * (n - 1))) * n +
                                          std::lround(end.z() / spacing + 0.5 * (n - 1)))]
            .push_back(p);
      }
    };
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) {
        if (i + 1 < n) add_rod(joint(i, k), joint(i + 1, k), along_x);
        if (k + 1 < n) add_rod(joint(i, k), joint(i, k + 1), along_z);
      }
    for (std::size_t j = 0; j < at_joint.size(); ++j)
      for (std::size_t a = 1; a < at_joint[j].size(); ++a) system().add_binding_spring({at_joint[j][a - 1], at_joint[j][a], 2e5, 1.0});
    for (auto [i, k] : {std::pair{0, 0}, std::pair{0, n - 1}, std::pair{n - 1, 0}, std::pair{n - 1, n - 1}}) {
      const Index anchor = system().add_kinematic_particle(joint(i, k));
      system().add_binding_spring({anchor, at_joint[static_cast<std::size_t>(i * n + k)].front(), 2e5, 1.0});
    }
    btCollisionShape* ball = m_world.keep(std::make_unique<btSphereShape>(0.2));
    m_ball = m_world.add_body(ball, 5.0, at(btVector3(0.05, 2.0, -0.03)));
    m_ball->setActivationState(DISABLE_DEACTIVATION);
  }
  std::string name() const override { return "net"; }
  // Stiff point joints between light rods meet Bullet's contact solver when the ball lands; at 1/240 s
  // ticks the exchange of the two solvers' velocities gains energy on impact and diverges within a
  // second; at 1/480 s it is stable.
  int default_substeps() const override { return 8; }
  btRigidBody* ball() const { return m_ball; }

 private:
  btRigidBody* m_ball = nullptr;
};

// ---- plates (figure 14) -----------------------------------------------------------------------------
// Three rigid plates with cloth sheets hard-bound between them, held by two rigid bodies that Bullet
// constrains to the world, swinging under gravity.
class Plates final : public BulletScene {
 public:
  Plates() : BulletScene(btVector3(0, -9.81, 0)) {
    const double width = 0.6, gap = 0.35, thick = 0.02, plate_mass = 0.4;
    btCollisionShape* plate = m_world.keep(std::make_unique<btBoxShape>(btVector3(btScalar(width / 2), btScalar(thick / 2), btScalar(width / 2))));
    btCollisionShape* holder = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.04, 0.04, 0.04)));
    const double top = 2.0;
    std::vector<btRigidBody*> plates;
    for (int i = 0; i < 3; ++i) {
      btRigidBody* p = m_world.add_body(plate, plate_mass, at(btVector3(0, btScalar(top - gap * (i + 1)), 0)));
      p->setActivationState(DISABLE_DEACTIVATION);
      p->setLinearVelocity(btVector3(btScalar(0.6 * (i + 1)), 0, 0));  // start the swing
      plates.push_back(p);
    }
    // The two holders hang from the world on point-to-point constraints.
    std::vector<btRigidBody*> holders;
    for (int side : {-1, 1}) {
      btRigidBody* h = m_world.add_body(holder, 0.3, at(btVector3(btScalar(side * width / 2), btScalar(top), 0)));
      h->setActivationState(DISABLE_DEACTIVATION);
      m_world.add_constraint(std::make_unique<btPoint2PointConstraint>(*h, btVector3(0, 0.04, 0)));
      holders.push_back(h);
    }
    // Sheets: holders -> plate 0 -> plate 1 -> plate 2, top and bottom rows hard-bound.
    for (int s = 0; s < 3; ++s) {
      ClothGridSettings c;
      c.nx = 13;
      c.ny = 8;
      c.width = width;
      c.height = gap - thick - (s == 0 ? 0.04 : 0.0);
      c.mass = 0.1;
      const double y_top = s == 0 ? top - 0.04 : top - gap * s - thick / 2;
      c.origin = Vec3(-width / 2, y_top, 0.0);
      const ClothGrid sheet = add_cloth_grid(system(), c);
      add_surface("sheet" + std::to_string(s), sheet.triangles);
      for (int i = 0; i < c.nx; ++i) {
        btRigidBody* above = s == 0 ? holders[i < c.nx / 2 ? 0 : 1] : plates[static_cast<std::size_t>(s - 1)];
        if (s == 0 && i == c.nx / 2) continue;  // the middle of the top edge hangs free between the holders
        coupling().bind_here(sheet.node(i, 0), above);
        coupling().bind_here(sheet.node(i, c.ny - 1), plates[static_cast<std::size_t>(s)]);
      }
    }
  }
  std::string name() const override { return "plates"; }
};

}  // namespace

// ---- BulletWorld --------------------------------------------------------------------------------------

BulletWorld::BulletWorld(const btVector3& gravity)
    : m_configuration(std::make_unique<btDefaultCollisionConfiguration>()),
      m_dispatcher(std::make_unique<btCollisionDispatcher>(m_configuration.get())),
      m_broadphase(std::make_unique<btDbvtBroadphase>()),
      m_solver(std::make_unique<btSequentialImpulseConstraintSolver>()),
      m_world(std::make_unique<btDiscreteDynamicsWorld>(m_dispatcher.get(), m_broadphase.get(), m_solver.get(), m_configuration.get())) {
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

btRigidBody* BulletWorld::add_body(btCollisionShape* shape, double mass, const btTransform& at, btVector3 inertia, int group, int mask) {
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

double BulletScene::hard_binding_drift() {
  System& s = system();
  double drift = 0.0;
  const HardBindings& hard = s.hard_bindings();
  for (Index k = 0; k < hard.rigid_count(); ++k) {
    const btRigidBody* body = m_coupling->body(hard.rigid_body(k));
    // Kinematic parents follow their own swept pose inside a frame; they meet Bullet's at its end.
    const btTransform& frame = body->getCenterOfMassTransform();
    const Vec3 expected = to_eigen(frame * to_bullet(hard.rigid_offset_body(k)));
    drift = std::max(drift, (s.particles().x.col(hard.rigid_particle(k)) - expected).norm());
  }
  return std::max(drift, s.max_hard_binding_drift());
}

double BulletScene::total_energy() {
  System& s = system();
  double e = s.potential_energy() + m_world.rigid_energy();
  for (Index i = 0; i < s.particles().size(); ++i)
    if (s.particles().kind[i] == ParticleKind::free) e += 0.5 * s.particles().mass[i] * s.particles().v.col(i).squaredNorm();
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
    for (int v = 0; v < hull.numVertices(); ++v) out.vertices.col(base + v) = to_eigen(frame * hull.getVertexPointer()[v]);
    for (int t = 0; t + 2 < hull.numIndices(); t += 3)
      out.triangles.push_back({base + hull.getIndexPointer()[t], base + hull.getIndexPointer()[t + 1], base + hull.getIndexPointer()[t + 2]});
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

std::vector<std::string> bullet_scene_names() { return {"curtain", "net", "plates", "hello"}; }

std::unique_ptr<BulletScene> make_bullet_scene(const std::string& name) {
  if (name == "curtain") return std::make_unique<Curtain>();
  if (name == "net") return std::make_unique<Net>();
  if (name == "plates") return std::make_unique<Plates>();
  if (name == "hello") return std::make_unique<Hello>();
  fail("unknown scene '", name, "' (curtain, net, plates, hello)");
}

}  // namespace sinew::scenes
