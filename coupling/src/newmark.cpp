#include "newmark.hpp"

#include "sinew/parallel.hpp"

#include <Eigen/SVD>

#include <algorithm>
#include <chrono>
#include <utility>

namespace sinew {

namespace {

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// CG's vector work on the flat particle block (3N doubles, contiguous in Vectors3) plus the rigid
// block, parallel over fixed ranges (sinew/parallel.hpp: the same bits for any thread count).

using FlatMap = Eigen::Map<VectorXd, Eigen::Aligned16>;
using ConstFlatMap = Eigen::Map<const VectorXd, Eigen::Aligned16>;

/// Reductions split the particle block into fixed blocks of 3 kReductionBlock doubles (aligned, as
/// every Eigen allocation is), whatever the thread count; each block's sum is Eigen's vectorised
/// dot, whose association depends only on the block's length and alignment, and the blocks are
/// added in order: the same bits for any thread count.
double dot(const GeneralizedVector& a, const GeneralizedVector& b) {
  const Index n = a.particles.size();
  const double* pa = a.particles.data();
  const double* pb = b.particles.data();
  constexpr Index block = 3 * parallel::kReductionBlock;
  const Index blocks = (n + block - 1) / block;
  thread_local std::vector<double> partial;
  partial.assign(static_cast<std::size_t>(blocks), 0.0);
  double* out = partial.data();
  parallel::for_ranges_when(n >= 3 * parallel::kMinParallelLightItems, blocks, [&](Index b0, Index b1) {
    for (Index k = b0; k < b1; ++k) {
      const Index begin = k * block, length = std::min(n, begin + block) - begin;
      out[k] = ConstFlatMap(pa + begin, length).dot(ConstFlatMap(pb + begin, length));
    }
  });
  double total = 0.0;
  for (Index k = 0; k < blocks; ++k) total += out[k];
  return total + a.rigid.cwiseProduct(b.rigid).sum();
}

/// The b a force's implicit terms are taken at: beta_el for elastic forces with a definite
/// differential (implicit elasticity), 0 (damping alone) for the others.
double implicit_b(const Force& f, double beta_el) { return f.has_definite_differentials() ? beta_el : 0.0; }

/// Runs body(i0, i1) over fixed ranges of a flat particle block of n doubles (3 per particle); the
/// ranges start at even offsets so that maps of them stay 16-byte aligned.
template <typename Body>
void for_flat_ranges(Index n, Body&& body) {
  const bool parallel = n >= 3 * parallel::kMinParallelLightItems;
  parallel::for_ranges_when(parallel, (n + 1) / 2, [&](Index p0, Index p1) { body(2 * p0, std::min(n, 2 * p1)); });
}

/// y += alpha x.
void axpy(double alpha, const GeneralizedVector& x, GeneralizedVector& y) {
  const double* px = x.particles.data();
  double* py = y.particles.data();
  for_flat_ranges(x.particles.size(), [&](Index i0, Index i1) {
    FlatMap(py + i0, i1 - i0) += alpha * ConstFlatMap(px + i0, i1 - i0);
  });
  y.rigid += alpha * x.rigid;
}

/// p = z + beta p.
void update_direction(const GeneralizedVector& z, double beta, GeneralizedVector& p) {
  const double* pz = z.particles.data();
  double* pp = p.particles.data();
  for_flat_ranges(z.particles.size(), [&](Index i0, Index i1) {
    FlatMap(pp + i0, i1 - i0) = ConstFlatMap(pz + i0, i1 - i0) + beta * FlatMap(pp + i0, i1 - i0);
  });
  p.rigid = z.rigid + beta * p.rigid;
}

/// The largest |component| (order-independent, so any partition gives the same value).
double max_abs(const GeneralizedVector& v) {
  const Index n = v.particles.size();
  const double* pv = v.particles.data();
  const int parts = n >= 3 * parallel::kMinParallelLightItems ? std::max(1, thread_count()) : 1;
  thread_local std::vector<double> part;
  part.assign(static_cast<std::size_t>(parts), 0.0);
  double* out = part.data();
  parallel::for_ranges_when(parts > 1, parts, [&](Index p0, Index p1) {
    for (Index p = p0; p < p1; ++p) {
      const Index i0 = n * p / parts, i1 = n * (p + 1) / parts;
      out[p] = i1 > i0 ? Eigen::Map<const VectorXd>(pv + i0, i1 - i0).cwiseAbs().maxCoeff() : 0.0;
    }
  });
  double m = v.rigid.size() > 0 ? v.rigid.cwiseAbs().maxCoeff() : 0.0;
  for (double x : part) m = std::max(m, x);
  return m;
}

}  // namespace

void Newmark::allocate(const System& s) {
  m_n = s.m_particles.size();
  m_r = s.m_bodies.size();
  const Index n = m_n, r = m_r;
  m_dof_mass.setZero(n);
  m_dynamic_mask.setZero(n);
  for (Index i = 0; i < n; ++i) {
    if (!is_dynamic(s.m_particles.kind[i])) continue;
    m_dof_mass[i] = s.m_particles.mass[i];
    m_dynamic_mask[i] = 1.0;
  }
  m_dynamic_body.assign(static_cast<std::size_t>(r), 0);
  for (Index b = 0; b < r; ++b) m_dynamic_body[b] = s.m_bodies.kinematic[b] ? 0 : 1;
  for (Vectors3* a : {&m_x_n, &m_v_n, &m_x_np1, &m_v_tilde_n, &m_v_half, &m_f, &m_g, &m_tmp_v, &m_apply_f, &m_bound_force})
    a->setZero(3, n);
  m_wrench.setZero(6, r);
  m_apply_wrench.setZero(6, r);
  m_twist_half.setZero(6, r);
  for (Vectors3* a : {&m_body_x_n, &m_body_v_n, &m_body_w_n, &m_body_L_n, &m_body_x_np1}) a->setZero(3, r);
  m_body_q_n.assign(static_cast<std::size_t>(r), Quat::Identity());
  m_body_q_np1 = m_body_q_n;
  m_body_I.assign(static_cast<std::size_t>(r), Mat3::Zero());
  m_body_preconditioner.assign(static_cast<std::size_t>(r), Eigen::Matrix<double, 6, 6>::Zero());
  m_diag.setZero(n);
  m_diag_blocks.setZero(9, n);
  m_inverse_blocks.setZero(9, n);
  m_dof_mass3.setZero(3 * n);
  m_h_mask3.setZero(3 * n);
  for (Index i = 0; i < n; ++i) m_dof_mass3.segment<3>(3 * i).setConstant(m_dof_mass[i]);
  m_h_mask_h = -1.0;
  for (GeneralizedVector* g : {&m_c, &m_y, &m_r_vec, &m_z, &m_p, &m_q, &m_guess, &m_last_half}) g->resize(n, r);
  m_last_dt = 0.0;
  m_guess_trial = 0;
  m_extrapolate = false;
  m_constraints.reserve(static_cast<std::size_t>(n));
  m_has_damping = false;
  for (const auto& f : s.m_forces) m_has_damping = m_has_damping || f->has_damping();
  m_multigrid.reset();
  m_allocated = true;
}

// Section 3.3, steps 1-5. Positions and velocities in s are at t^n on entry and t^{n+1} on exit.
StepStats Newmark::step(System& s, double dt) {
  if (!m_allocated) allocate(s);
  const auto start = Clock::now();
  m_implicit_elasticity = false;  // the setting may change between steps
  for (const auto& f : s.m_forces) {
    const bool implicit = s.m_step_settings.implicit_elasticity && f->has_definite_differentials();
    f->set_implicit(implicit);
    m_implicit_elasticity = m_implicit_elasticity || implicit;
  }
  StepStats stats;
  stats.substeps = 1;
  stats.dt = dt;
  save_state(s);
  prepare_joints(s);

  auto t = Clock::now();
  implicit_half_velocity(s, dt, stats);
  check_finite(s, "step 1 (implicit half velocity)");
  stats.ms.implicit_half_velocity = ms_since(t);

  t = Clock::now();
  advance_positions(s, dt);
  check_finite(s, "step 2 (advance positions)");
  stats.ms.advance_positions = ms_since(t);

  t = Clock::now();
  process_collisions(s, dt);
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

  stats.ms.total = ms_since(start);
  ++m_step_count;
  return stats;
}

void Newmark::save_state(System& s) {
  // Bound rows are derived state: recompute them from parents that the caller (or a rigid solver
  // writing into the rigid-body particles) may have moved since the last step.
  s.clamp_bound_rows();
  m_x_n = s.m_particles.x;
  m_v_n = s.m_particles.v;
  auto& bodies = s.m_bodies;
  for (Index b = 0; b < m_r; ++b)
    if (!(bodies.force.col(b).allFinite() && bodies.torque.col(b).allFinite()))
      fail("rigid body ", b, ": applied force (", bodies.force.col(b).transpose(), ") or torque (", bodies.torque.col(b).transpose(),
           ") is not finite");
  m_body_x_n = bodies.x;
  m_body_v_n = bodies.v;
  m_body_w_n = bodies.w;
  for (Index b = 0; b < m_r; ++b) {
    m_body_q_n[b] = bodies.q[b];
    m_body_L_n.col(b) = m_dynamic_body[b] ? bodies.angular_momentum(b) : Vec3::Zero();
  }
}

void Newmark::update_body_inertias(const System& s) {
  for (Index b = 0; b < m_r; ++b) m_body_I[b] = s.m_bodies.world_inertia(b);
}

// Step 1 (eq. 8): (M + dt/2 D + dt^2/4 K) v~^{n+1/2} = M v^n + dt/2 (F_el(x^n) + F_ext - K x^n),
// implicit in all damping and in the binding springs, explicit in the other elastic forces unless
// StepSettings::implicit_elasticity adds their definite differentials to K: then
// F_el(x^n + dt/2 v~^{n+1/2}) ~ F_el(x^n) + dt/2 K+ v~^{n+1/2}, linearised once, as for the springs.
void Newmark::implicit_half_velocity(System& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  auto t = Clock::now();
  update_body_inertias(s);
  for (auto& f : s.m_forces) f->update_position_state(s.m_particles.x);
  compute_forces(s, s.m_particles.x);
  build_rhs(s, h, m_v_n, m_body_v_n, m_body_L_n);
  m_y.particles = m_v_n;
  m_y.rigid.topRows<3>() = m_body_v_n;
  m_y.rigid.bottomRows<3>() = m_body_w_n;
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
  const bool history = m_last_dt > 0.0;
  const Step1Guess guess_rule = s.m_step_settings.step1_guess;
  bool extrapolate = false, trial = false;
  if (history) {
    const double ratio = dt / m_last_dt;
    double change = 0.0;
    for (Index i = 0; i < m_n; ++i) {
      const Vec3 d = m_dynamic_mask[i] > 0.0 ? Vec3(ratio * (m_v_n.col(i) - m_last_half.particles.col(i))) : Vec3::Zero();
      m_guess.particles.col(i) = d;
      change = std::max(change, d.cwiseAbs().maxCoeff());
    }
    for (Index b = 0; b < m_r; ++b) {
      const Vec6 d = m_dynamic_body[b] ? Vec6(ratio * (m_y.rigid.col(b) - m_last_half.rigid.col(b))) : Vec6::Zero();
      m_guess.rigid.col(b) = d;
      change = std::max(change, d.cwiseAbs().maxCoeff());
    }
    if (guess_rule == Step1Guess::extrapolated) {
      extrapolate = true;
    } else if (guess_rule == Step1Guess::adaptive && change > 10.0 * s.m_step_settings.cg_tolerance) {
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
  }
  // Before the first step, a second initial guess instead: M^-1 c = v^n + dt/2 M^-1 F on the
  // unknowns (explicit in the implicit terms): exact for motion they do not resist (free fall,
  // rigid translation), so solve() takes it when it is exact; far off where they are stiff, where
  // v^n is kept.
  if (!history) {
    for (Index i = 0; i < m_n; ++i)
      m_guess.particles.col(i) = m_dynamic_mask[i] > 0.0 ? Vec3(m_c.particles.col(i) / m_dof_mass[i]) : Vec3(m_v_n.col(i));
    for (Index b = 0; b < m_r; ++b) {
      if (m_dynamic_body[b]) {
        m_guess.rigid.col(b).head<3>() = m_c.rigid.col(b).head<3>() / s.m_bodies.mass[b];
        m_guess.rigid.col(b).tail<3>() = m_body_I[b].inverse() * m_c.rigid.col(b).tail<3>();
      } else {
        m_guess.rigid.col(b) = m_y.rigid.col(b);
      }
    }
  }
  m_constraints.clear();  // collisions are inactive in the first solve
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  const bool linear_solve = m_has_damping || s.m_springs.size() > 0 || m_implicit_elasticity || m_joint_group_count > 0;
  m_refresh_preconditioner = true;
  GeneralizedVector* alternative = !history || trial ? &m_guess : nullptr;
  const SolveResult result = solve(s, h, h, m_implicit_elasticity ? h : 0.0, linear_solve, alternative,
                                   history ? Alternative::if_smaller : Alternative::if_exact);
  if (trial) m_extrapolate = result.took_alternative;
  stats.ms.cg += ms_since(t);
  stats.linear_solve = linear_solve;
  record_solve(result, stats.cg_iterations_step1, stats);

  keep_half_velocity(s);
  if (m_implicit_elasticity && linear_solve)
    for (int k = 0; k < s.m_step_settings.newton_iterations; ++k) newton_iteration(s, dt, stats);
}

// A solve's iterations (into `iterations`, step 1's or step 4's count), residual and convergence.
void Newmark::record_solve(const SolveResult& result, int& iterations, StepStats& stats) {
  iterations += result.iterations;
  stats.cg_residual = std::max(stats.cg_residual, result.residual);
  stats.cg_converged = stats.cg_converged && result.converged;
}

// Step 1's answer (in m_y) as the half-step velocities: kept for step 2 and step 4's guess, and set
// on the particles and bodies.
void Newmark::keep_half_velocity(System& s) {
  m_v_half = m_y.particles;
  m_twist_half = m_y.rigid;
  s.m_particles.v = m_y.particles;
  s.m_bodies.v = m_y.rigid.topRows<3>();
  s.m_bodies.w = m_y.rigid.bottomRows<3>();
}

// One Newton iteration on step 1 (StepSettings::newton_iterations): the implicit forces relinearised
// at x_mid = x^n + h v~^{n+1/2}, where the half step ends (F(x_mid + h (v - v_prev)) ~ F(x_mid) +
// h K+(x_mid) (v - v_prev)), so (M - h D - h^2 K+) v = M v^n + h F(x_mid) - h^2 K+ v_prev: the same
// operator as step 1's at the new state, and c gains apply(with K) - apply(without K) of v_prev.
// Linear forces (binding springs) come out unchanged: their F(x_mid) - F(x^n) is that correction.
// Positions go back to x^n exactly afterwards; step 2 advances from there.
void Newmark::newton_iteration(System& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  auto t = Clock::now();
  move_positions(s, h);
  synchronize(s, true, false);
  for (auto& f : s.m_forces) f->update_position_state(s.m_particles.x);
  compute_forces(s, s.m_particles.x);
  build_rhs(s, h, m_v_n, m_body_v_n, m_body_L_n);
  apply(s, h, h, h, m_y, m_q);
  apply(s, h, 0.0, 0.0, m_y, m_p);
  m_c.particles += m_q.particles - m_p.particles;
  m_c.rigid += m_q.rigid - m_p.rigid;
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  m_refresh_preconditioner = true;
  const SolveResult result = solve(s, h, h, h, true);
  stats.ms.cg += ms_since(t);
  record_solve(result, stats.cg_iterations_step1, stats);
  ++stats.newton_iterations;

  restore_positions(s);
  keep_half_velocity(s);
}

// Step 2: x~^{n+1} = x^n + dt v~^{n+1/2}; rigid frames x_c += dt v_c, q = q(dt w^{n+1/2}) q^n
// (section 5, step 3). Velocities return to v^n, which step 3 turns into v~^n.
void Newmark::advance_positions(System& s, double dt) {
  auto& p = s.m_particles;
  auto& bodies = s.m_bodies;
  move_positions(s, dt);
  p.v = m_v_n;
  bodies.v = m_body_v_n;
  bodies.w = m_body_w_n;
  s.m_hard.clamp_velocities(p.v, bodies.v, bodies.w);
}

// Positions x^n + tau v~^{n+1/2} on the particles that move (dynamic and kinematic rows), rigid frames
// x_c + tau v_c and q(tau w) q^n with the bodies' current (step 1's) twists, bound rows from their
// parents; velocities untouched.
void Newmark::move_positions(System& s, double tau) {
  auto& p = s.m_particles;
  for (Index i = 0; i < m_n; ++i)
    if (is_dynamic(p.kind[i]) || p.kind[i] == ParticleKind::kinematic) p.x.col(i) = m_x_n.col(i) + tau * m_v_half.col(i);
  auto& bodies = s.m_bodies;
  const bool gyroscopic = s.m_step_settings.gyroscopic_correction;
  for (Index b = 0; b < m_r; ++b) {
    Vec3 w = bodies.w.col(b);
    if (gyroscopic && m_dynamic_body[b]) {
      // w(t) = I(t)^-1 L drifts even without torque when I0 is not isotropic: dw/dt = I^-1 (L x w).
      // Rotating with the midpoint value keeps the orientation update second order.
      const Vec3 L = m_body_I[b] * w;
      w += 0.5 * tau * (m_body_I[b].inverse() * L.cross(w));
    }
    bodies.x.col(b) = m_body_x_n.col(b) + tau * bodies.v.col(b);
    bodies.q[b] = (rotation_from_vector(tau * w) * m_body_q_n[b]).normalized();
  }
  s.m_hard.update_rigid_offsets(bodies);
  s.m_hard.clamp_positions(p.x, bodies.x);
}

void Newmark::restore_positions(System& s) {
  s.m_particles.x = m_x_n;
  auto& bodies = s.m_bodies;
  bodies.x = m_body_x_n;
  for (Index b = 0; b < m_r; ++b) bodies.q[b] = m_body_q_n[b];
  s.m_hard.update_rigid_offsets(bodies);
}

// Step 3: (x~^{n+1}, v^n) -> (x^{n+1}, v~^n). Deformables only (section 5, step 4): the hook sees
// free and soft-bound particles; synchronized soft particles start on their targets and whatever
// drift the hook gives them is pushed back to the targets' parents.
void Newmark::process_collisions(System& s, double dt) {
  synchronize(s, true, true);
  m_constraints.clear();
  if (s.m_collision_hook) {
    CollisionContext context;
    context.time = s.m_time;
    context.dt = dt;
    context.x_n = &m_x_n;
    context.x = &s.m_particles.x;
    context.v = &s.m_particles.v;
    context.particles = &s.m_particles;
    context.bodies = &s.m_bodies;
    context.constraints = &m_constraints;
    s.m_collision_hook(context);
    for (const CollisionConstraint& c : m_constraints)
      if (c.particle < 0 || c.particle >= m_n || !is_dynamic(s.m_particles.kind[c.particle]))
        fail("collision hook: constraint on particle ", c.particle, ", which is not a free or soft-spring particle");
    push_synchronized_drift(s);
  }
  s.m_hard.clamp_positions(s.m_particles.x, s.m_bodies.x);
  s.m_hard.clamp_velocities(s.m_particles.v, s.m_bodies.v, s.m_bodies.w);
  synchronize(s, true, true);
  m_x_np1 = s.m_particles.x;
  m_body_x_np1 = s.m_bodies.x;
  for (Index b = 0; b < m_r; ++b) m_body_q_np1[b] = s.m_bodies.q[b];
}

// Step 4: (M + dt/2 D) v^{n+1/2} = M v~^n + dt/2 (F_el(x^{n+1/2}) + F_ext - K x^{n+1/2}), with the
// collision constraints of step 3 projected. x^{n+1/2} is what keeps the stiff binding springs
// stable (section 3.3); BindingSpringStep4 selects the alternatives. Implicit elasticity adds
// dt^2/4 K+(x^{n+1/2}) of the elastic forces to the operator.
void Newmark::backward_euler_velocity(System& s, double dt, StepStats& stats) {
  const double h = 0.5 * dt;
  auto t = Clock::now();
  auto& p = s.m_particles;
  auto& bodies = s.m_bodies;
  m_v_tilde_n = p.v;
  for (Index i = 0; i < m_n; ++i) p.x.col(i) = 0.5 * (m_x_n.col(i) + m_x_np1.col(i));
  for (Index b = 0; b < m_r; ++b) {
    bodies.x.col(b) = 0.5 * (m_body_x_n.col(b) + m_body_x_np1.col(b));
    bodies.q[b] = m_body_q_n[b].slerp(0.5, m_body_q_np1[b]).normalized();
  }
  s.m_hard.update_rigid_offsets(bodies);
  s.m_hard.clamp_positions(p.x, bodies.x);
  synchronize(s, true, false);
  update_body_inertias(s);
  for (auto& f : s.m_forces) f->update_position_state(p.x);

  const BindingSpringStep4 mode = s.m_step_settings.binding_springs_in_step4;
  const Vec3 mapped = compute_forces(s, mode == BindingSpringStep4::explicit_end_of_step ? m_x_np1 : p.x, true);
  stats.mapped_impulse += dt * mapped;
  // Rigid rows start from v~^n = (v_c, L^n): L is the momentum-like state, so w is recomputed with
  // the inertia at the half-step orientation.
  build_rhs(s, h, m_v_tilde_n, bodies.v, m_body_L_n);
  // Initial guess: step 1's half-step velocity v~^{n+1/2} on the unknowns (it solves nearly the same
  // system at nearly the same configuration, so CG starts O(dt) from the answer instead of O(dt)
  // times the accelerations away), the prescribed values on constrained rows. The result is the
  // same to the CG tolerance whichever guess is used.
  for (Index i = 0; i < m_n; ++i)
    m_y.particles.col(i) = m_dynamic_mask[i] > 0.0 ? Vec3(m_v_half.col(i)) : Vec3(m_v_tilde_n.col(i));
  for (Index b = 0; b < m_r; ++b) {
    if (m_dynamic_body[b]) {
      m_y.rigid.col(b) = m_twist_half.col(b);
    } else {
      m_y.rigid.col(b).head<3>() = bodies.v.col(b);
      m_y.rigid.col(b).tail<3>() = bodies.w.col(b);
    }
  }
  for (const CollisionConstraint& c : m_constraints) {
    auto y = m_y.particles.col(c.particle);
    y += (c.normal_velocity - c.normal.dot(y)) * c.normal;
  }
  stats.ms.forces += ms_since(t);

  t = Clock::now();
  const double beta = mode == BindingSpringStep4::implicit_half_step ? h : 0.0;
  const bool linear_solve = m_has_damping || s.m_springs.size() > 0 || m_implicit_elasticity || m_joint_group_count > 0;
  m_refresh_preconditioner = false;
  const SolveResult result = solve(s, h, beta, m_implicit_elasticity ? h : 0.0, linear_solve);
  stats.ms.cg += ms_since(t);
  record_solve(result, stats.cg_iterations_step4, stats);
  m_v_half = m_y.particles;
  m_last_half.particles = m_y.particles;
  m_last_half.rigid = m_y.rigid;
  m_last_dt = dt;

  // Back to x^{n+1}; the half-step twists stay in m_y.rigid for step 5.
  p.x = m_x_np1;
  bodies.x = m_body_x_np1;
  for (Index b = 0; b < m_r; ++b) bodies.q[b] = m_body_q_np1[b];
}

// Step 5: v^{n+1} = 2 v^{n+1/2} - v~^n. Rigid bodies extrapolate momentum, L^{n+1} = 2 L^{n+1/2} - L^n,
// and take w^{n+1} = I(q^{n+1})^-1 L^{n+1}, so a torque-free body keeps L exactly.
void Newmark::extrapolate_velocity(System& s) {
  auto& p = s.m_particles;
  for (Index i = 0; i < m_n; ++i)
    if (is_dynamic(p.kind[i])) p.v.col(i) = 2.0 * m_v_half.col(i) - m_v_tilde_n.col(i);
  auto& bodies = s.m_bodies;
  for (Index b = 0; b < m_r; ++b) {
    if (!m_dynamic_body[b]) continue;
    const Vec3 L_half = m_body_I[b] * m_y.rigid.col(b).tail<3>();
    const Vec3 L = 2.0 * L_half - m_body_L_n.col(b);
    bodies.v.col(b) = 2.0 * m_y.rigid.col(b).head<3>() - bodies.v.col(b);
    bodies.w.col(b) = bodies.world_inverse_inertia(b) * L;
  }
  if (m_joint_group_count > 0) {
    // The joints hold at the end of the step too: extrapolation through v^{n+1/2} would otherwise
    // reflect a violation present at t^n (-err at t^{n+1}, +err at t^{n+2}, ...) instead of removing it.
    m_y.rigid.topRows<3>() = bodies.v;
    m_y.rigid.bottomRows<3>() = bodies.w;
    impose_joints(m_y);
    bodies.v = m_y.rigid.topRows<3>();
    bodies.w = m_y.rigid.bottomRows<3>();
  }
  s.m_hard.update_rigid_offsets(bodies);
  s.m_hard.clamp_velocities(p.v, bodies.v, bodies.w);
  synchronize(s, true, true);
}

// ---- forces and right-hand side ---------------------------------------------------------------

// The order matters (see the reference notes on the authors' code): elastic and external forces
// are distributed to parents (W^T), then mapped onto soft particles (section 3: f_s = m_s a_target),
// and only then are the binding springs added and distributed, so no soft particle inherits its own
// spring's pull and damping is never mapped.
Vec3 Newmark::compute_forces(System& s, const Vectors3& x_springs, bool record_bound_forces) {
  auto& p = s.m_particles;
  auto& bodies = s.m_bodies;
  const HardBindings& hard = s.m_hard;
  auto record = [&](bool first) {
    if (!record_bound_forces) return;
    for (Index k = 0; k < hard.linear_count(); ++k) {
      const Index i = hard.linear_particle(k);
      m_bound_force.col(i) = (first ? Vec3::Zero() : Vec3(m_bound_force.col(i))) + Vec3(m_f.col(i));
    }
    for (Index k = 0; k < hard.rigid_count(); ++k) {
      const Index i = hard.rigid_particle(k);
      m_bound_force.col(i) = (first ? Vec3::Zero() : Vec3(m_bound_force.col(i))) + Vec3(m_f.col(i));
    }
  };
  m_f.setZero();
  m_wrench.setZero();
  for (const auto& f : s.m_forces) f->add_elastic_forces(p.x, m_f);
  gather_synchronized(s, m_f);
  record(true);
  s.m_hard.distribute(m_f, m_wrench);

  const Vec3& g = s.m_settings.gravity;
  for (Index i = 0; i < m_n; ++i)
    if (p.kind[i] == ParticleKind::free) m_f.col(i) += p.mass[i] * g;
  for (Index b = 0; b < m_r; ++b)
    if (m_dynamic_body[b]) {
      if (bodies.gravity[b]) m_wrench.col(b).head<3>() += bodies.mass[b] * g;
      m_wrench.col(b).head<3>() += bodies.force.col(b);
      m_wrench.col(b).tail<3>() += bodies.torque.col(b);
    }

  // Parent accelerations a = M^-1 F (zero for kinematic parents, 1/inf = 0), read at the target.
  Vec3 mapped_total = Vec3::Zero();
  const SoftBindings& soft = s.m_soft;
  for (Index k = 0; k < soft.size(); ++k) {
    if (soft.coupling[k] != SoftCoupling::spring) continue;
    const Index target = soft.target[k];
    Vec3 a;
    const Index code = s.m_hard.binding_of(target);
    if (code == HardBindings::unbound) {
      a = p.kind[target] == ParticleKind::kinematic ? Vec3::Zero() : Vec3(m_f.col(target) / p.mass[target]);
    } else if (code >= 0) {
      a.setZero();
      const auto parents = s.m_hard.linear_parents(code);
      const auto weights = s.m_hard.linear_weights(code);
      for (std::size_t j = 0; j < parents.size(); ++j) a += (weights[j] / p.mass[parents[j]]) * m_f.col(parents[j]);
    } else {
      const Index r = -code - 1, b = s.m_hard.rigid_body(r);
      if (!m_dynamic_body[b]) {
        a.setZero();
      } else {
        const Vec3 alpha = bodies.world_inverse_inertia(b) * m_wrench.col(b).tail<3>();
        a = m_wrench.col(b).head<3>() / bodies.mass[b] + alpha.cross(s.m_hard.rigid_offset_world(r));
      }
    }
    const Vec3 f_mapped = p.mass[soft.particle[k]] * a;
    m_f.col(soft.particle[k]) += f_mapped;
    mapped_total += f_mapped;
  }

  m_g.setZero();
  s.m_springs.add_elastic_forces(x_springs, m_g);
  m_f += m_g;
  gather_synchronized(s, m_f);
  record(false);
  s.m_hard.distribute(m_f, m_wrench);
  return mapped_total;
}

void Newmark::build_rhs(const System& s, double h, const Vectors3& v_start, const Vectors3& body_v, const Vectors3& body_L) {
  for (Index i = 0; i < m_n; ++i) m_c.particles.col(i) = m_dof_mass[i] * v_start.col(i) + (h * m_dynamic_mask[i]) * m_f.col(i);
  for (Index b = 0; b < m_r; ++b) {
    if (!m_dynamic_body[b]) {
      m_c.rigid.col(b).setZero();
      continue;
    }
    m_c.rigid.col(b).head<3>() = s.m_bodies.mass[b] * body_v.col(b) + h * m_wrench.col(b).head<3>();
    m_c.rigid.col(b).tail<3>() = body_L.col(b) + h * m_wrench.col(b).tail<3>();
  }
}

// ---- the linear solve -----------------------------------------------------------------------------

// S u = M u - h W^T (D + beta K) W u on the unknowns; rows without unknowns return zero. W is applied
// by clamping bound rows from the trial velocities (hard bindings are eliminated, not projected).
void Newmark::apply(System& s, double h, double beta, double beta_el, const GeneralizedVector& u, GeneralizedVector& out) {
  parallel::for_light_ranges(m_n, [&](Index i0, Index i1) {
    m_tmp_v.middleCols(i0, i1 - i0) = u.particles.middleCols(i0, i1 - i0);
    m_apply_f.middleCols(i0, i1 - i0).setZero();
  });
  s.m_hard.clamp_velocities(m_tmp_v, u.rigid);
  for (Index k = 0; k < s.m_soft.size(); ++k)
    if (s.m_soft.coupling[k] == SoftCoupling::synchronized) m_tmp_v.col(s.m_soft.particle[k]) = m_tmp_v.col(s.m_soft.target[k]);
  m_apply_wrench.setZero();
  for (const auto& f : s.m_forces) f->add_implicit_products(m_tmp_v, implicit_b(*f, beta_el), m_apply_f);
  s.m_springs.add_linear_forces(m_tmp_v, 1.0, beta, m_apply_f);
  gather_synchronized(s, m_apply_f);
  s.m_hard.distribute(m_apply_f, m_apply_wrench);

  // Rows without unknowns have zero mass and mask, so they come out zero here (project() below then
  // only has bodies and collision normals to handle on the particle block).
  if (m_h_mask_h != h) {
    for (Index i = 0; i < m_n; ++i) m_h_mask3.segment<3>(3 * i).setConstant(h * m_dynamic_mask[i]);
    m_h_mask_h = h;
  }
  {
    const double* pm = m_dof_mass3.data();
    const double* ph = m_h_mask3.data();
    const double* pu = u.particles.data();
    const double* pf = m_apply_f.data();
    double* po = out.particles.data();
    for_flat_ranges(3 * m_n, [&](Index i0, Index i1) {
      const Index l = i1 - i0;
      FlatMap(po + i0, l) = ConstFlatMap(pm + i0, l).cwiseProduct(ConstFlatMap(pu + i0, l)) -
                            ConstFlatMap(ph + i0, l).cwiseProduct(ConstFlatMap(pf + i0, l));
    });
  }
  const auto& bodies = s.m_bodies;
  for (Index b = 0; b < m_r; ++b) {
    if (!m_dynamic_body[b]) {
      out.rigid.col(b).setZero();
      continue;
    }
    out.rigid.col(b).head<3>() = bodies.mass[b] * u.rigid.col(b).head<3>() - h * m_apply_wrench.col(b).head<3>();
    out.rigid.col(b).tail<3>() = m_body_I[b] * u.rigid.col(b).tail<3>() - h * m_apply_wrench.col(b).tail<3>();
  }
  project_constraints(out);
}

// Block Jacobi: each particle's 3x3 diagonal block m I + h (D_ii + beta_el K+_ii + springs) (forces
// without blocks contribute a multiple of the identity from their scalar diagonal), hard-bound rows'
// blocks passed to their parents through W^T W (a 6x6 block per rigid body). The 3x3 blocks matter
// for cloth: an edge spring is stiff along its direction only, so a node's block is stiff in the
// cloth's plane and soft across it, which a scalar diagonal cannot express.
void Newmark::build_preconditioner(System& s, double h, double beta, double beta_el, bool jacobi) {
  m_diag_blocks.setZero();
  if (jacobi) {
    m_diag.setZero();
    for (const auto& f : s.m_forces)
      if (const ImplicitBlocks* blocks = f->implicit_blocks()) {
        const double b = implicit_b(*f, beta_el);
        if (!blocks->add_diagonal_blocks(b, m_diag_blocks)) blocks->add_diagonal(b, m_diag);
      }
    m_diag_blocks *= h;
    m_diag *= h;
    s.m_springs.add_diagonal(h, h * beta, m_diag);
    for (Index i = 0; i < m_n; ++i) {
      m_diag_blocks(0, i) += m_diag[i];
      m_diag_blocks(4, i) += m_diag[i];
      m_diag_blocks(8, i) += m_diag[i];
    }
    for (Index k = 0; k < s.m_soft.size(); ++k)
      if (s.m_soft.coupling[k] == SoftCoupling::synchronized) {
        m_diag_blocks.col(s.m_soft.target[k]) += m_diag_blocks.col(s.m_soft.particle[k]);
        m_diag_blocks.col(s.m_soft.particle[k]).setZero();
      }
  }
  auto block_of = [&](Index i) { return Eigen::Map<Mat3>(m_diag_blocks.col(i).data()); };
  const HardBindings& hard = s.m_hard;
  for (Index b = 0; b < m_r; ++b) {
    auto& block = m_body_preconditioner[b];
    block.setZero();
    block.topLeftCorner<3, 3>() = s.m_bodies.mass[b] * Mat3::Identity();
    block.bottomRightCorner<3, 3>() = m_body_I[b];
  }
  if (jacobi) {
    for (Index k = 0; k < hard.linear_count(); ++k) {
      const Mat3 d = block_of(hard.linear_particle(k));
      const auto parents = hard.linear_parents(k);
      const auto weights = hard.linear_weights(k);
      for (std::size_t j = 0; j < parents.size(); ++j) block_of(parents[j]) += (weights[j] * weights[j]) * d;
    }
    for (Index k = 0; k < hard.rigid_count(); ++k) {
      // W^T B W with W = [I  r*^T]: the bound point's block seen by the body's twist.
      const Mat3 d = block_of(hard.rigid_particle(k));
      const Mat3 rs = cross_matrix(hard.rigid_offset_world(k));
      auto& block = m_body_preconditioner[hard.rigid_body(k)];
      block.topLeftCorner<3, 3>() += d;
      block.topRightCorner<3, 3>() += d * rs.transpose();
      block.bottomLeftCorner<3, 3>() += rs * d;
      block.bottomRightCorner<3, 3>() += rs * d * rs.transpose();
    }
  }
  for (Index i = 0; i < m_n; ++i) {
    Eigen::Map<Mat3> inverse(m_inverse_blocks.col(i).data());
    if (m_dynamic_mask[i] > 0.0) {
      Mat3 block = block_of(i);
      block.diagonal().array() += m_dof_mass[i];
      inverse = block.inverse();
    } else {
      inverse.setZero();
    }
  }
  for (Index b = 0; b < m_r; ++b)
    m_body_preconditioner[b] = m_dynamic_body[b] ? Eigen::Matrix<double, 6, 6>(m_body_preconditioner[b].inverse())
                                                 : Eigen::Matrix<double, 6, 6>::Zero();
  m_use_multigrid = jacobi && s.m_step_settings.multigrid;
  if (m_use_multigrid) {
    // The coarse operators: the full diagonal blocks (mass included) and every force's pair blocks
    // of S = M - h F, restricted to the particle unknowns.
    for (Index i = 0; i < m_n; ++i) {
      auto block = m_diag_blocks.col(i);
      block[0] += m_dof_mass[i];
      block[4] += m_dof_mass[i];
      block[8] += m_dof_mass[i];
    }
    m_multigrid.begin(m_dynamic_mask, m_diag_blocks, -h);
    // Level 1 gathers the forces' blocks in parallel once the hierarchy exists; the first update
    // (which records the pairs) and forces that offer no single blocks go through the visits.
    m_pair_sources.clear();
    std::size_t counted = 0;
    for (const auto& f : s.m_forces)
      if (const ImplicitBlocks* blocks = f->implicit_blocks(); blocks && blocks->pair_block_count() > 0) {
        m_pair_sources.push_back({blocks, implicit_b(*f, beta_el)});
        counted += static_cast<std::size_t>(blocks->pair_block_count());
      }
    m_multigrid.reserve(counted);
    auto pass = [&] {
      if (!m_multigrid.gather(m_pair_sources))
        for (const auto& f : s.m_forces)
          if (const ImplicitBlocks* blocks = f->implicit_blocks()) blocks->visit_pair_blocks(implicit_b(*f, beta_el), m_multigrid);
      m_multigrid.end();
    };
    pass();
    if (m_multigrid.needs_blocks_again()) {  // the first update: the pairs chose level 1, now its blocks
      m_multigrid.begin(m_dynamic_mask, m_diag_blocks, -h);
      pass();
    }
  }
}

// Rows without unknowns have zero inverse blocks, so z is zero there without projecting.
void Newmark::precondition(const GeneralizedVector& r, GeneralizedVector& z) {
  if (m_use_multigrid) {
    m_multigrid.apply(r.particles, z.particles, m_inverse_blocks);
    for (Index b = 0; b < m_r; ++b) z.rigid.col(b) = m_body_preconditioner[b] * r.rigid.col(b);
    project_constraints(z);
    return;
  }
  const double* pb = m_inverse_blocks.data();
  const double* pr = r.particles.data();
  double* pz = z.particles.data();
  parallel::for_light_ranges(m_n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      const double* B = pb + 9 * i;
      const double r0 = pr[3 * i], r1 = pr[3 * i + 1], r2 = pr[3 * i + 2];
      pz[3 * i] = B[0] * r0 + B[3] * r1 + B[6] * r2;
      pz[3 * i + 1] = B[1] * r0 + B[4] * r1 + B[7] * r2;
      pz[3 * i + 2] = B[2] * r0 + B[5] * r1 + B[8] * r2;
    }
  });
  for (Index b = 0; b < m_r; ++b) z.rigid.col(b) = m_body_preconditioner[b] * r.rigid.col(b);
  project_constraints(z);
}

void Newmark::project(GeneralizedVector& u) const {
  parallel::for_light_ranges(m_n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i)
      if (m_dynamic_mask[i] == 0.0) u.particles.col(i).setZero();
  });
  project_constraints(u);
}

void Newmark::project_constraints(GeneralizedVector& u) const {
  for (Index b = 0; b < m_r; ++b)
    if (!m_dynamic_body[b]) u.rigid.col(b).setZero();
  for (const CollisionConstraint& c : m_constraints) {
    auto col = u.particles.col(c.particle);
    col -= c.normal.dot(col) * c.normal;
  }
  project_joint_groups(u, false);
}

void Newmark::impose_joints(GeneralizedVector& u) const { project_joint_groups(u, true); }

// Each joint group's twists u_g -> u_g - Q Q^T u_g (the rows' null space), plus the particular
// solution when the rows' targets are imposed; in scratch kept between steps (no allocation).
void Newmark::project_joint_groups(GeneralizedVector& u, bool impose_targets) const {
  for (std::size_t gi = 0; gi < m_joint_group_count; ++gi) {
    const JointGroup& g = m_joint_groups[gi];
    const Index k = static_cast<Index>(g.bodies.size());
    auto u_g = m_joint_scratch.head(6 * k);
    auto coefficients = m_joint_coefficients.head(g.basis.cols());
    for (Index j = 0; j < k; ++j) u_g.segment<6>(6 * j) = u.rigid.col(g.bodies[j]);
    coefficients.noalias() = g.basis.transpose() * u_g;
    u_g.noalias() -= g.basis * coefficients;
    if (impose_targets) u_g += g.particular;
    for (Index j = 0; j < k; ++j) u.rigid.col(g.bodies[j]) = u_g.segment<6>(6 * j);
  }
}

// Joint rows J u = t on the dynamic bodies (kinematic bodies' twists moved to t). The CG then works
// in the rows' null space, like the collision normals: P = I - Q Q^T with Q an orthonormal basis of
// the rows (redundant rows, as two joints on one axis give, drop out by rank), and the joints'
// reactions are the multipliers J^T lambda the projection removes.
void Newmark::prepare_joints(const System& s) {
  m_joint_group_count = 0;
  const auto& rows = s.m_joint_rows;
  if (rows.empty()) return;
  const auto& bodies = s.m_bodies;
  // Groups of dynamic bodies linked by rows (union-find), in the order of their first row.
  std::vector<Index>& root = m_joint_root;
  root.resize(static_cast<std::size_t>(m_r));
  for (Index b = 0; b < m_r; ++b) root[b] = b;
  auto find = [&](Index b) {
    while (root[b] != b) b = root[b] = root[root[b]];
    return b;
  };
  auto dynamic = [&](Index b) { return b >= 0 && m_dynamic_body[b]; };
  for (const JointRow& row : rows)
    if (dynamic(row.body_a) && dynamic(row.body_b)) {
      const Index a = find(row.body_a), b = find(row.body_b);
      if (a != b) root[std::max(a, b)] = std::min(a, b);
    }
  std::vector<Index>& group_of = m_joint_group_of;
  group_of.assign(static_cast<std::size_t>(m_r), -1);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const JointRow& row = rows[i];
    const Index body = dynamic(row.body_a) ? row.body_a : dynamic(row.body_b) ? row.body_b : -1;
    if (body < 0) continue;  // between prescribed bodies: nothing to solve
    const Index r = find(body);
    if (group_of[r] < 0) {
      group_of[r] = static_cast<Index>(m_joint_group_count++);
      if (m_joint_groups.size() < m_joint_group_count) m_joint_groups.emplace_back();
      m_joint_groups[m_joint_group_count - 1].rows.clear();
      m_joint_groups[m_joint_group_count - 1].bodies.clear();
    }
    m_joint_groups[group_of[r]].rows.push_back(static_cast<Index>(i));
  }
  for (Index b = 0; b < m_r; ++b)
    if (m_dynamic_body[b] && group_of[find(b)] >= 0) m_joint_groups[group_of[find(b)]].bodies.push_back(b);
  Index largest = 0, largest_rank = 0;
  for (std::size_t g = 0; g < m_joint_group_count; ++g) {
    JointGroup& group = m_joint_groups[g];
    const Index k = static_cast<Index>(group.bodies.size());
    largest = std::max(largest, k);
    auto slot = [&](Index b) {
      return static_cast<Index>(std::lower_bound(group.bodies.begin(), group.bodies.end(), b) - group.bodies.begin());
    };
    const Index m = static_cast<Index>(group.rows.size());
    group.J.setZero(m, 6 * k);
    group.t.resize(m);
    for (Index i = 0; i < m; ++i) {
      const JointRow& row = rows[group.rows[i]];
      group.t[i] = row.target;
      for (const auto& [body, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}}) {
        if (body < 0) continue;
        if (m_dynamic_body[body]) {
          group.J.row(i).segment<6>(6 * slot(body)) += j.transpose();
        } else {
          group.t[i] -= j.head<3>().dot(bodies.v.col(body)) + j.tail<3>().dot(bodies.w.col(body));
        }
      }
    }
    // The SVD keeps its work space between steps (Eigen reallocates only when the shape changes).
    group.svd.compute(group.J, Eigen::ComputeThinU | Eigen::ComputeThinV);
    const VectorXd& sigma = group.svd.singularValues();
    Index rank = 0;
    while (rank < sigma.size() && sigma[rank] > 1e-10 * sigma[0]) ++rank;
    largest_rank = std::max(largest_rank, rank);
    group.basis = group.svd.matrixV().leftCols(rank);
    group.coefficients.resize(rank);
    group.coefficients.noalias() = group.svd.matrixU().leftCols(rank).transpose() * group.t;
    group.coefficients.array() /= sigma.head(rank).array();
    group.particular.resize(6 * k);
    group.particular.noalias() = group.basis * group.coefficients;
  }
  m_joint_scratch.resize(6 * largest);
  m_joint_coefficients.resize(largest_rank);
}

// Preconditioned conjugate gradients on the symmetric positive definite S = M + h W^T(D + beta K)W
// (symmetric in the plain inner product; the paper's mass inner product form is the same iteration).
// Constrained directions (kinematic rows and bodies, collision normals) keep their initial values.
Newmark::SolveResult Newmark::solve(System& s, double h, double beta, double beta_el, bool linear_solve,
                                    GeneralizedVector* alternative, Alternative rule) {
  SolveResult result;
  const StepSettings& settings = s.m_step_settings;
  // Step 4 keeps step 1's preconditioner (blocks at x^n instead of x^{n+1/2}, half a step apart)
  // when it was built for the same h and beta_el, and for the same beta where binding springs make
  // the blocks depend on it: a preconditioner needs only to be close, the answer is the same to the
  // CG tolerance, and rebuilding it (every force's diagonal blocks, a 3x3 inverse per particle, the
  // multigrid's coarse operators) costs about a tenth of a cloth step.
  const bool jacobi = settings.jacobi_preconditioner && linear_solve;
  const PreconditionerKey& key = m_preconditioner_key;
  const bool reuse = !m_refresh_preconditioner && key.h == h && key.beta_el == beta_el && key.jacobi == jacobi &&
                     (s.m_springs.size() == 0 || key.beta == beta) && (!m_use_multigrid || m_multigrid.built());
  if (!reuse) {
    build_preconditioner(s, h, beta, beta_el, jacobi);
    m_preconditioner_key = {h, beta, beta_el, jacobi};
  }
  impose_joints(m_y);
  if (alternative) impose_joints(*alternative);
  apply(s, h, beta, beta_el, m_y, m_q);
  m_r_vec.particles = m_c.particles - m_q.particles;
  m_r_vec.rigid = m_c.rigid - m_q.rigid;
  project(m_r_vec);
  precondition(m_r_vec, m_z);
  if (!linear_solve) {
    // No implicit term: S is M (diagonal for particles, diag(m I, I) per body), solved exactly.
    m_y.particles += m_z.particles;
    m_y.rigid += m_z.rigid;
    return result;
  }
  auto residual = [&] { return max_abs(m_z); };
  if (m_n == 0 && m_r == 0) return result;
  result.residual = residual();
  if (alternative) {
    // The alternative's preconditioned residual, in m_p (r) and m_q (z). Alternative::if_exact (the
    // first step's M^-1 c): taken only when it is exact to well below the tolerance (1e-3 of it: no
    // iteration needed, and no answer merely at the tolerance's edge) and beats the first guess;
    // preferring it whenever its residual was smaller gained no iterations on the cloth there.
    // Alternative::if_smaller (step 1's trials): the first guess is kept when it already meets the
    // tolerance, the alternative taken when it does, else the one with the smaller r . z.
    apply(s, h, beta, beta_el, *alternative, m_q);
    m_p.particles = m_c.particles - m_q.particles;
    m_p.rigid = m_c.rigid - m_q.rigid;
    project(m_p);
    precondition(m_p, m_q);
    const double alternative_residual = max_abs(m_q);
    const double tolerance = settings.cg_tolerance;
    const bool take = rule == Alternative::if_smaller
                          ? result.residual > tolerance && (alternative_residual <= tolerance || dot(m_p, m_q) < dot(m_r_vec, m_z))
                          : alternative_residual <= 1e-3 * tolerance && alternative_residual < result.residual;
    if (take) {
      m_y.particles = alternative->particles;
      m_y.rigid = alternative->rigid;
      std::swap(m_r_vec, m_p);
      std::swap(m_z, m_q);
      result.residual = alternative_residual;
      result.took_alternative = true;
    }
  }
  m_p.particles = m_z.particles;
  m_p.rigid = m_z.rigid;
  double rz = dot(m_r_vec, m_z);
  while (result.residual > settings.cg_tolerance) {
    if (result.iterations >= settings.cg_max_iterations) {
      result.converged = false;
      break;
    }
    apply(s, h, beta, beta_el, m_p, m_q);
    const double pq = dot(m_p, m_q);
    if (!(pq > 0.0)) {
      if (!std::isfinite(pq)) fail("Newmark step ", m_step_count, ": conjugate gradients produced a non-finite value");
      break;  // the remaining residual lies in S's null space: nothing more to gain
    }
    const double alpha = rz / pq;
    axpy(alpha, m_p, m_y);
    axpy(-alpha, m_q, m_r_vec);
    precondition(m_r_vec, m_z);
    const double rz_new = dot(m_r_vec, m_z);
    const double beta_cg = rz_new / rz;
    rz = rz_new;
    update_direction(m_z, beta_cg, m_p);
    ++result.iterations;
    result.residual = residual();
  }
  return result;
}

// ---- soft bindings -------------------------------------------------------------------------------

void Newmark::synchronize(System& s, bool positions, bool velocities) {
  const SoftBindings& soft = s.m_soft;
  auto& p = s.m_particles;
  for (Index k = 0; k < soft.size(); ++k) {
    if (soft.coupling[k] != SoftCoupling::synchronized) continue;
    if (positions) p.x.col(soft.particle[k]) = p.x.col(soft.target[k]);
    if (velocities) p.v.col(soft.particle[k]) = p.v.col(soft.target[k]);
  }
}

void Newmark::gather_synchronized(System& s, Vectors3& f) const {
  const SoftBindings& soft = s.m_soft;
  for (Index k = 0; k < soft.size(); ++k) {
    if (soft.coupling[k] != SoftCoupling::synchronized) continue;
    f.col(soft.target[k]) += f.col(soft.particle[k]);
    f.col(soft.particle[k]).setZero();
  }
}

// Section 3.1: drift dx = x_s - x_e, dv = v_s - v_e goes to the target: directly for a free target,
// as dx_i = w_i (m_e/m_i) dx to the parents of a point embedded in particles (section 2), and as
// the impulse m_e dv (and the matching displacement) at the point of a rigid frame, with m_e the
// effective mass along the drift so the target point moves by exactly the drift (to first order).
void Newmark::push_synchronized_drift(System& s) {
  const SoftBindings& soft = s.m_soft;
  auto& p = s.m_particles;
  auto& bodies = s.m_bodies;
  const HardBindings& hard = s.m_hard;
  for (Index k = 0; k < soft.size(); ++k) {
    if (soft.coupling[k] != SoftCoupling::synchronized) continue;
    const Index sp = soft.particle[k], t = soft.target[k];
    const Vec3 dx = p.x.col(sp) - p.x.col(t);
    const Vec3 dv = p.v.col(sp) - p.v.col(t);
    if (dx.isZero(0.0) && dv.isZero(0.0)) continue;
    const Index code = hard.binding_of(t);
    if (code == HardBindings::unbound) {
      if (p.kind[t] == ParticleKind::kinematic) continue;  // a prescribed target cannot move
      p.x.col(t) += dx;
      p.v.col(t) += dv;
    } else if (code >= 0) {
      const double m_e = s.m_effective_mass[t];
      if (!std::isfinite(m_e)) continue;
      const auto parents = hard.linear_parents(code);
      const auto weights = hard.linear_weights(code);
      for (std::size_t j = 0; j < parents.size(); ++j) {
        if (p.kind[parents[j]] == ParticleKind::kinematic) continue;
        const double c = weights[j] * m_e / p.mass[parents[j]];
        p.x.col(parents[j]) += c * dx;
        p.v.col(parents[j]) += c * dv;
      }
    } else {
      const Index r = -code - 1, b = hard.rigid_body(r);
      if (!m_dynamic_body[b]) continue;
      const Vec3 offset = hard.rigid_offset_world(r);
      const Mat3 inverse_inertia = bodies.world_inverse_inertia(b);
      auto apply = [&](const Vec3& delta, bool position) {
        const double n2 = delta.squaredNorm();
        if (n2 == 0.0) return;
        const Vec3 n = delta / std::sqrt(n2);
        const double m_e = 1.0 / n.dot(bodies.impulse_matrix(b, offset) * n);
        const Vec3 j = m_e * delta;
        const Vec3 dtheta = inverse_inertia * offset.cross(j);
        if (position) {
          bodies.x.col(b) += j / bodies.mass[b];
          bodies.q[b] = (rotation_from_vector(dtheta) * bodies.q[b]).normalized();
        } else {
          bodies.v.col(b) += j / bodies.mass[b];
          bodies.w.col(b) += dtheta;
          m_body_L_n.col(b) += offset.cross(j);
        }
      };
      apply(dv, false);
      apply(dx, true);
      s.m_hard.update_rigid_offsets(bodies);
    }
  }
}

void Newmark::check_finite(const System& s, const char* phase) const {
  const auto& p = s.m_particles;
  for (Index i = 0; i < m_n; ++i) {
    if (!all_finite(p.x.col(i)))
      fail("Newmark step ", m_step_count, ", ", phase, ": particle ", i, " has a non-finite position (", p.x.col(i).transpose(), ")");
    if (!all_finite(p.v.col(i)))
      fail("Newmark step ", m_step_count, ", ", phase, ": particle ", i, " has a non-finite velocity (", p.v.col(i).transpose(), ")");
  }
  const auto& bodies = s.m_bodies;
  for (Index b = 0; b < m_r; ++b)
    if (!all_finite(bodies.x.col(b)) || !all_finite(bodies.v.col(b)) || !all_finite(bodies.w.col(b)) ||
        !std::isfinite(bodies.q[b].norm()))
      fail("Newmark step ", m_step_count, ", ", phase, ": rigid body ", b, " has a non-finite state");
}

}  // namespace sinew
