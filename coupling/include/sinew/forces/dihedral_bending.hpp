// Discrete-shell bending on the dihedral angle of interior edges (hinges).
#pragma once

#include "sinew/force.hpp"
#include "sinew/parallel.hpp"

#include <array>
#include <vector>

namespace sinew {

struct DihedralBendingSettings {
  double stiffness = 1.0e-3;  ///< k_b [J] (N m); finite, >= 0
  double damping = 0.0;       ///< c [J s], damps the dihedral angle's rate; finite, >= 0
  /// Offer the definite differential K+ below, so that StepSettings::implicit_elasticity treats
  /// bending implicitly too. Off, bending stays explicit and its stable step limits the substep
  /// (cheaper per step: each CG iteration then skips the hinges). On, nothing limits the step, but
  /// the linearisation holds only while hinges turn little per step: the benchmark curtain (40 x 40)
  /// is stable at 1/48 s and gains energy at 1/24 s, 7.6 times the explicit stable step.
  bool implicit = false;
};

/// Psi = k_b * 3 |e0|^2 / (A1 + A2) * (theta - theta0)^2 per hinge (Grinspun et al. 2003), with
/// rest edge length |e0|, rest wing areas A1, A2 and rest angle theta0 (curved rest shapes allowed).
///
/// Definite differential (for StepSettings::implicit_elasticity): with g = d theta / dx (3 x 4) and
/// w = 3 |e0|^2 / (A1 + A2), the exact differential is -2 k_b w (g g^T + (theta - theta0) d^2 theta/dx^2);
/// K+ = -2 k_b w g g^T keeps the Gauss-Newton part, rank one per hinge and negative semi-definite, and
/// equals the exact differential wherever the hinge is at its rest angle. The dropped term is what
/// makes a bent hinge's exact differential indefinite.
///
/// Sign convention: with e = x1 - x0, n1 = e x (x2 - x0) (the normal of triangle (x0, x1, x2)) and
/// n2 = (x3 - x0) x e, theta = atan2((n1 x n2) . e / |e|, n1 . n2) in (-pi, pi]. theta = 0 when
/// flat; theta = a when the wing of x3 is rotated by a about e, right-handed; theta > 0 when x3
/// lies on the side of triangle 1 opposite to n1 (the sheet folds away from n1).
class DihedralBending final : public Force, public ImplicitBlocks {
 public:
  /// (x0, x1): shared edge; x2: opposite vertex in the first triangle; x3: in the second.
  using Hinge = std::array<Index, 4>;
  using Triangle = std::array<Index, 3>;

  /// Interior edges shared by exactly two triangles, sorted by (min, max) vertex of the edge. x0, x1
  /// follow the winding of the lower-numbered triangle, so n1 is that triangle's normal. Boundary
  /// edges yield no hinge; throws sinew::Error on an edge shared by more than two triangles or a
  /// triangle with a negative or repeated index.
  static std::vector<Hinge> hinges_from_triangles(const std::vector<Triangle>& triangles);

  /// The signed dihedral angle of the hinge (x0, x1, x2, x3), convention above.
  static double dihedral_angle(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3);

  /// rest_x: 3 x N rest positions, giving theta0, |e0| and the areas. Throws sinew::Error naming
  /// the bad setting or hinge (index out of range, repeated vertex, zero edge, degenerate wing).
  DihedralBending(std::vector<Hinge> hinges, const Vectors3& rest_x, const DihedralBendingSettings& settings = {});

  std::string_view name() const override { return "dihedral bending"; }
  void validate(Index particle_count) const override;
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.damping > 0.0; }
  bool has_definite_differentials() const override { return m_settings.implicit || m_offered; }
  bool can_offer_definite_differentials() const override { return true; }
  void offer_definite_differentials(bool offer) override { m_offered = offer; }
  void set_implicit(bool implicit) override { m_implicit = implicit; }
  void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const override;
  double stable_dt(const VectorXd& m_eff) const override;
  bool can_remove_elements() const override { return true; }
  Index remove_elements_touching(std::span<const std::uint8_t> removed) override;
  /// Every block: scalar and 3x3 diagonal, six pair blocks per hinge one at a time.
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double b, VectorXd& diag) const override;
  bool add_diagonal_blocks(double b, Blocks& blocks) const override;
  bool visit_pair_blocks(double b, PairBlockSink& sink) const override;
  Index pair_block_count() const override { return 6 * static_cast<Index>(m_hinges.size()); }
  Mat3 pair_block(Index k, double b) const override;

  const std::vector<Hinge>& hinges() const { return m_hinges; }
  const std::vector<double>& rest_angles() const { return m_rest_angle; }
  /// 3 |e0|^2 / (A1 + A2) per hinge (dimensionless).
  const std::vector<double>& weights() const { return m_weight; }
  const DihedralBendingSettings& settings() const { return m_settings; }

 private:
  std::vector<Hinge> m_hinges;
  DihedralBendingSettings m_settings;
  Vectors3 m_rest_x;  ///< the rest positions it was built from (remove_elements_touching rebuilds from them)
  std::vector<double> m_rest_angle;
  /// (cos theta0, sin theta0) per hinge up to a positive power of two, as the kinematics compute them.
  std::vector<std::array<double, 2>> m_rest_direction;
  std::vector<double> m_weight;
  std::vector<std::array<double, 4>> m_dt_weights;  ///< stable_dt weights w_{e,a}
  std::vector<Index> m_incidence_offsets;
  std::vector<Index> m_incidence;
  std::vector<Index> m_incidence_slot;                  ///< per incidence entry: 4 h + a, node i = hinge h's vertex a
  Eigen::Matrix<double, 9, Eigen::Dynamic> m_node_ggt;  ///< per node: sum over its hinges of w g_a g_a^T
  std::vector<double> m_delta;                          ///< theta - theta0 per hinge at the cached state
  bool m_grad_valid = false;                            ///< m_grad, m_delta, m_node_ggt hold the cached state's values
  // Position state: hinge vertex positions (for the differential) and d theta / dx (for damping).
  bool m_offered = false;              // offer_definite_differentials: implicit whatever m_settings says
  bool m_implicit = false;             // set_implicit: the angle gradients are needed even without damping
  Vectors3 m_x;                        // positions of the cached state (a plain copy: cheaper than per-hinge stencils)
  mutable ScatterGather<4> m_scatter;  // per-hinge forces on its four nodes, gathered per node
  ChunkedScatter m_chunks;             // the implicit products' fixed chunks of hinges
  std::vector<Eigen::Matrix<double, 3, 4>> m_grad;
  /// m_node_ggt from m_grad; sets m_grad_valid.
  void cache_node_gradients();
};

}  // namespace sinew
