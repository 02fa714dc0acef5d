// The corotated linear material in the signed-SVD frame, shared by the tets and the meshfree matrix
// (private to the forces). With F = U diag(sigma) V^T (signed_svd.hpp):
//   Psi    = mu sum_i (sigma_i - 1)^2 + lambda/2 (sum_i sigma_i - 3)^2
//   Phat_i = 2 mu (sigma_i - 1) + lambda (sum_k sigma_k - 3),   P = U Phat V^T
// and its differential (Teran, Sifakis, Irving and Fedkiw 2005, section 5), dFhat = U^T dF V:
//   dPhat_ii = sum_j (2 mu delta_ij + lambda) dFhat_jj
//   [dPhat_ij]   [A B] [dFhat_ij]      A + B = (Phat_i - Phat_j) / (sigma_i - sigma_j) = 2 mu
//   [dPhat_ji] = [B A] [dFhat_ji],     A - B = (Phat_i + Phat_j) / (sigma_i + sigma_j)
// A + B is exactly 2 mu for this model, so the sigma_i = sigma_j case needs no limit. A - B is
// genuinely unbounded as sigma_i + sigma_j -> 0 (two signed stretches cancelling: the rotation
// U V^T is not differentiable there), so |sigma_i + sigma_j| is clamped to >= 1e-6 keeping its
// sign; the differential is exact everywhere else and stays finite there.
#pragma once

#include "sinew/types.hpp"

#include <cmath>

namespace sinew::detail {

inline Vec3 corotated_diagonal_stress(const Vec3& sigma, double mu, double lambda) {
  return 2.0 * mu * (sigma.array() - 1.0).matrix() + Vec3::Constant(lambda * (sigma.sum() - 3.0));
}

inline double corotated_energy_density(const Vec3& sigma, double mu, double lambda) {
  const double volumetric = sigma.sum() - 3.0;
  return mu * (sigma.array() - 1.0).square().sum() + 0.5 * lambda * volumetric * volumetric;
}

/// dPhat from dFhat = U^T dF V at signed singular values sigma and diagonal stress phat.
inline Mat3 corotated_stress_differential(const Mat3& dF_hat, const Vec3& sigma, const Vec3& phat, double mu,
                                          double lambda) {
  constexpr double kSigmaSumFloor = 1.0e-6;
  constexpr int kPairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  Mat3 dP_hat;
  const double trace = lambda * dF_hat.trace();
  for (int i = 0; i < 3; ++i) dP_hat(i, i) = 2.0 * mu * dF_hat(i, i) + trace;
  for (const auto& pair : kPairs) {
    const int i = pair[0];
    const int j = pair[1];
    double sum = sigma(i) + sigma(j);
    if (std::abs(sum) < kSigmaSumFloor) sum = sum < 0.0 ? -kSigmaSumFloor : kSigmaSumFloor;
    const double half_a_minus_b = 0.5 * (phat(i) + phat(j)) / sum;
    const double a = mu + half_a_minus_b;  // (A + B) / 2 = mu
    const double b = mu - half_a_minus_b;
    dP_hat(i, j) = a * dF_hat(i, j) + b * dF_hat(j, i);
    dP_hat(j, i) = b * dF_hat(i, j) + a * dF_hat(j, i);
  }
  return dP_hat;
}

}  // namespace sinew::detail
