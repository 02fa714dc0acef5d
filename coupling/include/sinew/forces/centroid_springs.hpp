// Springs from particles to the centroids of their neighbourhoods: elements of varying size.
#pragma once

#include "sinew/force.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/parallel.hpp"

#include <vector>

namespace sinew {

/// An edge spring's two settings: k [N/m] for every element, b [N s/m] along the current spring
/// direction.
using CentroidSpringsSettings = EdgeSpringsSettings;

/// Element e ties its first node p to the centroid c of the others (its neighbourhood N, any size
/// from 1): Psi = k/2 (|x_p - c| - l0)^2, l0 from the rest positions. The stencils are compressed
/// rows (Stencils), as a meshfree particle's neighbourhood of 30-60 nodes or a contact's 2-4 are.
/// With one neighbour it is an edge spring.
class CentroidSprings final : public Force, public ImplicitBlocks {
 public:
  /// stencils: per element the particle, then its neighbourhood; rest_x: 3 x N rest positions.
  /// Throws sinew::Error naming the bad setting or element (fewer than two nodes, index out of
  /// range, repeated node, zero rest length).
  CentroidSprings(Stencils stencils, const Vectors3& rest_x, const CentroidSpringsSettings& settings = {});

  std::string_view name() const override { return "centroid springs"; }
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
  bool can_remove_elements() const override { return true; }
  Index remove_elements_touching(std::span<const std::uint8_t> removed) override;
  /// Every block: scalar and 3x3 diagonal, each element's node pairs one at a time.
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double b, VectorXd& diag) const override;
  bool add_diagonal_blocks(double b, Blocks& blocks) const override;
  bool visit_pair_blocks(double b, PairBlockSink& sink) const override;
  Index pair_block_count() const override { return m_pair_offset.back(); }
  Mat3 pair_block(Index k, double b) const override;

  const Stencils& stencils() const { return m_stencils; }
  const VectorXd& rest_lengths() const { return m_rest_length; }

 private:
  /// Node a's weight in element e's d = x_p - c: 1 for the particle, -1/|N| for a neighbour.
  double weight(Index e, std::size_t a) const;
  /// d = sum_a w_a y_a over element e's nodes, in stencil order.
  Vec3 weighted_sum(Index e, const Vectors3& y) const;
  /// m_chunks.run of -w_a g into node a, g = element_term(e) per element.
  template <typename ElementTerm>
  void scatter(Vectors3& f, ElementTerm&& element_term) const;
  /// Element e's matrix B = b_d u u^T + b k (u u^T + t+ (I - u u^T)) at the cached state: its
  /// implicit products are f_a = -w_a B sum_c w_c v_c, its blocks -(D + b K+)_ac = w_a w_c B.
  Mat3 element_block(Index e, double b) const;

  Stencils m_stencils;
  CentroidSpringsSettings m_settings;
  Vectors3 m_rest_x;       ///< the rest positions it was built from (remove_elements_touching rebuilds from them)
  VectorXd m_rest_length;  ///< l0 per element
  VectorXd m_weight_sum;   ///< per particle: sum of |w| over its elements (stable_dt)
  std::vector<Index> m_pair_offset;  ///< element e's node pairs are blocks [m_pair_offset[e], m_pair_offset[e + 1])
  Index m_index_span = 0;            ///< one past the largest particle index used
  // Position state: unit direction u of d, |d|, clamped transverse factor t+ = max(0, 1 - l0/l).
  Vectors3 m_direction;
  VectorXd m_length, m_transverse;
  ChunkedScatter m_chunks;
};

}  // namespace sinew
