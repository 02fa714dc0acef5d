#include "newmark.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>

#include <chrono>
#include <string>

namespace sinew {

namespace {
using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}
}  // namespace

void Newmark::allocate(const StepModel& s) {
  m_unknowns.build(s.particles, s.bodies);
  const Index n = m_unknowns.n, r = m_unknowns.r;
  m_constraints.reset(m_unknowns);
  m_preconditioner.reset(m_unknowns);
  m_system.reset();
  m_cg.resize(n, r);
  for (Vectors3* a : {&m_x_n, &m_v_n, &m_x_np1, &m_v_tilde_n, &m_v_half, &m_f, &m_g, &m_bound_force}) a->setZero(3, n);
  m_wrench.setZero(6, r);
  m_scratch_wrench.setZero(6, r);
  m_twist_half.setZero(6, r);
  for (Vectors3* a : {&m_body_x_n, &m_body_v_n, &m_body_w_n, &m_body_L_n, &m_body_x_np1}) a->setZero(3, r);
  m_body_q_n.assign(static_cast<std::size_t>(r), Quat::Identity());
  m_body_q_np1 = m_body_q_n;
  m_body_I.assign(static_cast<std::size_t>(r), Mat3::Zero());
  m_body_I_n = m_body_I;
  m_arm_maps.assign(static_cast<std::size_t>(r), Mat3::Identity());
  m_angular_maps = m_arm_maps;
  m_turn.setZero(3, r);
  for (Vectors3* a : {&m_mix_x, &m_mix_g, &m_mix_next}) a->setZero(3, r);
  m_w_lin.setZero(3, r);
  m_u.setZero(3, n);
  m_bound_offset.setZero(3, n);
  m_has_bound_offset = false;
  // A body's radius of gyration: where a change of its inertia shows as a velocity.
  m_body_gyration.setZero(r);
  for (Index b = 0; b < r; ++b)
    if (m_unknowns.dynamic_body[b])
      m_body_gyration[b] = std::sqrt(s.bodies.inertia.col(b).maxCoeff() / s.bodies.mass[b]);
  for (GeneralizedVector* g :
       {&m_c, &m_y, &m_product, &m_product0, &m_guess, &m_last_half, &m_lin, &m_saved_half, &m_spread, &m_spread_rhs})
    g->resize(n, r);
  m_geometric.assign(static_cast<std::size_t>(r), Mat3::Zero());
  m_last_dt = 0.0;
  m_guess_trial = 0;
  m_extrapolate = false;
  m_preconditioner_key = {};
  m_has_damping = false;
  for (const auto& f : s.forces) m_has_damping = m_has_damping || f->has_damping();
  m_allocated = true;
}

// Section 3.3, steps 1-5. Positions and velocities in s are at t^n on entry and t^{n+1} on exit.
StepStats Newmark::step(const StepModel& s, double dt) {
  if (!m_allocated) allocate(s);
  const auto start = Clock::now();
  m_implicit_elasticity = false;  // the setting may change between steps
  m_implicit_solid = false;
  for (const auto& f : s.forces) {
    const bool implicit = s.settings.implicit_elasticity && f->has_definite_differentials();
    f->set_implicit(implicit);
    m_implicit_elasticity = m_implicit_elasticity || implicit;
    m_implicit_solid = m_implicit_solid || (implicit && f->volumetric());
  }
  StepStats stats;
  stats.substeps = 1;
  stats.dt = dt;
  m_dt = dt;
  check_finite(s, "the state at the step's start", false);
  save_state(s);
  // A step that throws (a non-finite value, divergence, a bad collision constraint, a stalled solve)
  // leaves the state of its start, so the caller can change what diverged and step again.
  try {
    m_divergence.begin_step(s, record(), dt);
    predict_contacts(s, dt);
    prepare_rows(s, dt, true);

    auto t = Clock::now();
    implicit_half_velocity(s, dt, stats);
    for (int pass = 1; pass < kContactPasses && revise_contacts(s, dt); ++pass) {
      ++stats.contact_passes;
      implicit_half_velocity(s, dt, stats);
    }
    check_finite(s, "step 1 (implicit half velocity)");
    stats.ms.implicit_half_velocity = ms_since(t);

    t = Clock::now();
    advance_positions(s, dt);
    check_finite(s, "step 2 (advance positions)");
    stats.ms.advance_positions = ms_since(t);

    t = Clock::now();
    process_collisions(s, dt, stats);
    for (const auto& source : s.collision_sources) stats.contact_work += source->work();
    check_finite(s, "step 3 (process collisions)");
    stats.ms.process_collisions = ms_since(t);

    t = Clock::now();
    backward_euler_velocity(s, dt, stats);
    check_finite(s, "step 4 (backward Euler velocity)");
    stats.ms.backward_euler_velocity = ms_since(t);

    t = Clock::now();
    extrapolate_velocity(s);
    check_finite(s, "step 5 (extrapolate velocity)");
    stats.ms.extrapolate_velocity = ms_since(t);

    // Divergence: some item's kinetic energy far above the scene's energy budget (divergence.hpp).
    m_divergence.end_step(s, record(), m_step_count, m_g, m_scratch_wrench);
    advance_contact_gaps(s, dt);
  } catch (...) {
    restore_start_state(s);
    throw;
  }
  stats.ms.total = ms_since(start);
  ++m_step_count;
  return stats;
}

// Bound rows are derived state: recompute them from parents that the caller (or a rigid solver
// writing into the rigid-body particles) may have moved since the last step.
void Newmark::save_state(const StepModel& s) {
  s.hard.update_rigid_offsets(s.bodies);
  s.hard.clamp_positions(s.particles.x, s.bodies.x);
  s.hard.clamp_velocities(s.particles.v, s.bodies.v, s.bodies.w);
  s.soft.synchronize(s.particles, true, true);
  m_r_n.resize(static_cast<std::size_t>(s.hard.rigid_count()));
  for (Index k = 0; k < s.hard.rigid_count(); ++k) m_r_n[k] = s.hard.rigid_offset_world(k);
  m_x_n = s.particles.x;
  m_v_n = s.particles.v;
  auto& bodies = s.bodies;
  for (Index b = 0; b < m_unknowns.r; ++b)
    if (!(bodies.force.col(b).allFinite() && bodies.torque.col(b).allFinite()))
      fail("rigid body ", b, ": applied force (", bodies.force.col(b).transpose(), ") or torque (",
           bodies.torque.col(b).transpose(), ") is not finite");
  m_body_x_n = bodies.x;
  m_body_v_n = bodies.v;
  m_body_w_n = bodies.w;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    m_body_q_n[b] = bodies.q[b];
    m_body_L_n.col(b) = m_unknowns.dynamic_body[b] ? bodies.angular_momentum(b) : Vec3::Zero();
  }
}

void Newmark::update_body_inertias(const StepModel& s) {
  for (Index b = 0; b < m_unknowns.r; ++b) m_body_I[b] = s.bodies.world_inertia(b);
}

// Step 1 (eq. 8): (M + dt/2 D + dt^2/4 K) v~^{n+1/2} = M v^n + dt/2 (F_el(x^n) + F_ext - K x^n),
// implicit in all damping and in the binding springs, explicit in the other elastic forces unless
// StepSettings::implicit_elasticity adds their definite differentials to K: then
// F_el(x^n + dt/2 v~^{n+1/2}) ~ F_el(x^n) + dt/2 K+ v~^{n+1/2}, linearised once, as for the springs.
void Newmark::implicit_half_velocity(const StepModel& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  auto t = Clock::now();
  update_body_inertias(s);
  m_body_I_n = m_body_I;
  for (const auto& f : s.forces) f->update_position_state(s.particles.x);
  predict_angular_velocities(dt);
  set_step_maps(s, dt, true, ChordForm::arm);
  const SolveCoefficients k{h, h, m_implicit_elasticity ? h : 0.0};
  m_system.set(s, k, m_body_I);
  compute_forces(s, s.particles.x, true);
  add_geometric_stiffness(s, k, dt, ChordForm::arm);
  build_rhs(s, h, m_v_n, m_body_v_n, m_body_L_n);
  add_bound_offset_impulse();
  bool trial = false;
  GeneralizedVector* alternative = choose_step1_guess(s, dt, trial);
  m_constraints.collisions().clear();  // collisions are inactive in the first solve
  m_constraints.prepare_collisions();
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  const bool linear_solve = needs_linear_solve(s);
  const bool history = m_last_dt > 0.0;
  const SolveResult result =
      solve(s, k, linear_solve, true, alternative, history ? Alternative::if_smaller : Alternative::if_exact);
  if (trial) m_extrapolate = result.took_alternative;
  stats.ms.cg += ms_since(t);
  stats.linear_solve = linear_solve;
  stats.implicit_elasticity = m_implicit_elasticity;
  record_solve(result, stats.cg_iterations_step1, stats);
  keep_half_velocity(s);

  // Newton's iteration over the frames' turns: relinearise the points' chords at the last answer and
  // solve again from it, until the chords the solve used are the chords of its answer.
  // One pass: the chords linearised at the angular velocities `w` (the last answer's, or an
  // accelerated guess), solved from the last answer.
  auto pass = [&](ChordForm form, const Vectors3& w) {
    t = Clock::now();
    m_w_lin = w;
    set_step_maps(s, dt, true, form);
    m_system.set(s, k, m_body_I);
    compute_forces(s, s.particles.x, true);
    add_geometric_stiffness(s, k, dt, form);
    build_rhs(s, h, m_v_n, m_body_v_n, m_body_L_n);
    add_bound_offset_impulse();
    stats.ms.forces += ms_since(t);
    t = Clock::now();
    const SolveResult again = solve(s, k, linear_solve, false);  // the last preconditioner is close enough
    stats.ms.cg += ms_since(t);
    record_solve(again, stats.cg_iterations_step1, stats);
    ++stats.rotation_iterations;
    keep_half_velocity(s);
    return chord_error(s, dt);
  };
  // The turns converge to the solves' accuracy, not below it: each answer is good to that only.
  const double tolerance = std::max(s.settings.cg_tolerance, s.settings.cg_rms_tolerance);
  const int passes = s.settings.rotation_iterations;
  // First the fixed point of the arms J(theta) r, the work-conserving form (see above): each pass
  // contracts the turn's error by about |theta| / 2, so with the predicted turn it usually holds at
  // once. It stalls near the solves' own accuracy (each answer is good to the tolerance only), where
  // it holds; where it stops contracting well above it (a chain whipping round, where the joints'
  // stiffness multiplies the arms' change), Newton's iteration on the derivative form takes over.
  m_form = ChordForm::arm;
  m_saved_half.particles = m_y.particles;  // the first answer, where Newton starts if this fails
  m_saved_half.rigid = m_y.rigid;
  double error = chord_error(s, dt);
  bool turned = error <= tolerance;
  int pass_count = 0;
  // The fixed point w = g(w) of "linearise at w, solve, read the answer's w" is found with one step
  // of Anderson's mixing (a secant on the residual r = g(w) - w): w' = g_k - gamma (g_k - g_{k-1}),
  // gamma = r_k . (r_k - r_{k-1}) / |r_k - r_{k-1}|^2, where plain iteration contracts by only
  // |theta| / 2 per pass.
  m_mix_x = m_w_lin;  // the linearisation of the first solve and its answer
  m_mix_g = s.bodies.w;
  m_mix_next = s.bodies.w;
  for (; !turned && pass_count < passes; ++pass_count) {
    const double e = pass(ChordForm::arm, m_mix_next);
    mix_turns(s.bodies.w);
    turned = e <= tolerance;
    if (!(e < error)) {
      turned = std::min(e, error) <= 10.0 * tolerance;
      break;
    }
    error = e;
  }
  if (!turned) {
    // Newton's answer, then the arm form again from there (close to its fixed point, it contracts
    // where it did not from the prediction); Newton's answer stands if it still does not.
    m_form = ChordForm::derivative;
    m_y.particles = m_saved_half.particles;
    m_y.rigid = m_saved_half.rigid;
    keep_half_velocity(s);
    for (int i = 0; !turned && i < passes; ++i) turned = pass(ChordForm::derivative, s.bodies.w) <= tolerance;
    if (turned) {
      m_saved_half.particles = m_y.particles;
      m_saved_half.rigid = m_y.rigid;
      error = kInfinity;
      bool held = false;
      for (int i = 0; i < passes && !held; ++i) {
        const double e = pass(ChordForm::arm, s.bodies.w);
        held = e <= tolerance;
        if (!(e < error)) {
          held = std::min(e, error) <= 10.0 * tolerance;
          break;
        }
        error = e;
      }
      if (held) {
        m_form = ChordForm::arm;
      } else {
        m_y.particles = m_saved_half.particles;
        m_y.rigid = m_saved_half.rigid;
        keep_half_velocity(s);
      }
    }
  }
  stats.cg_converged = stats.cg_converged && turned;
  for (Index b = 0; b < m_unknowns.r; ++b) {  // the geometric stiffness belongs to the iteration over the turns
    m_body_I[b] -= m_geometric[b];
    m_geometric[b].setZero();
  }
  if (m_implicit_elasticity && linear_solve)
    for (int i = 0; i < s.settings.newton_iterations; ++i) newton_iteration(s, dt, stats);
  // The frames turn with the answer (step 2), and step 4 sees the chords there, in the same form.
  m_w_lin = s.bodies.w;
  set_step_maps(s, dt, false, m_form);
}

// ---- rigid frames over the step ---------------------------------------------------------------
//
// Over a step a body turns by theta = dt w^{n+1/2} (step 2), so a point at offset r on it moves by
// the chord dt u with
//
//   u(v, w) = v + (R(theta) - I) r / dt,
//
// not by dt (v + w x r): the tangent is |theta|^2 |r| / 2 off the arc. Binding springs and elements
// see the points' positions x^n + h u (step 1) and x^{n+1/2} (step 4); a spring of stiffness k
// would kick every such miss back with k |theta|^2 |r| / 2, which for a light body on a stiff spring
// is no longer small against anything (a 0.1 kg rod hung on 1e9 N/m gained 1e244 times its energy
// in 600 steps at 1/60 s). So the solves see the chords, in one of two forms.
//
// The arm form. (R(theta) - I) r = theta x (J(theta) r) exactly (J: rotation_left_jacobian), so with
// theta = dt w the chord is u = v + w x r~ for the arm r~ = J(theta) r: the solve's points sit at r~
// (W = [I  -r~*], W^T f = (f, r~ x f), hard bindings' set_step_arms). Then W t = u(t) at the answer,
// and the work the forces do in the step's velocity update is the work they do along the chords:
// for a binding spring, whose force at the chord's midpoint does exactly minus its energy change
// over the chord, the kinetic energy changes by that and no more (a discrete gradient), and a
// force pair on two points keeps the angular momentum. r~ = r + theta x r / 2 + O(theta^2) is, to
// first order, the arm at the half-step orientation. r~ depends on the answer's w, so step 1 finds
// the fixed point: linearise at w0, solve, read w, again (with Anderson's mixing, mix_turns). It
// contracts by about |theta| / 2 times the share of the joints' stiffness in a body's motion: at
// once for a cloth on a turning body or a pendulum, not for a chain whipping round.
//
// The derivative form, for Newton's iteration where the fixed point stalls:
//
//   u(v, w) ~ v + (A w) x r' + o,   r' = R(theta0) r,   A = J(theta0) dtheta/dw / dt,
//   o = (R(theta0) - I) r / dt - (A w0) x r',
//
// from d/dtheta (R(theta) r) = -(R(theta) r)* J(theta). The points sit at their end-of-step offsets
// r' and move with the angular velocity A w (W = [I  -r'* A]), plus an offset o that the step moves
// to the right-hand side (ImplicitSystem::apply_bound_offset). W^T maps a force f on a point to (f,
// A^T (r' x f)), the derivative of the point's chord: step 1 is then the stationary point of
//   1/2 |t - t^n|_M^2 + E(x^n + h u(t)) - h F_ext . t
// over the twists and velocities t (E: the implicit forces' energy), which Newton's iteration finds
// with the symmetric operator CG needs once the chords' geometric stiffness is in it
// (add_geometric_stiffness). But W t differs from u(t) by O(theta) (the arm is the end-of-step one),
// so this form dissipates (a stiff pendulum at 1/60 s lost 80% of its energy in a second) and does
// not keep angular momentum; step 1 therefore tries the arm form again from Newton's answer, and
// only where that still stalls does the step keep Newton's answer (and step 4 the same form).
//
// Where StepSettings::max_rotation_per_step cuts theta to the limit along w, the arm is scaled by
// |theta| / (dt |w|) and dtheta/dw keeps only the change of direction. Step 1 takes each dynamic
// body's inertia at its half-step orientation, R(theta/2) I R(theta/2)^T (StepSettings::
// gyroscopic_correction), lagged one iteration.

Vec3 Newmark::turn_of(const Vec3& w, double dt, double limit) {
  const double angle = dt * w.norm();
  return angle > limit ? Vec3((limit / angle) * dt * w) : Vec3(dt * w);
}

// Anderson's mixing of the last two linearisations and answers (see implicit_half_velocity); the
// next linearisation in m_mix_next. Plain iteration (the answer itself) where the residuals did not
// change.
void Newmark::mix_turns(const Vectors3& answer) {
  double numerator = 0.0, denominator = 0.0;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    const Vec3 r = answer.col(b) - m_w_lin.col(b);
    const Vec3 dr = r - (m_mix_g.col(b) - m_mix_x.col(b));
    numerator += r.dot(dr);
    denominator += dr.squaredNorm();
  }
  double gamma = denominator > 0.0 ? numerator / denominator : 0.0;
  if (!std::isfinite(gamma)) gamma = 0.0;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    m_mix_next.col(b) = answer.col(b) - gamma * (answer.col(b) - m_mix_g.col(b));
    m_mix_x.col(b) = m_w_lin.col(b);
    m_mix_g.col(b) = answer.col(b);
  }
}

// Step 1's first linearisation: at the angular velocities the step-1 guess predicts, w^n + (dt /
// dt_last)(w^n - w^{n-1/2}) (exact under a constant angular acceleration), or w^n on the first step.
void Newmark::predict_angular_velocities(double dt) {
  const bool history = m_last_dt > 0.0;
  const double ratio = history ? dt / m_last_dt : 0.0;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    Vec3 w = m_body_w_n.col(b);
    if (history && m_unknowns.dynamic_body[b]) w += ratio * (w - Vec3(m_last_half.rigid.col(b).tail<3>()));
    m_w_lin.col(b) = w;
  }
}

// The turns, arms, angular maps and offsets of the linearisation at m_w_lin (see above), set on the
// bindings; with `inertias`, step 1's half-step inertias of the dynamic bodies.
void Newmark::set_step_maps(const StepModel& s, double dt, bool inertias, ChordForm form) {
  const double limit = s.settings.max_rotation_per_step;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    const Vec3 w = m_w_lin.col(b);
    const Vec3 turn = turn_of(w, dt, limit);
    m_turn.col(b) = turn;
    const Mat3 R = rotation_from_vector(turn).toRotationMatrix();
    m_arm_maps[b] = R * m_body_q_n[b].toRotationMatrix();
    Mat3 dturn = Mat3::Identity();  // dtheta/dw / dt
    const double speed = w.norm();
    if (dt * speed > limit) {
      const Vec3 axis = w / speed;
      dturn = limit / (dt * speed) * (Mat3::Identity() - axis * axis.transpose());
    }
    m_angular_maps[b] = rotation_left_jacobian(turn) * dturn;
    if (form == ChordForm::arm) {  // u = v + w x (scale J(theta) r) exactly at this w
      const double scale = dt * speed > limit ? limit / (dt * speed) : 1.0;
      m_arm_maps[b] = scale * rotation_left_jacobian(turn) * m_body_q_n[b].toRotationMatrix();
      m_angular_maps[b] = Mat3::Identity();
    }
    if (inertias && m_unknowns.dynamic_body[b]) {
      if (s.settings.gyroscopic_correction) {
        const Mat3 half = rotation_from_vector(0.5 * turn).toRotationMatrix();
        m_body_I[b] = half * m_body_I_n[b] * half.transpose();
      } else {
        m_body_I[b] = m_body_I_n[b];
      }
    }
  }
  s.hard.set_step_arms(m_arm_maps, m_angular_maps);
  m_has_bound_offset = false;
  for (Index k = 0; k < s.hard.rigid_count(); ++k) {
    const Index b = s.hard.rigid_body(k);
    const Vec3 w = m_w_lin.col(b);
    const Vec3 arm = s.hard.rigid_offset_world(k);
    const Vec3 chord = rotation_from_vector(m_turn.col(b)) * m_r_n[k] - m_r_n[k];
    const Vec3 o = chord / dt - Vec3(m_angular_maps[b] * w).cross(arm);
    m_bound_offset.col(s.hard.rigid_particle(k)) = o;
    m_has_bound_offset = m_has_bound_offset || !o.isZero(0.0);
  }
  // A mixed point moves with W of its parents, its frame parents' offsets included.
  const MixedBindings& mixed = s.hard.mixed();
  for (Index k = 0; k < mixed.size(); ++k) {
    Vec3 o = Vec3::Zero();
    for (std::size_t i = 0; i < mixed.parents(k).size(); ++i)
      if (mixed.frame(k, i) >= 0) o += mixed.weights(k)[i] * Vec3(m_bound_offset.col(mixed.parents(k)[i]));
    m_bound_offset.col(mixed.particle(k)) = o;
  }
}

// The largest difference, over the points on frames, between the chord velocity of the current
// answer (the bodies' twists) and the one the solve used, linearised at m_w_lin; for the dynamic
// bodies also the change of the half-step inertia as a velocity at the radius of gyration.
double Newmark::chord_error(const StepModel& s, double dt) const {
  const double limit = s.settings.max_rotation_per_step;
  double error = 0.0;
  for (Index k = 0; k < s.hard.rigid_count(); ++k) {
    const Index b = s.hard.rigid_body(k);
    const Vec3 w = s.bodies.w.col(b);
    const Vec3 chord = (rotation_from_vector(turn_of(w, dt, limit)) * m_r_n[k] - m_r_n[k]) / dt;
    const Vec3 used = Vec3(m_angular_maps[b] * w).cross(s.hard.rigid_offset_world(k)) +
                      Vec3(m_bound_offset.col(s.hard.rigid_particle(k)));
    error = std::max(error, (chord - used).norm());
  }
  if (s.settings.gyroscopic_correction) {
    for (Index b = 0; b < m_unknowns.r; ++b) {
      if (!m_unknowns.dynamic_body[b]) continue;
      const Vec3 w = s.bodies.w.col(b);
      const Vec3 turn = turn_of(w, dt, limit);
      const Mat3 half = rotation_from_vector(0.5 * turn).toRotationMatrix();
      const Mat3 I = half * m_body_I_n[b] * half.transpose();
      const Vec3 dw = I.inverse() * ((I - (m_body_I[b] - m_geometric[b])) * w);
      error = std::max(error, dw.norm() * m_body_gyration[b]);
    }
  }
  return error;
}

// The geometric stiffness of the chords (Newton's iteration over the turns, see set_step_maps): the
// Hessian of E(x^n + h u(t)) has, besides h^2 W^T K W, the term h lambda . d2u/dw2 with lambda =
// dE/dx = -f the force on each point at the linearisation, and d2u/dw2 = dt d2(R(theta) r)/dtheta2,
// which at the arm a = R(theta) r is, to leading order, the symmetric
//   H = h dt [ (lambda a^T + a lambda^T) / 2 - (lambda . a) I ].
// Against a body's inertia it is not small: a point pulled outward with tension T (a pendulum's
// hinge, a chain's joints) gets h dt T |a| (I - a a^T / |a|^2), of the order of dt^2 T / (m |a|)
// times the inertia, which for a whipping chain is order one; Newton without it overshoots and
// settles into two-cycles. Each body's sum is projected onto its positive semidefinite part (a
// compressed point's negative curvature would make the system indefinite for CG) and added to
// its step-1 inertia, with H w0 on the right-hand side, so that the solve is Newton's step.
void Newmark::add_geometric_stiffness(const StepModel& s, const SolveCoefficients& k, double dt, ChordForm form) {
  // Newton's iteration only: the arm form is a fixed-point iteration, which the term slows down (a
  // stiff pendulum at 1/60 s then stalls and falls back to Newton's answer every step).
  for (Mat3& g : m_geometric) g.setZero();
  if (form == ChordForm::arm || s.hard.rigid_count() == 0) return;
  m_lin.particles = s.particles.v;
  m_lin.rigid.topRows<3>() = s.bodies.v;
  m_lin.rigid.bottomRows<3>() = m_w_lin;
  m_system.implicit_forces(m_lin, m_bound_offset, m_u);
  for (Index j = 0; j < s.hard.rigid_count(); ++j) {
    const Index b = s.hard.rigid_body(j);
    if (!m_unknowns.dynamic_body[b]) continue;
    const Index i = s.hard.rigid_particle(j);
    const Vec3 lambda = -(Vec3(m_bound_force.col(i)) + Vec3(m_u.col(i)));
    const Vec3 a = s.hard.rigid_offset_world(j);
    m_geometric[b] +=
        (k.h * dt) * (0.5 * (lambda * a.transpose() + a * lambda.transpose()) - lambda.dot(a) * Mat3::Identity());
  }
  for (Index b = 0; b < m_unknowns.r; ++b) {
    if (!m_unknowns.dynamic_body[b] || m_geometric[b].isZero(0.0)) continue;
    Eigen::SelfAdjointEigenSolver<Mat3> eig(m_geometric[b]);
    const Vec3 positive = eig.eigenvalues().cwiseMax(0.0);
    m_geometric[b] = eig.eigenvectors() * positive.asDiagonal() * eig.eigenvectors().transpose();
    m_body_I[b] += m_geometric[b];
  }
}

// c += -h W^T (D + beta K) o: the offsets' share of the implicit forces (ImplicitSystem::
// apply_bound_offset), with the coefficients m_system was last set with.
void Newmark::add_bound_offset_impulse() {
  for (Index b = 0; b < m_unknowns.r; ++b)
    if (m_unknowns.dynamic_body[b]) m_c.rigid.col(b).tail<3>() += m_geometric[b] * m_w_lin.col(b);
  if (!m_has_bound_offset) return;
  m_system.apply_bound_offset(m_bound_offset, m_product0);
  m_c.particles += m_product0.particles;
  m_c.rigid += m_product0.rigid;
}

// Initial guess from the last step: v^{n+1/2} ~ v^n + (dt / dt_last) (v^n - v^{n-1/2}), as
// v^n - v^{n-1/2} ~ dt_last/2 a: exact under constant acceleration (free fall, a steady push) and
// O(dt^2) off in smooth motion, where v^n alone is O(dt) off. But the difference also holds the
// last step's error in the stiff modes, which ring from step to step when the step is long
// against them (implicit elasticity at 1/60 s: the trapezoidal half step turns them over each
// step), and the extrapolation doubles that. Neither guess wins everywhere (on the benchmark
// curtain, CG iterations per step-1 solve: 40x40 at 1/240 s, tol 1e-3: 6.5 from v^n, 3.9
// extrapolated; 150x150 multigrid at 1/60 s, tol 1e-2, over 2 s: 19.5 extrapolated), so
// Step1Guess::adaptive tries both every kGuessTrialSteps steps (one more product and
// preconditioner application) and keeps the one with the smaller r . z (solve(),
// Alternative::if_smaller) until the next trial (150x150: 12.4). Only where the change it
// predicts is well above the tolerance (tenfold, on some unknown), else v^n: the last answer's
// own error (up to the tolerance) is doubled too (Step1Guess::extrapolated skips that test). On
// the unknowns only.
GeneralizedVector* Newmark::choose_step1_guess(const StepModel& s, double dt, bool& trial) {
  const Unknowns& u = m_unknowns;
  m_y.particles = m_v_n;
  m_y.rigid.topRows<3>() = m_body_v_n;
  m_y.rigid.bottomRows<3>() = m_body_w_n;
  const bool history = m_last_dt > 0.0;
  const Step1Guess guess_rule = s.settings.step1_guess;
  bool extrapolate = false;
  trial = false;
  if (history) {
    const double ratio = dt / m_last_dt;
    double change = 0.0;
    for (Index i = 0; i < u.n; ++i) {
      const Vec3 d =
          u.dynamic_mask[i] > 0.0 ? Vec3(ratio * (m_v_n.col(i) - m_last_half.particles.col(i))) : Vec3::Zero();
      m_guess.particles.col(i) = d;
      change = std::max(change, d.cwiseAbs().maxCoeff());
    }
    for (Index b = 0; b < u.r; ++b) {
      const Vec6 d = u.dynamic_body[b] ? Vec6(ratio * (m_y.rigid.col(b) - m_last_half.rigid.col(b))) : Vec6::Zero();
      m_guess.rigid.col(b) = d;
      change = std::max(change, d.cwiseAbs().maxCoeff());
    }
    if (guess_rule == Step1Guess::extrapolated) {
      extrapolate = true;
    } else if (guess_rule == Step1Guess::adaptive && change > 10.0 * s.settings.cg_tolerance) {
      trial = m_guess_trial == 0;
      m_guess_trial = trial ? kGuessTrialSteps - 1 : m_guess_trial - 1;
      extrapolate = !trial && m_extrapolate;
    } else {
      m_guess_trial = 0;  // after a quiet spell (or another rule) the next qualifying step tries again
    }
    if (extrapolate || trial) {
      m_guess.particles += m_y.particles;  // the extrapolated guess, in full
      m_guess.rigid += m_y.rigid;
    }
    if (extrapolate) {
      m_y.particles = m_guess.particles;
      m_y.rigid = m_guess.rigid;
    }
    return trial ? &m_guess : nullptr;
  }
  // Before the first step, a second initial guess instead: M^-1 c = v^n + dt/2 M^-1 F on the
  // unknowns (explicit in the implicit terms): exact for motion they do not resist (free fall,
  // rigid translation), so solve() takes it when it is exact; far off where they are stiff, where
  // v^n is kept.
  for (Index i = 0; i < u.n; ++i)
    m_guess.particles.col(i) =
        u.dynamic_mask[i] > 0.0 ? Vec3(m_c.particles.col(i) / u.dof_mass[i]) : Vec3(m_v_n.col(i));
  for (Index b = 0; b < u.r; ++b) {
    if (u.dynamic_body[b]) {
      m_guess.rigid.col(b).head<3>() = m_c.rigid.col(b).head<3>() / s.bodies.mass[b];
      m_guess.rigid.col(b).tail<3>() = m_body_I[b].inverse() * m_c.rigid.col(b).tail<3>();
    } else {
      m_guess.rigid.col(b) = m_y.rigid.col(b);
    }
  }
  return &m_guess;
}

// A solve's iterations (into `iterations`, step 1's or step 4's count), residual and convergence.
void Newmark::record_solve(const SolveResult& result, int& iterations, StepStats& stats) {
  iterations += result.iterations;
  stats.cg_residual = std::max(stats.cg_residual, result.residual);
  stats.cg_converged = stats.cg_converged && result.converged;
}

// Step 1's answer (in m_y) as the half-step velocities: kept for step 2 and step 4's guess, and set
// on the particles and bodies.
void Newmark::keep_half_velocity(const StepModel& s) {
  m_v_half = m_y.particles;
  m_twist_half = m_y.rigid;
  s.particles.v = m_y.particles;
  s.bodies.v = m_y.rigid.topRows<3>();
  s.bodies.w = m_y.rigid.bottomRows<3>();
}

// One Newton iteration on step 1 (StepSettings::newton_iterations): the implicit forces relinearised
// at x_mid = x^n + h v~^{n+1/2}, where the half step ends (F(x_mid + h (v - v_prev)) ~ F(x_mid) +
// h K+(x_mid) (v - v_prev)), so (M - h D - h^2 K+) v = M v^n + h F(x_mid) - h^2 K+ v_prev: the same
// operator as step 1's at the new state, and c gains apply(with K) - apply(without K) of v_prev.
// Linear forces (binding springs) come out unchanged: their F(x_mid) - F(x^n) is that correction.
// Positions go back to x^n exactly afterwards; step 2 advances from there.
void Newmark::newton_iteration(const StepModel& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  auto t = Clock::now();
  move_positions(s, h);
  s.soft.synchronize(s.particles, true, false);
  for (const auto& f : s.forces) f->update_position_state(s.particles.x);
  compute_forces(s, s.particles.x);
  build_rhs(s, h, m_v_n, m_body_v_n, m_body_L_n);
  m_system.set(s, {h, h, h}, m_body_I);
  m_system.apply(m_y, m_product);
  m_system.set(s, {h, 0.0, 0.0}, m_body_I);
  m_system.apply(m_y, m_product0);
  m_c.particles += m_product.particles - m_product0.particles;
  m_c.rigid += m_product.rigid - m_product0.rigid;
  add_bound_offset_impulse();  // damping's share only: the stiffness sees x_mid, whose chords hold o
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  const SolveResult result = solve(s, {h, h, h}, true, true);
  stats.ms.cg += ms_since(t);
  record_solve(result, stats.cg_iterations_step1, stats);
  ++stats.newton_iterations;

  restore_positions(s);
  keep_half_velocity(s);
}

// Step 2: x~^{n+1} = x^n + dt v~^{n+1/2}; rigid frames x_c += dt v_c, q = q(theta) q^n with the
// turn theta = dt w^{n+1/2} (section 5, step 3), and the points on them exactly on their frames.
// Velocities return to v^n, which step 3 turns into v~^n.
void Newmark::advance_positions(const StepModel& s, double dt) {
  move_positions(s, dt);
  s.hard.update_rigid_offsets(s.bodies);
  s.hard.clamp_positions(s.particles.x, s.bodies.x);
  s.particles.v = m_v_n;
  s.bodies.v = m_body_v_n;
  s.bodies.w = m_body_w_n;
  s.hard.clamp_velocities(s.particles.v, s.bodies.v, s.bodies.w);
}

// Positions a fraction tau / dt along the step: x^n + tau u on the rows that move (dynamic,
// kinematic and hard-bound), u the step's velocities with the bound rows' from the step's arms, so
// that a point on a frame is on its chord; frames at x_c + tau v_c and q(tau/dt theta) q^n.
// Velocities untouched; the arms stay.
void Newmark::move_positions(const StepModel& s, double tau) {
  auto& p = s.particles;
  m_u = m_v_half;
  s.hard.clamp_velocities(m_u, s.bodies.v, s.bodies.w);
  if (m_has_bound_offset) {
    for (Index k = 0; k < s.hard.rigid_count(); ++k) {
      const Index i = s.hard.rigid_particle(k);
      m_u.col(i) += m_bound_offset.col(i);
    }
    for (Index k = 0; k < s.hard.mixed().size(); ++k) {
      const Index i = s.hard.mixed().particle(k);
      m_u.col(i) += m_bound_offset.col(i);
    }
  }
  for (Index i = 0; i < m_unknowns.n; ++i) {
    const ParticleKind kind = p.kind[i];
    if (is_dynamic(kind) || kind == ParticleKind::kinematic || kind == ParticleKind::hard_bound)
      p.x.col(i) = m_x_n.col(i) + tau * m_u.col(i);
  }
  auto& bodies = s.bodies;
  const double fraction = tau / m_dt;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    bodies.x.col(b) = m_body_x_n.col(b) + tau * bodies.v.col(b);
    bodies.q[b] = (rotation_from_vector(fraction * Vec3(m_turn.col(b))) * m_body_q_n[b]).normalized();
  }
}

void Newmark::restore_positions(const StepModel& s) {
  s.particles.x = m_x_n;
  auto& bodies = s.bodies;
  bodies.x = m_body_x_n;
  for (Index b = 0; b < m_unknowns.r; ++b) bodies.q[b] = m_body_q_n[b];
}

// Step 3: (x~^{n+1}, v^n) -> (x^{n+1}, v~^n). Deformables only (section 5, step 4): the collision
// sources, in order, see free and soft-bound particles; synchronized soft particles start on their
// targets and whatever drift the sources give them is pushed back to the targets' parents.
void Newmark::process_collisions(const StepModel& s, double dt, StepStats& stats) {
  auto& p = s.particles;
  s.soft.synchronize(p, true, true);
  auto& constraints = m_constraints.collisions();
  constraints.clear();
  if (!s.collision_sources.empty()) {
    // The spread (below) measures step 3's moves from the positions the sources are handed.
    const bool will_spread = s.settings.spread_collisions && m_implicit_solid;
    if (will_spread) m_x_predicted = p.x;
    CollisionContext context;
    context.time = s.time;
    context.dt = dt;
    context.x_n = &m_x_n;
    context.x = &p.x;
    context.v = &p.v;
    context.particles = &p;
    context.bodies = &s.bodies;
    context.body_x_n = &m_body_x_n;
    context.body_q_n = &m_body_q_n;
    context.geometry = &s.geometry;
    context.m_constraints = &constraints;
    context.m_bodies = &s.bodies;
    context.m_body_L = &m_body_L_n;
    context.m_particles = &p;
    context.m_hard = &s.hard;
    context.m_soft = &s.soft;
    context.m_effective_mass = &s.effective_mass;
    // The spread (spread_collisions) comes after every source, or before the first that must have the
    // step's final positions (a continuous test's guarantee is about them), over what the sources
    // before it moved.
    bool spread = will_spread;
    const auto spread_now = [&] {
      s.soft.push_drift(p, s.bodies, s.hard, s.effective_mass, m_body_L_n);
      s.hard.clamp_positions(p.x, s.bodies.x);
      s.hard.clamp_velocities(p.v, s.bodies.v, s.bodies.w);
      s.soft.synchronize(p, true, true);
      spread_collisions(s, dt, stats);
      s.hard.clamp_positions(p.x, s.bodies.x);
      s.soft.synchronize(p, true, true);
      spread = false;
    };
    for (const auto& source : s.collision_sources) {
      if (spread && source->needs_final_positions()) spread_now();
      const std::size_t first = constraints.size();
      source->process(context);
      for (std::size_t c = first; c < constraints.size(); ++c) check_constraint(s, constraints[c], source->name());
    }
    if (spread) spread_now();
    s.soft.push_drift(p, s.bodies, s.hard, s.effective_mass, m_body_L_n);
  }
  m_constraints.prepare_collisions();
  if (m_has_contacts) collide_contacts(s, dt);
  s.hard.clamp_positions(p.x, s.bodies.x);
  s.hard.clamp_velocities(p.v, s.bodies.v, s.bodies.w);
  s.soft.synchronize(p, true, true);
  m_x_np1 = p.x;
  m_body_x_np1 = s.bodies.x;
  for (Index b = 0; b < m_unknowns.r; ++b) m_body_q_np1[b] = s.bodies.q[b];
}

// Step 3's moves spread through the implicit forces (StepSettings::spread_collisions). Step 1 solved
// for the half-step velocities without the contacts step 3 then finds; step 3 puts the particles that
// crossed a surface back out of it, by up to their approach times dt, and moves nothing else. On a
// stiff solid that lands at speed v the contact layer is then squashed by v dt against the layer above
// it (a bar of 1.5 cm layers landing at 1.3 m/s at one 1/60 s step: 67%, several joules a bar), and
// step 4 turns that elastic energy into a bounce. Step 1 solved again with the moved particles held
// where step 3 put them would let the implicit forces carry the stop into the solid, as they carry
// any prescribed motion. Its answer differs from the first one by the solution d of
//
//   S d = 0,   J_c d = (n_c . sum_a w_a (x_a - x~_a)) / dt  for every constraint c,
//
// (S: step 1's operator, linear in the velocities, so the right-hand side cancels), x~ the positions
// before step 3 and x after; d = 0 on the bodies (held: the contacts were found against them where
// they are); a point held with friction also keeps its motion along the surface (J_t d = 0); every
// particle step 3 moved without a row of its own held where it was put (along its move and across).
// So the positions become x + dt (d - d_0), d_0 the least-norm velocities meeting the rows (the part
// step 3 already did): the constrained stencils keep the relative normal positions step 3 gave them,
// and the rest follows. A point's own row is unilateral (it may leave the surface, not go in), found
// by active set: rows whose multipliers pull are let go. The velocities keep what step 3 made them
// (step 1's answer is positions only, and step 4 spreads the stop in velocity through the same
// operator with the constraints held). What the spread moves is not tested against the surfaces
// again in this step (a bulge pushed sideways into a wall is found by the next step 3).
void Newmark::spread_collisions(const StepModel& s, double dt, StepStats& stats) {
  const Unknowns& u = m_unknowns;
  auto& p = s.particles;
  std::vector<CollisionConstraint>& constraints = m_constraints.collisions();
  m_spread_held.assign(static_cast<std::size_t>(u.n), 0);
  m_spread_rows.clear();
  m_step3_constraints = constraints;  // step 4's, given back at the end
  double largest = 0.0;
  auto add_row = [&](const CollisionConstraint& c, Index owner) {
    m_spread_rows.push_back({c, owner, true});
    largest = std::max(largest, std::abs(c.normal_velocity));
  };
  for (const CollisionConstraint& step3 : constraints) {
    CollisionConstraint c = step3;
    double moved = 0.0;
    const bool point = c.size == 1 && c.weights[0] == 1.0;
    for (int a = 0; a < c.size; ++a) {
      const Index i = c.particles[static_cast<std::size_t>(a)];
      moved += c.weights[static_cast<std::size_t>(a)] * c.normal.dot(p.x.col(i) - m_x_predicted.col(i));
      if (point) m_spread_held[static_cast<std::size_t>(i)] = 1;  // a stencil's moved points: below
    }
    c.normal_velocity = moved / dt;
    const auto owner = static_cast<Index>(m_spread_rows.size());
    add_row(c, -1);
    // A point held with friction keeps step 1's motion along the surface too: sliding in the spread
    // would go past Coulomb's bound, which acts on the velocities only (a resting ball crept outwards
    // on the floor, gaining elastic energy every step).
    if (point && c.friction > 0.0) {
      const Vec3 t1 = c.normal.unitOrthogonal(), t2 = c.normal.cross(t1);
      for (const Vec3& t : {t1, t2}) add_row(CollisionConstraint::point(c.particles[0], t, 0.0), owner);
    }
  }
  // A point moved without a row of its own (against a dynamic body, in a stencil: the parents of a
  // synchronized particle that moved) is held where it was put, along its move and across it.
  for (Index i = 0; i < u.n; ++i) {
    if (m_spread_held[static_cast<std::size_t>(i)] || u.dynamic_mask[i] == 0.0) continue;
    const Vec3 move = p.x.col(i) - m_x_predicted.col(i);
    const double length = move.norm();
    if (!(length > 0.0)) continue;
    const auto owner = static_cast<Index>(m_spread_rows.size());
    const Vec3 n = move / length, t1 = n.unitOrthogonal(), t2 = n.cross(t1);
    add_row(CollisionConstraint::point(i, n, length / dt), -1);
    for (const Vec3& t : {t1, t2}) add_row(CollisionConstraint::point(i, t, 0.0), owner);
  }
  if (largest > s.settings.cg_tolerance) {
    struct Restore {  // the bodies free again and step 3's constraints back, however the solves end
      Constraints& c;
      std::vector<CollisionConstraint>& step3;
      ~Restore() {
        c.hold_bodies(false);
        c.collisions().swap(step3);
      }
    } restore{m_constraints, m_step3_constraints};
    m_constraints.hold_bodies(true);
    m_spread.particles.setZero();
    m_spread.rigid.setZero();
    m_spread_rhs.particles.setZero();
    m_spread_rhs.rigid.setZero();
    m_system.set(s, m_last_k, m_body_I);
    // A point's own row is unilateral: a point step 3 put on a surface may leave it (a layer that only
    // touched, with the layer under it pushed up into it), not go back in. Rows whose multiplier pulls
    // are let go with their tangents and the solve repeated from its answer; a point let go that then
    // goes in is held again.
    const auto unilateral = [&](const SpreadRow& r) {
      return r.owner < 0 && r.row.size == 1 && r.row.weights[0] == 1.0;
    };
    const auto set_active = [&](std::size_t k, bool active) {
      m_spread_rows[k].active = active;
      for (std::size_t t = k + 1; t < m_spread_rows.size() && m_spread_rows[t].owner == static_cast<Index>(k); ++t)
        m_spread_rows[t].active = active;
    };
    for (int pass = 0;; ++pass) {
      constraints.clear();
      m_spread_active.clear();
      for (std::size_t k = 0; k < m_spread_rows.size(); ++k)
        if (m_spread_rows[k].active) {
          constraints.push_back(m_spread_rows[k].row);
          m_spread_active.push_back(k);
        }
      m_constraints.prepare_collisions();
      m_constraints.impose_collisions(m_spread);
      const SolveResult result =
          m_cg.solve(m_system, m_spread_rhs, m_spread, s.settings.cg_tolerance, s.settings.cg_rms_tolerance,
                     s.settings.cg_max_iterations, true, nullptr, Alternative::if_exact, m_step_count);
      record_solve(result, stats.cg_iterations_step3, stats);
      if (pass + 1 >= kSpreadPasses) break;
      bool changed = false;
      const double slack = 10.0 * s.settings.cg_tolerance;
      for (std::size_t k = 0; k < m_spread_rows.size(); ++k) {  // let go before, but going in: held again
        const SpreadRow& r = m_spread_rows[k];
        if (r.active || !unilateral(r)) continue;
        if (r.row.normal.dot(m_spread.particles.col(r.row.particles[0])) < r.row.normal_velocity - slack) {
          set_active(k, true);
          changed = true;
        }
      }
      m_system.apply_unprojected(m_spread, m_product);  // S d - 0: the rows' reactions
      m_constraints.collision_multipliers(m_product, m_collision_lambda);
      for (std::size_t j = 0; j < m_spread_active.size(); ++j) {
        const std::size_t k = m_spread_active[j];
        if (unilateral(m_spread_rows[k]) && m_collision_lambda[static_cast<Index>(j)] < 0.0) {
          set_active(k, false);
          changed = true;
        }
      }
      if (!changed) break;
    }
    // Positions: x + dt (d - d_0) on the points in held rows (d_0 the part step 3 did, imposed on
    // zero), x + dt d on the rest, but x~ + dt d on a point let go and in no held row: its own answer
    // from where step 1 put them, never further in than step 3 put it (the last solve may end with
    // one going in, and the passes allow a slack).
    m_spread_rhs.particles.setZero();
    m_constraints.impose_collisions(m_spread_rhs);
    m_spread_imposed = m_spread_rhs.particles;
    m_spread_rhs.particles.setZero();
    std::fill(m_spread_held.begin(), m_spread_held.end(), std::uint8_t{0});
    for (const CollisionConstraint& c : constraints)
      for (int a = 0; a < c.size; ++a)
        m_spread_held[static_cast<std::size_t>(c.particles[static_cast<std::size_t>(a)])] = 1;
    for (const SpreadRow& r : m_spread_rows) {
      const Index i = r.row.particles[0];
      if (r.active || !unilateral(r) || m_spread_held[static_cast<std::size_t>(i)]) continue;
      auto d = m_spread.particles.col(i);
      const double in = r.row.normal_velocity - r.row.normal.dot(d);
      if (in > 0.0) d += in * r.row.normal;
      m_spread_imposed.col(i) = (p.x.col(i) - m_x_predicted.col(i)) / dt;
    }
    for (Index i = 0; i < u.n; ++i)
      if (u.dynamic_mask[i] > 0.0) p.x.col(i) += dt * (m_spread.particles.col(i) - m_spread_imposed.col(i));
    return;
  }
  constraints.swap(m_step3_constraints);
}

// Step 4: (M + dt/2 D) v^{n+1/2} = M v~^n + dt/2 (F_el(x^{n+1/2}) + F_ext - K x^{n+1/2}), with the
// collision constraints of step 3 projected. x^{n+1/2} is what keeps the stiff binding springs
// stable (section 3.3); BindingSpringStep4 selects the alternatives. Implicit elasticity adds
// dt^2/4 K+(x^{n+1/2}) of the elastic forces to the operator.
void Newmark::backward_euler_velocity(const StepModel& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  const Unknowns& u = m_unknowns;
  auto t = Clock::now();
  auto& p = s.particles;
  auto& bodies = s.bodies;
  m_v_tilde_n = p.v;
  // Every row at the midpoint of its chord, points on frames included (not on the half-turned frame,
  // which is |theta|^2 |r| / 8 outside the chord): with the step's arms the binding springs then do
  // exactly the work of their chords (see set_step_maps).
  for (Index i = 0; i < u.n; ++i) p.x.col(i) = 0.5 * (m_x_n.col(i) + m_x_np1.col(i));
  for (Index b = 0; b < u.r; ++b) {
    bodies.x.col(b) = 0.5 * (m_body_x_n.col(b) + m_body_x_np1.col(b));
    // Half the step's turn, and half of what step 3 turned the frame on top of it (drift push-back).
    const Quat half = rotation_from_vector(0.5 * Vec3(m_turn.col(b)));
    const Quat rest = m_body_q_np1[b] * (half * half * m_body_q_n[b]).conjugate();
    bodies.q[b] = (Quat::Identity().slerp(0.5, rest) * half * m_body_q_n[b]).normalized();
  }
  s.hard.set_step_arms(m_arm_maps, m_angular_maps);  // the chords linearised at step 1's answer
  s.soft.synchronize(p, true, false);
  update_body_inertias(s);
  for (const auto& f : s.forces) f->update_position_state(p.x);

  const BindingSpringStep4 mode = s.settings.binding_springs_in_step4;
  const Vec3 mapped = compute_forces(s, mode == BindingSpringStep4::explicit_end_of_step ? m_x_np1 : p.x, true);
  stats.mapped_impulse += dt * mapped;
  // Rigid rows start from v~^n = (v_c, L^n): L is the momentum-like state, so w is recomputed with
  // the inertia at the half-step orientation.
  build_rhs(s, h, m_v_tilde_n, bodies.v, m_body_L_n);
  const double beta = mode == BindingSpringStep4::implicit_half_step ? h : 0.0;
  const SolveCoefficients k{h, beta, m_implicit_elasticity ? h : 0.0};
  m_system.set(s, k, m_body_I);
  add_bound_offset_impulse();
  // Initial guess: step 1's half-step velocity v~^{n+1/2} on the unknowns (it solves nearly the same
  // system at nearly the same configuration, so CG starts O(dt) from the answer instead of O(dt)
  // times the accelerations away), the prescribed values on constrained rows. The result is the
  // same to the CG tolerance whichever guess is used.
  for (Index i = 0; i < u.n; ++i)
    m_y.particles.col(i) = u.dynamic_mask[i] > 0.0 ? Vec3(m_v_half.col(i)) : Vec3(m_v_tilde_n.col(i));
  for (Index b = 0; b < u.r; ++b) {
    if (u.dynamic_body[b]) {
      m_y.rigid.col(b) = m_twist_half.col(b);
    } else {
      m_y.rigid.col(b).head<3>() = bodies.v.col(b);
      m_y.rigid.col(b).tail<3>() = bodies.w.col(b);
    }
  }
  m_constraints.impose_collisions(m_y);
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  const SolveResult result = solve(s, k, needs_linear_solve(s), false);
  stats.ms.cg += ms_since(t);
  record_solve(result, stats.cg_iterations_step4, stats);
  apply_surface_friction();
  m_v_half = m_y.particles;
  m_last_half.particles = m_y.particles;
  m_last_half.rigid = m_y.rigid;
  m_last_dt = dt;

  // Back to x^{n+1}; the half-step twists stay in m_y.rigid for step 5.
  p.x = m_x_np1;
  bodies.x = m_body_x_np1;
  for (Index b = 0; b < u.r; ++b) bodies.q[b] = m_body_q_np1[b];
}

// Coulomb friction at the step-4 collision constraints. A particle resting on a prescribed surface
// has no approach for step 3 to stop (v^n is already tangent), so its friction must come from the
// load the step-4 projection carries: the constraint's multiplier lambda (J^T lambda = S v^{n+1/2} - c,
// the surface's impulse over the half step). Each constraint with a coefficient mu then changes its
// stencil's tangential velocity relative to the surface by at most mu lambda / m_eff over the half
// step, spread over the stencil as an impulse would be (w_a / m_a / S, S = sum w_a^2 / m_a), in the
// direction that slows the slip at the step's end, v^{n+1} = 2 v^{n+1/2} - v~^n, and never past zero
// there: so over the whole step the change is mu times the full step's normal impulse, 2 lambda, and
// a contact that sticks ends the step without slip (clamping v^{n+1/2} instead would leave
// v^{n+1} = -v~^n, a slip that flips sign every step). The changes are tangential, so each
// constraint's own row still holds; constraints sharing particles are imposed again afterwards.
void Newmark::apply_surface_friction() {
  const std::vector<CollisionConstraint>& constraints = m_constraints.collisions();
  bool any = false;
  for (const CollisionConstraint& c : constraints) any = any || c.friction > 0.0;
  if (!any) return;
  const Unknowns& u = m_unknowns;
  m_system.apply_unprojected(m_y, m_product);
  m_product.particles -= m_c.particles;
  m_constraints.collision_multipliers(m_product, m_collision_lambda);
  for (std::size_t k = 0; k < constraints.size(); ++k) {
    const CollisionConstraint& c = constraints[k];
    const double lambda = m_collision_lambda[static_cast<Index>(k)];
    if (!(c.friction > 0.0) || !(lambda > 0.0)) continue;
    Vec3 end = Vec3::Zero();
    double S = 0.0;
    for (int a = 0; a < c.size; ++a) {
      const Index i = c.particles[static_cast<std::size_t>(a)];
      const double w = c.weights[static_cast<std::size_t>(a)];
      end += w * (2.0 * Vec3(m_y.particles.col(i)) - Vec3(m_v_tilde_n.col(i)));
      S = u.dof_mass[i] > 0.0 && std::isfinite(S) ? S + w * w / u.dof_mass[i] : kInfinity;
    }
    end -= c.velocity;
    const Vec3 slip = end - c.normal.dot(end) * c.normal;
    const double slip_speed = slip.norm();
    if (!(slip_speed > 0.0) || !(S > 0.0 && std::isfinite(S))) continue;  // massless rows take no impulse
    // The half step's change of the stencil's velocity: half the end's, at most mu lambda S.
    const Vec3 change = -std::min(0.5 * slip_speed, c.friction * lambda * S) / slip_speed * slip;
    for (int a = 0; a < c.size; ++a) {
      const Index i = c.particles[static_cast<std::size_t>(a)];
      m_y.particles.col(i) += (c.weights[static_cast<std::size_t>(a)] / u.dof_mass[i] / S) * change;
    }
  }
  m_constraints.impose_collisions(m_y);
}

// Step 5: v^{n+1} = 2 v^{n+1/2} - v~^n. Rigid bodies extrapolate momentum, L^{n+1} = 2 L^{n+1/2} - L^n,
// and take w^{n+1} = I(q^{n+1})^-1 L^{n+1}, so a torque-free body keeps L exactly.
void Newmark::extrapolate_velocity(const StepModel& s) {
  auto& p = s.particles;
  for (Index i = 0; i < m_unknowns.n; ++i)
    if (is_dynamic(p.kind[i])) p.v.col(i) = 2.0 * m_v_half.col(i) - m_v_tilde_n.col(i);
  auto& bodies = s.bodies;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    if (!m_unknowns.dynamic_body[b]) continue;
    const Vec3 L_half = m_body_I[b] * m_y.rigid.col(b).tail<3>();
    const Vec3 L = 2.0 * L_half - m_body_L_n.col(b);
    bodies.v.col(b) = 2.0 * m_y.rigid.col(b).head<3>() - bodies.v.col(b);
    bodies.w.col(b) = bodies.world_inverse_inertia(b) * L;
  }
  const bool settle = s.settings.settle_stiff_binding_springs && s.springs.size() > 0;
  const bool passes = settle || m_has_contacts;
  if (passes) {  // what the passes change, for the history below (m_product is free until step 1)
    m_product.particles = p.v;
    m_product.rigid.topRows<3>() = bodies.v;
    m_product.rigid.bottomRows<3>() = bodies.w;
  }
  if (m_has_contacts) {
    prepare_rows(s, m_dt, false);  // the contacts hold as inequalities below, not as the solves' equalities
    const auto count = static_cast<Index>(s.joint_rows.size());
    m_end_normal.setZero(count);
    m_end_friction.setZero(3, count);
    // Each contact's bound at the end-of-step gap (the gap the step's motion left).
    m_predicted_v = m_twist_half.topRows<3>();
    m_predicted_w = m_twist_half.bottomRows<3>();
    m_end_bound.setZero(count);
    for (Index i = 0; i < count; ++i) {
      const JointRow& row = s.joint_rows[static_cast<std::size_t>(i)];
      if (row.unilateral)
        m_end_bound[i] =
            row.target - std::max(row.gap + m_dt * row_velocity(row, m_predicted_v, m_predicted_w), 0.0) / m_dt;
    }
  }
  for (int pass = 0; pass < (m_has_contacts ? kContactEndPasses : settle ? kSettlePasses : 1); ++pass) {
    if (settle) {
      s.hard.update_rigid_offsets(bodies);
      settle_stiff_binding_springs(s);
    }
    if (m_constraints.has_joints()) {
      // The joints hold at the end of the step too: extrapolation through v^{n+1/2} would otherwise
      // reflect a violation present at t^n (-err at t^{n+1}, +err at t^{n+2}, ...) instead of removing it.
      m_y.rigid.topRows<3>() = bodies.v;
      m_y.rigid.bottomRows<3>() = bodies.w;
      m_constraints.impose_joints(m_y);
      bodies.v = m_y.rigid.topRows<3>();
      bodies.w = m_y.rigid.bottomRows<3>();
    }
    if (m_has_contacts) hold_contacts_at_step_end(s);
  }
  if (passes) {
    // Step 1's extrapolated guess reads the motion's trend from v^n - v^{n-1/2}: the settling and the
    // contacts' end impulses are no part of that trend, so the last half-step velocities move with them.
    m_last_half.particles += p.v - m_product.particles;
    m_last_half.rigid.topRows<3>() += bodies.v - m_product.rigid.topRows<3>();
    m_last_half.rigid.bottomRows<3>() += bodies.w - m_product.rigid.bottomRows<3>();
  }
  s.hard.update_rigid_offsets(bodies);
  s.hard.clamp_velocities(p.v, bodies.v, bodies.w);
  s.soft.synchronize(p, true, true);
}

// A binding spring whose damped relative motion decays within a small part of the step (rate
// min(c / 2 m, k / c) at the ends' effective mass m along their relative velocity, times dt, at least
// kSettleDecay) holds its ends together in velocity too: the continuous system would have damped
// their relative motion to nothing within the step. Step 5 cannot: v^{n+1} = 2 v~^{n+1/2} - v~^n
// keeps a stiff mode's velocity error and flips its sign every step (the trapezoidal rule damps
// nothing at k dt^2 / m >> 1), so an end-of-step relative velocity, once there (an initial condition,
// an impact), would ring from step to step whatever the spring's damping; read by a rigid solver (its
// contacts, its joints), it feeds energy in. Each such spring's ends get equal and opposite impulses
// that leave them approaching at the speed that closes their present gap g over the next step,
// -g / dt (a stiff spring's ends coincide; zero instead would keep the gap the step left, and a
// swinging chain of them then opens its joints), so momentum is kept and only the relative motion's
// energy goes. Gauss-Seidel passes over the springs in their order (deterministic), alternating with
// the joints' projection.
void Newmark::settle_stiff_binding_springs(const StepModel& s) {
  auto& p = s.particles;
  auto& bodies = s.bodies;
  const auto movable = [&](Index i) {
    const ParticleKind kind = p.kind[i];
    return kind == ParticleKind::free || kind == ParticleKind::soft_spring || kind == ParticleKind::kinematic ||
           s.hard.is_bound(i);
  };
  for (Index k = 0; k < s.springs.size(); ++k) {
    if (s.springs.removed(k) || !s.springs.active(k)) continue;
    const Index a = s.springs.a(k), b = s.springs.b(k);
    if (!movable(a) || !movable(b)) continue;
    const double stiffness = s.springs.stiffness(k), damping = s.springs.damping(k);
    if (!(damping > 0.0 && stiffness > 0.0)) continue;
    // Relative velocity against the one that closes the ends' present gap over the next step.
    const Vec3 u = s.hard.point_velocity(a, p.v, bodies) - s.hard.point_velocity(b, p.v, bodies) +
                   Vec3(p.x.col(a) - p.x.col(b)) / m_dt;
    const double speed = u.norm();
    if (!(speed > 0.0)) continue;
    const Vec3 n = u / speed;
    const double m_a = s.hard.effective_mass_along(a, n, s.effective_mass[a], bodies);
    const double m_b = s.hard.effective_mass_along(b, n, s.effective_mass[b], bodies);
    const double inverse = (std::isfinite(m_a) ? 1.0 / m_a : 0.0) + (std::isfinite(m_b) ? 1.0 / m_b : 0.0);
    if (!(inverse > 0.0)) continue;
    const double m = 1.0 / inverse;
    const double rate = std::min(damping / (2.0 * m), stiffness / damping);
    if (!(rate * m_dt >= kSettleDecay)) continue;
    const Vec3 j = -m * speed * n;
    s.hard.apply_impulse(a, j, p, bodies);
    s.hard.apply_impulse(b, -j, p, bodies);
  }
}

// ---- contacts between rigid bodies ------------------------------------------------------------
//
// A rigid solver's contact between two bodies (JointRow::unilateral) is a row J t >= b: the bodies'
// relative normal velocity at the point may close the present gap over the step, b = -max(gap, 0) / dt
// (plus the row's own target, a push-out for an overlap), and no more. A contact that only the rigid
// solver saw, after the step, would move a body off the step's update by (impulse / m) dt, and a stiff
// binding spring on it would kick that back every step; here the contacts are held in the step's
// solves with everything else, so a heavy ball lands in a net of light rods on stiff springs as one
// system. Which contacts hold (the solves hold equalities, as for the collision constraints of step 3):
//   - predicted: a contact holds in step 1 when the relative velocity its bodies would have after a
//     step of their applied forces alone, t^n + dt M^-1 f_ext, reaches b within a step of gravity
//     (a resting contact holds at once);
//   - added: a free contact that step 1's answer crosses (J t < b; the springs and joints the
//     prediction left out pushed it there) holds, and step 1 is solved again from t^n, up to
//     kContactPasses solves. A held contact is not released within the step even where it pulls (a
//     ball the net throws up sticks for that step and leaves at the next one, as a particle's
//     collision constraint does): released by the sign of their multipliers, the ball and net rods
//     cycled between sets and the net gained 100 J at a landing.
// Friction: a held contact with a coefficient first sticks, two more rows holding its relative
// tangential velocity at the point to zero (prepare_rows); when the tangential multipliers of a pair
// of bodies' sticking contacts leave Coulomb's cone around their summed normal multipliers (from J^T
// lambda = S t - c, Constraints::joint_multipliers; summed, since redundant rows, a box on four
// corners, split a load arbitrarily), the pair slides and step 1 is solved again without those rows.
// Held rows whose targets disagree are reconciled per group, sticking within Coulomb's pyramid
// (Constraints::agree_contact_targets). Step 3 makes each held contact the step closes an inelastic
// collision (collide_contacts), step 4 holds step 1's set. At the step's end (step 5's passes), each
// held contact keeps v^{n+1} from approaching (J t >= b at the end-of-step gap) by pushes only, and
// takes Coulomb friction up to mu times the impulse it carried over the step (twice its share of its
// pair's step-1 load, an impulse over dt/2, plus its end pushes), in Gauss-Seidel passes with the
// springs' settling and the joints: a sliding contact's friction acts there, on the velocities, a
// step late (the step's positions slide without it; a box sliding at 2 m/s with mu 0.5 stops within
// 2% of v^2 / (2 mu g)). Each row's gap then moves by dt J t^{n+1/2}, the step's relative motion
// (linearised at the row's levers).

double Newmark::row_velocity(const JointRow& row, const Vectors3& v, const Vectors3& w) {
  double u = row.j_a.head<3>().dot(v.col(row.body_a)) + row.j_a.tail<3>().dot(w.col(row.body_a));
  if (row.body_b >= 0) u += row.j_b.head<3>().dot(v.col(row.body_b)) + row.j_b.tail<3>().dot(w.col(row.body_b));
  return u;
}

void Newmark::predict_contacts(const StepModel& s, double dt) {
  const std::vector<JointRow>& rows = s.joint_rows;
  m_has_contacts = std::any_of(rows.begin(), rows.end(), [](const JointRow& r) { return r.unilateral; });
  m_contact_active.assign(rows.size(), 0);
  m_contact_sliding.assign(rows.size(), 0);
  // Pairs of bodies that were still slipping at the last step's end start this one sliding (no
  // sticking rows to try and release again: a ring drawn along its rod would solve step 1 twice per
  // step); the others start sticking.
  for (std::size_t i = 0; i < rows.size(); ++i)
    if (rows[i].unilateral && std::find(m_slipping_pairs.begin(), m_slipping_pairs.end(),
                                        std::pair{rows[i].body_a, rows[i].body_b}) != m_slipping_pairs.end())
      m_contact_sliding[i] = 1;
  m_contact_impulse.setZero(static_cast<Index>(rows.size()));
  if (!m_has_contacts) return;
  const RigidBodyParticles& bodies = s.bodies;
  m_predicted_v = bodies.v;
  m_predicted_w = bodies.w;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    if (!m_unknowns.dynamic_body[b]) continue;
    Vec3 a = bodies.force.col(b) / bodies.mass[b];
    if (bodies.gravity[b]) a += s.gravity;
    m_predicted_v.col(b) += dt * a;
    m_predicted_w.col(b) += dt * (bodies.world_inverse_inertia(b) * Vec3(bodies.torque.col(b)));
  }
  const double reach = s.gravity.norm() * dt;
  for (std::size_t i = 0; i < rows.size(); ++i)
    if (rows[i].unilateral)
      m_contact_active[i] = row_velocity(rows[i], m_predicted_v, m_predicted_w) - contact_target(rows[i], dt) <= reach;
}

// The rows the solves hold: the bilateral joint rows and, with `contacts`, the active contacts with
// their step targets.
void Newmark::prepare_rows(const StepModel& s, double dt, bool contacts) {
  const std::vector<JointRow>& rows = s.joint_rows;
  m_rows.clear();
  m_row_source.clear();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    if (rows[i].unilateral) continue;
    m_rows.push_back(rows[i]);
    m_row_source.push_back(static_cast<Index>(i));
  }
  if (contacts)
    for (std::size_t i = 0; i < rows.size(); ++i) {
      if (!rows[i].unilateral || !m_contact_active[i]) continue;
      m_rows.push_back(rows[i]);
      m_rows.back().target = contact_target(rows[i], dt);
      m_row_source.push_back(static_cast<Index>(i));
      if (!(rows[i].friction > 0.0) || m_contact_sliding[i]) continue;
      // Sticking: no relative tangential motion at the point (two bilateral rows right after the
      // normal one), while the multipliers stay within the friction cone (revise_contacts).
      const JointRow& row = rows[i];
      const Vec3 n = row.j_a.head<3>();
      const Vec3 t1 = n.unitOrthogonal(), t2 = n.cross(t1);
      const Vec3 lever_a = row.point - Vec3(s.bodies.x.col(row.body_a));
      const Vec3 lever_b = row.body_b >= 0 ? Vec3(row.point - Vec3(s.bodies.x.col(row.body_b))) : Vec3::Zero();
      for (const Vec3& t : {t1, t2}) {
        JointRow tangent;
        tangent.body_a = row.body_a;
        tangent.j_a << t, lever_a.cross(t);
        tangent.body_b = row.body_b;
        if (row.body_b >= 0) tangent.j_b << -t, -lever_b.cross(t);
        m_rows.push_back(tangent);
        m_row_source.push_back(-1 - static_cast<Index>(i));  // a tangent of contact i
      }
    }
  m_tangent_of.assign(m_rows.size(), -1);
  for (std::size_t j = 0; j < m_rows.size(); ++j)
    if (m_row_source[j] < 0)
      m_tangent_of[j] = m_row_source[j - 1] < 0 ? m_tangent_of[j - 1] : static_cast<Index>(j - 1);
  m_constraints.prepare_joints(m_rows, s.bodies, &m_tangent_of);
}

// After step 1: each held contact's multiplier (for friction), and the free contacts the answer
// crosses by more than ten times the solve's tolerance (relative to the speeds of the row's bodies)
// held. On a change the rows are prepared again and the state is back at t^n for step 1 to be solved
// again.
bool Newmark::revise_contacts(const StepModel& s, double dt) {
  if (!m_has_contacts) return false;
  m_system.set(s, m_last_k, m_body_I);
  m_system.apply(m_y, m_product);
  m_product.particles -= m_c.particles;
  m_product.rigid -= m_c.rigid;
  m_constraints.joint_multipliers(m_product, m_rows.size(), m_lambda);
  const double tolerance = 10.0 * s.settings.cg_tolerance;
  const std::vector<JointRow>& rows = s.joint_rows;
  bool changed = false;
  // Per pair of touching bodies: the normal multipliers' sum (signed: the held rows of a box on four
  // corners may pull at some, and the sum is the pair's load) and positive part, and the tangential
  // impulse of its sticking contacts (redundant rows split a load arbitrarily; the pair's sums do not).
  // Each contact's normal impulse is its share of the pair's load, in proportion to its push.
  m_pairs.clear();
  for (std::size_t j = 0; j < m_rows.size(); ++j) {
    const Index i = m_row_source[j];
    if (i < 0 || !rows[static_cast<std::size_t>(i)].unilateral) continue;
    const JointRow& row = rows[static_cast<std::size_t>(i)];
    const double lambda = m_lambda[static_cast<Index>(j)];
    auto pair = std::find_if(m_pairs.begin(), m_pairs.end(),
                             [&](const ContactPair& p) { return p.a == row.body_a && p.b == row.body_b; });
    if (pair == m_pairs.end())
      pair = m_pairs.insert(m_pairs.end(), {row.body_a, row.body_b, 0.0, 0.0, Vec3::Zero(), kInfinity, false});
    pair->load += lambda;
    pair->push += std::max(lambda, 0.0);
    pair->friction = std::min(pair->friction, row.friction);
    if (j + 2 < m_rows.size() && m_row_source[j + 1] == -1 - i) {
      pair->tangential += m_lambda[static_cast<Index>(j + 1)] * m_rows[j + 1].j_a.head<3>() +
                          m_lambda[static_cast<Index>(j + 2)] * m_rows[j + 2].j_a.head<3>();
      pair->sticking = true;
    }
  }
  // A pair whose sticking contacts' tangential impulse leaves Coulomb's cone slides from now on: its
  // contacts lose their sticking rows, and take their friction at the step's end.
  for (const ContactPair& pair : m_pairs) {
    const double load = std::max(pair.load, 0.0);
    const bool slides = pair.sticking && pair.tangential.norm() > pair.friction * load * (1.0 + tolerance);
    for (std::size_t j = 0; j < m_rows.size(); ++j) {
      const Index i = m_row_source[j];
      if (i < 0 || !rows[static_cast<std::size_t>(i)].unilateral) continue;
      const JointRow& row = rows[static_cast<std::size_t>(i)];
      if (row.body_a != pair.a || row.body_b != pair.b) continue;
      m_contact_impulse[i] = pair.push > 0.0 ? load * std::max(m_lambda[static_cast<Index>(j)], 0.0) / pair.push : 0.0;
      if (slides && row.friction > 0.0 && !m_contact_sliding[static_cast<std::size_t>(i)]) {
        m_contact_sliding[static_cast<std::size_t>(i)] = 1;
        changed = true;
      }
    }
  }
  m_predicted_v = m_y.rigid.topRows<3>();
  m_predicted_w = m_y.rigid.bottomRows<3>();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const JointRow& row = rows[i];
    if (!row.unilateral || m_contact_active[i]) continue;
    double speed = std::abs(contact_target(row, dt));
    speed += row.j_a.norm() * m_y.rigid.col(row.body_a).norm();
    if (row.body_b >= 0) speed += row.j_b.norm() * m_y.rigid.col(row.body_b).norm();
    if (row_velocity(row, m_predicted_v, m_predicted_w) < contact_target(row, dt) - tolerance * speed) {
      m_contact_active[i] = 1;
      changed = true;
    }
  }
  if (!changed) return false;
  prepare_rows(s, dt, true);
  s.particles.v = m_v_n;
  s.bodies.v = m_body_v_n;
  s.bodies.w = m_body_w_n;
  return true;
}

// Step 3 for the contacts: each held contact that the step's motion closes (its gap at the step's end
// within the solve's reach of 0) is a collision, inelastic as step 3's are for particles: v^n -> v~^n
// with its approach removed (J t~^n >= the row's own target), by impulses on the start velocities and
// momenta, in Gauss-Seidel passes. Without it step 5's v^{n+1} = 2 v^{n+1/2} - v~^n would reflect
// the approach (a box dropped on the ground would bounce back at the speed it fell with).
void Newmark::collide_contacts(const StepModel& s, double dt) {
  RigidBodyParticles& bodies = s.bodies;
  const std::vector<JointRow>& rows = s.joint_rows;
  auto dynamic = [&](Index b) { return b >= 0 && m_unknowns.dynamic_body[b]; };
  for (Index b = 0; b < m_unknowns.r; ++b)
    if (m_unknowns.dynamic_body[b]) bodies.w.col(b) = m_body_I_n[b].inverse() * Vec3(m_body_L_n.col(b));
  m_predicted_v = m_twist_half.topRows<3>();
  m_predicted_w = m_twist_half.bottomRows<3>();
  m_end_normal.setZero(static_cast<Index>(rows.size()));
  for (int pass = 0; pass < kSettlePasses; ++pass)
    for (std::size_t i = 0; i < rows.size(); ++i) {
      if (!m_contact_active[i]) continue;
      const JointRow& row = rows[i];
      const auto r = static_cast<Index>(i);
      const double closing = row.gap + dt * row_velocity(row, m_predicted_v, m_predicted_w);
      if (closing > 10.0 * s.settings.cg_tolerance * dt) continue;  // the contact is not reached this step
      double k = 0.0;
      for (const auto& [b, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}})
        if (dynamic(b))
          k += j.head<3>().squaredNorm() / bodies.mass[b] + j.tail<3>().dot(m_body_I_n[b].inverse() * j.tail<3>());
      if (!(k > 0.0)) continue;
      const double dn =
          std::max(m_end_normal[r] + (row.target - row_velocity(row, bodies.v, bodies.w)) / k, 0.0) - m_end_normal[r];
      if (dn == 0.0) continue;
      m_end_normal[r] += dn;
      for (const auto& [b, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}})
        if (dynamic(b)) {
          bodies.v.col(b) += j.head<3>() * (dn / bodies.mass[b]);
          m_body_L_n.col(b) += j.tail<3>() * dn;
          bodies.w.col(b) = m_body_I_n[b].inverse() * Vec3(m_body_L_n.col(b));
        }
    }
}

// One Gauss-Seidel pass over the held contacts at the step's end (see above), in the rows' order.
void Newmark::hold_contacts_at_step_end(const StepModel& s) {
  RigidBodyParticles& bodies = s.bodies;
  const std::vector<JointRow>& rows = s.joint_rows;
  auto dynamic = [&](Index b) { return b >= 0 && m_unknowns.dynamic_body[b]; };
  auto push = [&](Index b, const Vec3& j, const Vec3& lever) {  // an impulse j at `lever` from b's centre
    if (!dynamic(b)) return;
    bodies.v.col(b) += j / bodies.mass[b];
    bodies.w.col(b) += bodies.world_inverse_inertia(b) * lever.cross(j);
  };
  auto inverse_mass = [&](Index b, const Vec3& lever, const Vec3& u) {
    if (!dynamic(b)) return 0.0;
    const Vec3 t = lever.cross(u);
    return 1.0 / bodies.mass[b] + t.dot(bodies.world_inverse_inertia(b) * t);
  };
  auto point_velocity = [&](Index b, const Vec3& lever) {
    return b < 0 ? Vec3::Zero() : Vec3(Vec3(bodies.v.col(b)) + Vec3(bodies.w.col(b)).cross(lever));
  };
  for (std::size_t i = 0; i < rows.size(); ++i) {
    if (!m_contact_active[i]) continue;
    const JointRow& row = rows[i];
    const auto r = static_cast<Index>(i);
    const Vec3 n = row.j_a.head<3>();
    const Vec3 lever_a = row.point - Vec3(bodies.x.col(row.body_a));
    const Vec3 lever_b = row.body_b >= 0 ? Vec3(row.point - Vec3(bodies.x.col(row.body_b))) : Vec3::Zero();
    // Normal: pushes only, to the end-of-step gap's bound.
    const double bound = m_end_bound[r];
    double k = 0.0;
    for (const auto& [b, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}})
      if (dynamic(b))
        k +=
            j.head<3>().squaredNorm() / bodies.mass[b] + j.tail<3>().dot(bodies.world_inverse_inertia(b) * j.tail<3>());
    if (!(k > 0.0)) continue;
    const double speed = row_velocity(row, bodies.v, bodies.w);
    const double dn = std::max(m_end_normal[r] + (bound - speed) / k, 0.0) - m_end_normal[r];
    m_end_normal[r] += dn;
    for (const auto& [b, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}})
      if (dynamic(b)) {
        bodies.v.col(b) += j.head<3>() * (dn / bodies.mass[b]);
        bodies.w.col(b) += bodies.world_inverse_inertia(b) * Vec3(j.tail<3>() * dn);
      }
    // Friction: the accumulated tangential impulse within the disc of mu times the normal impulse.
    if (!(row.friction > 0.0)) continue;
    Vec3 slip = point_velocity(row.body_a, lever_a) - point_velocity(row.body_b, lever_b);
    slip -= n.dot(slip) * n;
    const double speed_t = slip.norm();
    if (!(speed_t > 0.0)) continue;
    const Vec3 u = slip / speed_t;
    const double k_t = inverse_mass(row.body_a, lever_a, u) + inverse_mass(row.body_b, lever_b, u);
    if (!(k_t > 0.0)) continue;
    Vec3 friction = Vec3(m_end_friction.col(r)) - slip / k_t;
    const double limit = row.friction * (2.0 * m_contact_impulse[r] + m_end_normal[r]);
    if (friction.norm() > limit) friction *= limit / friction.norm();
    const Vec3 j = friction - Vec3(m_end_friction.col(r));
    m_end_friction.col(r) = friction;
    push(row.body_a, j, lever_a);
    push(row.body_b, -j, lever_b);
  }
}

void Newmark::advance_contact_gaps(const StepModel& s, double dt) {
  m_slipping_pairs.clear();
  if (!m_has_contacts) return;
  m_predicted_v = m_twist_half.topRows<3>();
  m_predicted_w = m_twist_half.bottomRows<3>();
  for (JointRow& row : s.joint_rows)
    if (row.unilateral) row.gap += dt * row_velocity(row, m_predicted_v, m_predicted_w);
  // The sliding pairs still slipping at the step's end (faster than a tenth of what gravity gives in a
  // step): the next step starts them sliding.
  const RigidBodyParticles& bodies = s.bodies;
  const double still = 0.1 * s.gravity.norm() * dt;
  for (std::size_t i = 0; i < s.joint_rows.size(); ++i) {
    const JointRow& row = s.joint_rows[i];
    if (!m_contact_active[i] || !m_contact_sliding[i]) continue;
    const std::pair pair{row.body_a, row.body_b};
    if (std::find(m_slipping_pairs.begin(), m_slipping_pairs.end(), pair) != m_slipping_pairs.end()) continue;
    auto point_velocity = [&](Index b) {
      return b < 0 ? Vec3::Zero()
                   : Vec3(Vec3(bodies.v.col(b)) + Vec3(bodies.w.col(b)).cross(row.point - Vec3(bodies.x.col(b))));
    };
    const Vec3 n = row.j_a.head<3>();
    Vec3 slip = point_velocity(row.body_a) - point_velocity(row.body_b);
    slip -= n.dot(slip) * n;
    if (slip.norm() > still) m_slipping_pairs.push_back(pair);
  }
}

// ---- forces and right-hand side ---------------------------------------------------------------

// The order matters (see the reference notes on the authors' code): elastic and external forces
// are distributed to parents (W^T), then mapped onto soft particles (section 3: f_s = m_s a_target),
// and only then are the binding springs added and distributed, so no soft particle inherits its own
// spring's pull and damping is never mapped.
Vec3 Newmark::compute_forces(const StepModel& s, const Vectors3& x_springs, bool record_bound_forces) {
  auto& p = s.particles;
  auto& bodies = s.bodies;
  m_f.setZero();
  m_wrench.setZero();
  for (const auto& f : s.forces) f->add_elastic_forces(p.x, m_f);
  s.soft.gather_synchronized(m_f);
  if (record_bound_forces) s.hard.record_bound_rows(m_f, m_bound_force, false);
  s.hard.distribute(m_f, m_wrench);

  const Vec3& g = s.gravity;
  for (Index i = 0; i < m_unknowns.n; ++i)
    if (p.kind[i] == ParticleKind::free) m_f.col(i) += p.mass[i] * g;
  for (Index b = 0; b < m_unknowns.r; ++b)
    if (m_unknowns.dynamic_body[b]) {
      if (bodies.gravity[b]) m_wrench.col(b).head<3>() += bodies.mass[b] * g;
      m_wrench.col(b).head<3>() += bodies.force.col(b);
      m_wrench.col(b).tail<3>() += bodies.torque.col(b);
    }

  const Vec3 mapped_total = s.soft.map_forces(p, bodies, s.hard, m_f, m_wrench);

  m_g.setZero();
  s.springs.add_elastic_forces(x_springs, m_g);
  m_f += m_g;
  s.soft.gather_synchronized(m_f);
  if (record_bound_forces) s.hard.record_bound_rows(m_f, m_bound_force, true);
  s.hard.distribute(m_f, m_wrench);
  return mapped_total;
}

void Newmark::build_rhs(const StepModel& s, double h, const Vectors3& v_start, const Vectors3& body_v,
                        const Vectors3& body_L) {
  const Unknowns& u = m_unknowns;
  for (Index i = 0; i < u.n; ++i)
    m_c.particles.col(i) = u.dof_mass[i] * v_start.col(i) + (h * u.dynamic_mask[i]) * m_f.col(i);
  for (Index b = 0; b < u.r; ++b) {
    if (!u.dynamic_body[b]) {
      m_c.rigid.col(b).setZero();
      continue;
    }
    m_c.rigid.col(b).head<3>() = s.bodies.mass[b] * body_v.col(b) + h * m_wrench.col(b).head<3>();
    m_c.rigid.col(b).tail<3>() = body_L.col(b) + h * m_wrench.col(b).tail<3>();
  }
}

// Step 4 keeps step 1's preconditioner (blocks at x^n instead of x^{n+1/2}, half a step apart) when it
// was built for the same h and beta_el, and for the same beta where binding springs make the blocks
// depend on it: a preconditioner needs only to be close, the answer is the same to the CG tolerance,
// and rebuilding it (every force's diagonal blocks, a 3x3 inverse per particle, the multigrid's
// coarse operators) costs about a tenth of a cloth step.
SolveResult Newmark::solve(const StepModel& s, const SolveCoefficients& k, bool linear_solve, bool refresh,
                           GeneralizedVector* alternative, Alternative rule) {
  const StepSettings& settings = s.settings;
  const bool jacobi = settings.jacobi_preconditioner && linear_solve;
  const PreconditionerKey& key = m_preconditioner_key;
  const bool reuse = !refresh && key.k.h == k.h && key.k.beta_el == k.beta_el && key.jacobi == jacobi &&
                     (s.springs.size() == 0 || key.k.beta == k.beta) &&
                     (!m_preconditioner.uses_multigrid() || m_preconditioner.multigrid_built());
  m_system.set(s, k, m_body_I);
  m_last_k = k;
  if (!reuse) {
    m_preconditioner.build(s, m_body_I, k, jacobi);
    m_preconditioner_key = {k, jacobi};
  }
  try {
    return m_cg.solve(m_system, m_c, m_y, settings.cg_tolerance, settings.cg_rms_tolerance, settings.cg_max_iterations,
                      linear_solve, alternative, rule, m_step_count);
  } catch (const Error& e) {
    // Which term turns finite velocities into non-finite forces: each force's implicit products, and
    // the binding springs', on a finite probe (a NaN coefficient set where nothing validated it).
    m_u.setOnes();
    fail(e.what(), non_finite_culprit(s, s.particles.x, m_u, k, m_g));
  }
}

void Newmark::check_constraint(const StepModel& s, const CollisionConstraint& c, std::string_view source) const {
  if (c.size < 1 || c.size > 4)
    fail("collision source '", source, "': a constraint has ", c.size, " particles (1 to 4)");
  if (!(c.normal.allFinite() && std::abs(c.normal.norm() - 1.0) < 1e-6 && std::isfinite(c.normal_velocity)))
    fail("collision source '", source, "': a constraint's normal (", c.normal.transpose(),
         ") is not a unit vector or its velocity ", c.normal_velocity, " is not finite");
  if (!(std::isfinite(c.friction) && c.friction >= 0.0 && c.velocity.allFinite()))
    fail("collision source '", source, "': a constraint's friction ", c.friction, " or surface velocity (",
         c.velocity.transpose(), ") is not finite and non-negative");
  for (int a = 0; a < c.size; ++a) {
    const Index i = c.particles[static_cast<std::size_t>(a)];
    if (i < 0 || i >= m_unknowns.n || !is_dynamic(s.particles.kind[i]))
      fail("collision source '", source, "': constraint on particle ", i,
           ", which is not a free or soft-spring particle");
    if (!std::isfinite(c.weights[static_cast<std::size_t>(a)]))
      fail("collision source '", source, "': constraint on particle ", i, " has a non-finite weight");
    for (int b = 0; b < a; ++b)
      if (c.particles[static_cast<std::size_t>(b)] == i)
        fail("collision source '", source, "': particle ", i, " appears twice in a constraint");
  }
}

void Newmark::restore_start_state(const StepModel& s) {
  s.particles.x = m_x_n;
  s.particles.v = m_v_n;
  s.bodies.x = m_body_x_n;
  s.bodies.v = m_body_v_n;
  s.bodies.w = m_body_w_n;
  for (Index b = 0; b < m_unknowns.r; ++b) s.bodies.q[b] = m_body_q_n[b];
  s.hard.update_rigid_offsets(s.bodies);
}

// Bodies first: a body's bad state reaches the points bound to it, and the body is what to name. With
// `culprit`, the force (or the binding springs) that gives non-finite forces at the step's finite
// start, x^n and v^n: a NaN coefficient that nothing validated, which the state only shows.
void Newmark::check_finite(const StepModel& s, const char* phase, bool culprit) {
  auto named = [&] {
    if (!culprit) return std::string();
    const double h = 0.5 * m_dt;
    return non_finite_culprit(s, m_x_n, m_v_n, {h, h, m_implicit_elasticity ? h : 0.0}, m_g);
  };
  const auto& bodies = s.bodies;
  for (Index b = 0; b < m_unknowns.r; ++b)
    if (!all_finite(bodies.x.col(b)) || !all_finite(bodies.v.col(b)) || !all_finite(bodies.w.col(b)) ||
        !std::isfinite(bodies.q[b].norm()))
      fail("Newmark step ", m_step_count, ", ", phase, ": rigid body ", b, " has a non-finite state", named());
  const auto& p = s.particles;
  for (Index i = 0; i < m_unknowns.n; ++i) {
    if (!all_finite(p.x.col(i)))
      fail("Newmark step ", m_step_count, ", ", phase, ": particle ", i, " has a non-finite position (",
           p.x.col(i).transpose(), ")", named());
    if (!all_finite(p.v.col(i)))
      fail("Newmark step ", m_step_count, ", ", phase, ": particle ", i, " has a non-finite velocity (",
           p.v.col(i).transpose(), ")", named());
  }
}

}  // namespace sinew
