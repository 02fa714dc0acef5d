#include "sinew/embedding.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <numeric>

namespace sinew {

std::array<double, 2> segment_weights(const Vec3& a, const Vec3& b, const Vec3& p) {
  const Vec3 e = b - a;
  const double l2 = e.squaredNorm();
  if (!(l2 > 0.0)) fail("segment embedding: segment has zero length");
  const double t = std::clamp(e.dot(p - a) / l2, 0.0, 1.0);
  return {1.0 - t, t};
}

std::array<double, 3> triangle_weights(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p) {
  const Vec3 e1 = b - a, e2 = c - a, d = p - a;
  const double d11 = e1.dot(e1), d12 = e1.dot(e2), d22 = e2.dot(e2);
  const double det = d11 * d22 - d12 * d12;
  if (!(det > 1e-14 * d11 * d22))
    fail("triangle embedding: triangle is degenerate (area ", 0.5 * std::sqrt(std::max(det, 0.0)), ")");
  const double u = (d22 * d.dot(e1) - d12 * d.dot(e2)) / det;
  const double v = (d11 * d.dot(e2) - d12 * d.dot(e1)) / det;
  return {1.0 - u - v, u, v};
}

std::array<double, 4> tet_weights(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, const Vec3& p) {
  Mat3 m;
  m << b - a, c - a, d - a;
  const double det = m.determinant();
  const double scale = (b - a).norm() * (c - a).norm() * (d - a).norm();
  if (!(std::abs(det) > 1e-12 * scale)) fail("tet embedding: tetrahedron is degenerate (volume ", det / 6.0, ")");
  const Vec3 w = m.inverse() * (p - a);
  return {1.0 - w.sum(), w[0], w[1], w[2]};
}

PointCloudEmbedding point_cloud_weights(const Vectors3& cloud, const Vec3& p, int k) {
  const Index n = cloud.cols();
  if (k < 1) fail("point cloud embedding: k = ", k, " must be at least 1");
  if (n < k) fail("point cloud embedding: k = ", k, " but the cloud has ", n, " points");
  std::vector<Index> order(static_cast<std::size_t>(n));
  std::iota(order.begin(), order.end(), Index{0});
  std::vector<double> d2(static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i) d2[i] = (cloud.col(i) - p).squaredNorm();
  std::partial_sort(order.begin(), order.begin() + k, order.end(),
                    [&](Index a, Index b) { return d2[a] < d2[b] || (d2[a] == d2[b] && a < b); });
  order.resize(static_cast<std::size_t>(k));
  std::sort(order.begin(), order.end());

  double support2 = 0.0;
  for (Index i : order) support2 = std::max(support2, d2[i]);
  const double support = 1.5 * std::sqrt(support2);
  PointCloudEmbedding out;
  out.parents = order;
  if (support == 0.0) {  // p coincides with every neighbour: equal weights
    out.weights.assign(static_cast<std::size_t>(k), 1.0 / k);
    return out;
  }
  // Constraints A w = b with A = [1 ... 1; x_i - p], b = (1, 0, 0, 0); w = Phi A^T (A Phi A^T)^+ b.
  Eigen::Matrix<double, 4, Eigen::Dynamic> A(4, k);
  VectorXd phi(k);
  for (int j = 0; j < k; ++j) {
    const double q = std::sqrt(d2[order[j]]) / support;
    phi[j] = std::pow(1.0 - q, 4) * (4.0 * q + 1.0);  // Wendland C2
    A(0, j) = 1.0;
    A.block<3, 1>(1, j) = (cloud.col(order[j]) - p) / support;
  }
  const Eigen::Matrix4d G = A * phi.asDiagonal() * A.transpose();
  // A pseudo-inverse keeps linear precision in the directions the neighbours span when they are
  // coplanar or collinear.
  const Eigen::Vector4d lambda = G.completeOrthogonalDecomposition().solve(Eigen::Vector4d(1, 0, 0, 0));
  const VectorXd w = phi.asDiagonal() * (A.transpose() * lambda);
  out.weights.assign(w.data(), w.data() + k);
  // Restore the exact partition of unity lost to round-off.
  const double sum = w.sum();
  for (double& x : out.weights) x /= sum;
  return out;
}

}  // namespace sinew
