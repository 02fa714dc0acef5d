#include "intersections.hpp"

#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/collision_object.h>
#include <fcl/narrowphase/detail/traversal/collision/intersect.h>

#include <algorithm>
#include <limits>

namespace sinew::intersections {
namespace {

using BVH = fcl::BVHModel<fcl::OBBRSSd>;

bool share_a_vertex(const std::array<Index, 3>& a, const std::array<Index, 3>& b) {
  for (const Index i : a)
    for (const Index j : b)
      if (i == j) return true;
  return false;
}

fcl::Vector3d point(const Vectors3& x, Index i) { return fcl::Vector3d(x(0, i), x(1, i), x(2, i)); }

}  // namespace

struct SurfaceIntersections::Model {
  std::shared_ptr<BVH> bvh = std::make_shared<BVH>();
};

SurfaceIntersections::SurfaceIntersections(std::vector<std::array<Index, 3>> triangles, const Vectors3& x)
    : m_triangles(std::move(triangles)), m_model(std::make_unique<Model>()) {
  std::vector<fcl::Vector3d> points;
  for (Index i = 0; i < x.cols(); ++i) points.push_back(point(x, i));
  std::vector<fcl::Triangle> faces;
  for (const auto& t : m_triangles) {
    for (const Index i : t)
      if (i < 0 || i >= x.cols()) fail("intersection checker: vertex ", i, " is not one of the ", x.cols(), " points");
    faces.emplace_back(static_cast<std::size_t>(t[0]), static_cast<std::size_t>(t[1]), static_cast<std::size_t>(t[2]));
  }
  m_model->bvh->beginModel();
  m_model->bvh->addSubModel(points, faces);
  m_model->bvh->endModel();
}

SurfaceIntersections::~SurfaceIntersections() = default;

std::vector<std::pair<Index, Index>> SurfaceIntersections::pairs(const Vectors3& x) {
  BVH& bvh = *m_model->bvh;
  if (x.cols() != bvh.num_vertices)
    fail("intersection checker: ", x.cols(), " points for a model of ", bvh.num_vertices);
  bvh.beginUpdateModel();
  for (Index i = 0; i < x.cols(); ++i) bvh.updateVertex(point(x, i));
  bvh.endUpdateModel(true, true);
  const fcl::CollisionObjectd a(m_model->bvh), b(m_model->bvh);
  fcl::CollisionRequestd request(std::numeric_limits<std::size_t>::max() / 2, false);
  fcl::CollisionResultd result;
  fcl::collide(&a, &b, request, result);
  std::vector<std::pair<Index, Index>> found;
  for (std::size_t k = 0; k < result.numContacts(); ++k) {
    const fcl::Contactd& c = result.getContact(k);
    const Index i = std::min(c.b1, c.b2), j = std::max(c.b1, c.b2);
    if (i == j || share_a_vertex(m_triangles[static_cast<std::size_t>(i)], m_triangles[static_cast<std::size_t>(j)]))
      continue;
    found.emplace_back(i, j);
  }
  std::sort(found.begin(), found.end());
  found.erase(std::unique(found.begin(), found.end()), found.end());
  return found;
}

std::vector<std::pair<Index, Index>> intersecting_pairs_brute_force(const std::vector<std::array<Index, 3>>& triangles,
                                                                    const Vectors3& x) {
  std::vector<std::pair<Index, Index>> found;
  for (std::size_t i = 0; i < triangles.size(); ++i)
    for (std::size_t j = i + 1; j < triangles.size(); ++j) {
      const auto& p = triangles[i];
      const auto& q = triangles[j];
      if (share_a_vertex(p, q)) continue;
      if (fcl::detail::Intersect<double>::intersect_Triangle(point(x, p[0]), point(x, p[1]), point(x, p[2]),
                                                             point(x, q[0]), point(x, q[1]), point(x, q[2])))
        found.emplace_back(static_cast<Index>(i), static_cast<Index>(j));
    }
  return found;
}

}  // namespace sinew::intersections
