// Points embedded among particles some of which lie on one rigid frame (Sifakis et al. 2007, sections 2
// and 5 together): a point of a point-cloud embedding (a fiber's structure particle, eq. 16-17 of Liu et
// al. 2012) whose parents are partly free particles and partly points hard-bound to a rigid body, as
// where a meshfree body is rooted in a Bullet body. With F the free parents and B those on body b,
//
//   x_e = sum_F w_i x_i + sum_B w_i (x_c + R r0_i),   v_e = sum_F w_i v_i + w_B v_c + w x sum_B w_i r_i,
//
// w_B = sum_B w_i: linear in the free particles' states and the body's twist, so W^T passes f to the
// free parents (w_i f) and to the frame points (w_i f), whose own bindings carry it on to the body as
// a wrench. The parents on the frame are kept as particles (their bindings own the offsets and follow
// the body's frame as masses merge into it), so every pass that maps parents to points (W) visits this
// kind after RigidBindings and every pass that maps points to parents (W^T) before it (HardBindings).
//
// Such a point must have no mass of its own: its share on the frame points would reach them after
// their masses were merged into the body, and be lost (distribute_masses refuses it by name).
#pragma once

#include "sinew/bindings/binding_kind.hpp"
#include "sinew/bindings/linear_bindings.hpp"
#include "sinew/bindings/rigid_bindings.hpp"

#include <span>

namespace sinew {

class MixedBindings final : public BindingKind {
 public:
  std::string_view name() const override { return "point embedded in particles and a rigid frame"; }
  Index size() const override { return m_map.size(); }
  Index particle(Index k) const override { return m_map.particle(k); }
  Index id(Index k) const override { return m_map.id(k); }
  /// Every parent, free or on the frame, and its weight.
  std::span<const Index> parents(Index k) const { return m_map.parents(k); }
  std::span<const double> weights(Index k) const { return m_map.weights(k); }
  Index body(Index k) const { return m_body[k]; }
  /// Parent i's frame binding (an index into the RigidBindings), or -1 for a free parent.
  Index frame(Index k, std::size_t i) const { return m_frame[static_cast<std::size_t>(m_offset[k]) + i]; }

  /// Appends a binding: `parents` and `weights` (checked: finite, summing to 1), `frame[i]` the index
  /// of parent i's binding in `frames` or -1 for a free parent, all frame parents on `body`.
  void add(Index id, Index particle, std::span<const Index> parents, std::span<const double> weights,
           std::span<const Index> frame, Index body);
  void remove(Index k) override;
  void clear();
  /// The rigid frame points the parents' frame indices refer to (set whenever they may have moved).
  void set_frames(RigidBindings* frames) { m_frames = frames; }

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
  /// w_B and the frame share's moment s = sum_B w_i r_i (world, at the frames' current offsets): an
  /// impulse j at the point gives the body (w_B j, s x j).
  double frame_share(Index k, Vec3& moment) const;
  /// The frame share's impulse matrix, w_B^2 / m I + s*^T I^-1 s* (zero for a kinematic body).
  Mat3 frame_impulse_matrix(Index k, const RigidBodyParticles& bodies) const;

  // The map over every parent as a point-cloud embedding: W and W^T themselves (the frame parents'
  // rows are mapped from and to the body by RigidBindings, before and after).
  LinearBindings m_map;
  std::vector<Index> m_body;
  std::vector<Index> m_offset{0};  // CSR over m_frame, aligned with m_map's parents
  std::vector<Index> m_frame;
  RigidBindings* m_frames = nullptr;
};

}  // namespace sinew
