// Corotated linear elasticity on linear tetrahedra, robust to inversion.
#pragma once

#include "sinew/force.hpp"
#include "sinew/parallel.hpp"

#include <array>
#include <vector>

namespace sinew {

struct CorotatedTetsSettings {
  double young_modulus = 1.0e5;  ///< E [Pa]; finite, > 0
  double poisson_ratio = 0.3;    ///< nu, in (-1, 0.5)
  double beta = 0.0;             ///< stiffness-proportional (strain-rate) damping time [s]; finite, >= 0
  /// Per tet, the part of its volume that is material, in (0, 1]; empty: all of it. A lattice tet
  /// that a surface cuts (bcc_lattice) holds fill V_e of material: its energy, forces, differentials
  /// and damping are scaled by fill, as its lumped mass is, so the body is as stiff and as heavy as
  /// its material and the stable step is the whole tet's.
  std::vector<double> volume_fraction{};
  /// Offer the warped-stiffness differential K+ (below), so that StepSettings::implicit_elasticity
  /// treats the tets implicitly and their stable step stops limiting the substep. Off (the default),
  /// the tets stay explicit.
  bool implicit = false;
};

class CorotatedTets final : public Force, public ImplicitBlocks {
 public:
  using Tet = std::array<Index, 4>;

  /// rest_x: 3 x N rest positions; tets index its columns with positive orientation
  /// ((x1 - x0) x (x2 - x0)) . (x3 - x0) > 0. Throws sinew::Error naming the bad setting or tet
  /// (index out of range, repeated vertex, inverted or flat at rest).
  CorotatedTets(std::vector<Tet> tets, const Vectors3& rest_x, const CorotatedTetsSettings& settings = {});

  std::string_view name() const override { return "corotated tets"; }
  void validate(Index particle_count) const override;
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.beta > 0.0; }
  /// K+ is the warped stiffness: the linear elasticity of the rest state turned by each tet's R,
  ///   dP = R (2 mu sym(R^T dF) + lambda tr(R^T dF) I),   df = -V dP Dm^-T  (R held fixed),
  /// symmetric and negative semi-definite (the exact differential at rest, where R = I; away from it
  /// it leaves out R's own change). The damping D = beta K+ uses the same operator.
  bool has_definite_differentials() const override { return m_settings.implicit; }
  bool volumetric() const override { return true; }
  void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const override;
  double stable_dt(const VectorXd& m_eff) const override;
  bool can_remove_elements() const override { return true; }
  Index remove_elements_touching(std::span<const std::uint8_t> removed) override;
  /// The scalar diagonal of D + b K+ (b is 0 unless implicit): no 3x3 or pair blocks.
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double b, VectorXd& diag) const override;

  const std::vector<Tet>& tets() const { return m_tets; }
  /// Each tet's material volume at rest: its volume times its volume_fraction [m^3].
  const std::vector<double>& rest_volumes() const { return m_volume; }
  const CorotatedTetsSettings& settings() const { return m_settings; }
  double mu() const { return m_mu; }          ///< Lame shear modulus [Pa]
  double lambda() const { return m_lambda; }  ///< Lame first parameter [Pa]

 private:
  /// Signed SVD of F and what the differential and damping need from it.
  struct TetState {
    /// The deformation gradient the rest was computed from (NaN until the first update): a force or
    /// energy asked at positions giving the same F, bit for bit, reuses the SVD (same bits as redoing it).
    Mat3 F;
    Mat3 U;      ///< left rotation
    Mat3 V;      ///< right rotation
    Mat3 R;      ///< U V^T
    Vec3 sigma;  ///< signed singular values (the smallest negative when inverted)
    Vec3 phat;   ///< diagonal first Piola-Kirchhoff stress in the SVD frame
  };

  /// f += the tets' terms h_e = term(e) (vertex 0 gets -h_e's row sums, vertices 1-3 its columns),
  /// by the fixed chunks of m_chunks.
  template <typename TetTerm>
  void for_each_tet(Vectors3& f, TetTerm&& term) const;

  std::vector<Tet> m_tets;
  CorotatedTetsSettings m_settings;
  Vectors3 m_rest_x;  ///< the rest positions it was built from (remove_elements_touching rebuilds from them)
  double m_mu = 0.0;
  double m_lambda = 0.0;
  std::vector<Mat3> m_dm_inv;  ///< inverse of the rest edge matrix [x1-x0, x2-x0, x3-x0]
  std::vector<double> m_volume;
  std::vector<std::array<double, 4>> m_dt_weights;  ///< stable_dt weights w_{e,a}
  std::vector<Index> m_incidence_offsets;
  std::vector<Index> m_incidence;
  std::vector<TetState> m_state;
  ChunkedScatter m_chunks;  ///< the element loops' fixed chunks (parallel::ChunkedScatter)
};

}  // namespace sinew
