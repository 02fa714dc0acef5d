// Hard bindings (Sifakis et al. 2007, sections 2 and 5): points with no degrees of freedom whose
// state is a linear map W of their parents.
//
// Each kind of binding lives in its own class (sinew/bindings/): LinearBindings, points embedded in
// particles (segment, triangle, tet, point cloud), RigidBindings, points on rigid frames, and
// MixedBindings, points embedded among free particles and points of one rigid frame (a fiber's
// structure particle near where its body is bound to a Bullet body). A kind owns its maths (W, W^T,
// masses, effective masses, impulses, drift, preconditioner blocks; see BindingKind). This class holds
// one of each, visits them in a fixed order (linear, rigid, mixed for W; mixed, rigid, linear for
// W^T: a mixed point's parents on the frame are rigid frame points, mapped before it and carrying its
// share after it), finds the binding of a particle, and resolves chains: once flatten() has run, a
// parent is bound only where a mixed point hangs on frame points (T-junctions on refined edges,
// points on points of a rigid frame resolve fully), so W and W^T are single passes in list order.
//
// Adding a kind: its class under sinew/bindings/ (and src/bindings/), a member here with its entries
// in kinds() and mutable_kinds(), an add_* here and a System::bind_* that creates its bindings.
// flatten() resolves chains through linear and rigid points (mixed ones go back to linear first and
// are resolved again): a point of another kind cannot be the parent of a linear binding (flatten
// says so by name) unless flatten learns to expand it.
#pragma once

#include "sinew/bindings/linear_bindings.hpp"
#include "sinew/bindings/mixed_bindings.hpp"
#include "sinew/bindings/rigid_bindings.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

namespace sinew {

class HardBindings {
 public:
  HardBindings() = default;
  // Copies and moves point the mixed points at their own RigidBindings (MixedBindings::set_frames).
  HardBindings(const HardBindings& other) { *this = other; }
  HardBindings(HardBindings&& other) noexcept { *this = std::move(other); }
  HardBindings& operator=(const HardBindings& other) {
    if (this == &other) return *this;
    m_linear = other.m_linear;
    m_rigid = other.m_rigid;
    m_mixed = other.m_mixed;
    m_added = other.m_added;
    m_kind_of = other.m_kind_of;
    m_index_in_kind = other.m_index_in_kind;
    m_mixed.set_frames(&m_rigid);
    return *this;
  }
  HardBindings& operator=(HardBindings&& other) noexcept {
    if (this == &other) return *this;
    m_linear = std::move(other.m_linear);
    m_rigid = std::move(other.m_rigid);
    m_mixed = std::move(other.m_mixed);
    m_added = other.m_added;
    m_kind_of = std::move(other.m_kind_of);
    m_index_in_kind = std::move(other.m_index_in_kind);
    m_mixed.set_frames(&m_rigid);
    return *this;
  }

  // ---- set-up --------------------------------------------------------------------------------
  /// Binds `particle` to `parents` with `weights`. Weights must be finite and sum to 1 (to 1e-9).
  /// Chains are allowed here and flattened by flatten().
  void add_linear(Index particle, std::span<const Index> parents, std::span<const double> weights);
  /// Binds `particle` to the frame of rigid body `body` at body-frame offset r0 from its centre of
  /// mass (in the principal frame).
  void add_rigid(Index particle, Index body, const Vec3& r0);

  /// After flatten(): gives the embedded point `particle` new parents and weights in place (checked as
  /// add_linear; the parents must not be bound), keeping everything else set up (plastic flow,
  /// Sifakis et al. 2007 figure 9).
  void replace_linear(Index particle, std::span<const Index> parents, std::span<const double> weights);
  /// Removes the hard binding of `particle`; returns false if it had none. Call flatten() afterwards.
  bool remove(Index particle);

  /// Resolves chains so that no parent is bound, merging repeated parents; a chain that reaches free
  /// particles and one rigid frame's points becomes a mixed binding on both. Throws on cycles and on
  /// linear bindings whose parents lie on different rigid bodies.
  void flatten(Index particle_count, Index rigid_count);

  /// Every kind, in the order W visits them (W^T visits them backwards).
  std::array<const BindingKind*, 3> kinds() const { return {&m_linear, &m_rigid, &m_mixed}; }
  const LinearBindings& linear() const { return m_linear; }
  const RigidBindings& rigid() const { return m_rigid; }
  const MixedBindings& mixed() const { return m_mixed; }

  Index linear_count() const { return m_linear.size(); }
  Index rigid_count() const { return m_rigid.size(); }
  Index size() const {
    Index count = 0;
    for (const BindingKind* kind : kinds()) count += kind->size();
    return count;
  }
  Index linear_particle(Index k) const { return m_linear.particle(k); }
  std::span<const Index> linear_parents(Index k) const { return m_linear.parents(k); }
  std::span<const double> linear_weights(Index k) const { return m_linear.weights(k); }
  Index rigid_particle(Index k) const { return m_rigid.particle(k); }
  Index rigid_body(Index k) const { return m_rigid.body(k); }
  const Vec3& rigid_offset_body(Index k) const { return m_rigid.offset_body(k); }
  /// World offset r = R(q) r0 at the frames of the last update_rigid_offsets call.
  Vec3 rigid_offset_world(Index k) const { return m_rigid.offset_world(k); }

  /// True when `particle` is hard-bound (after flatten()).
  bool is_bound(Index particle) const { return kind_of(particle) != nullptr; }
  /// True when `particle` is bound to a rigid frame.
  bool on_rigid_frame(Index particle) const {
    const BindingKind* kind = kind_of(particle);
    return kind != nullptr && kind->on_rigid_frames();
  }

  /// The linear binding holding `particle` (after flatten()): its index in linear(), or -1 when it has
  /// none (free, on a rigid frame, or a mixed point).
  Index linear_binding_of(Index particle) const {
    const BindingKind* kind = kind_of(particle);
    return kind == &m_linear ? m_index_in_kind[static_cast<std::size_t>(particle)] : -1;
  }

  // ---- W, W^T over every binding -----------------------------------------------------------------
  /// Caches r = R(q) r0 for every rigid binding; call whenever orientations change.
  void update_rigid_offsets(const RigidBodyParticles& bodies);
  /// Within a step's solves: every point on body b at arm_maps[b] r0, moving with angular_maps[b] w
  /// (BindingKind::set_step_arms); update_rigid_offsets puts the frames' offsets back.
  void set_step_arms(const std::vector<Mat3>& arm_maps, const std::vector<Mat3>& angular_maps);
  /// x_e = W x for every bound row (positions of parents and centres of mass).
  void clamp_positions(Vectors3& x, const Vectors3& body_x) const;
  /// v_e = W (v, twist) for every bound row, twist = (v_c, w) stacked 6 x R.
  void clamp_velocities(Vectors3& v, const Vectors6& twist) const;
  /// Same with the twist given as separate linear and angular blocks.
  void clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const;
  /// W^T: adds each bound row's force to its parents and zeroes the bound row.
  void distribute(Vectors3& f, Vectors6& wrench) const;
  /// m = W^T m_bar on every bound row (BindingKind::distribute_masses).
  void distribute_masses(VectorXd& mass) const;
  /// W^T B W of every bound row's diagonal block (BindingKind::add_preconditioner_blocks).
  void add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const;
  /// 1/m_e (eq. 4) of every bound row into inverse_mass (per particle), from the parents' masses.
  void inverse_effective_masses(const VectorXd& mass, const RigidBodyParticles& bodies, VectorXd& inverse_mass) const;
  /// Merges the points' masses into their rigid bodies (RigidBindings::absorb_masses).
  void absorb_masses_into_bodies(const VectorXd& mass, RigidBodyParticles& bodies) {
    m_rigid.absorb_masses(mass, bodies);
  }
  /// Takes them out again (RigidBindings::release_masses), before bindings change.
  void release_masses_from_bodies(RigidBodyParticles& bodies) { m_rigid.release_masses(bodies); }
  /// Largest |x_e - W x_parents| over every binding.
  double max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const;
  /// out.col(i) = (add ? out.col(i) : 0) + f.col(i) on every bound row i (the forces bindings carry).
  void record_bound_rows(const Vectors3& f, Vectors3& out, bool add) const;

  // ---- one particle, through its binding (unbound particles are their own parents) ---------------
  /// The acceleration of `particle` given the parents' forces after W^T (f, wrench): f/m for a free
  /// particle, 0 for a kinematic one, BindingKind::point_acceleration for a bound one.
  Vec3 point_acceleration(Index particle, const Particles& p, const RigidBodyParticles& bodies, const Vectors3& f,
                          const Vectors6& wrench) const;
  /// The effective mass along unit direction n; `scalar` is the particle's eq. 4 effective mass.
  double effective_mass_along(Index particle, const Vec3& n, double scalar, const RigidBodyParticles& bodies) const;
  /// The velocity of `particle`: its own if unbound, W (v, twist) of its parents' if bound.
  Vec3 point_velocity(Index particle, const Vectors3& v, const RigidBodyParticles& bodies) const;
  /// Impulse j at `particle`: its own velocity if free, its parents' if bound; bound rows are not
  /// re-clamped here.
  void apply_impulse(Index particle, const Vec3& j, Particles& p, RigidBodyParticles& bodies) const;
  /// Moves `particle` (free: itself; bound: its parents) so that it moves by dx and its velocity
  /// changes by dv (section 3.1's drift push-back); m_e its effective mass.
  void push_drift(Index particle, const Vec3& dx, const Vec3& dv, Particles& p, RigidBodyParticles& bodies,
                  const VectorXd& effective_mass, Vectors3& L_n);

 private:
  const BindingKind* kind_of(Index particle) const {
    if (particle < 0 || particle >= static_cast<Index>(m_kind_of.size()) || m_kind_of[particle] < 0) return nullptr;
    const auto all = kinds();
    const auto kind = static_cast<std::size_t>(m_kind_of[particle]);
    return kind < all.size() ? all[kind] : nullptr;
  }
  std::array<BindingKind*, 3> mutable_kinds() { return {&m_linear, &m_rigid, &m_mixed}; }
  void rebuild_lookup(Index particle_count);
  struct Term {
    Index parent;
    double weight;
  };
  /// Linear binding k expanded through bound parents (flatten's work per binding; scratch reused).
  struct Chain {
    std::vector<Term> terms, next;  ///< on unbound particles
    std::vector<Term> frame_terms;  ///< on the rigid frame points reached
    Index rigid_body = -1;          ///< the rigid frame the chain reached, or -1
    Vec3 rigid_r0 = Vec3::Zero();   ///< sum of w r0 over the frame points reached
    double rigid_weight = 0.0;      ///< sum of their weights
  };
  void resolve_chain(Index k, Chain& chain) const;

  LinearBindings m_linear;
  RigidBindings m_rigid;
  MixedBindings m_mixed;
  Index m_added = 0;  // bindings ever added: the id that names the next one in messages
  // Per particle: the kind (index into kinds(), -1 when unbound) and the binding's index in it.
  std::vector<std::int8_t> m_kind_of;
  std::vector<Index> m_index_in_kind;
};

}  // namespace sinew
