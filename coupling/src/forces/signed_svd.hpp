// Signed ("rotation-variant") SVD of a 3x3 deformation gradient, private to the forces.
#pragma once

#include "sinew/types.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <cmath>

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

namespace sinew::detail {

/// The same decomposition, faster (about a fifth of JacobiSVD's time), for forces that take one per
/// particle per pass (the meshfree matrix): V from the eigenvectors of F^T F (closed form, then
/// re-orthonormalised and made proper), U from F V by Gram-Schmidt (u2 = u0 x u1, so det U = +1), and
/// sigma the diagonal of U^T F V, whose last entry then carries the sign of det F. The closed-form
/// eigenvectors lose digits where two stretches nearly coincide: U diag(sigma) V^T then differs from
/// F by up to about 1e-8 |F| (test_meshfree's ItsSignedSvdMatchesTheJacobiOne), round-off elsewhere,
/// and the stress U Phat V^T is the energy's derivative to that accuracy.
inline SignedSvd signed_svd_from_eigen(const Mat3& F) {
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(F.transpose() * F);  // ascending eigenvalues
  const Mat3& E = eig.eigenvectors();
  SignedSvd out;
  const auto unit_normal_to = [](const Vec3& a) {  // any unit vector normal to unit a
    const Vec3 t = std::abs(a.x()) < 0.6 ? Vec3::UnitX() : Vec3::UnitY();
    return Vec3((t - a.dot(t) * a).normalized());
  };
  Vec3 v0 = E.col(2).normalized();
  Vec3 v1 = E.col(1) - v0.dot(E.col(1)) * v0;
  v1 = v1.norm() > 1e-8 ? Vec3(v1.normalized()) : unit_normal_to(v0);
  out.V.col(0) = v0;
  out.V.col(1) = v1;
  out.V.col(2) = v0.cross(v1);
  const double scale = F.cwiseAbs().maxCoeff();
  const double tiny = 1e-14 * (scale > 0.0 ? scale : 1.0);
  Vec3 u0 = F * v0;
  u0 = u0.norm() > tiny ? Vec3(u0.normalized()) : Vec3::UnitX();
  Vec3 u1 = F * v1;
  u1 -= u0.dot(u1) * u0;
  u1 = u1.norm() > tiny ? Vec3(u1.normalized()) : unit_normal_to(u0);
  out.U.col(0) = u0;
  out.U.col(1) = u1;
  out.U.col(2) = u0.cross(u1);
  out.sigma = (out.U.transpose() * F * out.V).diagonal();
  return out;
}

}  // namespace sinew::detail
