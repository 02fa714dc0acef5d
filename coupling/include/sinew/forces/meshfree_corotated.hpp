// Corotated linear elasticity on a meshfree particle cloud (Liu et al. 2012, section 4.2, eq. 9-15,
// after Becker et al. 2009), the matrix that fibers are embedded in.
//
// Each material particle i keeps the neighbours j within the support radius h at rest (fixed, total
// Lagrangian) and the corrected kernel gradients
//   g_ij = M_i^-T grad W(X_j - X_i),   M_i = sum_j V_j (X_j - X_i) grad W(X_j - X_i)^T,
// with Lucy's quartic W(q) = 105 / (16 pi h^3) (1 + 3q)(1 - q)^3, q = r / h (eq. 13, normalised), so
// that the deformation gradient
//   F_i = sum_j V_j (x_j - x_i) g_ij^T
// reproduces every affine map exactly, at the boundary too (the paper's uncorrected sums leave a
// flat face up to half as stiff along its normal). The energy is V_i Psi(F_i) with the corotated
// linear Psi of CorotatedTets (signed SVD F = U Sigma V^T, Psi = mu sum (sigma - 1)^2 + lambda/2
// (sum sigma - 3)^2, R = U V^T: the linear strain of eq. 14 measured in the rotated frame), and the
// forces its exact gradient: with P_i = U Phat V^T = R_i sigma_i,
//   f_j -= V_i V_j P_i g_ij,   f_i += V_i V_j P_i g_ij   (each neighbour j of i).
// This is eq. 10 corrected: the paper's (I + grad u^T) factor belongs to Green strain, and the force
// must be turned back by R_i; so written it is conservative, sums to zero, and its torque vanishes
// (P_i F_i^T is symmetric), so linear and angular momentum are kept.
//
// Zero-energy modes: a particle's F sees only the affine part of its neighbours' motion. The penalty
//   E_hg = alpha mu / 2 sum_i sum_j V_i V_j W_ij / |X_ij|^2 |x_j - x_i - F_i (X_j - X_i)|^2
// (Kugelstadt et al. 2021's zero-energy control) costs exactly the non-affine rest. Its residuals are
// linear in the positions, so it is a quadratic form: zero for every affine map (rigid motion too),
// its differential constant and exact.
//
// Damping is strain-rate (stiffness-proportional) as in CorotatedTets: Fdot_i from the velocities,
// Edot = sym(R_i^T Fdot_i), f = -beta V_i V_j R_i (2 mu Edot + lambda tr Edot I) g_ij; it leaves
// rigid motion of an unstretched body undamped (not -c v). With `implicit`, the same warped operator
// (beta replaced by b) is offered as the definite differential K+.
#pragma once

#include "sinew/force.hpp"

#include <span>
#include <vector>

namespace sinew {

struct MeshfreeCorotatedSettings {
  double support_radius = 0.015;  ///< h [m]: rest neighbours closer than h
  double young_modulus = 1.0e5;   ///< E [Pa]
  double poisson_ratio = 0.3;     ///< nu, in (-1, 0.5)
  double beta = 0.0;              ///< strain-rate damping time [s]
  double hourglass = 0.1;         ///< alpha: zero-energy-mode penalty, in units of mu
  bool implicit = false;          ///< offer the warped stiffness as a definite differential
};

class MeshfreeCorotated final : public Force {
 public:
  /// `particles`: the material particles (indices into the system's rows); `rest_x`: 3 x N rest
  /// positions of the whole particle array; `volumes`: each material particle's rest volume V_i [m^3]
  /// (in `particles`' order). Throws sinew::Error naming a bad setting, a repeated or out-of-range
  /// particle, a non-positive volume, or a particle whose neighbours within h do not span space
  /// (its moment matrix M_i is singular: fewer than three non-coplanar neighbours).
  MeshfreeCorotated(std::vector<Index> particles, const Vectors3& rest_x, std::vector<double> volumes,
                    const MeshfreeCorotatedSettings& settings = {});

  std::string_view name() const override { return "meshfree corotated"; }
  void validate(Index particle_count) const override;
  bool touches(std::span<const std::uint8_t> removed) const override {
    for (const Index p : m_particles)
      if (removed[static_cast<std::size_t>(p)]) return true;
    return false;
  }
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.beta > 0.0; }
  bool has_definite_differentials() const override { return m_settings.implicit; }
  bool volumetric() const override { return true; }
  /// f += D v + b K+ v: the warped stiffness R K0 R^T of the corotated part (R held fixed), scaled
  /// by beta + b, plus b times the hourglass penalty's constant differential.
  void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const override;
  /// Gershgorin bound on the rest stiffness against each particle's mass.
  double stable_dt(const VectorXd& m_eff) const override;
  double turn_work_rate(const Vectors3& x, const Vectors3& v) const override;
  double turn_stretch_rate(const Vectors3& x, const Vectors3& v) const override;

  const std::vector<Index>& particles() const { return m_particles; }
  /// The deformation gradient of material particle k (in `particles`' order) at the cached state.
  const Mat3& deformation_gradient(std::size_t k) const { return m_state[k].F; }
  /// Material particle k's rest neighbours (positions in `particles`' order).
  std::span<const Index> neighbours(std::size_t k) const {
    return {m_neighbours.data() + m_offset[k], m_neighbours.data() + m_offset[k + 1]};
  }
  /// The zero-energy modes' measure (the fibers notes' P8): per material particle k, its neighbours'
  /// departure from the affine map F_k, sum_j w_kj |x_j - x_k - F_k X_kj|^2 / sum_j w_kj |X_kj|^2
  /// (w_kj = V_j W(|X_kj|)); the largest over the particles at x. Zero for any affine x.
  double largest_non_affine_residual(const Vectors3& x) const;
  double mu() const { return m_mu; }
  double lambda() const { return m_lambda; }
  /// The part (1 - lambda, eq. 18) of material particle `particle`'s stencil that is matrix where
  /// fibers take the rest: its energy, forces, damping and penalty are scaled by it. 1 by default;
  /// set before the system's first step.
  void set_volume_fraction(Index particle, double fraction);

 private:
  struct State {
    Mat3 F, U, V, R;
    Vec3 sigma, phat;
  };
  Mat3 gradient_of(const Vectors3& x, std::size_t k) const;  // F_k at x
  /// f += each stencil's stress terms (h_k = stress(k, F_k of y), f_j -= h_k V_j g_kj, f_k += the
  /// same) and hourglass_scale times its penalty's, in one pass (see the source).
  template <typename Stress>
  void stencil_pass(const Vectors3& y, double hourglass_scale, Vectors3& f, bool cached, Stress&& stress) const;
  /// True when x holds, to the bit, the positions update_position_state last cached the state at.
  bool state_is_at(const Vectors3& x) const;
  double hourglass_energy(const Vectors3& x) const;

  std::vector<Index> m_particles;
  std::vector<double> m_volume;
  MeshfreeCorotatedSettings m_settings;
  double m_mu = 0.0, m_lambda = 0.0;
  Vectors3 m_rest;                          // 3 x M: the material particles' rest positions
  std::vector<std::size_t> m_offset;        // CSR: particle k's neighbours are [m_offset[k], m_offset[k + 1])
  std::vector<Index> m_neighbours;          // positions in m_particles
  std::vector<Index> m_neighbour_particle;  // the system's particle of each neighbour entry
  std::vector<Vec3> m_g;                    // corrected kernel gradient g_kj per neighbour entry
  std::vector<Vec3> m_vg;                   // V_j g_kj per neighbour entry
  std::vector<Vec3> m_X;                    // X_kj = X_j - X_k per neighbour entry
  std::vector<double> m_hg_weight;          // V_k V_j W_kj / |X_kj|^2 per neighbour entry
  std::vector<double> m_fraction;           // per material particle: its stencil's matrix fraction
  std::vector<State> m_state;
  Vectors3 m_state_x;  // the material particles' positions the state was cached at (3 x M)
};

}  // namespace sinew
