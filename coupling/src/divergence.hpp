// Early divergence detection for the Newmark step (internal to sinew::Newmark).
//
// A blow-up shows as a non-finite value only once it overflows, tens to thousands of steps after it
// starts (an explicit cloth at three times its stable step grows about fifteenfold a step). This
// check stops it within a few steps, naming the particle or body, against a bound from the scene:
// an energy budget.
//
// The budget E_b is the scene's energy at the first step (kinetic + elastic, binding springs
// included) plus, step by step, the work its inputs can do:
//   - gravity, signed (it is a potential);
//   - the applied forces and torques on the bodies, along the step's displacement and turn;
//   - the kinematic particles and bodies, moving against the forces on them (step 4's);
//   - kinetic energy the collision sources add in step 3;
//   - energy the caller adds between steps: kinetic (a rigid solver's new velocities, an impulse)
//     and the binding springs' (a spring switched on or moved to new ends, as a viewer's mouse
//     spring is), and the elastic forces' where the caller moved positions (a teleported body
//     carrying part of a cloth; one pass over the positions finds it, and only then are the forces
//     evaluated).
// All but gravity count in absolute value, so the budget overestimates. The implicit terms between
// a kinematic parent and its neighbours (damping, the implicit part of a binding spring) are not in
// step 4's forces; for them each item may also have the kinetic energy of moving as fast as the
// fastest kinematic point (a cloth dragged at speed V reaches about V).
//
// A step diverges when one item's kinetic energy exceeds StepSettings::divergence_factor times
//   max_k E_b(t_k) + 1/2 m V_kin^2 (+ 1/2 tr(I) W_kin^2 for a body),
// V_kin, W_kin the largest kinematic point speed and angular velocity, and max_k the largest budget
// so far: with gravity signed, a pendulum's budget is its kinetic energy, near zero at the top of
// each swing, where integration error alone would exceed it. A budget of zero (a scene at rest
// without gravity) would fire on round-off, so the budget is at least 1/2 M (1e-3 L / dt)^2, M the
// dynamic mass: a speed that crosses a thousandth of the scene's extent L each step.
//
// Rejected: "the energy must not grow" fires on every active scene; a test on the growth rate of the
// velocities alone fires on transients from rest (a stiff spring released: its velocity change
// doubles in the second step) unless given a floor, which is this budget again, and misses a
// growth of a few percent a step. An instability grows geometrically, so a generous factor costs a
// delay of only log(factor) / log(growth per step) steps.
#pragma once

#include "step_model.hpp"

#include <string>

namespace sinew {

/// What the step leaves for the check to read: the state at t^n and the step's forces.
struct StepRecord {
  const Unknowns& unknowns;
  const Vectors3& x_n;        ///< particle positions at t^n (3 x N)
  const Vectors3& v_n;        ///< particle velocities at t^n (3 x N)
  const Vectors3& v_tilde_n;  ///< step 3's velocities v~^n (3 x N)
  const Vectors3& f;          ///< step 4's forces, kinematic rows included (3 x N)
  const Vectors6& wrench;     ///< step 4's wrenches on the bodies, kinematic ones included (6 x R)
  const Vectors3& body_x_n;   ///< centres of mass at t^n (3 x R)
  const Vectors3& body_L_n;   ///< angular momenta at t^n, 0 on kinematic bodies (3 x R)
  const Vectors3& turn;       ///< each body's turn over the step (3 x R)
};

class DivergenceCheck {
 public:
  /// At the step's start (after save_state): the scene's energy on the first step, else the kinetic
  /// energy the caller added since the last step. Reads only.
  void begin_step(const StepModel& s, const StepRecord& r, double dt);
  /// At the step's end: throws sinew::Error naming the item whose kinetic energy exceeds the bound,
  /// and the force largest on it (evaluated into the scratch buffers, 3 x N and 6 x R). Keeps the
  /// budget for the next step only when it does not throw.
  void end_step(const StepModel& s, const StepRecord& r, long step, Vectors3& scratch, Vectors6& scratch_wrench);

 private:
  bool m_started = false;
  double m_budget = 0.0;         // E_b after the last accepted step [J]
  double m_peak = 0.0;           // the largest E_b so far, what the items are allowed [J]
  double m_pending = 0.0;        // E_b at this step's start (with what the caller added)
  double m_end_kinetic = 0.0;    // kinetic energy at the end of the last accepted step [J]
  double m_start_kinetic = 0.0;  // this step's, at its start
  double m_end_springs = 0.0;    // the binding springs' energy at the end of the last accepted step [J]
  double m_start_springs = 0.0;  // and at this step's start
  double m_injected = 0.0;       // energy the caller added between the last step and this one [J]
  double m_energy_floor = 0.0;   // 1/2 M (1e-3 L / dt)^2 for this step
  Vectors3 m_end_x;              // particle positions at the end of the last accepted step
};

/// Kinetic energy of the dynamic particles (velocities v, 3 x N) and bodies (velocities in s,
/// angular momenta L, 3 x R).
double kinetic_energy(const StepModel& s, const Unknowns& u, const Vectors3& v, const Vectors3& L);

/// "; force 'name' gives non-finite forces ..." for the first force (or the binding springs) whose
/// elastic forces at the finite positions x (3 x N), or implicit products (with the coefficients k)
/// of the finite velocities v, are not finite; else an empty string. Finds a NaN or infinite
/// coefficient that nothing validated (a user's force, a parameter changed between steps). scratch
/// is 3 x N.
std::string non_finite_culprit(const StepModel& s, const Vectors3& x, const Vectors3& v, const SolveCoefficients& k,
                               Vectors3& scratch);

}  // namespace sinew
