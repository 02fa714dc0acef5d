// The constrained directions of the Newmark step's implicit solves (internal to sinew::Newmark):
// rows without unknowns, kinematic bodies, the collision constraints of step 3 (weighted stencils),
// and the joint rows
// between rigid-body particles. Each is a projection, so CG works in the constraints' null space
// and the constrained components keep their prescribed values (projected CG).
#pragma once

#include "step_model.hpp"

#include <Eigen/SVD>

#include <vector>

namespace sinew {

class Constraints {
 public:
  void reset(const Unknowns& unknowns);
  std::vector<CollisionConstraint>& collisions() { return m_collisions; }
  const std::vector<CollisionConstraint>& collisions() const { return m_collisions; }
  /// Call once the collisions are final (after step 3): constraints that share a particle are
  /// grouped and each group's rows factored, so that the projection onto all of them together is
  /// exact and symmetric (a constraint alone takes the short form of shift()).
  void prepare_collisions();

  /// Groups the dynamic bodies that joint rows connect and factors each group's rows (SVD), once per
  /// step: the orthonormal basis of the rows' span and the least-norm twists meeting the targets.
  /// `tangent_of` (optional, per row): for a contact's sticking row, the index of its contact's normal
  /// row (unilateral, with the friction coefficient), else -1; their multipliers stay in Coulomb's
  /// pyramid where targets must be reconciled (agree_contact_targets).
  void prepare_joints(const std::vector<JointRow>& rows, const RigidBodyParticles& bodies,
                      const std::vector<Index>* tangent_of = nullptr);
  bool has_joints() const { return m_joint_group_count > 0; }
  /// The multiplier of each row passed to prepare_joints (in their order), from r = S t - c on the
  /// twists: J^T lambda = r on each group, least norm (rows between prescribed bodies get 0). For a
  /// solve that held the rows, r is the reaction the rows exert, J^T lambda.
  void joint_multipliers(const GeneralizedVector& r, std::size_t rows, VectorXd& lambda) const;

  /// The multiplier of each collision constraint (in collisions()' order) from r = S u - c after a
  /// solve that held them: J^T lambda = r on each constraint or group, least norm. lambda > 0 pushes
  /// along the constraint's normal; it is the impulse over the solve's step.
  void collision_multipliers(const GeneralizedVector& r, VectorXd& lambda) const;
  /// Zeroes rows without unknowns, then project_constraints.
  void project(GeneralizedVector& u) const;
  /// project() without the particle mask: for vectors already zero on rows without unknowns.
  void project_constraints(GeneralizedVector& u) const;
  /// Sets the collision constraints' components of u to their normal velocities (the rest is kept).
  void impose_collisions(GeneralizedVector& u) const;
  /// Sets the joint rows' components of the rigid twists in u to their targets (the rest is kept).
  void impose_joints(GeneralizedVector& u) const { project_joint_groups(u, true); }
  /// While on, every rigid twist is held at zero (a solve over the particles alone, with the bodies
  /// where they are: Newmark::spread_collisions).
  void hold_bodies(bool on) { m_hold_bodies = on; }

 private:
  void project_joint_groups(GeneralizedVector& u, bool impose_targets) const;
  /// u += J^T (J J^T)^-1 (target - J u) for constraint c's row J.
  static void shift(const CollisionConstraint& c, GeneralizedVector& u, double target);

  /// The rows' null-space projection of every group, plus the particular solution with `impose_targets`.
  void project_collision_groups(GeneralizedVector& u, bool impose_targets) const;

  const Unknowns* m_unknowns = nullptr;
  bool m_hold_bodies = false;
  std::vector<CollisionConstraint> m_collisions;
  // Collision constraints alone on their particles (indices into m_collisions), and groups of those
  // that share particles, each with an orthonormal basis of its rows and the least-norm velocities on
  // its targets (as the joint groups below).
  std::vector<std::size_t> m_single;
  struct CollisionGroup {
    std::vector<Index> particles;   // ascending
    Eigen::MatrixXd basis;          // 3k x rank
    VectorXd particular;            // 3k
    std::vector<std::size_t> rows;  // its constraints (indices into m_collisions)
    Eigen::MatrixXd multipliers;    // m x rank: U Sigma^-1, so lambda = multipliers * basis^T r
  };
  std::vector<CollisionGroup> m_collision_groups;
  std::vector<Index> m_collision_root;  // per particle: union-find parent, -1 when in no constraint
  std::vector<Index> m_collision_count, m_collision_group_of;
  mutable VectorXd m_group_scratch, m_group_coefficients;  // project_collision_groups' scratch
  struct JointGroup {
    std::vector<Index> bodies;  // ascending
    Eigen::MatrixXd basis;      // 6k x rank, orthonormal, spanning the rows
    VectorXd particular;        // 6k, in the span: the least-norm twists on the targets
    // Set-up scratch, kept so that a step whose joints have the same shape as the last allocates nothing.
    std::vector<Index> rows;  // indices into the system's joint rows
    Eigen::MatrixXd J;
    VectorXd t, coefficients;
    Eigen::JacobiSVD<Eigen::MatrixXd> svd;
  };
  /// A group with contact rows: its rows' targets made to agree, from group.svd (of group.J, computed
  /// first; see constraints.cpp).
  void agree_contact_targets(JointGroup& group, const std::vector<JointRow>& rows,
                             const std::vector<Index>* tangent_of);
  std::vector<Index> m_local_row;  // agree_contact_targets' scratch: each row's place in its group
  static constexpr int kQpPasses = 200;
  // The first m_joint_group_count entries are this step's groups; entries past it keep their storage.
  std::vector<JointGroup> m_joint_groups;
  std::size_t m_joint_group_count = 0;
  std::vector<Index> m_joint_root, m_joint_group_of;
  mutable VectorXd m_joint_scratch, m_joint_coefficients;
};

}  // namespace sinew
