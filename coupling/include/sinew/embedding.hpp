// Weights for embedding a point in parents (Sifakis et al. 2007, sections 2 and 2.2).
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <vector>

namespace sinew {

/// Barycentric weights of p's projection on segment (a, b) (clamped to the segment).
std::array<double, 2> segment_weights(const Vec3& a, const Vec3& b, const Vec3& p);
/// Barycentric weights of p's projection on the plane of triangle (a, b, c); throws if degenerate.
std::array<double, 3> triangle_weights(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p);
/// Barycentric weights of p in tetrahedron (a, b, c, d); throws if degenerate.
std::array<double, 4> tet_weights(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, const Vec3& p);

struct PointCloudEmbedding {
  std::vector<Index> parents;
  std::vector<double> weights;
};

/// Embeds p in the k nearest points of a cloud (section 2.2) with moving-least-squares weights:
/// the minimiser of sum w_i^2 / phi_i subject to sum w_i = 1 and sum w_i x_i = p, phi a Wendland
/// kernel with support 1.5 times the k-th neighbour distance. The weights form a partition of unity
/// that reproduces linear fields, so p sits exactly at its embedded position in the rest state and the
/// embedding follows any affine motion of the cloud. Ties are broken by index (deterministic).
PointCloudEmbedding point_cloud_weights(const Vectors3& cloud, const Vec3& p, int k);

}  // namespace sinew
