#include "sinew/bullet/shapes.hpp"

#include "sinew/bullet/convert.hpp"

namespace sinew::bullet {

MeshShape convex_hull_shape(const Vectors3& vertices) {
  if (vertices.cols() < 3) fail("convex hull shape: needs at least 3 vertices, got ", vertices.cols());
  auto hull = std::make_unique<btConvexHullShape>();
  for (Index v = 0; v < vertices.cols(); ++v) {
    if (!all_finite(vertices.col(v))) fail("convex hull shape: vertex ", v, " is not finite");
    hull->addPoint(to_bullet(vertices.col(v)), v + 1 == vertices.cols());
  }
  hull->optimizeConvexHull();
  MeshShape out;
  out.shape = std::move(hull);
  return out;
}

MeshShape triangle_mesh_shape(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles) {
  if (triangles.empty()) fail("triangle mesh shape: no triangles");
  MeshShape out;
  out.triangles = std::make_unique<btTriangleMesh>(true, false);
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    for (Index v : triangles[t])
      if (v < 0 || v >= vertices.cols())
        fail("triangle mesh shape: triangle ", t, " refers to vertex ", v, ", which does not exist");
    out.triangles->addTriangle(to_bullet(vertices.col(triangles[t][0])), to_bullet(vertices.col(triangles[t][1])),
                               to_bullet(vertices.col(triangles[t][2])), false);
  }
  out.shape = std::make_unique<btBvhTriangleMeshShape>(out.triangles.get(), true);
  return out;
}

}  // namespace sinew::bullet
