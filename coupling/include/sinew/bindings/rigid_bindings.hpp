// Points on rigid frames (Sifakis et al. 2007, section 5): a point at body-frame offset r0 from a
// rigid body's centre of mass, in its principal frame,
//
//   x_e = x_c + R(q) r0,   v_e = v_c + w x r = W(q) (v_c, w),   W(q) = [I  r*^T],   r = R(q) r0,
//
// so a force f on the point is the wrench (f, r x f) on the body, and the point's impulse matrix is
// K = I/m + r*^T I^-1 r*.
#pragma once

#include "sinew/bindings/binding_kind.hpp"

namespace sinew {

class RigidBindings final : public BindingKind {
 public:
  std::string_view name() const override { return "rigid frame point"; }
  Index size() const override { return static_cast<Index>(m_particle.size()); }
  Index particle(Index k) const override { return m_particle[k]; }
  bool on_rigid_frames() const override { return true; }
  Index body(Index k) const { return m_body[k]; }
  const Vec3& offset_body(Index k) const { return m_r0[k]; }
  /// r = R(q) r0 at the frames of the last update_offsets call (or the step's arm after set_step_arms).
  Vec3 offset_world(Index k) const { return m_r.col(k); }
  void set_offset_body(Index k, const Vec3& r0) { m_r0[k] = r0; }
  Index id(Index k) const override { return m_id[k]; }

  void add(Index id, Index particle, Index body, const Vec3& r0);
  void remove(Index k) override;

  /// Merges each point's mass (mass[particle], the mass it was created with) into its dynamic body by
  /// the parallel-axis theorem, moving the centre of mass, rediagonalising the inertia and
  /// re-expressing every offset on that body in the new principal frame; momentum is kept. What was
  /// merged is remembered, so that release_masses() can take it out again.
  void absorb_masses(const VectorXd& mass, RigidBodyParticles& bodies);
  /// Undoes absorb_masses (to round-off): each body gets back its own mass and inertia, its centre of mass
  /// and principal frame where they are on the body now (the body has moved rigidly since), with the
  /// velocity of that point, and the offsets on it are re-expressed in that frame. Bindings may then
  /// change and absorb_masses run again.
  void release_masses(RigidBodyParticles& bodies);

  void update_offsets(const RigidBodyParticles& bodies) override;
  void set_step_arms(const std::vector<Mat3>& arm_maps, const std::vector<Mat3>& angular_maps) override;
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
  std::vector<Index> m_id;
  std::vector<Index> m_particle;
  std::vector<Index> m_body;
  std::vector<Vec3> m_r0;
  Vectors3 m_r;  // cached world offsets (3 x size), or the step's arms
  // Within a step's solves, per body: the map A from the body's angular velocity to the one its points
  // move with (W = [I  -r* A]); empty while the points move with w itself.
  std::vector<Mat3> m_angular;
  const Mat3& angular(Index b) const { return m_angular[static_cast<std::size_t>(b)]; }
  // Per body that absorb_masses changed: its own mass and principal moments, and where its own frame
  // sits in the merged one (centre d and rotation q_rel, constant while the body moves rigidly).
  struct Absorbed {
    Index body = -1;
    double mass = 0.0;
    Vec3 inertia = Vec3::Zero();
    Vec3 d = Vec3::Zero();
    Quat q_rel = Quat::Identity();
  };
  std::vector<Absorbed> m_absorbed;
};

}  // namespace sinew
