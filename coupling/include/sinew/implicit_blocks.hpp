// What a preconditioner may ask a force for, beside the products every force computes: the blocks
// of its implicit matrix D + b K+ (damping D, definite differential K+, both symmetric negative
// semi-definite; Sifakis et al. 2007, eq. 6-8 for the implicit velocity solves they enter).
//
// A force offers this through Force::implicit_blocks() (nullptr by default). What the step does
// without it, part by part:
//   - no ImplicitBlocks at all: the force adds nothing to the preconditioner's diagonal (the mass
//     and the other forces' blocks still precondition; CG converges, more slowly);
//   - add_diagonal only: the Jacobi block of each particle gets a third of the trace times I;
//   - no pair blocks: the force's couplings reach only the finest level of the multigrid;
//   - pair blocks without single access (pair_block_count() == 0): the multigrid takes them through
//     the visit, serially, instead of gathering them in parallel.
#pragma once

#include "sinew/types.hpp"

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

/// The blocks of a force's implicit matrix D + b K+ at the cached position state. b is the factor of
/// K+ (0 for a force without definite differentials: its matrix is then D alone).
class ImplicitBlocks {
 public:
  using Blocks = Eigen::Matrix<double, 9, Eigen::Dynamic>;

  /// diag(i) += a third of the trace of -(D_ii + b K+_ii), particle i's 3x3 diagonal block (the
  /// scalar Jacobi preconditioner). diag has one entry per particle.
  virtual void add_diagonal(double b, VectorXd& diag) const = 0;

  /// blocks.col(i) += -(D_ii + b K+_ii), the 3x3 diagonal blocks (column-major, 9 x N), for the
  /// block-Jacobi preconditioner. Returns false, having added nothing, when the force does not
  /// offer them (the preconditioner then uses add_diagonal times I).
  virtual bool add_diagonal_blocks(double b, Blocks& blocks) const {
    (void)b, (void)blocks;
    return false;
  }

  /// Passes every off-diagonal block of D + b K+ (exactly the couplings Force::add_implicit_products
  /// applies) to `sink`, always in the same order and always every pair, even where the block is
  /// zero (the multigrid records the sequence once). Returns false when not offered.
  virtual bool visit_pair_blocks(double b, PairBlockSink& sink) const {
    (void)b, (void)sink;
    return false;
  }

  /// The blocks visit_pair_blocks passes, one at a time: how many it passes, and the k-th of them
  /// (the same value, in the same order), so that the multigrid can sum its coarse blocks in
  /// parallel, each coarse block gathering its own terms. 0: not offered.
  virtual Index pair_block_count() const { return 0; }
  virtual Mat3 pair_block(Index k, double b) const {
    (void)k, (void)b;
    return Mat3::Zero();
  }

 protected:
  ~ImplicitBlocks() = default;
};

}  // namespace sinew
