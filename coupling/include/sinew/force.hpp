// The interface every particle force implements.
//
// A force acts on the full particle array: free particles, soft-bound particles and hard-bound rows
// alike. Forces on hard-bound rows reach the parents through W^T (Sifakis et al. 2007, eq. 1-3);
// the integrator does that, a force never needs to know which rows are bound.
//
// Elastic forces are explicit in the Newmark step (section 3.3), unless StepSettings::
// implicit_elasticity asks for those that offer a definite differential to enter the first velocity
// solve the way binding springs do (eq. 6-8). Damping is linear in v (f = D(x) v, D symmetric
// negative semi-definite) and is implicit in both velocity solves.
#pragma once

#include "sinew/types.hpp"

#include <string_view>

namespace sinew {

/// Receives the off-diagonal blocks of a force's implicit matrix D + b K+, one node pair at a time
/// (the aggregation multigrid builds its coarse operators from them).
class PairBlockSink {
 public:
  /// The block coupling nodes i and j (i != j): (D + b K+)_ij, 3x3; the (j, i) block is its transpose.
  /// A pair may come several times (once per element that couples it); the blocks add.
  virtual void add(Index i, Index j, const Mat3& block) = 0;

 protected:
  ~PairBlockSink() = default;
};

class Force {
 public:
  virtual ~Force() = default;

  /// Short name used in error messages and timings, e.g. "edge springs".
  virtual std::string_view name() const = 0;

  /// Throws sinew::Error naming the bad item if any index is outside [0, particle_count) or any
  /// element is degenerate. Called once when the force joins a system.
  virtual void validate(Index particle_count) const = 0;

  /// Caches position-dependent data (rotations, directions, gradients) at positions x (3 x N).
  /// Every call below except potential_energy and add_elastic_forces uses the cached state.
  virtual void update_position_state(const Vectors3& x) = 0;

  /// Elastic potential energy at x (3 x N).
  virtual double potential_energy(const Vectors3& x) const = 0;

  /// f += f_el(x), with f_el = -dPsi/dx. x and f are 3 x N.
  virtual void add_elastic_forces(const Vectors3& x, Vectors3& f) const = 0;

  /// df += (d f_el / dx) dx at the cached state. dx and df are 3 x N.
  virtual void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const = 0;

  /// f += D v at the cached state; D symmetric negative semi-definite. v and f are 3 x N.
  virtual void add_damping_forces(const Vectors3& v, Vectors3& f) const { (void)v, (void)f; }

  /// diag(i) += -D_ii at the cached state, the damping's contribution to the diagonal of the
  /// implicit system (a scalar per particle: a third of the trace of its 3x3 diagonal block).
  /// Used only by the Jacobi preconditioner.
  virtual void add_damping_diagonal(VectorXd& diag) const { (void)diag; }

  /// True when the force offers a definite differential K+ (symmetric negative semi-definite; the
  /// exact differential wherever that is definite) and so may be treated implicitly.
  virtual bool has_definite_differentials() const { return false; }

  /// Called before every step with whether the step treats this force implicitly (it has definite
  /// differentials and StepSettings::implicit_elasticity is on), before update_position_state, so
  /// that a force can cache what its implicit products need only when they are used.
  virtual void set_implicit(bool implicit) { (void)implicit; }

  /// f += D v + b K+ v at the cached state: what the implicit solve multiplies by, in one pass over
  /// the elements. Forces without a definite differential add D v only (b must then be 0).
  virtual void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
    (void)b;
    add_damping_forces(v, f);
  }

  /// diag(i) += -(D_ii + b K+_ii), a third of the traces of the diagonal blocks (Jacobi).
  virtual void add_implicit_diagonal(double b, VectorXd& diag) const {
    (void)b;
    add_damping_diagonal(diag);
  }

  /// blocks.col(i) += -(D_ii + b K+_ii), the 3x3 diagonal blocks (column-major, 9 x N) of the implicit
  /// system, for the block-Jacobi preconditioner. Returns false when the force does not provide
  /// blocks; the preconditioner then uses add_implicit_diagonal (a multiple of the identity).
  virtual bool add_implicit_diagonal_blocks(double b, Eigen::Matrix<double, 9, Eigen::Dynamic>& blocks) const {
    (void)b, (void)blocks;
    return false;
  }

  /// Passes every off-diagonal block of D + b K+ (exactly the couplings add_implicit_products applies)
  /// to `sink`, always in the same order and always every pair, even where the block is zero (the
  /// multigrid records the sequence once). Returns false when the force does not provide them; its
  /// couplings then reach only the finest level of the multigrid.
  virtual bool visit_implicit_pair_blocks(double b, PairBlockSink& sink) const {
    (void)b, (void)sink;
    return false;
  }

  /// The blocks visit_implicit_pair_blocks passes, one at a time: how many it passes, and the k-th
  /// of them (the same value, in the same order), so that the multigrid can sum its coarse blocks
  /// in parallel, each coarse block gathering its own terms. 0: not offered (the blocks then go
  /// through the visit, serially).
  virtual Index implicit_pair_block_count() const { return 0; }
  virtual Mat3 implicit_pair_block(Index k, double b) const {
    (void)k, (void)b;
    return Mat3::Zero();
  }

  /// True when add_damping_forces adds anything; a scene whose forces all return false and that
  /// has no binding springs runs no linear solve at all.
  virtual bool has_damping() const { return false; }

  /// Largest step for which the explicit treatment of this elastic force stays stable, from the
  /// stiffest element and the lightest particle it touches (masses m, infinite for kinematic or
  /// zero for hard-bound rows, in which case effective masses m_eff are used). Returns +inf when
  /// the force imposes no restriction.
  virtual double stable_dt(const VectorXd& m_eff) const { (void)m_eff; return kInfinity; }
};

}  // namespace sinew
