// The preconditioner of the Newmark step's implicit solves (internal to sinew::Newmark): block
// Jacobi (each particle's 3x3 diagonal block, each rigid body's 6x6 block with what its hard-bound
// points carry), optionally with the aggregation multigrid on the particles (multigrid.hpp).
#pragma once

#include "constraints.hpp"
#include "multigrid.hpp"
#include "step_model.hpp"

#include <vector>

namespace sinew {

class Preconditioner {
 public:
  void reset(const Unknowns& unknowns);
  /// Builds it for S = M - h W^T (D + beta K + beta_el K+) W at the forces' cached state; without
  /// `jacobi` the mass matrix alone (particles' m I, bodies' diag(m I, I)). body_I: world inertias.
  void build(const StepModel& model, const std::vector<Mat3>& body_I, const SolveCoefficients& k, bool jacobi);
  /// z = P^-1 r, then the constraints' projection.
  void apply(const GeneralizedVector& r, GeneralizedVector& z, const Constraints& constraints);
  /// r^T M^-1 r / M over the unknowns, M the mass matrix (particles' m I, bodies' diag(m I, I)) and M
  /// its dynamic total: since S - M is positive semidefinite, e^T M e <= e^T S e = r^T S^-1 r <= r^T
  /// M^-1 r for the error e = S^-1 r of a solve with residual r, so the root of this bounds the solve's
  /// mass-weighted RMS velocity error, whatever the preconditioner (CG's stop on it, cg_rms_tolerance).
  double mass_norm_squared(const GeneralizedVector& r) const;
  /// t = the uniform translation velocity (sum of r's linear components) / M on every unknown (bodies'
  /// linear twist parts), 0 elsewhere: added to a solve's answer it makes the answer's net linear
  /// momentum the system's where S moves a uniform translation as M does (translation-invariant forces).
  void net_translation(const GeneralizedVector& r, GeneralizedVector& t) const;
  bool uses_multigrid() const { return m_use_multigrid; }
  bool multigrid_built() const { return m_multigrid.built(); }

 private:
  void build_multigrid(const StepModel& model, double h, double beta_el);

  const Unknowns* m_unknowns = nullptr;
  std::vector<Mat6> m_body_preconditioner;
  std::vector<Mat6> m_body_mass_inverse;  // diag(m I, I)^-1 per dynamic body, 0 on kinematic ones
  double m_dynamic_mass = 0.0;            // the unknowns' total mass
  VectorXd m_diag;                        // scalar diagonal of forces without blocks
  DiagonalBlocks m_diag_blocks;           // 3x3 diagonal blocks, column-major
  DiagonalBlocks m_inverse_blocks;        // their inverses (with mass), 0 off the unknowns
  AggregationMultigrid m_multigrid;       // StepSettings::multigrid
  std::vector<AggregationMultigrid::PairBlockSource> m_pair_sources;  // build's scratch
  bool m_use_multigrid = false;                                       // this solve preconditions with the multigrid
};

/// The b a force's implicit terms are taken at: beta_el for elastic forces with a definite
/// differential (implicit elasticity), 0 (damping alone) for the others.
inline double implicit_b(const Force& f, double beta_el) { return f.has_definite_differentials() ? beta_el : 0.0; }

}  // namespace sinew
