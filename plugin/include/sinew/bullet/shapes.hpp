// Bullet collision shapes from triangle meshes (for rigid bodies loaded from mesh files).
#pragma once

#include "sinew/types.hpp"

#include <btBulletCollisionCommon.h>

#include <array>
#include <memory>
#include <vector>

namespace sinew::bullet {

/// A collision shape that owns whatever it draws its triangles from.
struct MeshShape {
  std::unique_ptr<btTriangleMesh> triangles;  ///< null for a convex hull
  std::unique_ptr<btCollisionShape> shape;
};

/// The convex hull of the vertices (3 x V), for dynamic bodies; throws on fewer than 3 vertices or a
/// non-finite one.
MeshShape convex_hull_shape(const Vectors3& vertices);

/// The triangles themselves as a static (or kinematic) BVH triangle-mesh shape; throws on an empty
/// mesh or an index out of range, naming the triangle.
MeshShape triangle_mesh_shape(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles);

}  // namespace sinew::bullet
