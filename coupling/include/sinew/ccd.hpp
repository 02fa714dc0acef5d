// Continuous tests between moving points, edges and triangles, and a grid of boxes, for
// SelfCollisions (self_collisions.cpp). Every point moves on a straight line over the step, from
// x^n at t = 0 to its end position at t = 1.
//
// A triangle mesh that does not intersect itself at t = 0 can only come to intersect by passing
// through a configuration where a vertex lies on a triangle or an edge on another edge (the pairs
// are then coplanar). So the tests find the times in [0, 1] at which the four points of a pair are
// coplanar, the roots of the cubic
//   f(t) = ((x1 - x0) x (x2 - x0)) . (x3 - x0),
// and report the first root at which the pair is within `eta` of touching (vertex on the triangle,
// edges on each other). Roots are bracketed between the cubic's critical points and bisected to
// round-off, so none is missed; a pair that stays coplanar over the step (f identically zero to
// round-off) is judged by its distance at evenly spaced times.
#pragma once

#include "sinew/types.hpp"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

namespace sinew::ccd {

/// Closest point to p on triangle (a, b, c), as barycentric weights (Ericson, Real-Time Collision
/// Detection, 5.1.5).
std::array<double, 3> closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

/// Parameters (s, t) of the closest points of segments p0 p1 and q0 q1 (Ericson 5.1.9).
void closest_on_segments(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, double& s, double& t);

/// The first time in [0, 1] at which point p comes within eta of triangle (a, b, c), each moving
/// from its `0` position to its `1` position; none when it never does at a coplanarity time.
std::optional<double> vertex_triangle(const Vec3& p0, const Vec3& a0, const Vec3& b0, const Vec3& c0, const Vec3& p1,
                                      const Vec3& a1, const Vec3& b1, const Vec3& c1, double eta);

/// The same for edges p q and r s.
std::optional<double> edge_edge(const Vec3& p0, const Vec3& q0, const Vec3& r0, const Vec3& s0, const Vec3& p1,
                                const Vec3& q1, const Vec3& r1, const Vec3& s1, double eta);

/// Boxes binned into cubic cells of a given size, in a hash table of cells built by counting sort
/// (no sorting, no allocation once the arrays have grown; items in the order of their index within a
/// bucket). A query visits the buckets of the cells a box overlaps: every item binned in one of
/// those cells comes, and possibly more (cells sharing a bucket) and more than once, so callers
/// filter by box and skip repeats. A box spanning more than kMaxCellsPerBox cells goes to a list
/// every query visits.
class BoxGrid {
 public:
  static constexpr double kMaxCellsPerBox = 512;

  void build(const std::vector<Eigen::AlignedBox3d>& boxes, double cell);
  template <class Visit>
  void query(const Eigen::AlignedBox3d& box, Visit&& visit) const {
    for (const Index item : m_oversized) visit(item);
    if (m_items.empty()) return;
    std::array<long long, 3> lo, hi;
    cells_of(box, lo, hi);
    if (span(lo, hi) > kMaxCellsPerBox) {
      for (const Index item : m_items) visit(item);
      return;
    }
    for (long long i = lo[0]; i <= hi[0]; ++i)
      for (long long j = lo[1]; j <= hi[1]; ++j)
        for (long long k = lo[2]; k <= hi[2]; ++k) {
          const std::size_t b = bucket(i, j, k);
          for (std::size_t e = m_start[b]; e < m_start[b + 1]; ++e) visit(m_items[e]);
        }
  }
  double cell() const { return m_cell; }

 private:
  std::size_t bucket(long long i, long long j, long long k) const {
    const auto h = static_cast<std::uint64_t>(i) * 73856093u ^ static_cast<std::uint64_t>(j) * 19349663u ^
                   static_cast<std::uint64_t>(k) * 83492791u;
    return static_cast<std::size_t>(h & m_mask);
  }
  static double span(const std::array<long long, 3>& lo, const std::array<long long, 3>& hi) {
    return double(hi[0] - lo[0] + 1) * double(hi[1] - lo[1] + 1) * double(hi[2] - lo[2] + 1);
  }
  void cells_of(const Eigen::AlignedBox3d& box, std::array<long long, 3>& lo, std::array<long long, 3>& hi) const;

  double m_cell = 0.0;
  std::uint64_t m_mask = 0;
  std::vector<std::size_t> m_start;  // per bucket, its first entry in m_items (one past the end last)
  std::vector<std::size_t> m_cursor;
  std::vector<Index> m_items;
  std::vector<Index> m_oversized;
};

}  // namespace sinew::ccd
