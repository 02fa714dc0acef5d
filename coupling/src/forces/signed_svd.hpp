// Signed ("rotation-variant") SVD of a 3x3 deformation gradient, private to the forces.
#pragma once

#include "sinew/types.hpp"

#include <Eigen/SVD>

namespace sinew::detail {

/// F = U diag(sigma) V^T with det U = det V = +1. When det F < 0 the smallest singular value
/// (sigma(2); Eigen sorts them in decreasing order) carries the sign, so an inverted element sees
/// one negative stretch and is pushed back through the smallest-stretch direction (Irving, Teran and
/// Fedkiw 2004, section 4).
struct SignedSvd {
  Mat3 U;
  Vec3 sigma;
  Mat3 V;
};

inline SignedSvd signed_svd(const Mat3& F) {
  const Eigen::JacobiSVD<Mat3> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  SignedSvd out{svd.matrixU(), svd.singularValues(), svd.matrixV()};
  if (out.U.determinant() < 0.0) {
    out.U.col(2) = -out.U.col(2);
    out.sigma(2) = -out.sigma(2);
  }
  if (out.V.determinant() < 0.0) {
    out.V.col(2) = -out.V.col(2);
    out.sigma(2) = -out.sigma(2);
  }
  return out;
}

}  // namespace sinew::detail
