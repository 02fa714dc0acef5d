// Deformable collisions against Bullet's collision objects (step 3 of the Newmark step, section 3.3;
// "collisions for deformables only", section 5).
#pragma once

#include "sinew/system.hpp"

#include <btBulletDynamicsCommon.h>

#include <vector>

namespace sinew::bullet {

/// Signed distance from a world point to a collision shape at a world transform, with the outward
/// unit normal at the closest point. Convex primitives and hulls are exact (analytic or GJK/EPA);
/// compounds take the closest child; concave shapes (triangle meshes, height fields) give the
/// unsigned distance to the nearest triangle within `reach`. Returns false when nothing is within
/// `reach` (concave) or the shape type is not supported.
bool signed_distance(const btCollisionShape* shape, const btTransform& frame, const Vec3& x, double reach,
                     double& phi, Vec3& normal);

struct CollisionSettings {
  double thickness = 0.01;  ///< particles keep this distance from every surface [m]
  double friction = 0.3;    ///< Coulomb coefficient between cloth and rigid surfaces
};

/// Collides free and soft-bound particles with every collision object of a world, in the world's
/// object order (deterministic): projects penetrating particles out to the thickness, removes their
/// approaching normal velocity relative to the surface with Coulomb friction on the tangential part,
/// hands step 4 a velocity constraint, and gives dynamic bodies the opposite impulse.
class DeformableCollisions {
 public:
  DeformableCollisions(btCollisionWorld* world, const CollisionSettings& settings);
  void process(CollisionContext& context);
  /// Deepest penetration below the thickness seen at the last call, before projection [m].
  double deepest_penetration() const { return m_deepest; }
  int contacts() const { return m_contacts; }

 private:
  btCollisionWorld* m_world;
  CollisionSettings m_settings;
  std::vector<btVector3> m_aabb_min, m_aabb_max;
  double m_deepest = 0.0;
  int m_contacts = 0;
};

}  // namespace sinew::bullet
