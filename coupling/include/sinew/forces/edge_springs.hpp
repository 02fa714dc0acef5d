// Linear springs along mesh edges, with damping along the current edge direction.
#pragma once

#include "sinew/force.hpp"
#include "sinew/parallel.hpp"

#include <array>
#include <vector>

namespace sinew {

struct EdgeSpringsSettings {
  double stiffness = 1.0e3;  ///< k [N/m], the same for every edge; finite, >= 0
  double damping = 0.0;      ///< b [N s/m], along the current edge direction; finite, >= 0
};

/// Springs Psi = k/2 (l - l0)^2 on edges (i, j), with l0 taken from the rest positions.
class EdgeSprings final : public Force, public ImplicitBlocks {
 public:
  using Edge = std::array<Index, 2>;

  /// rest_x: 3 x N rest positions; edges index its columns. Throws sinew::Error naming the bad
  /// setting or edge (index out of range, repeated vertex, zero rest length).
  EdgeSprings(std::vector<Edge> edges, const Vectors3& rest_x, const EdgeSpringsSettings& settings = {});

  std::string_view name() const override { return "edge springs"; }
  void validate(Index particle_count) const override;
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.damping > 0.0; }
  bool has_definite_differentials() const override { return true; }
  void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const override;
  double stable_dt(const VectorXd& m_eff) const override;
  double turn_work_rate(const Vectors3& x, const Vectors3& v) const override;
  bool can_remove_elements() const override { return true; }
  Index remove_elements_touching(std::span<const std::uint8_t> removed) override;
  /// Every block: scalar and 3x3 diagonal, pair blocks one edge at a time.
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double b, VectorXd& diag) const override;
  bool add_diagonal_blocks(double b, Blocks& blocks) const override;
  bool visit_pair_blocks(double b, PairBlockSink& sink) const override;
  Index pair_block_count() const override { return static_cast<Index>(m_edges.size()); }
  Mat3 pair_block(Index k, double b) const override { return implicit_block(k, b); }

  const std::vector<Edge>& edges() const { return m_edges; }
  const VectorXd& rest_lengths() const { return m_rest_length; }
  const EdgeSpringsSettings& settings() const { return m_settings; }

 private:
  /// m_chunks.run of f_i = edge_force(e, edge) into end i and -f_i into end j, edge by edge.
  template <typename EdgeForce>
  void scatter_edges(Vectors3& f, EdgeForce&& edge_force) const;
  /// Edge e's implicit product matrix b_d d d^T + b k (d d^T + t+ (I - d d^T)) at the cached state.
  Mat3 implicit_block(Index e, double b) const;

  std::vector<Edge> m_edges;
  EdgeSpringsSettings m_settings;
  Vectors3 m_rest_x;         ///< the rest positions it was built from (remove_elements_touching rebuilds from them)
  VectorXd m_rest_length;    ///< l0 per edge
  VectorXd m_stiffness_sum;  ///< sum of k over the edges at each particle (stable_dt)
  Index m_index_span = 0;    ///< one past the largest particle index used
  // Position state (update_position_state): unit direction x_j - x_i and length per edge, and the
  // positions they were computed from (forces there reuse them).
  Vectors3 m_direction;
  VectorXd m_length;
  Vectors3 m_x;
  // The implicit products' per-edge data, refreshed with the position state so a CG iteration
  // divides nothing: columns 0-2 the unit direction d, column 3 the clamped transverse factor
  // t+ = max(0, 1 - l0/l), each contiguous over the edges (two edges per SIMD register).
  Eigen::Matrix<double, Eigen::Dynamic, 4> m_implicit_state;
  // Every per-edge loop scatters f_i, -f_i straight into the nodes by fixed chunks of edges
  // (deterministic on any thread count).
  ChunkedScatter m_chunks;
};

}  // namespace sinew
