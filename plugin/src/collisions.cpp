#include "sinew/bullet/collisions.hpp"

#include "sinew/bullet/convert.hpp"

#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>
#include <LinearMath/btConvexHullComputer.h>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace sinew::bullet {

namespace {

// Box of half extents h centred at the origin, local frame.
double box_distance(const Vec3& h, const Vec3& p, Vec3& n) {
  const Vec3 q = p.cwiseAbs() - h;
  if ((q.array() > 0.0).any()) {
    const Vec3 outside = q.cwiseMax(0.0);
    const double d = outside.norm();
    n = outside.cwiseProduct(p.cwiseSign()) / d;
    return d;
  }
  Index axis;
  const double d = q.maxCoeff(&axis);  // inside: the nearest face
  n = Vec3::Zero();
  n[axis] = p[axis] >= 0.0 ? 1.0 : -1.0;
  return d;
}

struct ClosestTriangle : btTriangleCallback {
  Vec3 p;
  double best = kInfinity;
  Vec3 closest = Vec3::Zero(), face_normal = Vec3::UnitY();
  void processTriangle(btVector3* t, int, int) override {
    const Vec3 a = to_eigen(t[0]), b = to_eigen(t[1]), c = to_eigen(t[2]);
    // Closest point on a triangle (Ericson, Real-Time Collision Detection, 5.1.5).
    const Vec3 ab = b - a, ac = c - a, ap = p - a;
    Vec3 q;
    const double d1 = ab.dot(ap), d2 = ac.dot(ap);
    const Vec3 bp = p - b;
    const double d3 = ab.dot(bp), d4 = ac.dot(bp);
    const Vec3 cp = p - c;
    const double d5 = ab.dot(cp), d6 = ac.dot(cp);
    const double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
    if (d1 <= 0 && d2 <= 0) q = a;
    else if (d3 >= 0 && d4 <= d3) q = b;
    else if (vc <= 0 && d1 >= 0 && d3 <= 0) q = a + (d1 / (d1 - d3)) * ab;
    else if (d6 >= 0 && d5 <= d6) q = c;
    else if (vb <= 0 && d2 >= 0 && d6 <= 0) q = a + (d2 / (d2 - d6)) * ac;
    else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) q = b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
    else {
      const double denom = 1.0 / (va + vb + vc);
      q = a + ab * (vb * denom) + ac * (vc * denom);
    }
    const double d = (p - q).squaredNorm();
    if (d < best) {
      best = d;
      closest = q;
      const Vec3 normal = ab.cross(ac);
      face_normal = normal.norm() > 0 ? Vec3(normal.normalized()) : Vec3::UnitY();
    }
  }
};

}  // namespace

bool signed_distance(const btCollisionShape* shape, const btTransform& frame, const Vec3& x, double reach, double& phi,
                     Vec3& normal) {
  const btMatrix3x3& basis = frame.getBasis();
  const Vec3 local = to_eigen(frame.invXform(to_bullet(x)));
  auto to_world = [&](const Vec3& n) { return to_eigen(basis * to_bullet(n)); };
  switch (shape->getShapeType()) {
    case STATIC_PLANE_PROXYTYPE: {
      const auto* plane = static_cast<const btStaticPlaneShape*>(shape);
      const Vec3 n = to_eigen(plane->getPlaneNormal());
      phi = n.dot(local) - static_cast<double>(plane->getPlaneConstant());
      normal = to_world(n);
      return true;
    }
    case SPHERE_SHAPE_PROXYTYPE: {
      const double r = static_cast<const btSphereShape*>(shape)->getRadius();
      const double d = local.norm();
      phi = d - r;
      normal = to_world(d > 0 ? Vec3(local / d) : Vec3::UnitY());
      return true;
    }
    case BOX_SHAPE_PROXYTYPE: {
      Vec3 n;
      phi = box_distance(to_eigen(static_cast<const btBoxShape*>(shape)->getHalfExtentsWithMargin()), local, n);
      normal = to_world(n);
      return true;
    }
    case COMPOUND_SHAPE_PROXYTYPE: {
      const auto* compound = static_cast<const btCompoundShape*>(shape);
      bool found = false;
      for (int i = 0; i < compound->getNumChildShapes(); ++i) {
        double child_phi;
        Vec3 child_normal;
        if (!signed_distance(compound->getChildShape(i), frame * compound->getChildTransform(i), x, reach, child_phi,
                             child_normal))
          continue;
        if (!found || child_phi < phi) {
          phi = child_phi;
          normal = child_normal;
          found = true;
        }
      }
      return found;
    }
    default: break;
  }
  if (shape->isConvex()) {
    btGjkEpaSolver2::sResults result;
    const btScalar d = btGjkEpaSolver2::SignedDistance(to_bullet(x), btScalar(0),
                                                       static_cast<const btConvexShape*>(shape), frame, result);
    if (result.status == btGjkEpaSolver2::sResults::GJK_Failed ||
        result.status == btGjkEpaSolver2::sResults::EPA_Failed)
      return false;
    phi = static_cast<double>(d);
    normal = to_eigen(result.normal);  // outward, from the surface towards the point
    const double length = normal.norm();
    if (!(length > 0)) return false;
    normal /= length;
    return true;
  }
  if (shape->isConcave()) {
    ClosestTriangle closest;
    closest.p = local;
    const btScalar s = static_cast<btScalar>(reach);
    const btVector3 r{s, s, s};
    static_cast<const btConcaveShape*>(shape)->processAllTriangles(&closest, to_bullet(local) - r,
                                                                   to_bullet(local) + r);
    if (!std::isfinite(closest.best)) return false;
    const double d = std::sqrt(closest.best);
    phi = d;
    Vec3 n = d > 1e-12 ? Vec3((local - closest.closest) / d) : closest.face_normal;
    normal = to_world(n);
    return true;
  }
  return false;
}

Vec3 stop_approach(const Vec3& v, const Vec3& v_body, const Vec3& n, double mu) {
  const Vec3 v_rel = v - v_body;
  const double vn = n.dot(v_rel);
  if (!(vn < 0.0)) return v;
  Vec3 v_t = v_rel - vn * n;
  const double slip = v_t.norm();
  if (slip > 0.0) v_t *= std::max(0.0, 1.0 - mu * (-vn) / slip);
  return v_body + v_t;
}

Mat3 body_point_inverse_mass(double inverse_mass, const Vec3& linear_factor, const Mat3& inverse_inertia,
                             const Vec3& r) {
  // dv = m^-1 F j + (I^-1 (r x j)) x r = m^-1 F j - [r]x I^-1 [r]x j.
  const Mat3 arm = cross_matrix(r);
  return inverse_mass * Mat3(linear_factor.asDiagonal()) - arm * inverse_inertia * arm;
}

Vec3 inelastic_impulse(const Vec3& v_rel, const Vec3& n, double mu, const Mat3& K) {
  const double vn = n.dot(v_rel);
  const double k_n = n.dot(K * n);
  if (!(vn < 0.0) || !(k_n > 0.0)) return Vec3::Zero();
  const double j_n = -vn / k_n;
  Vec3 j = j_n * n;
  // Friction on the slip the normal impulse leaves (a body's lever couples the two): an impulse
  // against the slip of size lambda changes the kinetic energy by lambda (lambda k_u / 2 - |slip|),
  // so lambda <= |slip| / k_u (stopping the slip, no further) only takes energy out.
  const Vec3 after = v_rel + K * j;
  const Vec3 slip = after - n.dot(after) * n;
  const double speed = slip.norm();
  if (speed > 0.0 && mu > 0.0) {
    const Vec3 u = slip / speed;
    const double k_u = u.dot(K * u);
    if (k_u > 0.0) j -= std::min(speed / k_u, mu * j_n) * u;
  }
  return j;
}

BulletCollisions::BulletCollisions(btCollisionWorld* world, const CollisionSettings& settings,
                                   const std::unordered_map<const btCollisionObject*, Index>* rigid_particles)
    : m_world(world), m_settings(settings), m_rigid_particles(rigid_particles) {
  if (!(std::isfinite(settings.thickness) && settings.thickness > 0))
    fail("collision settings: thickness ", settings.thickness, " must be positive and finite");
  if (!(std::isfinite(settings.friction) && settings.friction >= 0))
    fail("collision settings: friction ", settings.friction, " must be non-negative and finite");
}

namespace {
// Pairs ordered by particle, then by object address (std::less: a total order on pointers).
bool pair_less(const std::pair<Index, const btCollisionObject*>& a,
               const std::pair<Index, const btCollisionObject*>& b) {
  return a.first != b.first ? a.first < b.first : std::less<const btCollisionObject*>()(a.second, b.second);
}
// Collects the object indices of the tree's leaves a query meets.
struct CollectLeaves : btDbvt::ICollide {
  std::vector<int>* out = nullptr;
  void Process(const btDbvtNode* leaf) override {
    out->push_back(static_cast<int>(reinterpret_cast<intptr_t>(leaf->data)));
  }
};
}  // namespace

void BulletCollisions::set_pinches(const ObjectPairs& only, const ObjectPairs& passes) {
  m_pinch_only.assign(only.begin(), only.end());  // into the capacity kept from earlier ticks
  m_pinch_passes.assign(passes.begin(), passes.end());
  std::sort(m_pinch_only.begin(), m_pinch_only.end(), pair_less);
  std::sort(m_pinch_passes.begin(), m_pinch_passes.end(), pair_less);
}

bool BulletCollisions::pinch_admits(Index i, const btCollisionObject* o) const {
  if (m_pinch_only.empty() && m_pinch_passes.empty()) return true;
  const auto first = std::lower_bound(m_pinch_only.begin(), m_pinch_only.end(), std::make_pair(i, o),
                                      [](const auto& a, const auto& b) { return a.first < b.first; });
  if (first != m_pinch_only.end() && first->first == i) return first->second == o;
  return !std::binary_search(m_pinch_passes.begin(), m_pinch_passes.end(), std::make_pair(i, o), pair_less);
}

bool BulletCollisions::admits(const CollisionContext& c, Index i, int o) const {
  const btCollisionObject* object = m_world->getCollisionObjectArray()[o];
  // CF_NO_CONTACT_RESPONSE: Bullet reports the object's contacts and resolves none; neither does sinew.
  if (!object->hasContactResponse()) return false;
  if (!pinch_admits(i, object)) return false;
  if (!m_tied.empty() && m_rigid_particles) {
    const auto found = m_rigid_particles->find(object);
    if (found != m_rigid_particles->end() &&
        std::binary_search(m_tied.begin(), m_tied.end(), std::pair<Index, Index>(i, found->second)))
      return false;
  }
  if (const btBroadphaseProxy* proxy = object->getBroadphaseHandle())
    if (!c.geometry->collides(i, static_cast<std::uint32_t>(proxy->m_collisionFilterGroup),
                              static_cast<std::uint32_t>(proxy->m_collisionFilterMask)))
      return false;
  return true;
}

bool BulletCollisions::held_by_bullet_alone(int o) const {
  const btCollisionObject* object = m_world->getCollisionObjectArray()[o];
  const btRigidBody* rigid = btRigidBody::upcast(object);
  return rigid && !rigid->isStaticOrKinematicObject() && !(m_rigid_particles && m_rigid_particles->count(object));
}

int BulletCollisions::pinching_object(const CollisionContext& c, Index i, int hit, double phi_hit, const Vec3& n_hit,
                                      bool entered, bool& move, double& phi, Vec3& normal) const {
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const double thickness = m_settings.thickness;
  const Vec3 x = c.x->col(i);
  const Vec3 pushed = x + (thickness - phi_hit) * n_hit;
  CollectLeaves collect;
  collect.out = &m_candidates;
  m_candidates.clear();
  btVector3 lo = to_bullet(x), hi = lo;
  lo.setMin(to_bullet(pushed));
  hi.setMax(to_bullet(pushed));
  m_tree.collideTVNoStackAlloc(m_tree.m_root, btDbvtVolume::FromMM(lo, hi), m_stack, collect);
  std::sort(m_candidates.begin(), m_candidates.end());
  // A particle that entered the body within this step came in through the face n_hit, which must
  // face the object for the object to hold it against the body.
  const btCollisionShape* body_shape = objects[hit]->getCollisionShape();
  btDispatcher* dispatcher = m_world->getDispatcher();
  btOverlappingPairCache* pairs = m_world->getPairCache();
  btBroadphaseProxy* body_proxy = objects[hit]->getBroadphaseHandle();
  int other = -1;
  for (const int o : m_candidates) {
    if (o == hit || !admits(c, i, o)) continue;
    const btRigidBody* rigid = btRigidBody::upcast(objects[o]);
    if (rigid && !rigid->isStaticOrKinematicObject()) continue;  // static and kinematic objects only
    // Only where Bullet itself keeps the two apart: its filters (groups and masks, or the
    // application's overlap filter callback), its ignore lists, contact response.
    btBroadphaseProxy* proxy = objects[o]->getBroadphaseHandle();
    if (!body_proxy || !proxy || !pairs->needsBroadphaseCollision(body_proxy, proxy) ||
        !dispatcher->needsCollision(objects[hit], objects[o]) || !dispatcher->needsResponse(objects[hit], objects[o]))
      continue;
    const btCollisionShape* shape = objects[o]->getCollisionShape();
    double d;
    Vec3 n;
    // Inside the body while touching the other, with the body within the thickness of the other at
    // the particle's foot there (no room left between them): whichever of the body's faces is
    // nearest, the way out is through the other. A particle that came in this step counts only
    // through a face against the other (a cloth falling on a crate beside a wall is pushed out of
    // the crate's top, not along the wall).
    if (phi_hit < 0.0 && signed_distance(shape, m_frame[o], x, thickness, d, n) && d < thickness &&
        (!entered || n.dot(n_hit) < -0.2)) {
      double d_foot;
      Vec3 n_foot;
      const Vec3 foot = x - d * n;
      if (!signed_distance(body_shape, m_frame[static_cast<std::size_t>(hit)], foot, thickness, d_foot, n_foot) ||
          !(d_foot < thickness))
        continue;
      if (other < 0 || d < phi) {
        other = o;
        phi = d;
        normal = n;
        move = false;
      }
      continue;
    }
    // Pushed out of the body, into the other's layer from the opposite side.
    if (signed_distance(shape, m_frame[o], pushed, thickness, d, n) && d < thickness && n.dot(n_hit) < -0.5 &&
        (other < 0 || d < phi)) {
      other = o;
      phi = d;
      normal = n;
      move = true;
    }
  }
  return other;
}

int BulletCollisions::closest_object(const CollisionContext& c, Index i, double& phi, Vec3& normal,
                                     bool& entered) const {
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const double thickness = m_settings.thickness;
  const Vectors3& x = *c.x;
  const btVector3 p = to_bullet(x.col(i));
  int hit = -1;
  phi = kInfinity;
  normal = Vec3::Zero();
  entered = false;
  // The objects whose swept box meets the particle's path over the step, taken in the world's order.
  CollectLeaves collect;
  collect.out = &m_candidates;
  m_candidates.clear();
  const btVector3 p_n = to_bullet(c.x_n->col(i));
  btVector3 lo = p, hi = p;
  lo.setMin(p_n);
  hi.setMax(p_n);
  m_tree.collideTVNoStackAlloc(m_tree.m_root, btDbvtVolume::FromMM(lo, hi), m_stack, collect);
  std::sort(m_candidates.begin(), m_candidates.end());
  for (const int o : m_candidates) {
    if (!admits(c, i, o)) continue;
    double d;
    Vec3 n;
    if (!signed_distance(objects[o]->getCollisionShape(), m_frame[o], x.col(i), thickness, d, n)) continue;
    bool came_in = false;
    if (d < 0.0 && d < phi) {
      // Entered this step: push back out through the side the particle came from, so a thin body
      // is not crossed by projecting to its far face.
      double d_n;
      Vec3 n_n;
      const bool known =
          signed_distance(objects[o]->getCollisionShape(), m_frame_n[o], c.x_n->col(i), thickness, d_n, n_n);
      came_in = !known || d_n > 0.0;
      if (known && d_n > 0.0) {
        n = n_n;
        d = d_n + n_n.dot(x.col(i) - c.x_n->col(i));
      }
    } else if (d >= 0.0 && m_spacing[o] > 0.0) {
      // Outside at the end: it may still have passed through a thin or fast body within the step
      // (whatever the objects before it found: a particle resting on a table is still swept by a blade).
      double d_c;
      Vec3 n_c;
      if (crossed(o, c.x_n->col(i), x.col(i), d_c, n_c)) {
        d = d_c;
        n = n_c;
        came_in = true;
      }
    }
    if (d < phi) {
      phi = d;
      normal = n;
      hit = o;
      entered = came_in;
    }
  }
  return hit;
}

// The smallest extent of a shape's own box, or of its thinnest child's for a compound (a tray of thin
// walls is as thin as a wall, however large its box).
static double thinnest_extent(const btCollisionShape* shape) {
  if (shape->isCompound()) {
    const auto* compound = static_cast<const btCompoundShape*>(shape);
    double thinnest = kInfinity;
    for (int i = 0; i < compound->getNumChildShapes(); ++i)
      thinnest = std::min(thinnest, thinnest_extent(compound->getChildShape(i)));
    return thinnest;
  }
  btVector3 lo, hi;
  shape->getAabb(btTransform::getIdentity(), lo, hi);
  const btVector3 extent = hi - lo;
  return static_cast<double>(extent[extent.minAxis()]);
}

// Continuous test against one object: the particle's straight path x0 -> x1 and the object's path
// (origin interpolated, orientation slerped between the step's two poses) give the particle's path in
// the object's frame; sampled finer than the object's thinnest extent, a sample inside it after one
// outside is a crossing, and bisection finds where it entered. The particle then belongs where it
// entered, carried with the object to its end pose: the contact of a particle that stayed on the
// near face while the body swept on.
bool BulletCollisions::crossed(int o, const Vec3& x0, const Vec3& x1, double& phi, Vec3& normal) const {
  const btCollisionShape* shape = m_world->getCollisionObjectArray()[o]->getCollisionShape();
  const double thickness = m_settings.thickness;
  const btTransform& f0 = m_frame_n[static_cast<std::size_t>(o)];
  const btTransform& f1 = m_frame[static_cast<std::size_t>(o)];
  const btVector3 q0 = f0.invXform(to_bullet(x0)), q1 = f1.invXform(to_bullet(x1));
  const btQuaternion r0 = f0.getRotation(), r1 = f1.getRotation();
  const double turn = static_cast<double>(r0.angleShortestPath(r1));
  // A bound on the local path's length: the chord plus the turn times the farther arm.
  const double length =
      static_cast<double>((q1 - q0).length()) + turn * static_cast<double>(std::max(q0.length(), q1.length()));
  const double spacing = m_spacing[static_cast<std::size_t>(o)];
  if (!(length > spacing)) return false;  // the end test sees anything this short
  double d;
  Vec3 n;
  if (!signed_distance(shape, f0, x0, thickness, d, n) || d < 0.0) return false;  // not from outside
  const auto pose = [&](double s) {
    return btTransform(r0.slerp(r1, btScalar(s)), f0.getOrigin().lerp(f1.getOrigin(), btScalar(s)));
  };
  const auto point = [&](double s) { return Vec3((1.0 - s) * x0 + s * x1); };
  const int samples = std::min(kMaxSweepSamples, static_cast<int>(std::ceil(length / spacing)));
  double outside = 0.0, d_out = d;  // the last sample found outside, with its distance and normal
  Vec3 n_out = n;
  for (int j = 1; j < samples; ++j) {  // the end itself is the caller's test
    const double s = double(j) / samples;
    if (!signed_distance(shape, pose(s), point(s), thickness, d, n)) continue;
    if (d >= 0.0) {
      outside = s;
      d_out = d;
      n_out = n;
      continue;
    }
    double inside = s;
    for (int k = 0; k < 10; ++k) {  // the entry to 1/1024 of a sample
      const double mid = 0.5 * (outside + inside);
      if (!signed_distance(shape, pose(mid), point(mid), thickness, d, n)) break;  // keep what is known
      if (d < 0.0) {
        inside = mid;
      } else {
        outside = mid;
        d_out = d;
        n_out = n;
      }
    }
    // The surface point under the entry, and its normal, in the object's frame, then at its end pose.
    const btTransform at = pose(outside);
    const btVector3 local_surface = at.invXform(to_bullet(point(outside) - d_out * n_out));
    const btVector3 local_normal = at.getBasis().transpose() * to_bullet(n_out);
    normal = to_eigen(f1.getBasis() * local_normal);
    phi = normal.dot(x1 - to_eigen(f1 * local_surface));
    return true;
  }
  return false;
}

// The particles' predicted positions x~^{n+1} are tested against each body where the step puts it
// at t^{n+1}, and where they came from (x^n) against the body at t^n: testing against Bullet's pose
// at the tick's start instead leaves a cloth riding on a moving body |v| (t - t_tick) off its face and
// projects particles out of where a turning body was, which feeds energy into the cloth.
void BulletCollisions::place_objects(const CollisionContext& c) {
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const int count = objects.size();
  // The tree is rebuilt when the world's objects are not the ones indexed; otherwise its leaves that
  // moved are refitted (Bullet reuses the nodes it frees: no allocation once it has its size).
  bool same = m_indexed.size() == static_cast<std::size_t>(count);
  for (int o = 0; same && o < count; ++o) same = m_indexed[static_cast<std::size_t>(o)] == objects[o];
  m_frame_n.resize(static_cast<std::size_t>(count));
  m_frame.resize(static_cast<std::size_t>(count));
  m_aabb_min.resize(static_cast<std::size_t>(count));
  m_aabb_max.resize(static_cast<std::size_t>(count));
  m_spacing.resize(static_cast<std::size_t>(count));
  m_placed_shape.resize(static_cast<std::size_t>(count));
  m_placed_scaling.resize(static_cast<std::size_t>(count));
  const btScalar t = static_cast<btScalar>(m_settings.thickness);
  const btVector3 pad{t, t, t};
  const btScalar since_tick = static_cast<btScalar>(c.time - m_tick_start);
  for (int o = 0; o < count; ++o) {
    const auto k = static_cast<std::size_t>(o);
    const btCollisionObject* object = objects[o];
    const btTransform& pose = object->getWorldTransform();
    const btCollisionShape* shape = object->getCollisionShape();
    // A static object placed before with this shape, scale and pose keeps its box and spacing (the
    // ground and the walls of a scene: most of its objects).
    if (same && object->isStaticObject() && m_placed_shape[k] == shape &&
        m_placed_scaling[k] == shape->getLocalScaling() && m_frame[k] == pose && m_frame_n[k] == pose)
      continue;
    m_placed_shape[k] = shape;
    m_placed_scaling[k] = shape->getLocalScaling();
    m_frame_n[o] = m_frame[o] = pose;
    const btRigidBody* rigid = btRigidBody::upcast(object);
    if (m_bullet_frame && rigid && m_rigid_particles) {
      const auto found = m_rigid_particles->find(object);
      if (found != m_rigid_particles->end() && found->second < c.bodies->size()) {
        const Index b = found->second;
        m_frame_n[o] = m_bullet_frame(b, c.body_x_n->col(b), (*c.body_q_n)[static_cast<std::size_t>(b)]);
        m_frame[o] = m_bullet_frame(b, c.bodies->x.col(b), c.bodies->q[static_cast<std::size_t>(b)]);
      } else if (!rigid->isStaticObject()) {
        // Bullet moves it through the tick with its velocities (a kinematic body with those its
        // motion state gives the tick).
        btTransformUtil::integrateTransform(pose, rigid->getLinearVelocity(), rigid->getAngularVelocity(), since_tick,
                                            m_frame_n[o]);
        btTransformUtil::integrateTransform(pose, rigid->getLinearVelocity(), rigid->getAngularVelocity(),
                                            since_tick + static_cast<btScalar>(c.dt), m_frame[o]);
      }
    }
    shape->getAabb(m_frame[o], m_aabb_min[o], m_aabb_max[o]);
    btVector3 lo, hi;
    shape->getAabb(m_frame_n[o], lo, hi);  // swept: where it was at t^n too
    m_aabb_min[o].setMin(lo);
    m_aabb_max[o].setMax(hi);
    // The box of both poses holds the straight path between them; a turn by theta (crossed() follows
    // the shortest one) bulges a point at distance r from the frame's origin out of it by at most
    // the arc's sagitta r (1 - cos(theta / 2)).
    btVector3 sagitta = pad;
    const btScalar turn = m_frame_n[o].getRotation().angleShortestPath(m_frame[o].getRotation());
    if (turn > btScalar(0)) {
      btVector3 centre;
      btScalar radius;
      shape->getBoundingSphere(centre, radius);
      const btScalar r = centre.length() + radius;
      const btScalar bulge = r * (btScalar(1) - btCos(btScalar(0.5) * turn));
      if (std::isfinite(bulge)) sagitta += btVector3(bulge, bulge, bulge);
    }
    m_aabb_min[o] -= sagitta;
    m_aabb_max[o] += sagitta;
    // crossed()'s spacing: half the shape's thinnest extent or half the thickness, whichever is less
    // (a plane has no far side to reach; concave shapes no inside).
    m_spacing[o] = 0.0;
    if ((shape->isConvex() || shape->isCompound()) && shape->getShapeType() != STATIC_PLANE_PROXYTYPE)
      m_spacing[o] = 0.5 * std::min(thinnest_extent(shape), m_settings.thickness);
  }
  if (!same) {
    m_tree.clear();
    m_indexed.assign(static_cast<std::size_t>(count), nullptr);
    m_leaves.assign(static_cast<std::size_t>(count), nullptr);
  }
  for (int o = 0; o < count; ++o) {
    btDbvtVolume box = btDbvtVolume::FromMM(m_aabb_min[o], m_aabb_max[o]);
    const auto k = static_cast<std::size_t>(o);
    if (same) {
      const btDbvtVolume& leaf = m_leaves[k]->volume;
      if (leaf.Mins() != box.Mins() || leaf.Maxs() != box.Maxs()) m_tree.update(m_leaves[k], box);  // static: kept
    } else {
      m_indexed[k] = objects[o];
      m_leaves[k] = m_tree.insert(box, reinterpret_cast<void*>(static_cast<intptr_t>(o)));
    }
  }
}

void BulletCollisions::process(CollisionContext& c) {
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const double thickness = m_settings.thickness;
  place_objects(c);
  m_deepest = 0.0;
  m_contacts = 0;
  m_dynamic_contacts.clear();
  m_particle_object.assign(static_cast<std::size_t>(c.particles->size()), -1);
  Vectors3& x = *c.x;
  Vectors3& v = *c.v;
  const Particles& particles = *c.particles;
  for (Index i = 0; i < particles.size(); ++i) {
    const ParticleKind kind = particles.kind[i];
    if (kind != ParticleKind::free && kind != ParticleKind::soft_spring && kind != ParticleKind::soft_synchronized)
      continue;
    // A synchronized particle is tested where its target is now, after the contacts before it moved
    // the target's parents, and what this contact does to it goes to them at once (Gauss-Seidel).
    const bool synchronized = kind == ParticleKind::soft_synchronized && c.synchronize(i);
    double phi;
    Vec3 normal;
    bool entered;
    int hit = closest_object(c, i, phi, normal, entered);
    if (hit < 0 || phi >= thickness) continue;
    // Caught between a body Bullet alone moves and a static or kinematic object (a box resting on a
    // cloth on the ground): pushed out of the body, the particle would be pushed into the object, and
    // back out of it into the body at the next step, each projection a jump of up to twice the
    // thickness (more where Bullet lets the body sink into the object for a few ticks) that the
    // cloth's springs turn into energy: a 5 kg box landing flat on a cloth on the ground at one 1/60 s
    // tick threw the cloth about at 1600 m/s. Bullet's own contact between the two holds them apart;
    // the particle follows the object and gives the body no impulse: it is squeezed to no thickness
    // between them, as a cloth under a weight is. Between two dynamic bodies (a box dropped on a cloth
    // on a dynamic table) the particle is still pushed out of the nearer: following the table, the
    // corner and edge pass pushed the cloth's faces out of the box into it, and the cloth diverged.
    // Rigid-body particles are held with the particles in sinew's step and keep their contacts.
    if (held_by_bullet_alone(hit)) {
      bool move = false;
      double phi_other;
      Vec3 n_other;
      const int other = pinching_object(c, i, hit, phi, normal, entered, move, phi_other, n_other);
      if (other >= 0) {
        if (move) x.col(i) += (thickness - phi) * normal;
        hit = other;
        phi = phi_other;
        normal = n_other;
      }
    }
    m_particle_object[static_cast<std::size_t>(i)] = hit;
    ++m_contacts;
    m_deepest = std::max(m_deepest, thickness - phi);
    const btCollisionObject* object = objects[hit];
    btRigidBody* rigid = const_cast<btRigidBody*>(btRigidBody::upcast(object));
    const bool prescribed = !rigid || rigid->isStaticOrKinematicObject();
    // A dynamic body the system has as a rigid-body particle moves with the particle's twist, which
    // carries the impulses earlier contacts of this step gave it.
    Index particle_body = -1;
    if (!prescribed && m_rigid_particles) {
      const auto found = m_rigid_particles->find(object);
      if (found != m_rigid_particles->end()) particle_body = found->second;
    }
    Vec3 v_body = Vec3::Zero();
    btVector3 arm(0, 0, 0);
    if (rigid) {
      arm = to_bullet(x.col(i)) - m_frame[hit].getOrigin();
      if (particle_body >= 0) {
        // The particle's twist is its centre's (the merged one when bound mass is carried), at the
        // predicted frame, from which apply_body_impulse takes its lever too.
        const Vec3 r = x.col(i) - c.bodies->x.col(particle_body);
        v_body = c.bodies->v.col(particle_body) + Vec3(c.bodies->w.col(particle_body)).cross(r);
      } else {
        v_body = to_eigen(rigid->getVelocityInLocalPoint(arm));
      }
    }
    x.col(i) += (thickness - phi) * normal;
    if (prescribed) hold_by_friction(c, i, static_cast<std::size_t>(hit), normal, thickness - phi);
    const Vec3 v_old = v.col(i);
    const double mass = particles.mass[i];
    if (prescribed || particle_body >= 0 || !(mass > 0.0)) {
      v.col(i) = stop_approach(v_old, v_body, normal, m_settings.friction);
    } else {
      // A body Bullet alone moves takes the contact as a body of its own mass, and sees the impulses
      // of the contacts before this one (Gauss-Seidel over the particles): stopping each particle's
      // approach as if the body were immovable, every reaction summed onto its velocity at the step's
      // start, threw a light body off (a 10 g box landing at 0.5 m/s on a bar of 3.4 g particles
      // left at 8 m/s). A rigid-body particle keeps the immovable rule, its impulses applied at once:
      // the step's joints and contact rows hold it, so its own mass alone is not what the particle
      // meets (on the curtain, rings taken at their own mass let the cloth through them: the handle
      // spring stretched 60 cm instead of 2.8).
      v_body += pending_velocity(rigid, arm);
      const Mat3 K = Mat3::Identity() / mass + bullet_point_inverse_mass(rigid, arm);
      v.col(i) = v_old + inelastic_impulse(v_old - v_body, normal, m_settings.friction, K) / mass;
    }
    if (prescribed) {
      // A prescribed surface also holds the particle in step 4 (a projection: its reaction goes to
      // a body of infinite mass, so no momentum is lost); a synchronized particle, through its
      // target's stencil.
      if (is_dynamic(kind)) {
        c.add_constraint(CollisionConstraint::point(i, normal, v_body, m_settings.friction));
      } else if (synchronized) {
        CollisionConstraint held;
        if (c.target_stencil(i, held)) {
          held.normal = normal;
          held.normal_velocity = normal.dot(v_body);
          held.velocity = v_body;
          held.friction = m_settings.friction;
          c.add_constraint(held);
        }
      }
      if (synchronized) c.push_drift(i);
      continue;
    }
    // Equal and opposite: the particle's momentum change goes into the dynamic body at the contact.
    // No step-4 constraint here: its reaction would have nowhere to go (hold_dynamic_contacts holds
    // the contact at the end of the step instead).
    m_dynamic_contacts.push_back({i, rigid, normal});
    const Vec3 j = particles.mass[i] * (v.col(i) - v_old);
    if (!j.isZero(0.0)) {
      if (particle_body >= 0) c.apply_body_impulse(particle_body, x.col(i), -j);
      else push_pending(rigid, arm, j);
    }
    if (synchronized) c.push_drift(i);
  }
  if (m_settings.features) process_features(c);
}

// Coulomb friction on the step's displacement of a particle pushed out of a prescribed surface by
// `push` along n. Step 1 moved it without contacts, x~^{n+1} = x^n + dt v~^{n+1/2}, so a particle
// resting on a slope slid by dt^2/2 g_t and sank by dt^2/2 g_n; step 4's friction (on the velocities,
// Newmark::apply_surface_friction) cannot take that back. The push is the normal displacement the
// contact imposed, so its tangential counterpart is at most mu push: the particle's displacement
// relative to the surface point it touches (where that point was at t^n, p_n, against x^n) loses its
// tangential part up to mu push, never past zero. A particle that sticks then stays where it was on
// the surface, and one that slides moves the distance Coulomb's deceleration leaves,
// dt v - dt^2/2 mu g_n.
void BulletCollisions::hold_by_friction(CollisionContext& c, Index i, std::size_t o, const Vec3& n, double push) {
  if (!(m_settings.friction > 0.0) || !(push > 0.0)) return;
  auto x = c.x->col(i);
  const Vec3 was =
      m_frame_n[o] == m_frame[o] ? Vec3(x) : to_eigen(m_frame_n[o] * (m_frame[o].inverse() * to_bullet(x)));
  const Vec3 relative = was - c.x_n->col(i);  // (x - x^n) - (x - p_n)
  const Vec3 slip = relative - n.dot(relative) * n;
  const double length = slip.norm();
  if (length > 0.0) x -= std::min(1.0, m_settings.friction * push / length) * slip;
}

// ---- corners and edges of polyhedral bodies against the surfaces' faces and edges --------------
//
// Particles alone cannot see a box edge between two cloth nodes: the face between them sags over it
// (a 45 degree ridge under a cloth of 20 cm cells poked 9 cm through). Each corner of a polyhedral
// body is tested against the surface triangles near its path, and each edge against the surface
// edges near its path, as the self-contact source tests a cloth against itself (Bridson et al.):
// a corner within the thickness of a face it lies over, or an edge within it of a surface edge, is a
// contact on the side the pair was on at t^n (so one that crossed within the step is put back), and
// the surface points of the contact (the triangle's corners by the barycentric weights of the
// nearest point, or the edge's two ends) are pushed out along the normal with their approach
// relative to the body stopped (Coulomb friction on the slip), the body taking the opposite impulse.

const BulletCollisions::Features& BulletCollisions::features_of(const btPolyhedralConvexShape* shape) const {
  // The shape's vertices as they are now (scaled), and its margin: an entry is reused only for the
  // same shape with the same vertices and margin, so a shape changed in place, or a new one at a
  // freed one's address, gets its own hull.
  std::vector<double> coords;
  for (int i = 0; i < shape->getNumVertices(); ++i) {
    btVector3 v;
    shape->getVertex(i, v);
    coords.insert(coords.end(), {double(v.x()), double(v.y()), double(v.z())});
  }
  // A box's vertices are its corners; any other polyhedral shape is rounded by its margin, which
  // Bullet's contacts (and sinew's particle tests) include.
  const double margin = shape->getShapeType() == BOX_SHAPE_PROXYTYPE ? 0.0 : double(shape->getMargin());
  for (const Features& f : m_features)
    if (f.shape == shape && f.margin == margin && f.vertices == coords) return f;
  if (m_features.size() >= kMaxFeatureShapes) m_features.clear();  // shapes come and go: start again
  Features& f = m_features.emplace_back();
  f.shape = shape;
  f.margin = margin;
  f.vertices = coords;
  btConvexHullComputer hull;
  if (!coords.empty()) {
    hull.compute(coords.data(), 3 * int(sizeof(double)), shape->getNumVertices(), 0, 0);
    for (int i = 0; i < hull.vertices.size(); ++i) f.corners.push_back(to_eigen(hull.vertices[i]));
    for (int e = 0; e < hull.edges.size(); ++e) {
      const int a = hull.edges[e].getSourceVertex(), b = hull.edges[e].getTargetVertex();
      if (a < b) f.edges.push_back({a, b});
    }
  }
  return f;
}

void BulletCollisions::respond_to_body(CollisionContext& c, int o, const std::array<Index, 3>& points,
                                       const std::array<double, 3>& weights, const Vec3& at, const Vec3& n,
                                       double gap) {
  const Particles& p = *c.particles;
  Vectors3& x = *c.x;
  Vectors3& v = *c.v;
  std::array<double, 3> inverse_mass{};
  double S = 0.0;
  for (std::size_t k = 0; k < 3; ++k) {
    const Index i = points[k];
    if (i < 0 || weights[k] == 0.0) continue;
    const ParticleKind kind = p.kind[i];
    const bool movable =
        (kind == ParticleKind::free || kind == ParticleKind::soft_spring || kind == ParticleKind::soft_synchronized) &&
        p.mass[i] > 0.0;
    inverse_mass[k] = movable ? 1.0 / p.mass[i] : 0.0;
    S += weights[k] * weights[k] * inverse_mass[k];
  }
  if (!(S > 0.0)) return;  // nothing here the contact can move
  ++m_contacts;
  m_deepest = std::max(m_deepest, gap);
  const btCollisionObject* object = m_world->getCollisionObjectArray()[o];
  btRigidBody* rigid = const_cast<btRigidBody*>(btRigidBody::upcast(object));
  const bool prescribed = !rigid || rigid->isStaticOrKinematicObject();
  Index particle_body = -1;
  if (!prescribed && m_rigid_particles) {
    const auto found = m_rigid_particles->find(object);
    if (found != m_rigid_particles->end()) particle_body = found->second;
  }
  // The body's surface velocity at the contact, as the particle pass takes it.
  Vec3 v_body = Vec3::Zero();
  const btVector3 arm = to_bullet(at) - m_frame[static_cast<std::size_t>(o)].getOrigin();
  if (particle_body >= 0)
    v_body = c.bodies->v.col(particle_body) +
             Vec3(c.bodies->w.col(particle_body)).cross(at - c.bodies->x.col(particle_body));
  else if (rigid) v_body = to_eigen(rigid->getVelocityInLocalPoint(arm)) + pending_velocity(rigid, arm);
  for (std::size_t k = 0; k < 3; ++k)
    if (inverse_mass[k] > 0.0) x.col(points[k]) += (weights[k] * inverse_mass[k] / S * gap) * n;
  Vec3 v_surface = Vec3::Zero();
  for (std::size_t k = 0; k < 3; ++k)
    if (points[k] >= 0) v_surface += weights[k] * v.col(points[k]);
  const Vec3 v_rel = v_surface - v_body;
  const double vn = v_rel.dot(n);
  Vec3 j = Vec3::Zero();  // the surface's momentum change
  if (vn < 0.0 && !prescribed && particle_body < 0) {
    // A body Bullet alone moves takes it as a body of its own mass, as in the particle pass: the
    // surface point answers an impulse J with S J (S = sum w^2 / m), so the pair's inverse mass is
    // S I + K_body.
    const Mat3 K = S * Mat3::Identity() + bullet_point_inverse_mass(rigid, arm);
    const Vec3 impulse = inelastic_impulse(v_rel, n, m_settings.friction, K);
    for (std::size_t k = 0; k < 3; ++k)
      if (inverse_mass[k] > 0.0) {
        const Vec3 dv = (weights[k] * inverse_mass[k]) * impulse;
        v.col(points[k]) += dv;
        j += p.mass[points[k]] * dv;
      }
  } else if (vn < 0.0) {
    Vec3 change = -vn * n;
    const Vec3 slip = v_rel - vn * n;
    const double slip_speed = slip.norm();
    if (slip_speed > 0.0) change -= std::min(1.0, m_settings.friction * (-vn) / slip_speed) * slip;
    for (std::size_t k = 0; k < 3; ++k)
      if (inverse_mass[k] > 0.0) {
        const Vec3 dv = (weights[k] * inverse_mass[k] / S) * change;
        v.col(points[k]) += dv;
        j += p.mass[points[k]] * dv;
      }
  }
  if (prescribed) {
    // Held in step 4 too, on the stencil of the points that have unknowns.
    CollisionConstraint constraint;
    constraint.size = 0;
    for (std::size_t k = 0; k < 3; ++k)
      if (inverse_mass[k] > 0.0 && is_dynamic(p.kind[points[k]])) {
        constraint.particles[static_cast<std::size_t>(constraint.size)] = points[k];
        constraint.weights[static_cast<std::size_t>(constraint.size)] = weights[k];
        ++constraint.size;
      }
    if (constraint.size > 0) {
      constraint.normal = n;
      constraint.normal_velocity = n.dot(v_body);
      constraint.velocity = v_body;
      constraint.friction = m_settings.friction;
      c.add_constraint(constraint);
    }
    return;
  }
  if (j.isZero(0.0)) return;
  if (particle_body >= 0) c.apply_body_impulse(particle_body, at, -j);
  else push_pending(rigid, arm, j);
}

void BulletCollisions::process_features(CollisionContext& c) {
  const auto& triangles = c.geometry->triangles;
  const auto& segments = c.geometry->segments;
  if (triangles.empty()) return;
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const Vectors3& x_n = *c.x_n;
  const Vectors3& x = *c.x;
  const double h = m_settings.thickness;
  // The polyhedral objects (and compound children) near the surfaces, each with its frames at t^n
  // and at the step's end.
  struct Part {
    int object;
    const btPolyhedralConvexShape* shape;
    btTransform frame_n, frame;
  };
  std::vector<Part> parts;
  Eigen::AlignedBox3d surfaces;
  for (const auto& t : triangles)
    for (const Index i : t) {
      surfaces.extend(Vec3(x.col(i)));
      surfaces.extend(Vec3(x_n.col(i)));
    }
  const std::function<void(int, const btCollisionShape*, const btTransform&, const btTransform&)> gather =
      [&](int o, const btCollisionShape* shape, const btTransform& f_n, const btTransform& f) {
        if (shape->isCompound()) {
          const auto* compound = static_cast<const btCompoundShape*>(shape);
          for (int k = 0; k < compound->getNumChildShapes(); ++k)
            gather(o, compound->getChildShape(k), f_n * compound->getChildTransform(k),
                   f * compound->getChildTransform(k));
        } else if (shape->isPolyhedral()) {
          parts.push_back({o, static_cast<const btPolyhedralConvexShape*>(shape), f_n, f});
        }
      };
  for (int o = 0; o < objects.size(); ++o) {
    if (!objects[o]->hasContactResponse()) continue;
    const auto k = static_cast<std::size_t>(o);
    const Eigen::AlignedBox3d box(to_eigen(m_aabb_min[k]), to_eigen(m_aabb_max[k]));
    if (!box.intersects(surfaces)) continue;
    gather(o, objects[o]->getCollisionShape(), m_frame_n[k], m_frame[k]);
  }
  if (parts.empty()) return;
  // The surfaces' triangles and edges over the step, padded by the reach of a contact.
  double reach = h;
  for (const Part& part : parts) reach = std::max(reach, h + features_of(part.shape).margin);
  const auto swept = [&](const auto& points, double pad) {
    Eigen::AlignedBox3d box;
    for (const Index i : points) {
      box.extend(Vec3(x_n.col(i)));
      box.extend(Vec3(x.col(i)));
    }
    box.min().array() -= pad;
    box.max().array() += pad;
    return box;
  };
  m_triangle_box.resize(triangles.size());
  m_segment_box.resize(segments.size());
  double size = 0.0;
  for (std::size_t k = 0; k < triangles.size(); ++k) {
    m_triangle_box[k] = swept(triangles[k], reach);
    size += m_triangle_box[k].sizes().maxCoeff();
  }
  for (std::size_t k = 0; k < segments.size(); ++k) m_segment_box[k] = swept(segments[k], reach);
  const double cell = size / double(triangles.size());
  m_triangle_grid.build(m_triangle_box, cell);
  m_segment_grid.build(m_segment_box, cell);
  const auto admits = [&](int o, Index i) {
    if (!pinch_admits(i, objects[o])) return false;
    const btBroadphaseProxy* proxy = objects[o]->getBroadphaseHandle();
    if (proxy && !c.geometry->collides(i, static_cast<std::uint32_t>(proxy->m_collisionFilterGroup),
                                       static_cast<std::uint32_t>(proxy->m_collisionFilterMask)))
      return false;
    if (!m_tied.empty() && m_rigid_particles) {
      const auto found = m_rigid_particles->find(objects[o]);
      if (found != m_rigid_particles->end() &&
          std::binary_search(m_tied.begin(), m_tied.end(), std::pair<Index, Index>(i, found->second)))
        return false;
    }
    return true;
  };
  // Only faces and edges whose every point the contact can move: one with a bound or kinematic point
  // is held where its binding puts it (a cloth hard-bound along a plate's edge lies within the
  // thickness of that edge by construction), and pushing its free points alone, by their small
  // share of the contact point, would throw them; the particle tests see its free points.
  const Particles& particles = *c.particles;
  // Nor one with a point another object holds this step (the particle tests found it within the
  // thickness of that object): pushed off this body, it would be pushed into the other (a cloth
  // pinched between a box and the ground); the particle tests keep it out of the nearer, or on the
  // static or kinematic object where the other is a body Bullet alone moves.
  // Likewise one with a pinched node (figure 10), which its duplicates hold off this body.
  const auto held_elsewhere = [&](Index i, int o) {
    const int other = m_particle_object[static_cast<std::size_t>(i)];
    return (other >= 0 && other != o) || !pinch_admits(i, objects[o]);
  };
  const auto movable = [&](Index i) {
    const ParticleKind kind = particles.kind[i];
    return (kind == ParticleKind::free || kind == ParticleKind::soft_spring ||
            kind == ParticleKind::soft_synchronized) &&
           particles.mass[i] > 0.0;
  };
  Index feature = 0;
  m_seen_feature.assign(std::max(triangles.size(), segments.size()), -1);
  for (const Part& part : parts) {
    const Features& f = features_of(part.shape);
    const double thickness = h + f.margin;
    std::vector<Vec3> corner_n(f.corners.size()), corner(f.corners.size());
    for (std::size_t k = 0; k < f.corners.size(); ++k) {
      corner_n[k] = to_eigen(part.frame_n * to_bullet(f.corners[k]));
      corner[k] = to_eigen(part.frame * to_bullet(f.corners[k]));
    }
    // Corners against faces.
    for (std::size_t k = 0; k < f.corners.size(); ++k, ++feature) {
      const Eigen::AlignedBox3d path(corner_n[k].cwiseMin(corner[k]), corner_n[k].cwiseMax(corner[k]));
      m_triangle_grid.query(path, [&](Index t) {
        const auto ts = static_cast<std::size_t>(t);
        if (m_seen_feature[ts] == feature) return;
        m_seen_feature[ts] = feature;
        if (!m_triangle_box[ts].intersects(path)) return;
        const auto& tri = triangles[ts];
        if (!(movable(tri[0]) && movable(tri[1]) && movable(tri[2]))) return;
        if (held_elsewhere(tri[0], part.object) || held_elsewhere(tri[1], part.object) ||
            held_elsewhere(tri[2], part.object))
          return;
        if (!(admits(part.object, tri[0]) || admits(part.object, tri[1]) || admits(part.object, tri[2]))) return;
        const Vec3 a = x.col(tri[0]), b = x.col(tri[1]), cc = x.col(tri[2]);
        const std::array<double, 3> w = ccd::closest_on_triangle(corner[k], a, b, cc);
        if (!(w[0] > 0.0 && w[1] > 0.0 && w[2] > 0.0)) return;  // over an edge or corner: their tests
        Vec3 n = (b - a).cross(cc - a);
        if (!(n.squaredNorm() > 0.0)) return;
        n.normalize();
        // The side of the face the body was on at t^n.
        const Vec3 n_n = (x_n.col(tri[1]) - x_n.col(tri[0])).cross(x_n.col(tri[2]) - x_n.col(tri[0]));
        const Vec3 q_n = w[0] * x_n.col(tri[0]) + w[1] * x_n.col(tri[1]) + w[2] * x_n.col(tri[2]);
        double side = (q_n - corner_n[k]).dot(n_n);
        const Vec3 q = w[0] * a + w[1] * b + w[2] * cc;
        if (side == 0.0) side = (q - corner[k]).dot(n);
        if (side < 0.0) n = -n;  // n: from the body towards the face
        const double d = (q - corner[k]).dot(n);
        if (d >= thickness) return;
        // On the wrong side: only a face the corner passed through in the step.
        if (d < 0.0 && !ccd::vertex_triangle(corner_n[k], x_n.col(tri[0]), x_n.col(tri[1]), x_n.col(tri[2]), corner[k],
                                             a, b, cc, 1e-3 * thickness))
          return;
        respond_to_body(c, part.object, tri, w, corner[k], n, thickness - d);
      });
    }
    // Edges against edges.
    for (const auto& e : f.edges) {
      ++feature;
      const Vec3 p0 = corner[static_cast<std::size_t>(e[0])], p1 = corner[static_cast<std::size_t>(e[1])];
      const Vec3 p0_n = corner_n[static_cast<std::size_t>(e[0])], p1_n = corner_n[static_cast<std::size_t>(e[1])];
      Eigen::AlignedBox3d path(p0);
      path.extend(p1);
      path.extend(p0_n);
      path.extend(p1_n);
      m_segment_grid.query(path, [&](Index g) {
        const auto gs = static_cast<std::size_t>(g);
        if (m_seen_feature[gs] == feature) return;
        m_seen_feature[gs] = feature;
        if (!m_segment_box[gs].intersects(path)) return;
        const auto& seg = segments[gs];
        if (!(movable(seg[0]) && movable(seg[1]))) return;
        if (held_elsewhere(seg[0], part.object) || held_elsewhere(seg[1], part.object)) return;
        if (!(admits(part.object, seg[0]) || admits(part.object, seg[1]))) return;
        double s, u;
        const Vec3 q0 = x.col(seg[0]), q1 = x.col(seg[1]);
        ccd::closest_on_segments(p0, p1, q0, q1, s, u);
        if (s <= 0.0 || s >= 1.0 || u <= 0.0 || u >= 1.0) return;  // a corner's or a node's case
        const Vec3 on_body = (1.0 - s) * p0 + s * p1;
        const Vec3 diff = (1.0 - u) * q0 + u * q1 - on_body;
        const Vec3 diff_n = (1.0 - u) * x_n.col(seg[0]) + u * x_n.col(seg[1]) - ((1.0 - s) * p0_n + s * p1_n);
        const double dist = diff.norm();
        if (dist >= thickness) return;
        Vec3 n = dist > 0.0 ? Vec3(diff / dist) : Vec3(diff_n.normalized());
        if (!n.allFinite()) return;
        double d = dist;
        if (diff_n.dot(n) < 0.0) {  // crossed within the step: back to the side of t^n
          if (!ccd::edge_edge(p0_n, p1_n, x_n.col(seg[0]), x_n.col(seg[1]), p0, p1, q0, q1, 1e-3 * thickness)) return;
          n = -n;
          d = -dist;
        }
        respond_to_body(c, part.object, {seg[0], seg[1], -1}, {1.0 - u, u, 0.0}, on_body, n, thickness - d);
      });
    }
  }
}

void BulletCollisions::push_pending(btRigidBody* body, const btVector3& arm, const Vec3& j) {
  auto pending = std::find_if(m_pending.begin(), m_pending.end(), [&](const Pending& p) { return p.body == body; });
  if (pending == m_pending.end())
    pending = m_pending.insert(m_pending.end(), {body, btVector3(0, 0, 0), btVector3(0, 0, 0)});
  pending->impulse -= to_bullet(j);
  pending->torque_impulse -= arm.cross(to_bullet(j));
}

Vec3 BulletCollisions::pending_velocity(const btRigidBody* body, const btVector3& arm) const {
  for (const Pending& p : m_pending)
    if (p.body == body) {
      const btVector3 dv = p.impulse * body->getLinearFactor() * body->getInvMass();
      const btVector3 dw = body->getInvInertiaTensorWorld() * p.torque_impulse * body->getAngularFactor();
      return to_eigen(dv + dw.cross(arm));
    }
  return Vec3::Zero();
}

Mat3 BulletCollisions::bullet_point_inverse_mass(const btRigidBody* body, const btVector3& arm) {
  // Bullet turns a torque impulse t into F (I^-1 t) (applyTorqueImpulse): the locks scale the inverse
  // inertia's rows.
  const btMatrix3x3& inverse = body->getInvInertiaTensorWorld();
  const Vec3 factor = to_eigen(body->getAngularFactor());
  Mat3 inertia;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) inertia(r, c) = factor[r] * static_cast<double>(inverse[r][c]);
  return body_point_inverse_mass(static_cast<double>(body->getInvMass()), to_eigen(body->getLinearFactor()), inertia,
                                 to_eigen(arm));
}

void BulletCollisions::apply_pending_impulses() {
  for (const Pending& p : m_pending) {
    p.body->applyCentralImpulse(p.impulse);
    p.body->applyTorqueImpulse(p.torque_impulse);
    p.body->activate(true);
  }
  m_pending.clear();
}

}  // namespace sinew::bullet
