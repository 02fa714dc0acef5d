#include "curtain_bench.hpp"

#include <BulletDynamics/Dynamics/btActionInterface.h>
#include <btBulletDynamicsCommon.h>

#include "sinew/bullet/convert.hpp"

#include <algorithm>
#include <cmath>

namespace sinew::bench {

namespace {

bool positive(double v) { return std::isfinite(v) && v > 0.0; }

// round(a / b) for a >= 0, b > 0, in integers so that ties (a / b = k + 1/2) always round up and do not
// depend on how a floating-point quotient happens to fall.
int round_ratio(long long a, long long b) { return static_cast<int>((2 * a + b) / (2 * b)); }

// Ring k's position along the width, as a fraction in [0, 1].
double ring_fraction(const CurtainSpec& spec, int k) { return spec.rings == 1 ? 0.5 : double(k) / (spec.rings - 1); }

bool dynamic_parent(RingParent p) { return p == RingParent::dynamic || p == RingParent::sleeping; }

// Counts the simulated time: Bullet runs every action once at the end of each internal tick.
class TickClock final : public btActionInterface {
 public:
  explicit TickClock(double* time) : m_time(time) {}
  void updateAction(btCollisionWorld*, btScalar dt) override { *m_time += static_cast<double>(dt); }
  void debugDraw(btIDebugDraw*) override {}

 private:
  double* m_time;
};

// A kinematic ring's prescribed pose: its rest centre moved by speed * t along the rod, t being the time
// simulated so far. Bullet reads it once per stepSimulation (btRigidBody::saveKinematicState), jumps the
// body there and sets its velocity to cover the move over that call's time.
class KinematicSlide final : public btMotionState {
 public:
  KinematicSlide(const btTransform& start, double speed, const double* time)
      : m_start(start), m_speed(speed), m_time(time) {}
  void getWorldTransform(btTransform& pose) const override {
    pose = m_start;
    pose.getOrigin() += btVector3(btScalar(m_speed * *m_time), 0, 0);
  }
  void setWorldTransform(const btTransform&) override {}  // Bullet never moves a kinematic body itself

 private:
  btTransform m_start;
  double m_speed;
  const double* m_time;
};

}  // namespace

const char* to_string(RingParent parent) {
  switch (parent) {
    case RingParent::dynamic: return "dynamic";
    case RingParent::sleeping: return "sleeping";
    case RingParent::kinematic: return "kinematic";
    case RingParent::fixed: return "static";
  }
  return "?";
}

void validate(const CurtainSpec& s) {
  if (s.n < 2) fail("curtain: n = ", s.n, ", needs at least 2 nodes per side");
  if (!positive(s.size)) fail("curtain: size = ", s.size, " m, must be positive");
  if (!positive(s.cloth_mass)) fail("curtain: cloth_mass = ", s.cloth_mass, " kg, must be positive");
  if (!(std::isfinite(s.stretch_stiffness) && s.stretch_stiffness >= 0))
    fail("curtain: stretch_stiffness = ", s.stretch_stiffness, " N/m, must be finite and >= 0");
  if (!(std::isfinite(s.stretch_damping) && s.stretch_damping >= 0))
    fail("curtain: stretch_damping = ", s.stretch_damping, " N s/m, must be finite and >= 0");
  if (!(std::isfinite(s.bending_stiffness) && s.bending_stiffness >= 0))
    fail("curtain: bending_stiffness = ", s.bending_stiffness, " N m, must be finite and >= 0");
  if (s.rings < 1) fail("curtain: rings = ", s.rings, ", needs at least 1");
  // More rings than top-row nodes would leave rings with no node of their own.
  if (s.rings > s.n) fail("curtain: rings = ", s.rings, " exceeds n = ", s.n);
  if (!positive(s.ring_mass)) fail("curtain: ring_mass = ", s.ring_mass, " kg, must be positive");
  if (!positive(s.ring_radius)) fail("curtain: ring_radius = ", s.ring_radius, " m, must be positive");
  if (!std::isfinite(s.rod_height)) fail("curtain: rod_height = ", s.rod_height, " m, must be finite");
  if (!all_finite(s.initial_velocity)) fail("curtain: initial_velocity is not finite");
  if (!(std::isfinite(s.gravity) && s.gravity >= 0))
    fail("curtain: gravity = ", s.gravity, " m/s^2, must be finite and >= 0");
  if (!std::isfinite(s.ring_spin)) fail("curtain: ring_spin = ", s.ring_spin, " rad/s, must be finite");
  if (s.ring_spin != 0.0 && s.parent != RingParent::dynamic)
    fail("curtain: ring_spin = ", s.ring_spin, " rad/s needs awake dynamic rings, not ", to_string(s.parent), " ones");
  if (!std::isfinite(s.kinematic_speed)) fail("curtain: kinematic_speed = ", s.kinematic_speed, " m/s, must be finite");
}

std::vector<std::pair<int, int>> bound_nodes(const CurtainSpec& spec) {
  validate(spec);
  std::vector<std::pair<int, int>> bound;
  if (spec.bind_all) {
    for (int i = 0; i < spec.n; ++i)
      bound.emplace_back(i, round_ratio(static_cast<long long>(i) * (spec.rings - 1), spec.n - 1));
  } else if (spec.rings == 1) {
    bound.emplace_back(round_ratio(spec.n - 1, 2), 0);
  } else {
    // The node nearest ring k; rings <= n keeps these distinct (their spacing is at least one node).
    for (int k = 0; k < spec.rings; ++k)
      bound.emplace_back(round_ratio(static_cast<long long>(k) * (spec.n - 1), spec.rings - 1), k);
  }
  return bound;
}

Vec3 node_rest_position(const CurtainSpec& spec, int i, int j) {
  const double dx = spec.size / (spec.n - 1);
  return Vec3(-0.5 * spec.size + i * dx, spec.rod_height - spec.ring_radius - j * dx, 0.0);
}

Vec3 ring_rest_centre(const CurtainSpec& spec, int k) {
  return Vec3(-0.5 * spec.size + ring_fraction(spec, k) * spec.size, spec.rod_height, 0.0);
}

Vec3 ring_inertia(const CurtainSpec& spec) {
  const double axial = spec.ring_mass * spec.ring_radius * spec.ring_radius;
  return Vec3(axial, 0.5 * axial, 0.5 * axial);
}

std::vector<BoundPivot> bound_pivots(const CurtainSpec& spec) {
  std::vector<BoundPivot> pivots;
  for (const auto& [i, k] : bound_nodes(spec))
    pivots.push_back({i, k, node_rest_position(spec, i, 0) - ring_rest_centre(spec, k)});  // unrotated frame at set-up
  return pivots;
}

// ---- RodAndRings ---------------------------------------------------------------------------------

RodAndRings::RodAndRings(btDynamicsWorld& world, const CurtainSpec& spec) : m_world(&world) {
  validate(spec);
  // Group bits are irrelevant with an empty mask: Bullet pairs two objects only when each one's group
  // meets the other's mask.
  constexpr int kCollidesWithNothing = 0;
  const double half_length = 0.5 * spec.size + 2.0 * spec.ring_radius;
  m_rod_shape = std::make_unique<btCylinderShapeX>(
      btVector3(btScalar(half_length), btScalar(0.25 * spec.ring_radius), btScalar(0.25 * spec.ring_radius)));
  m_ring_shape = std::make_unique<btSphereShape>(btScalar(spec.ring_radius));

  btTransform rod_pose(btQuaternion::getIdentity(), btVector3(0, btScalar(spec.rod_height), 0));
  m_states.push_back(std::make_unique<btDefaultMotionState>(rod_pose));
  m_rod = std::make_unique<btRigidBody>(
      btRigidBody::btRigidBodyConstructionInfo(0, m_states.back().get(), m_rod_shape.get()));
  m_world->addRigidBody(m_rod.get(), btBroadphaseProxy::StaticFilter, kCollidesWithNothing);

  const btVector3 inertia = bullet::to_bullet(ring_inertia(spec));
  const bool dynamic = dynamic_parent(spec.parent);
  if (spec.parent == RingParent::kinematic) {
    m_clock = std::make_unique<TickClock>(&m_time);
    m_world->addAction(m_clock.get());
  }
  for (int k = 0; k < spec.rings; ++k) {
    const Vec3 centre = ring_rest_centre(spec, k);
    const btTransform pose(btQuaternion::getIdentity(), bullet::to_bullet(centre));
    if (spec.parent == RingParent::kinematic)
      m_states.push_back(std::make_unique<KinematicSlide>(pose, spec.kinematic_speed, &m_time));
    else m_states.push_back(std::make_unique<btDefaultMotionState>(pose));
    const double mass = dynamic ? spec.ring_mass : 0.0;  // Bullet: mass 0 is a static or kinematic body
    auto ring = std::make_unique<btRigidBody>(btRigidBody::btRigidBodyConstructionInfo(
        btScalar(mass), m_states.back().get(), m_ring_shape.get(), dynamic ? inertia : btVector3(0, 0, 0)));
    switch (spec.parent) {
      case RingParent::dynamic:
        ring->setLinearVelocity(bullet::to_bullet(spec.initial_velocity));
        ring->setAngularVelocity(btVector3(btScalar(spec.ring_spin), 0, 0));
        // Bullet 3.24's deformable anchors explode on sleeping bodies, and a sleeping ring would stop the
        // classic anchor's impulses too: keep every ring awake.
        ring->setActivationState(DISABLE_DEACTIVATION);
        break;
      case RingParent::sleeping:
        // Asleep means at rest (Bullet zeroes a body's velocity when it puts it to sleep): no initial velocity.
        ring->setActivationState(ISLAND_SLEEPING);
        break;
      case RingParent::kinematic:
        ring->setCollisionFlags(ring->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
        ring->setActivationState(DISABLE_DEACTIVATION);  // a sleeping kinematic body is not moved
        break;
      case RingParent::fixed: break;
    }
    m_world->addRigidBody(ring.get(), dynamic ? btBroadphaseProxy::DefaultFilter : btBroadphaseProxy::StaticFilter,
                          kCollidesWithNothing);
    // Whatever addRigidBody did to the activation state, a sleeping ring starts asleep.
    if (spec.parent == RingParent::sleeping) ring->forceActivationState(ISLAND_SLEEPING);

    if (dynamic) {
      // Slider frames: x of both frames along the rod. The rod's frame sits at the ring's starting point so
      // the slide coordinate starts at 0; the ring's frame is its centre.
      const btTransform in_rod(btQuaternion::getIdentity(), btVector3(btScalar(centre.x()), 0, 0));
      const btTransform in_ring = btTransform::getIdentity();
      auto slider = std::make_unique<btSliderConstraint>(*m_rod, *ring, in_rod, in_ring, true);
      slider->setLowerLinLimit(1);  // lower > upper: no limit along the rod
      slider->setUpperLinLimit(-1);
      slider->setLowerAngLimit(1);  // lower > upper: free to turn about the rod
      slider->setUpperAngLimit(-1);
      m_world->addConstraint(slider.get(), true);
      m_sliders.push_back(std::move(slider));
    }
    m_rings.push_back(std::move(ring));
  }
}

RodAndRings::~RodAndRings() {
  for (auto& slider : m_sliders) m_world->removeConstraint(slider.get());
  for (auto& ring : m_rings) m_world->removeRigidBody(ring.get());
  m_world->removeRigidBody(m_rod.get());
  if (m_clock) m_world->removeAction(m_clock.get());
}

btRigidBody& RodAndRings::ring(int k) const {
  if (k < 0 || k >= count()) fail("curtain: ring ", k, " does not exist (", count(), " rings)");
  return *m_rings[static_cast<std::size_t>(k)];
}

Vec3 RodAndRings::world_point(int k, const Vec3& local) const {
  return bullet::to_eigen(ring(k).getWorldTransform() * bullet::to_bullet(local));
}

double RodAndRings::joint_error() const {
  const double axis_y = m_rod->getWorldTransform().getOrigin().y(), axis_z = m_rod->getWorldTransform().getOrigin().z();
  double worst = 0.0;
  for (const auto& ring : m_rings) {
    const btVector3& c = ring->getWorldTransform().getOrigin();
    const double e = std::hypot(c.y() - axis_y, c.z() - axis_z);
    worst = std::isnan(e) ? kInfinity : std::max(worst, e);
  }
  return worst;
}

double RodAndRings::momentum_along_rod() const {
  double p = 0.0;
  for (const auto& ring : m_rings)
    if (ring->getInvMass() > 0) p += ring->getLinearVelocity().x() / ring->getInvMass();
  return p;
}

double RodAndRings::energy(double gravity) const {
  double e = 0.0;
  for (const auto& ring : m_rings) {
    if (!(ring->getInvMass() > 0)) continue;  // infinite mass: not part of the moving system
    const double m = 1.0 / ring->getInvMass();
    const btVector3& v = ring->getLinearVelocity();
    // Spin energy in the body frame: 1/2 w_b^T I w_b with w_b = R^T w and I the principal moments.
    const btVector3 w_body = ring->getWorldTransform().getBasis().transpose() * ring->getAngularVelocity();
    const btVector3& inv_inertia = ring->getInvInertiaDiagLocal();
    double spin = 0.0;
    for (int a = 0; a < 3; ++a) spin += w_body[a] * w_body[a] / inv_inertia[a];
    e += 0.5 * m * v.length2() + 0.5 * spin + m * gravity * ring->getWorldTransform().getOrigin().y();
  }
  return e;
}

bool RodAndRings::healthy() const {
  for (const auto& ring : m_rings) {
    const btTransform& t = ring->getWorldTransform();
    if (!all_finite(t.getOrigin()) || !all_finite(ring->getLinearVelocity()) || !all_finite(ring->getAngularVelocity()))
      return false;
    for (int r = 0; r < 3; ++r)
      if (!all_finite(t.getBasis()[r])) return false;
    if (!(t.getOrigin().length() <= kFarAway)) return false;
  }
  return true;
}

AttachmentError attachment_error(const RodAndRings& rings, const Vectors3& x, const std::vector<BoundPivot>& pivots) {
  AttachmentError error;
  for (const BoundPivot& p : pivots) {
    if (p.node < 0 || p.node >= x.cols())
      fail("attachment error: bound node ", p.node, " is outside the ", x.cols(), " nodes given");
    const double e = (x.col(p.node) - rings.world_point(p.ring, p.local)).norm();
    error.bound_node = std::isnan(e) ? kInfinity : std::max(error.bound_node, e);  // a NaN must not hide
  }
  error.bound_node_before_overwrite = error.bound_node;
  error.ring_joint = rings.joint_error();
  return error;
}

}  // namespace sinew::bench
