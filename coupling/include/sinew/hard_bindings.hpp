// Hard bindings (Sifakis et al. 2007, sections 2 and 5): points with no degrees of freedom whose
// state is a linear map W of their parents.
//
//   linear binding   x_e = sum_i w_i x_i,   v_e = sum_i w_i v_i         (segment, triangle, tet,
//                    or k parents of a point-cloud embedding, section 2.2), sum_i w_i = 1;
//   rigid binding    x_e = x_c + R(q) r0,   v_e = v_c + w x r = W(q) (v_c, w),
//                    W(q) = [I  r*^T], r = R(q) r0                      (section 5).
//
// Forces on a bound point go to its parents through W^T (eq. 1-3): f_i += w_i f, or the wrench
// (f, r x f) for a rigid parent. Masses go the same way (m = W^T m_bar). The effective mass of a
// bound point is 1/m_e = sum w_i^2 / m_i (eq. 4), or the impulse matrix K = I/m + r*^T I^-1 r*
// for a rigid parent. Bindings are stored flattened: a parent is never itself bound (chains such as
// T-junctions on refined edges are resolved when the system is set up), so W and W^T are single
// passes in list order.
#pragma once

#include "sinew/particles.hpp"
#include "sinew/rigid_body_particles.hpp"

#include <span>
#include <vector>

namespace sinew {

class HardBindings {
 public:
  // ---- set-up --------------------------------------------------------------------------------
  /// Binds `particle` to `parents` with `weights`. Weights must be finite and sum to 1 (to 1e-9).
  /// Chains are allowed here and flattened by flatten().
  void add_linear(Index particle, std::span<const Index> parents, std::span<const double> weights);
  /// Binds `particle` to the frame of rigid body `body` at body-frame offset r0 from its centre of
  /// mass (in the principal frame).
  void add_rigid(Index particle, Index body, const Vec3& r0);

  /// Removes the hard binding of `particle`; returns false if it had none. Call flatten() afterwards.
  bool remove(Index particle);

  /// Resolves chains so that no parent is bound, merging repeated parents. Throws on cycles and on
  /// linear bindings whose parents lie on different rigid bodies or mix rigid and free parents.
  void flatten(Index particle_count, Index rigid_count);

  Index linear_count() const { return static_cast<Index>(m_linear_particle.size()); }
  Index rigid_count() const { return static_cast<Index>(m_rigid_particle.size()); }
  Index size() const { return linear_count() + rigid_count(); }

  Index linear_particle(Index k) const { return m_linear_particle[k]; }
  std::span<const Index> linear_parents(Index k) const;
  std::span<const double> linear_weights(Index k) const;
  Index rigid_particle(Index k) const { return m_rigid_particle[k]; }
  Index rigid_body(Index k) const { return m_rigid_body[k]; }
  const Vec3& rigid_offset_body(Index k) const { return m_r0[k]; }
  /// World offset r = R(q) r0 at the frames of the last update_rigid_offsets call.
  Vec3 rigid_offset_world(Index k) const { return m_r.col(k); }
  /// Moves a rigid binding's body-frame offset (used when mass absorption shifts a centre of mass).
  void set_rigid_offset_body(Index k, const Vec3& r0) { m_r0[k] = r0; }

  // ---- W, W^T ----------------------------------------------------------------------------------
  /// Caches r = R(q) r0 for every rigid binding; call whenever orientations change.
  void update_rigid_offsets(const RigidBodyParticles& bodies);
  /// x_e = W x for every bound row (positions of parents and centres of mass).
  void clamp_positions(Vectors3& x, const Vectors3& body_x) const;
  /// v_e = W (v, twist) for every bound row, twist = (v_c, w) stacked 6 x R.
  void clamp_velocities(Vectors3& v, const Vectors6& twist) const;
  /// Same with the twist given as separate linear and angular blocks.
  void clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const;
  /// W^T: adds each bound row's force to its parents (f_i += w_i f, wrench += (f, r x f)) and then
  /// zeroes the bound row, so the result lives on parents only.
  void distribute(Vectors3& f, Vectors6& wrench) const;
  /// sum_i w_i a_i for linear bindings or a_c + alpha x r for rigid ones: the acceleration of a
  /// bound point given parent accelerations (the centripetal term w x (w x r) is left out, as in
  /// the paper's force mapping, because it is not a force).
  Vec3 embedded_acceleration(Index particle, const Vectors3& a, const Vectors6& rigid_a) const;

  // ---- masses and impulses -----------------------------------------------------------------------
  /// 1/m_e = sum_i w_i^2 / m_i (eq. 4) for a linear binding; 0 when every parent is kinematic.
  double inverse_effective_mass_linear(Index k, const VectorXd& mass) const;
  /// Binding index of a bound particle: k >= 0 linear, -(k+1) rigid; `unbound` when not bound.
  static constexpr Index unbound = std::numeric_limits<Index>::min();
  Index binding_of(Index particle) const {
    return particle < static_cast<Index>(m_binding_of.size()) ? m_binding_of[particle] : unbound;
  }

 private:
  void rebuild_lookup(Index particle_count);
  /// y_e = sum_i w_i y_i for every linear binding (positions or velocities alike).
  void clamp_linear(Vectors3& y) const;

  // Linear bindings in compressed rows: parents/weights of binding k in [m_offset[k], m_offset[k+1]).
  // m_*_id is the order in which the user added the binding, used to name it in messages.
  std::vector<Index> m_linear_id;
  std::vector<Index> m_rigid_id;
  Index m_added = 0;
  std::vector<Index> m_linear_particle;
  std::vector<Index> m_offset{0};
  std::vector<Index> m_parent;
  std::vector<double> m_weight;
  // Rigid bindings.
  std::vector<Index> m_rigid_particle;
  std::vector<Index> m_rigid_body;
  std::vector<Vec3> m_r0;
  Vectors3 m_r;  // cached world offsets (3 x rigid_count)
  std::vector<Index> m_binding_of;
};

}  // namespace sinew
