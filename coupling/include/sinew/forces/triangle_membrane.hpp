// St. Venant-Kirchhoff membrane on triangles (cloth in-plane stretch and shear).
#pragma once

#include "sinew/force.hpp"

#include <array>
#include <vector>

namespace sinew {

/// Surface Lame parameters of the sheet, per unit rest area (N/m). For a sheet of Young's modulus
/// E [Pa], thickness h [m] and Poisson ratio nu, plane stress gives
///   mu = E h / (2 (1 + nu)),   lambda = E h nu / (1 - nu^2).
struct TriangleMembraneSettings {
  double mu = 1.0e3;      ///< shear modulus x thickness [N/m]; finite, >= 0
  double lambda = 1.0e3;  ///< first Lame parameter x thickness [N/m]; finite, >= -mu (2D bulk >= 0)
  double beta = 0.0;      ///< stiffness-proportional (strain-rate) damping time [s]; finite, >= 0
};

class TriangleMembrane final : public Force, public ImplicitBlocks {
 public:
  using Triangle = std::array<Index, 3>;

  /// rest_x: 3 x N rest positions; triangles index its columns (any winding). Throws sinew::Error
  /// naming the bad setting or triangle (index out of range, repeated vertex, degenerate).
  TriangleMembrane(std::vector<Triangle> triangles, const Vectors3& rest_x,
                   const TriangleMembraneSettings& settings = {});

  std::string_view name() const override { return "triangle membrane"; }
  void validate(Index particle_count) const override;
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.beta > 0.0; }
  double stable_dt(const VectorXd& m_eff) const override;
  bool can_remove_elements() const override { return true; }
  Index remove_elements_touching(std::span<const std::uint8_t> removed) override;
  /// The scalar diagonal of D only (no definite differential, so b is 0): no 3x3 or pair blocks.
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double b, VectorXd& diag) const override;

  const std::vector<Triangle>& triangles() const { return m_triangles; }
  const std::vector<double>& rest_areas() const { return m_area; }
  const TriangleMembraneSettings& settings() const { return m_settings; }

 private:
  std::vector<Triangle> m_triangles;
  TriangleMembraneSettings m_settings;
  Vectors3 m_rest_x;  ///< the rest positions it was built from (remove_elements_touching rebuilds from them)
  // Rest data: inverse of the 2x2 rest edge matrix in the triangle's own frame, and rest area.
  std::vector<Eigen::Matrix2d> m_dm_inv;
  std::vector<double> m_area;
  std::vector<std::array<double, 3>> m_dt_weights;  ///< stable_dt weights w_{e,a}
  std::vector<Index> m_incidence_offsets;
  std::vector<Index> m_incidence;
  // Position state: deformation gradient F (3x2) per triangle.
  std::vector<Eigen::Matrix<double, 3, 2>> m_F;
};

}  // namespace sinew
