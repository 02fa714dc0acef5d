// An independent intersection checker for deformable surfaces, built on FCL (not on sinew's own
// collision code): the tests' judge of "no triangle pair intersects at the end of a tick".
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <memory>
#include <utility>
#include <vector>

namespace sinew::intersections {

/// Counts the pairs of triangles of one surface that intersect and share no vertex (neighbours touch
/// along their shared edge or corner by construction). The surface's triangles are fixed at
/// construction; count() refits FCL's bounding-volume tree (BVHModel<OBBRSS>, beginUpdateModel /
/// updateVertex / endUpdateModel) to the positions it is given and collides the model with itself,
/// FCL testing each candidate pair with its own triangle-triangle test.
class SurfaceIntersections {
 public:
  SurfaceIntersections(std::vector<std::array<Index, 3>> triangles, const Vectors3& x);
  ~SurfaceIntersections();
  SurfaceIntersections(const SurfaceIntersections&) = delete;
  SurfaceIntersections& operator=(const SurfaceIntersections&) = delete;

  /// The intersecting pairs (i < j, triangle indices) at positions x, in increasing order.
  std::vector<std::pair<Index, Index>> pairs(const Vectors3& x);
  std::size_t count(const Vectors3& x) { return pairs(x).size(); }

 private:
  struct Model;
  std::vector<std::array<Index, 3>> m_triangles;
  std::unique_ptr<Model> m_model;
};

/// The same pairs by brute force: FCL's triangle-triangle test on every pair that shares no vertex
/// (quadratic; a cross-check of the tree for small surfaces).
std::vector<std::pair<Index, Index>> intersecting_pairs_brute_force(const std::vector<std::array<Index, 3>>& triangles,
                                                                    const Vectors3& x);

}  // namespace sinew::intersections
