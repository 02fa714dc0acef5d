#include "divergence.hpp"

#include "preconditioner.hpp"

#include <algorithm>
#include <cmath>

namespace sinew {

namespace {
// The check is off for a factor of 0 (or infinity).
bool enabled(const StepSettings& settings) {
  return settings.divergence_factor > 0.0 && std::isfinite(settings.divergence_factor);
}
}  // namespace

double kinetic_energy(const StepModel& s, const Unknowns& u, const Vectors3& v, const Vectors3& L) {
  double e = 0.0;
  for (Index i = 0; i < u.n; ++i) e += 0.5 * u.dof_mass[i] * v.col(i).squaredNorm();
  for (Index b = 0; b < u.r; ++b)
    if (u.dynamic_body[b])
      e += 0.5 * s.bodies.mass[b] * s.bodies.v.col(b).squaredNorm() + 0.5 * s.bodies.w.col(b).dot(L.col(b));
  return e;
}

void DivergenceCheck::begin_step(const StepModel& s, const StepRecord& r, double dt) {
  if (!enabled(s.settings)) {
    m_started = false;  // turned on again later, the budget starts afresh from that state
    return;
  }
  const Unknowns& u = r.unknowns;
  m_start_kinetic = kinetic_energy(s, u, s.particles.v, r.body_L_n);
  // The scene's extent and dynamic mass, for the budget's floor.
  Vec3 lo = Vec3::Constant(kInfinity), hi = Vec3::Constant(-kInfinity);
  double mass = 0.0;
  for (Index i = 0; i < u.n; ++i) {
    if (s.particles.kind[i] == ParticleKind::removed) continue;
    lo = lo.cwiseMin(s.particles.x.col(i));
    hi = hi.cwiseMax(s.particles.x.col(i));
    mass += u.dof_mass[i];
  }
  double body_size = 0.0;  // a lone body's extent is its own: twice its largest radius of gyration
  for (Index b = 0; b < u.r; ++b) {
    lo = lo.cwiseMin(s.bodies.x.col(b));
    hi = hi.cwiseMax(s.bodies.x.col(b));
    if (!u.dynamic_body[b]) continue;
    mass += s.bodies.mass[b];
    body_size = std::max(body_size, 2.0 * std::sqrt(s.bodies.inertia.col(b).maxCoeff() / s.bodies.mass[b]));
  }
  const double extent = std::max((hi - lo).allFinite() ? (hi - lo).norm() : 0.0, body_size);
  const double floor_speed = 1e-3 * extent / dt;
  m_energy_floor = 0.5 * mass * floor_speed * floor_speed;
  m_start_springs = s.springs.potential_energy(s.particles.x);
  if (!m_started) {
    // The scene's energy at the start: kinetic and elastic (gravity enters as work, step by step).
    double elastic = m_start_springs;
    for (const auto& f : s.forces) elastic += f->potential_energy(s.particles.x);
    m_budget = m_start_kinetic + std::max(elastic, 0.0);
    m_peak = m_budget;
    m_end_kinetic = m_start_kinetic;
    m_end_springs = m_start_springs;
    m_end_x = s.particles.x;
    m_started = true;
  }
  // Energy added between steps is input: kinetic (new velocities from a rigid solver, an impulse) and
  // the binding springs' (a spring switched on or moved to new ends, as a viewer's mouse spring is;
  // an end moved). They are few, so their energy is cheap to take at every step's start and end; the
  // elastic forces' would cost a force evaluation.
  m_injected = std::max(m_start_kinetic - m_end_kinetic, 0.0) + std::max(m_start_springs - m_end_springs, 0.0);
  // Positions the caller moved (a body's teleport carrying only part of a cloth, a dragged node): the
  // elastic energy that put in, from two force evaluations, paid only when something moved by more
  // than round-off of the scene's extent since the last step ended.
  if (m_end_x.cols() == s.particles.x.cols()) {
    double moved = 0.0;
    for (Index i = 0; i < u.n; ++i)
      if (s.particles.kind[i] != ParticleKind::removed)
        moved = std::max(moved, (s.particles.x.col(i) - m_end_x.col(i)).lpNorm<Eigen::Infinity>());
    if (moved > 1e-9 * std::max(extent, 1.0)) {
      double added = 0.0;
      for (const auto& f : s.forces) added += f->potential_energy(s.particles.x) - f->potential_energy(m_end_x);
      m_injected += std::max(added, 0.0);
    }
  }
  m_pending = m_budget + m_injected;
}

void DivergenceCheck::end_step(const StepModel& s, const StepRecord& r, long step, Vectors3& scratch,
                               Vectors6& scratch_wrench) {
  if (!enabled(s.settings) || !m_started) return;
  const double factor = s.settings.divergence_factor;
  const Unknowns& u = r.unknowns;
  const auto& p = s.particles;
  const auto& bodies = s.bodies;
  const Vec3& g = s.gravity;

  // The work of the step's inputs; the kinematic speeds.
  double gravity_work = 0.0, input_work = 0.0, collision_gain = 0.0;
  double v_kin = 0.0, w_kin = 0.0;
  for (Index i = 0; i < u.n; ++i) {
    const ParticleKind kind = p.kind[i];
    const Vec3 dx = p.x.col(i) - r.x_n.col(i);
    if (kind == ParticleKind::free) gravity_work += p.mass[i] * g.dot(dx);
    if (kind == ParticleKind::kinematic) {
      input_work += std::abs(r.f.col(i).dot(dx));
      v_kin = std::max(v_kin, p.v.col(i).norm());
    }
    collision_gain += 0.5 * u.dof_mass[i] * (r.v_tilde_n.col(i).squaredNorm() - r.v_n.col(i).squaredNorm());
  }
  for (Index b = 0; b < u.r; ++b) {
    const Vec3 dx = bodies.x.col(b) - r.body_x_n.col(b);
    const Vec3 turn = r.turn.col(b);
    if (u.dynamic_body[b]) {
      if (bodies.gravity[b]) gravity_work += bodies.mass[b] * g.dot(dx);
      input_work += std::abs(bodies.force.col(b).dot(dx)) + std::abs(bodies.torque.col(b).dot(turn));
    } else {
      input_work += std::abs(r.wrench.col(b).head<3>().dot(dx)) + std::abs(r.wrench.col(b).tail<3>().dot(turn));
      v_kin = std::max(v_kin, bodies.v.col(b).norm());
      w_kin = std::max(w_kin, bodies.w.col(b).norm());
    }
  }
  for (Index k = 0; k < s.hard.rigid_count(); ++k)  // points on kinematic bodies move at v + w x r
    if (!u.dynamic_body[s.hard.rigid_body(k)]) v_kin = std::max(v_kin, p.v.col(s.hard.rigid_particle(k)).norm());
  const double budget = m_pending + gravity_work + input_work + std::max(collision_gain, 0.0);
  // Against the largest budget so far: a pendulum at the top of its swing has all its energy as
  // height, and the signed budget (its kinetic energy then) is close to zero.
  const double peak = std::max(m_peak + m_injected, budget);
  const double allowed = std::max(peak, m_energy_floor);

  // The item whose kinetic energy is the largest share of what it is allowed.
  double end_kinetic = 0.0, worst = 0.0, worst_energy = 0.0, worst_allowed = 0.0, worst_mass = 0.0;
  Index worst_particle = -1, worst_body = -1;
  for (Index i = 0; i < u.n; ++i) {
    const double e = 0.5 * u.dof_mass[i] * p.v.col(i).squaredNorm();
    end_kinetic += e;
    const double allow = factor * (allowed + 0.5 * u.dof_mass[i] * v_kin * v_kin);
    if (e > allow && e > worst * allow) {
      worst = e / allow;
      worst_particle = i;
      worst_energy = e;
      worst_allowed = allow;
      worst_mass = u.dof_mass[i];
    }
  }
  for (Index b = 0; b < u.r; ++b) {
    if (!u.dynamic_body[b]) continue;
    const Mat3 I = bodies.world_inertia(b);
    const double e =
        0.5 * bodies.mass[b] * bodies.v.col(b).squaredNorm() + 0.5 * bodies.w.col(b).dot(I * bodies.w.col(b));
    end_kinetic += e;
    const double allow = factor * (allowed + 0.5 * bodies.mass[b] * v_kin * v_kin + 0.5 * I.trace() * w_kin * w_kin);
    if (e > allow && e > worst * allow) {
      worst = e / allow;
      worst_body = b;
      worst_particle = -1;
      worst_energy = e;
      worst_allowed = allow;
      worst_mass = bodies.mass[b];
    }
  }
  if (worst_particle < 0 && worst_body < 0) {
    m_budget = budget;
    m_peak = peak;
    m_end_kinetic = end_kinetic;
    m_end_springs = s.springs.potential_energy(p.x);
    m_end_x = p.x;  // allocates only when the particle count changes
    return;
  }

  // Which force is largest on the item, at the step's end: each force alone into scratch (bodies: as
  // the wrench W^T passes them, its torque counted as a force at the body's radius of gyration).
  auto size_on_item = [&]() {
    if (worst_particle >= 0) return scratch.col(worst_particle).norm();
    scratch_wrench.setZero();
    s.hard.distribute(scratch, scratch_wrench);
    const double gyration = std::sqrt(bodies.inertia.col(worst_body).maxCoeff() / bodies.mass[worst_body]);
    return scratch_wrench.col(worst_body).head<3>().norm() + scratch_wrench.col(worst_body).tail<3>().norm() / gyration;
  };
  std::string largest = "none";
  double largest_size = 0.0;
  for (const auto& f : s.forces) {
    scratch.setZero();
    f->add_elastic_forces(p.x, scratch);
    const double size = size_on_item();
    if (size > largest_size) {
      largest_size = size;
      largest = "'" + std::string(f->name()) + "'";
    }
  }
  scratch.setZero();
  s.springs.add_elastic_forces(p.x, scratch);
  if (const double size = size_on_item(); size > largest_size) {
    largest_size = size;
    largest = "the binding springs";
  }
  if (worst_body >= 0) {
    const double gyration = std::sqrt(bodies.inertia.col(worst_body).maxCoeff() / bodies.mass[worst_body]);
    if (const double size = bodies.force.col(worst_body).norm() + bodies.torque.col(worst_body).norm() / gyration;
        size > largest_size) {
      largest_size = size;
      largest = "its applied force and torque";
    }
  }
  const double speed = std::sqrt(2.0 * worst_energy / worst_mass);
  const double bound = std::sqrt(2.0 * worst_allowed / worst_mass);
  const std::string item =
      worst_particle >= 0 ? "particle " + std::to_string(worst_particle) : "rigid body " + std::to_string(worst_body);
  fail("Newmark step ", step, ": ", item, " diverged: its kinetic energy ", worst_energy, " J is over ", factor,
       " times the scene's energy budget (", allowed,
       " J: the energy at the start plus the work of gravity, applied forces, kinematic motion and collisions); ",
       worst_body >= 0 ? "its speed and spin amount to " : "its speed ", speed, " m/s, the bound there ", bound,
       " m/s; largest force on it: ", largest, " (", largest_size, " N)");
}

std::string non_finite_culprit(const StepModel& s, const Vectors3& x, const Vectors3& v, const SolveCoefficients& k,
                               Vectors3& scratch) {
  for (const auto& f : s.forces) {
    scratch.setZero();
    f->add_elastic_forces(x, scratch);
    if (!scratch.allFinite())
      return "; force '" + std::string(f->name()) + "' gives non-finite forces at finite positions";
    scratch.setZero();
    f->add_implicit_products(v, implicit_b(*f, k.beta_el), scratch);
    if (!scratch.allFinite())
      return "; force '" + std::string(f->name()) + "' gives non-finite forces for finite velocities";
  }
  scratch.setZero();
  s.springs.add_elastic_forces(x, scratch);
  s.springs.add_linear_forces(v, 1.0, k.beta, scratch);
  if (!scratch.allFinite()) return "; the binding springs give non-finite forces for finite positions and velocities";
  return {};
}

}  // namespace sinew
