// sinew running the benchmark curtain: the cloth of add_cloth_grid hard-bound (W, no DOFs of its own)
// (or, with SinewSettings::binding_spring_stiffness, tied by binding springs)
// to the rings of RodAndRings in a btDiscreteDynamicsWorld, coupled by sinew::bullet::Coupling
// (Sifakis et al. 2007, section 5). Bullet integrates the rings and their slider constraints; sinew's
// Newmark step runs once per Bullet tick, substepped when the tick exceeds the explicit forces'
// stable step.
#pragma once

#include "curtain_bench.hpp"

#include "sinew/step_stats.hpp"
#include "sinew/system.hpp"

#include <memory>

namespace sinew::bench {

struct SinewSettings {
  /// Edge springs enter both velocity solves implicitly (StepSettings::implicit_elasticity): no
  /// stable-step limit from them, first-order accurate in their stiff modes.
  bool implicit_elasticity = false;
  /// StepSettings::multigrid: the aggregation multigrid preconditioner (with implicit elasticity).
  bool multigrid = false;
  double cg_tolerance = 1e-9;  ///< StepSettings::cg_tolerance [m/s]
  double cfl = 0.9;            ///< StepSettings::cfl
  int threads = 1;             ///< StepSettings::threads (bit-identical for any count)
  int newton_iterations = 0;   ///< StepSettings::newton_iterations (with implicit elasticity)
  /// 0: the bound nodes are hard-bound to their rings (W, no DOFs of their own). Positive: they stay
  /// free particles tied to their pivots by zero-rest-length binding springs of this stiffness
  /// (Coupling::attach, implicit in the step, eq. 5) [N/m].
  double binding_spring_stiffness = 0.0;
  double binding_spring_damping_ratio = 1.0;  ///< of critical, for binding springs
};

/// "sinew", "sinew-implicit" with implicit elasticity, "sinew-implicit-bending" with bending implicit
/// too (CurtainSpec::bending_implicit), or "sinew-multigrid" with the multigrid as well.
class SinewCurtainRun : public CurtainRun {
 public:
  /// Per-phase timings, substeps and CG iterations summed over every tick since construction.
  virtual const StepStats& total_stats() const = 0;
  /// The coupling's deformable system (sinew-schemes sets its step settings between runs).
  virtual System& deformable_system() = 0;
};

std::unique_ptr<SinewCurtainRun> make_sinew_curtain(const CurtainSpec& spec, const SinewSettings& settings = {});

}  // namespace sinew::bench
