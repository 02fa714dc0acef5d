#include "sinew/system.hpp"

#include <cmath>

namespace sinew {

void validate(const StepSettings& s) {
  // Each setting is checked by name, so that a caller who set one wrongly reads which and why.
  if (!(std::isfinite(s.cg_tolerance) && s.cg_tolerance > 0.0))
    fail("step settings: cg_tolerance = ", s.cg_tolerance, ", must be positive and finite");
  if (s.cg_max_iterations < 1) fail("step settings: cg_max_iterations = ", s.cg_max_iterations, ", must be >= 1");
  if (s.newton_iterations < 0) fail("step settings: newton_iterations = ", s.newton_iterations, ", must be >= 0");
  if (s.threads < 0) fail("step settings: threads = ", s.threads, ", must be >= 0 (0: every hardware thread)");
  // Above 1 the substep exceeds the explicit forces' stable step: advance() would diverge by design.
  if (!(s.cfl > 0.0 && s.cfl <= 1.0)) fail("step settings: cfl = ", s.cfl, ", must be in (0, 1]");
  if (s.max_substeps < 1) fail("step settings: max_substeps = ", s.max_substeps, ", must be >= 1");
  if (!(s.max_rotation_per_step > 0.0))
    fail("step settings: max_rotation_per_step = ", s.max_rotation_per_step, ", must be positive (or infinite)");
  if (s.rotation_iterations < 1) fail("step settings: rotation_iterations = ", s.rotation_iterations, ", must be >= 1");
  if (!(std::isfinite(s.turn_work_per_implicit_step) && s.turn_work_per_implicit_step > 0.0))
    fail("step settings: turn_work_per_implicit_step = ", s.turn_work_per_implicit_step,
         ", must be positive and finite");
  if (!(std::isfinite(s.cg_rms_tolerance) && s.cg_rms_tolerance >= 0.0))
    fail("step settings: cg_rms_tolerance = ", s.cg_rms_tolerance, ", must be >= 0 and finite (0: off)");
  if (!(std::isfinite(s.relative_tolerance) && s.relative_tolerance >= 0.0))
    fail("step settings: relative_tolerance = ", s.relative_tolerance, ", must be >= 0 and finite (0: cg_tolerance)");
  if (!(s.divergence_factor >= 0.0))
    fail("step settings: divergence_factor = ", s.divergence_factor, ", must be >= 0 (0: no divergence check)");
  if (!(std::isfinite(s.sleep_speed) && s.sleep_speed >= 0.0))
    fail("step settings: sleep_speed = ", s.sleep_speed, ", must be non-negative and finite");
  if (!(std::isfinite(s.sleep_time) && s.sleep_time > 0.0))
    fail("step settings: sleep_time = ", s.sleep_time, ", must be positive and finite");
  if (s.multigrid && !s.jacobi_preconditioner)
    fail("step settings: multigrid needs jacobi_preconditioner (block Jacobi is its finest level)");
}

}  // namespace sinew
