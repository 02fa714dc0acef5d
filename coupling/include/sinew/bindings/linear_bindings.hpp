// Points embedded in particles (Sifakis et al. 2007, section 2): a segment, triangle or tet by
// barycentric weights, or k parents of a point-cloud embedding (section 2.2), sum_i w_i = 1:
//
//   x_e = sum_i w_i x_i,   v_e = sum_i w_i v_i,   f_i += w_i f_e,   m_i += w_i m_e,
//   1/m_e = sum_i w_i^2 / m_i                                                     (eq. 1-4)
//
// Masses pass with weight w (not w^2), so that the momentum m_bar^T W v is kept.
#pragma once

#include "sinew/bindings/binding_kind.hpp"

#include <span>

namespace sinew {

class LinearBindings final : public BindingKind {
 public:
  std::string_view name() const override { return "embedded point"; }
  Index size() const override { return static_cast<Index>(m_particle.size()); }
  Index particle(Index k) const override { return m_particle[k]; }
  std::span<const Index> parents(Index k) const {
    return {m_parent.data() + m_offset[k], static_cast<std::size_t>(m_offset[k + 1] - m_offset[k])};
  }
  std::span<const double> weights(Index k) const {
    return {m_weight.data() + m_offset[k], static_cast<std::size_t>(m_offset[k + 1] - m_offset[k])};
  }
  /// The order in which the user added binding k (among all hard bindings), to name it in messages.
  Index id(Index k) const override { return m_id[k]; }

  /// Appends a binding (weights already checked).
  void add(Index id, Index particle, std::span<const Index> parents, std::span<const double> weights);
  void remove(Index k) override;
  /// Gives binding k new parents and weights (already checked), keeping its place and id.
  void replace(Index k, std::span<const Index> parents, std::span<const double> weights);
  void clear();

  void clamp_positions(Vectors3& x, const Vectors3& body_x) const override;
  void clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const override;
  void clamp_velocities(Vectors3& v, const Vectors6& twist) const override;
  void distribute(Vectors3& f, Vectors6& wrench) const override;
  void distribute_masses(VectorXd& mass) const override;
  void add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const override;
  double max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const override;

  Vec3 point_velocity(Index k, const Vectors3& v, const RigidBodyParticles& bodies) const override;
  Vec3 point_acceleration(Index k, const Particles& p, const RigidBodyParticles& bodies, const Vectors3& f,
                          const Vectors6& wrench) const override;
  double inverse_effective_mass(Index k, const VectorXd& mass, const RigidBodyParticles& bodies) const override;
  double effective_mass_along(Index k, const Vec3& n, double scalar, const RigidBodyParticles& bodies) const override;
  void apply_impulse(Index k, const Vec3& j, Particles& p, RigidBodyParticles& bodies) const override;
  void push_drift(Index k, const Vec3& dx, const Vec3& dv, double m_e, Particles& p, RigidBodyParticles& bodies,
                  Vectors3& L_n) override;

 private:
  /// y_e = sum_i w_i y_i for every binding (positions or velocities alike).
  void clamp(Vectors3& y) const;

  // Compressed rows: the parents and weights of binding k are [m_offset[k], m_offset[k+1]).
  std::vector<Index> m_id;
  std::vector<Index> m_particle;
  std::vector<Index> m_offset{0};
  std::vector<Index> m_parent;
  std::vector<double> m_weight;
};

}  // namespace sinew
