// Conversions between sinew's Eigen types and Bullet's (btScalar is float unless Bullet was built with
// BT_USE_DOUBLE_PRECISION; SINEW_BULLET_DOUBLE links that build).
#pragma once

#include "sinew/types.hpp"

#include <LinearMath/btQuaternion.h>
#include <LinearMath/btVector3.h>

#include <cmath>

namespace sinew::bullet {

inline Vec3 to_eigen(const btVector3& v) { return Vec3(v.x(), v.y(), v.z()); }
/// Rounds to float in a single-precision Bullet build.
inline btVector3 to_bullet(const Vec3& v) { return btVector3(btScalar(v.x()), btScalar(v.y()), btScalar(v.z())); }
/// Normalised: Bullet's quaternions drift from unit length by float round-off, sinew's rotations may not.
inline Quat to_eigen(const btQuaternion& q) { return Quat(q.w(), q.x(), q.y(), q.z()).normalized(); }

}  // namespace sinew::bullet

namespace sinew {
// Beside sinew::all_finite(const Vec3&), not in sinew::bullet, where it would hide that overload.
inline bool all_finite(const btVector3& v) {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}
}  // namespace sinew
