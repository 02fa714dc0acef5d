// Aggregation multigrid for the particle block of the Newmark step's implicit system (internal to
// sinew::Newmark): a preconditioner whose cost per CG iteration does not grow with the resolution
// or the step, where block Jacobi's iteration count grows with both (as dt / dx for cloth).
//
// The operator is S = M - h (D + b K+) restricted to the particles with unknowns (free and soft
// rows; bound, kinematic and rigid rows are held at zero, so this is S's principal submatrix, which
// is symmetric positive definite whenever S is). The coarse levels hold assembled 3x3 blocks.
//
// Coarsening: unsmoothed aggregation by two rounds of pairwise matching per level (Notay 2010,
// "An aggregation-based algebraic multigrid method"), each node matched to its strongest unmatched
// neighbour (Frobenius norm of the coupling block), ties to the lowest index: aggregates of up to
// four nodes. Prolongation P is piecewise constant per aggregate (identity 3x3 blocks), so the
// Galerkin operator P^T S P is a sum of the fine blocks: an aggregate's diagonal block gathers its
// members' diagonal blocks and the couplings between them, and the block between two aggregates the
// couplings that cross. The aggregates are chosen once, from the first operator seen, and kept:
// the same scene gives the same hierarchy, and each update only re-sums blocks along a recorded
// plan (no search, no allocation).
//
// One application adds block Jacobi on the finest level to the coarse correction P B_1 P^T r, with
// B_1 a symmetric V-cycle on the assembled coarse levels (one damped block-Jacobi sweep before and
// after each coarse correction, damping 1.1 / lambda_max(D^-1 S) from power iterations, the coarsest
// level solved exactly by dense Cholesky). The finest level is not smoothed multiplicatively: its
// operator is the forces' own matrix-free products, and a multiplicative sweep there costs two of
// them per CG iteration; measured on the curtain, the additive form needs about 30% more
// iterations and half the time. Both parts are symmetric positive definite, so CG may use the sum
// as its preconditioner.
#pragma once

#include "sinew/implicit_blocks.hpp"
#include "sinew/types.hpp"

#include <Eigen/Cholesky>

#include <array>
#include <cstdint>
#include <vector>

namespace sinew {

class AggregationMultigrid final : public PairBlockSink {
 public:
  using Blocks = Eigen::Matrix<double, 9, Eigen::Dynamic>;
  /// The nodes of each aggregate, ascending (CSR): restriction gathers them per aggregate, in
  /// parallel and in the order a serial scatter would add them.
  struct Members {
    std::vector<Index> offset, index;
    void build(const std::vector<Index>& agg, Index aggregates);
  };
  /// For each block of a coarser level (diagonal blocks first, then pair blocks), the terms it
  /// receives along a plan (the plan's indices, ascending: the order a serial pass adds them in).
  struct Gather {
    Index diag_targets = 0;
    std::vector<Index> offset, term;
    void build(const std::vector<Index>& plan, Index diag_targets, Index pair_targets);
  };

  /// The coarsest level has at most this many nodes (a dense Cholesky of 3 n unknowns).
  static constexpr Index kCoarsestNodes = 48;
  /// A coarsest level larger than this (coarsening stalled) is smoothed, not factored.
  static constexpr Index kMaxDenseNodes = 256;
  /// Weight of block Jacobi on the finest level, beside the coarse correction (measured on the
  /// benchmark curtain: 0.6 needs 5-10% fewer iterations than 1 or 0.33 at 40 x 40 and 150 x 150).
  static constexpr double kOmega0 = 0.6;
  static constexpr int kMaxLevels = 16;

  /// Forgets the hierarchy: the particles, their kinds or the forces changed.
  void reset();
  bool built() const { return m_built && !m_awaiting_level1; }
  /// Levels including the finest (1 before the first update).
  int levels() const { return 1 + static_cast<int>(m_levels.size()); }
  /// Nodes on level l (0: the unknown particles).
  Index level_size(int l) const;

  /// Starts an update of the coarse operators. unknown (N): 1 on rows with unknowns, else 0; diag
  /// (9 x N, column-major 3x3): S's diagonal blocks, mass included; scale multiplies every pair block
  /// the forces pass (S = M - h F, so -h).
  void begin(const VectorXd& unknown, const Blocks& diag, double scale);
  /// The forces pass their pair blocks (D + b K+)_ij here, between begin() and end().
  void add(Index i, Index j, const Mat3& block) override;
  /// A force's pair blocks that reach level 1, with the b they are taken at.
  struct PairBlockSource {
    const ImplicitBlocks* blocks = nullptr;
    double b = 0.0;
  };
  /// Instead of the add() calls, between begin() and end(): every level-1 block gathers its terms
  /// from the forces' ImplicitBlocks::pair_block, in parallel, in the order add() would have received them
  /// (the same sums, bit for bit, on any thread count). sources: the forces that passed pair blocks
  /// when the hierarchy was built, in that order. Returns false, having done nothing, before the
  /// hierarchy exists or when the sources' block counts do not add up to its plan (a force that
  /// does not offer its blocks one at a time); the forces then pass them through add().
  bool gather(const std::vector<PairBlockSource>& sources);
  /// Finishes the update: sums every level's blocks, inverts the smoother's diagonal blocks and
  /// factors the coarsest level. The first update only records the pairs and their strengths and
  /// chooses level 1's aggregates from them; the forces then pass the same blocks once more
  /// (begin(), gather() or add(), end(): needs_blocks_again()) and level 1, summed from them,
  /// chooses the coarser levels. Two passes instead of storing every block of the first: at
  /// 150 x 150, 330 000 blocks, 24 MB.
  void end();
  bool needs_blocks_again() const { return m_awaiting_level1; }
  /// Room for this many pairs in the first update's record (a hint; no effect later).
  void reserve(std::size_t pairs);

  /// z = B r = omega0 D^-1 r + P (V-cycle on the coarse levels) P^T r. r, z: 3 x N; z is zero off
  /// the unknowns. inverse0 (9 x N): the inverse diagonal blocks of S on the unknowns (zero
  /// elsewhere), i.e. block Jacobi, to which the coarse correction is added.
  void apply(const Vectors3& r, Vectors3& z, const Blocks& inverse0);

 private:
  struct Level {
    Index n = 0;
    Blocks diag, inverse;                     // 9 x n
    std::vector<std::array<Index, 2>> pairs;  // i < j
    Blocks pair_block;                        // 9 x pairs: S_ij for i < j
    // Matvec rows: row i's entries (column, pair) are [row_offset[i], row_mid[i]) with the pair's block
    // as stored (i < j), then [row_mid[i], row_offset[i+1]) with its transpose (i > j).
    std::vector<Index> row_offset, row_mid, row_col, row_pair;
    // To the next level (empty on the coarsest): aggregate of each node, and where each pair's block
    // goes there (plan code, see encode_*).
    std::vector<Index> agg;
    Members members;  // agg's inverse
    std::vector<Index> pair_plan;
    Gather gather;       // pair_plan's, for the next level
    Vectors3 x, b, t;    // solution, right-hand side, scratch (3 x n)
    double omega = 0.5;  // Jacobi damping of the smoother (estimate_omegas)
  };

  static Index encode_diag(Index a) { return -2 - a; }
  static Index encode_pair(Index p, bool transposed) { return 2 * p + (transposed ? 1 : 0); }
  static constexpr Index kSkip = -1;

  void plan_level1(const VectorXd& unknown);  // the first update's end()
  void build_coarser_levels();                // the second pass's end()
  /// Two rounds of pairwise matching on the graph (pairs with strengths) of n nodes: the aggregate of
  /// each node; returns the aggregate count.
  static Index aggregate(Index n, const std::vector<std::array<Index, 2>>& pairs, const std::vector<double>& strength,
                         std::vector<Index>& agg);
  /// The next level's pair list from this level's pairs under agg, and each pair's plan code.
  static void coarse_pairs(const std::vector<std::array<Index, 2>>& pairs, const std::vector<Index>& agg,
                           std::vector<std::array<Index, 2>>& coarse, std::vector<Index>& plan);
  static void build_rows(Level& level);
  static void allocate(Level& level);  // storage for a level whose n and pairs are set
  void add_to_level1(Index code, const Mat3& block);
  void assemble_next(int l);  // m_levels[l] -> m_levels[l + 1]
  void invert_diagonals(Level& level) const;
  void matvec(const Level& level, const Vectors3& x, Vectors3& y) const;
  void cycle(int l);
  void estimate_omegas();  // solves m_levels[l].b approximately into m_levels[l].x

  bool m_built = false;
  bool m_omega_ready = false;
  bool m_dense_coarsest = true;    // the coarsest level is factored (else one Jacobi sweep)
  bool m_recording = false;        // the first update: pairs and strengths are stored, no plan yet
  bool m_awaiting_level1 = false;  // level 1 planned; its blocks (the second pass) choose the rest
  double m_scale = 0.0;
  Index m_particles = 0;
  std::vector<Index> m_agg0;  // particle -> level-1 node, -1 off the unknowns
  Members m_members0;
  std::vector<Index> m_plan0;        // per pair the forces pass: plan code on level 1
  Gather m_gather0;                  // m_plan0's (built with the hierarchy)
  std::vector<Index> m_source_base;  // gather(): first block of each source (scratch)
  std::size_t m_cursor = 0;
  std::vector<std::array<Index, 2>> m_recorded_pairs;  // first update only
  std::vector<double> m_recorded_strength;             // each recorded block's Frobenius norm
  VectorXd m_unknown0;                                 // the first update's unknown rows (for the build)
  std::vector<Level> m_levels;                         // levels 1 .. L-1
  Eigen::MatrixXd m_dense;                             // the coarsest level, assembled
  Eigen::LLT<Eigen::MatrixXd> m_coarsest;              // its storage is sized by the first compute() (in the build)
  Eigen::VectorXd m_dense_rhs;
};

}  // namespace sinew
