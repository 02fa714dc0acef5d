#include "sinew/bullet/collisions.hpp"

#include "sinew/bullet/convert.hpp"

#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>

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

BulletCollisions::BulletCollisions(btCollisionWorld* world, const CollisionSettings& settings,
                                   const std::unordered_map<const btCollisionObject*, Index>* rigid_particles)
    : m_world(world), m_settings(settings), m_rigid_particles(rigid_particles) {
  if (!(std::isfinite(settings.thickness) && settings.thickness > 0))
    fail("collision settings: thickness ", settings.thickness, " must be positive and finite");
  if (!(std::isfinite(settings.friction) && settings.friction >= 0))
    fail("collision settings: friction ", settings.friction, " must be non-negative and finite");
}

int BulletCollisions::closest_object(const CollisionContext& c, Index i, double& phi, Vec3& normal) const {
  const btCollisionObjectArray& objects = m_world->getCollisionObjectArray();
  const double thickness = m_settings.thickness;
  const Vectors3& x = *c.x;
  const btVector3 p = to_bullet(x.col(i));
  int hit = -1;
  phi = kInfinity;
  normal = Vec3::Zero();
  // The objects whose swept box meets the particle's path over the step, taken in the world's order.
  struct Collect : btDbvt::ICollide {
    std::vector<int>* out;
    void Process(const btDbvtNode* leaf) override {
      out->push_back(static_cast<int>(reinterpret_cast<intptr_t>(leaf->data)));
    }
  } collect;
  collect.out = &m_candidates;
  m_candidates.clear();
  const btVector3 p_n = to_bullet(c.x_n->col(i));
  btVector3 lo = p, hi = p;
  lo.setMin(p_n);
  hi.setMax(p_n);
  m_tree.collideTVNoStackAlloc(m_tree.m_root, btDbvtVolume::FromMM(lo, hi), m_stack, collect);
  std::sort(m_candidates.begin(), m_candidates.end());
  for (const int o : m_candidates) {
    // CF_NO_CONTACT_RESPONSE: Bullet reports the object's contacts and resolves none; neither does sinew.
    if (!objects[o]->hasContactResponse()) continue;
    if (!m_tied.empty() && m_rigid_particles) {
      const auto found = m_rigid_particles->find(objects[o]);
      if (found != m_rigid_particles->end() &&
          std::binary_search(m_tied.begin(), m_tied.end(), std::pair<Index, Index>(i, found->second)))
        continue;
    }
    if (const btBroadphaseProxy* proxy = objects[o]->getBroadphaseHandle())
      if (!c.geometry->collides(i, static_cast<std::uint32_t>(proxy->m_collisionFilterGroup),
                                static_cast<std::uint32_t>(proxy->m_collisionFilterMask)))
        continue;
    double d;
    Vec3 n;
    if (!signed_distance(objects[o]->getCollisionShape(), m_frame[o], x.col(i), thickness, d, n)) continue;
    if (d < 0.0 && d < phi) {
      // Entered this step: push back out through the side the particle came from, so a thin body
      // is not crossed by projecting to its far face.
      double d_n;
      Vec3 n_n;
      if (signed_distance(objects[o]->getCollisionShape(), m_frame_n[o], c.x_n->col(i), thickness, d_n, n_n) &&
          d_n > 0.0) {
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
      }
    }
    if (d < phi) {
      phi = d;
      normal = n;
      hit = o;
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
  Vectors3& x = *c.x;
  Vectors3& v = *c.v;
  const Particles& particles = *c.particles;
  for (Index i = 0; i < particles.size(); ++i) {
    const ParticleKind kind = particles.kind[i];
    if (kind != ParticleKind::free && kind != ParticleKind::soft_spring && kind != ParticleKind::soft_synchronized)
      continue;
    double phi;
    Vec3 normal;
    const int hit = closest_object(c, i, phi, normal);
    if (hit < 0 || phi >= thickness) continue;
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
    const Vec3 v_old = v.col(i);
    v.col(i) = stop_approach(v_old, v_body, normal, m_settings.friction);
    if (prescribed) {
      // A prescribed surface also holds the particle in step 4 (a projection: its reaction goes to
      // a body of infinite mass, so no momentum is lost).
      if (is_dynamic(kind)) c.add_constraint(CollisionConstraint::point(i, normal, normal.dot(v_body)));
      continue;
    }
    // Equal and opposite: the particle's momentum change goes into the dynamic body at the contact.
    // No step-4 constraint here: its reaction would have nowhere to go (hold_dynamic_contacts holds
    // the contact at the end of the step instead).
    m_dynamic_contacts.push_back({i, rigid, normal});
    const Vec3 j = particles.mass[i] * (v.col(i) - v_old);
    if (j.isZero(0.0)) continue;
    if (particle_body >= 0) {
      c.apply_body_impulse(particle_body, x.col(i), -j);
      continue;
    }
    push_pending(rigid, arm, j);
  }
}

void BulletCollisions::push_pending(btRigidBody* body, const btVector3& arm, const Vec3& j) {
  auto pending = std::find_if(m_pending.begin(), m_pending.end(), [&](const Pending& p) { return p.body == body; });
  if (pending == m_pending.end())
    pending = m_pending.insert(m_pending.end(), {body, btVector3(0, 0, 0), btVector3(0, 0, 0)});
  pending->impulse -= to_bullet(j);
  pending->torque_impulse -= arm.cross(to_bullet(j));
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
