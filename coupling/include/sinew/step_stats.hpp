// What one call to System::step or System::advance reports: per-phase timings, linear-solver work
// and the momentum bookkeeping of the force mapping.
#pragma once

#include "sinew/types.hpp"

namespace sinew {

/// Wall-clock milliseconds spent in each phase of the Newmark step (Sifakis et al. 2007, 3.3),
/// summed over substeps.
struct PhaseTimes {
  double implicit_half_velocity = 0;   ///< step 1, eq. 8 (forces, right-hand side and CG)
  double advance_positions = 0;        ///< step 2
  double process_collisions = 0;       ///< step 3 (sources, drift push-back, the spread's solves)
  double backward_euler_velocity = 0;  ///< step 4 (forces at x^{n+1/2}, right-hand side and CG)
  double extrapolate_velocity = 0;     ///< step 5
  double forces = 0;                   ///< of steps 1 and 4: force evaluation and right-hand side
  double cg = 0;                       ///< of steps 1 and 4: conjugate gradients (step 3's: in its own)
  double total = 0;

  PhaseTimes& operator+=(const PhaseTimes& o);
};

struct StepStats {
  int substeps = 0;
  double dt = 0;                ///< the substep used
  int cg_iterations_step1 = 0;  ///< summed over substeps
  int cg_iterations_step4 = 0;
  /// Of the solves that spread step 3's moves through the implicit forces (StepSettings::spread_collisions).
  int cg_iterations_step3 = 0;
  int newton_iterations = 0;  ///< StepSettings::newton_iterations done (their CG iterations count in step 1's)
  /// Step 1 solves repeated because a rigid body's turn over the step came out different from the one
  /// its points' arms were set from (StepSettings::rotation_iterations); their CG iterations count
  /// in step 1's.
  int rotation_iterations = 0;
  /// Step 1 solves repeated because the contacts between rigid bodies that hold changed (a held one
  /// pulled, a free one was crossed; JointRow::unilateral); their CG iterations count in step 1's.
  int contact_passes = 0;
  double cg_residual = 0;  ///< largest final residual [m/s] over all solves
  /// Every solve reached the tolerance, and every body's turn agreed with its arms to it.
  bool cg_converged = true;
  bool linear_solve = false;  ///< false when the scene has no implicit term (diagonal solve)
  /// Some step treated elasticity implicitly (StepSettings::implicit_elasticity, or System::advance's
  /// automatic choice).
  bool implicit_elasticity = false;
  /// dt * sum of the forces mapped onto soft-bound particles in step 4: the momentum the mapping adds
  /// to the system (section 3: soft particles duplicate mass, and the mapping duplicates momentum).
  Vec3 mapped_impulse = Vec3::Zero();
  /// The system slept through this call (System::advance): no step, no force, no solve.
  bool asleep = false;
  /// The collision sources' work in step 3 (CollisionSource::work), summed over substeps.
  double contact_work = 0;
  PhaseTimes ms;

  StepStats& operator+=(const StepStats& o);
};

}  // namespace sinew
