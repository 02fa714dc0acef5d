#include "sinew/system.hpp"

#include "sinew/parallel.hpp"

#include "newmark.hpp"
#include "step_model.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cstring>
#include <exception>

namespace sinew {

PhaseTimes& PhaseTimes::operator+=(const PhaseTimes& o) {
  implicit_half_velocity += o.implicit_half_velocity;
  advance_positions += o.advance_positions;
  process_collisions += o.process_collisions;
  backward_euler_velocity += o.backward_euler_velocity;
  extrapolate_velocity += o.extrapolate_velocity;
  forces += o.forces;
  cg += o.cg;
  total += o.total;
  return *this;
}

StepStats& StepStats::operator+=(const StepStats& o) {
  substeps += o.substeps;
  dt = o.dt;
  cg_iterations_step1 += o.cg_iterations_step1;
  cg_iterations_step4 += o.cg_iterations_step4;
  cg_iterations_step3 += o.cg_iterations_step3;
  newton_iterations += o.newton_iterations;
  rotation_iterations += o.rotation_iterations;
  contact_passes += o.contact_passes;
  cg_residual = std::max(cg_residual, o.cg_residual);
  cg_converged = cg_converged && o.cg_converged;
  linear_solve = linear_solve || o.linear_solve;
  implicit_elasticity = implicit_elasticity || o.implicit_elasticity;
  mapped_impulse += o.mapped_impulse;
  asleep = asleep || o.asleep;
  contact_work += o.contact_work;
  ms += o.ms;
  return *this;
}

System::System(const SystemSettings& settings) : m_settings(settings) {
  if (!all_finite(settings.gravity)) fail("system settings: gravity is not finite");
}
System::~System() = default;
System::System(System&&) noexcept = default;
System& System::operator=(System&&) noexcept = default;

void System::require_finalized(const char* what) const {
  if (!m_finalized) fail(what, ": finalize the system first (masses are set up there)");
}

void System::note_topology_change() {
  if (m_finalized) m_topology_changed = true;
}

Index System::add_particle(const Vec3& x, const Vec3& v, double mass) {
  note_topology_change();
  const Index i = m_particles.size();
  if (!all_finite(x) || !all_finite(v)) fail("particle ", i, ": position or velocity is not finite");
  if (!(std::isfinite(mass) && mass >= 0.0)) fail("particle ", i, ": mass ", mass, " must be non-negative and finite");
  m_particles.x.conservativeResize(3, i + 1);
  m_particles.v.conservativeResize(3, i + 1);
  m_particles.x.col(i) = x;
  m_particles.v.col(i) = v;
  m_input_mass.conservativeResize(i + 1);
  m_input_mass[i] = mass;
  if (m_particles.mass.size() == i) {
    // Added after set-up: its own mass until the next set-up distributes masses again, so that the
    // diagnostics (momentum, energy) can count it in between.
    m_particles.mass.conservativeResize(i + 1);
    m_particles.mass[i] = mass;
  }
  m_particles.kind.push_back(ParticleKind::free);
  m_input_kind.push_back(ParticleKind::free);
  m_geometry.group.push_back(kDefaultCollisionGroup);
  m_geometry.mask.push_back(kAllCollisionGroups);
  return i;
}

Index System::add_kinematic_particle(const Vec3& x, const Vec3& v) {
  const Index i = add_particle(x, v, 0.0);
  m_particles.kind[i] = ParticleKind::kinematic;
  m_input_kind[i] = ParticleKind::kinematic;
  return i;
}

Index System::add_rigid_body(const RigidBodySettings& settings) {
  note_topology_change();
  return sinew::add_rigid_body(m_bodies, settings);
}

void System::set_rigid_body_mass(Index body, bool kinematic, double mass, const Vec3& inertia) {
  if (body < 0 || body >= m_bodies.size())
    fail("set_rigid_body_mass: rigid body ", body, " does not exist (there are ", m_bodies.size(), ")");
  if (!kinematic) validate_rigid_body_mass(body, mass, inertia);
  // The merged masses come out first: they would otherwise be taken out of the new mass at set-up.
  m_hard.release_masses_from_bodies(m_bodies);
  m_bodies.kinematic[static_cast<std::size_t>(body)] = kinematic ? 1 : 0;
  m_bodies.mass[body] = kinematic ? kInfinity : mass;
  m_bodies.inertia.col(body) = kinematic ? Vec3::Constant(kInfinity) : inertia;
  note_topology_change();
}

void System::reembed(Index particle, std::span<const Index> parents, std::span<const double> weights) {
  const Index n = m_particles.size();
  if (particle < 0 || particle >= n) fail("reembed: particle ", particle, " does not exist (there are ", n, ")");
  if (m_input_mass[particle] != 0.0)
    fail("reembed: particle ", particle, " has mass ", m_input_mass[particle],
         "; only massless embedded points move in material space");
  for (const Index parent : parents)
    if (parent < 0 || parent >= n || m_input_kind[parent] == ParticleKind::removed)
      fail("reembed: parent ", parent, " of particle ", particle, " is not a particle");
  if (!m_finalized || m_topology_changed) {
    // Not set up: the next set-up flattens and distributes from the binding as it is now.
    HardBindings before = m_hard;
    try {
      if (!m_hard.remove(particle)) fail("reembed: particle ", particle, " is not hard-bound");
      m_hard.add_linear(particle, parents, weights);
    } catch (...) {
      m_hard = std::move(before);
      throw;
    }
    note_topology_change();
    return;
  }
  for (const Index parent : parents)
    if (m_particles.kind[parent] != ParticleKind::free && m_particles.kind[parent] != ParticleKind::kinematic)
      fail("reembed: parent ", parent, " of particle ", particle,
           " is bound (soft or hard); re-embed in free "
           "or kinematic particles");
  m_hard.replace_linear(particle, parents, weights);
  // Soft particles tied to it keep their present mass.
  for (Index s = 0; s < m_soft.size(); ++s)
    if (m_soft.target[s] == particle && m_soft.mass_override[s] == 0.0)
      m_soft.mass_override[s] = m_particles.mass[m_soft.particle[s]];
  const Index k = m_hard.linear_binding_of(particle);
  const LinearBindings& linear = m_hard.linear();
  m_particles.x.col(particle) = linear.point_velocity(k, m_particles.x, m_bodies);  // W is linear: x_e = W x
  m_particles.v.col(particle) = linear.point_velocity(k, m_particles.v, m_bodies);
  m_inverse_effective_mass[particle] = linear.inverse_effective_mass(k, m_particles.mass, m_bodies);
  m_effective_mass[particle] =
      m_inverse_effective_mass[particle] > 0.0 ? 1.0 / m_inverse_effective_mass[particle] : kInfinity;
  m_springs.set_damping_from_masses(m_inverse_effective_mass);
  m_force_stable_dt.clear();
  wake();
}

bool System::unbind(Index particle) {
  note_topology_change();
  return m_hard.remove(particle);
}

void System::remove_particles(std::span<const Index> particles) {
  const Index n = m_particles.size();
  std::vector<std::uint8_t> removed(static_cast<std::size_t>(n), 0);
  for (Index i : particles) {
    if (i < 0 || i >= n) fail("remove_particles: particle ", i, " does not exist (there are ", n, ")");
    if (m_input_kind[i] == ParticleKind::removed) fail("remove_particles: particle ", i, " was removed already");
    removed[static_cast<std::size_t>(i)] = 1;
  }
  // Checked before anything changes: a removed parent would leave its bound points with no state.
  const auto check_parents = [&](const auto& kind) {
    for (Index k = 0; k < kind.size(); ++k)
      for (Index parent : kind.parents(k))
        if (removed[static_cast<std::size_t>(parent)] && !removed[static_cast<std::size_t>(kind.particle(k))])
          fail("remove_particles: particle ", parent, " is a parent of hard-bound particle ", kind.particle(k),
               "; unbind or remove that point first");
  };
  check_parents(m_hard.linear());
  check_parents(m_hard.mixed());
  remove_elements_of(removed);
  for (Index i : particles) {
    m_hard.remove(i);
    m_input_kind[i] = ParticleKind::removed;
    m_input_mass[i] = 0.0;
    m_particles.kind[i] = ParticleKind::removed;
    m_particles.v.col(i).setZero();
  }
  for (Index k = m_soft.size() - 1; k >= 0; --k)
    if (removed[static_cast<std::size_t>(m_soft.particle[k])] || removed[static_cast<std::size_t>(m_soft.target[k])])
      remove_soft_binding(k);
  for (Index s = 0; s < m_springs.size(); ++s)
    if (!m_springs.removed(s) &&
        (removed[static_cast<std::size_t>(m_springs.a(s))] || removed[static_cast<std::size_t>(m_springs.b(s))]))
      m_springs.remove(s);
  auto& triangles = m_geometry.triangles;
  triangles.erase(std::remove_if(triangles.begin(), triangles.end(),
                                 [&](const std::array<Index, 3>& t) {
                                   return removed[static_cast<std::size_t>(t[0])] ||
                                          removed[static_cast<std::size_t>(t[1])] ||
                                          removed[static_cast<std::size_t>(t[2])];
                                 }),
                  triangles.end());
  auto& segments = m_geometry.segments;
  segments.erase(std::remove_if(segments.begin(), segments.end(),
                                [&](const std::array<Index, 2>& e) {
                                  return removed[static_cast<std::size_t>(e[0])] ||
                                         removed[static_cast<std::size_t>(e[1])];
                                }),
                 segments.end());
  note_topology_change();
}

void System::remove_elements_touching(std::span<const Index> particles) {
  const Index n = m_particles.size();
  std::vector<std::uint8_t> removed(static_cast<std::size_t>(n), 0);
  for (Index i : particles) {
    if (i < 0 || i >= n) fail("remove_elements_touching: particle ", i, " does not exist (there are ", n, ")");
    removed[static_cast<std::size_t>(i)] = 1;
  }
  remove_elements_of(removed);
  note_topology_change();
}

void System::remove_elements_of(std::span<const std::uint8_t> removed) {
  for (const auto& f : m_forces)
    if (!f->can_remove_elements() && f->touches(removed))
      fail(f->name(),
           ": cannot remove elements (it does not implement Force::remove_elements_touching); nothing was removed");
  for (const auto& f : m_forces)
    if (f->can_remove_elements()) f->remove_elements_touching(removed);
  m_force_stable_dt.clear();
}

void System::remove_soft_binding(Index soft) {
  if (soft < 0 || soft >= m_soft.size()) fail("soft binding ", soft, " does not exist (there are ", m_soft.size(), ")");
  if (m_soft.spring[soft] >= 0) m_springs.remove(m_soft.spring[soft]);
  for (auto* list : {&m_soft.particle, &m_soft.target, &m_soft.spring}) list->erase(list->begin() + soft);
  m_soft.coupling.erase(m_soft.coupling.begin() + soft);
  m_soft.mass_override.erase(m_soft.mass_override.begin() + soft);
  note_topology_change();
}

void System::remove_binding_spring(Index spring) {
  if (spring < 0 || spring >= m_springs.size()) fail("binding spring ", spring, " does not exist");
  for (Index k = 0; k < m_soft.size(); ++k)
    if (m_soft.spring[k] == spring)
      fail("binding spring ", spring, " belongs to soft binding ", k, "; remove that instead");
  m_springs.remove(spring);
  note_topology_change();
}

void System::remove_force(const Force& force) {
  const auto found = std::find_if(m_forces.begin(), m_forces.end(), [&](const auto& f) { return f.get() == &force; });
  if (found == m_forces.end()) fail("remove_force: ", force.name(), " is not a force of this system");
  m_forces.erase(found);
  m_force_stable_dt.clear();
  note_topology_change();
}

void System::set_binding_spring_active(Index spring, bool active) {
  if (spring < 0 || spring >= m_springs.size()) fail("binding spring ", spring, " does not exist");
  if (m_springs.removed(spring)) fail("binding spring ", spring, " was removed");
  m_springs.set_active(spring, active);
  wake();
}

Vec3 System::binding_spring_force(Index spring) const {
  if (spring < 0 || spring >= m_springs.size()) fail("binding spring ", spring, " does not exist");
  return m_springs.force(spring, m_particles.x, m_particles.v);
}

Vec3 System::hard_binding_force(Index particle) const {
  if (!m_hard.is_bound(particle)) fail("particle ", particle, " is not hard-bound");
  return m_newmark ? m_newmark->bound_force(particle) : Vec3::Zero();
}

Index System::bind_linear(Index particle, std::span<const Index> parents, std::span<const double> weights) {
  note_topology_change();
  const Index id = m_hard.size();
  m_hard.add_linear(particle, parents, weights);
  return id;
}

Index System::bind_rigid(Index particle, Index body, const Vec3& r0) {
  note_topology_change();
  const Index id = m_hard.size();
  m_hard.add_rigid(particle, body, r0);
  return id;
}

Index System::bind_rigid_here(Index particle, Index body) {
  if (particle < 0 || particle >= m_particles.size())
    fail("binding ", m_hard.size(), ": particle ", particle, " does not exist");
  if (body < 0 || body >= m_bodies.size()) fail("binding ", m_hard.size(), ": rigid body ", body, " does not exist");
  const Vec3 r0 = m_bodies.q[body].conjugate() * (m_particles.x.col(particle) - m_bodies.x.col(body));
  return bind_rigid(particle, body, r0);
}

Index System::add_embedded_point(std::span<const Index> parents, std::span<const double> weights) {
  note_topology_change();
  const Index point = m_particles.size();
  if (parents.size() != weights.size())
    fail("embedded point ", point, ": ", parents.size(), " parents but ", weights.size(), " weights");
  Vec3 x = Vec3::Zero(), v = Vec3::Zero();
  for (std::size_t i = 0; i < parents.size(); ++i) {
    if (parents[i] < 0 || parents[i] >= point)
      fail("embedded point ", point, ": parent ", parents[i], " does not exist");
    x += weights[i] * m_particles.x.col(parents[i]);
    v += weights[i] * m_particles.v.col(parents[i]);
  }
  bind_linear(point, parents, weights);  // validates the weights before the particle exists
  add_particle(x, v, 0.0);
  return point;
}

Index System::add_soft_binding(const SoftBindingSettings& s) {
  note_topology_change();
  const Index id = m_soft.size();
  if (!(std::isfinite(s.mass) && s.mass >= 0.0))
    fail("soft binding ", id, ": mass ", s.mass, " must be non-negative and finite");
  if (s.particle == s.target) fail("soft binding ", id, ": particle ", s.particle, " is its own target");
  Index spring = -1;
  if (s.coupling == SoftCoupling::spring) {
    try {
      spring = m_springs.add({s.particle, s.target, s.stiffness, s.damping_ratio});
    } catch (const Error& e) {
      fail("soft binding ", id, ": ", e.what());
    }
  }
  m_soft.particle.push_back(s.particle);
  m_soft.target.push_back(s.target);
  m_soft.coupling.push_back(s.coupling);
  m_soft.spring.push_back(spring);
  m_soft.mass_override.push_back(s.mass);
  return id;
}

Index System::add_binding_spring(const BindingSpringSettings& settings) {
  note_topology_change();
  return m_springs.add(settings);
}

void System::set_binding_spring_ends(Index spring, Index a, Index b) {
  if (spring < 0 || spring >= m_springs.size())
    fail("binding spring ", spring, " does not exist (there are ", m_springs.size(), ")");
  const Index n = m_particles.size();
  if (a < 0 || a >= n || b < 0 || b >= n)
    fail("binding spring ", spring, ": ends ", a, " and ", b, " must be particles (0 to ", n - 1, ")");
  if (a == b) fail("binding spring ", spring, ": both ends are particle ", a);
  if (m_springs.removed(spring)) fail("binding spring ", spring, " was removed");
  for (Index end : {a, b})
    if (m_input_kind[end] == ParticleKind::removed) fail("binding spring ", spring, ": end ", end, " was removed");
  // Set up and unchanged since: the masses are current, so check the ends and damp the spring now;
  // otherwise the next set-up does both.
  const bool set_up = m_finalized && !m_topology_changed;
  if (set_up && !(m_inverse_effective_mass[a] + m_inverse_effective_mass[b] > 0.0))
    fail("binding spring ", spring, ": ends ", a, " and ", b,
         " both have infinite mass (kinematic or on kinematic parents)");
  m_springs.set_ends(spring, a, b);
  if (set_up) m_springs.set_damping_from_masses(m_inverse_effective_mass);
  wake();
}

void System::set_gravity(const Vec3& gravity) {
  if (!all_finite(gravity)) fail("set_gravity: gravity (", gravity.transpose(), ") is not finite");
  m_settings.gravity = gravity;
}

CollisionSource& System::add_collision_source(std::unique_ptr<CollisionSource> source) {
  if (!source) fail("add_collision_source: null source");
  m_collision_sources.push_back(std::move(source));
  return *m_collision_sources.back();
}

void System::add_collision_surface(std::span<const std::array<Index, 3>> triangles) {
  const Index n = m_particles.size();
  for (std::size_t t = 0; t < triangles.size(); ++t)
    for (Index i : triangles[t])
      if (i < 0 || i >= n)
        fail("collision surface: triangle ", t, " has vertex ", i, ", which is not a particle (there are ", n, ")");
  m_geometry.triangles.insert(m_geometry.triangles.end(), triangles.begin(), triangles.end());
  // Each edge once, as (lower, higher), in a fixed (sorted) order.
  std::vector<std::array<Index, 2>>& segments = m_geometry.segments;
  for (const auto& t : triangles)
    for (int e = 0; e < 3; ++e) {
      const Index a = t[static_cast<std::size_t>(e)], b = t[static_cast<std::size_t>((e + 1) % 3)];
      segments.push_back({std::min(a, b), std::max(a, b)});
    }
  std::sort(segments.begin(), segments.end());
  segments.erase(std::unique(segments.begin(), segments.end()), segments.end());
  wake();
}

void System::set_collision_filter(Index particle, std::uint32_t group, std::uint32_t mask) {
  if (particle < 0 || particle >= m_particles.size())
    fail("set_collision_filter: particle ", particle, " does not exist");
  m_geometry.group[static_cast<std::size_t>(particle)] = group;
  m_geometry.mask[static_cast<std::size_t>(particle)] = mask;
  wake();
}

void System::set_joint_rows(std::vector<JointRow> rows) {
  const Index r = m_bodies.size();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const JointRow& row = rows[i];
    if (row.body_a < 0 || row.body_a >= r)
      fail("joint row ", i, ": body_a = ", row.body_a, " is not a rigid body (there are ", r, ")");
    if (row.body_b < -1 || row.body_b >= r)
      fail("joint row ", i, ": body_b = ", row.body_b, " is neither -1 (the fixed world) nor a rigid body (there are ",
           r, ")");
    if (row.body_a == row.body_b) fail("joint row ", i, ": both ends are rigid body ", row.body_a);
    if (!(row.j_a.allFinite() && row.j_b.allFinite() && std::isfinite(row.target)))
      fail("joint row ", i, ": Jacobian or target is not finite");
    if (row.j_a.isZero(0.0) && row.j_b.isZero(0.0)) fail("joint row ", i, ": the Jacobian is zero");
    if (!row.unilateral) continue;
    if (!std::isfinite(row.gap)) fail("contact row ", i, ": gap ", row.gap, " is not finite");
    if (!(std::isfinite(row.friction) && row.friction >= 0.0))
      fail("contact row ", i, ": friction ", row.friction, " must be finite and >= 0");
    if (!row.point.allFinite()) fail("contact row ", i, ": the contact point is not finite");
  }
  m_joint_rows = std::move(rows);
}

void System::add_force_impl(std::unique_ptr<Force> force) {
  note_topology_change();
  if (!force) fail("add_force: null force");
  force->validate(m_particles.size());
  m_forces.push_back(std::move(force));
}

void System::finalize() {
  if (m_finalized && !m_topology_changed) return;
  const Index n = m_particles.size();
  // Bindings may have changed: bodies give back the masses merged into them, which are merged again
  // below from the bindings as they are now.
  m_hard.release_masses_from_bodies(m_bodies);
  m_force_stable_dt.clear();  // effective masses change below
  m_hard.flatten(n, m_bodies.size());

  // Particle kinds: hard-bound rows first, then soft-bound ones, each checked against the others.
  auto& kind = m_particles.kind;
  kind = m_input_kind;
  for (const BindingKind* binding : m_hard.kinds())
    for (Index k = 0; k < binding->size(); ++k) {
      const Index p = binding->particle(k);
      if (kind[p] == ParticleKind::kinematic) fail("particle ", p, " is kinematic and cannot be hard-bound");
      if (kind[p] == ParticleKind::removed) fail("particle ", p, " was removed and cannot be hard-bound");
      kind[p] = ParticleKind::hard_bound;
    }
  std::vector<std::uint8_t> is_soft(static_cast<std::size_t>(n), 0);
  for (Index s = 0; s < m_soft.size(); ++s) {
    const Index p = m_soft.particle[s], t = m_soft.target[s];
    if (p < 0 || p >= n) fail("soft binding ", s, ": particle ", p, " out of range [0, ", n, ")");
    if (t < 0 || t >= n) fail("soft binding ", s, ": target ", t, " out of range [0, ", n, ")");
    if (kind[p] != ParticleKind::free)
      fail("soft binding ", s, ": particle ", p, " is already kinematic, bound or removed");
    if (kind[t] == ParticleKind::removed) fail("soft binding ", s, ": target ", t, " was removed");
    if (is_soft[p]) fail("soft binding ", s, ": particle ", p, " is soft-bound twice");
    is_soft[p] = 1;
    kind[p] = m_soft.coupling[s] == SoftCoupling::spring ? ParticleKind::soft_spring : ParticleKind::soft_synchronized;
  }
  for (Index s = 0; s < m_soft.size(); ++s)
    if (is_soft[m_soft.target[s]]) fail("soft binding ", s, ": target ", m_soft.target[s], " is itself soft-bound");
  for (Index s = 0; s < m_springs.size(); ++s) {
    if (m_springs.removed(s)) continue;
    if (m_springs.a(s) >= n || m_springs.b(s) >= n) fail("binding spring ", s, ": endpoint out of range [0, ", n, ")");
    if (kind[m_springs.a(s)] == ParticleKind::removed || kind[m_springs.b(s)] == ParticleKind::removed)
      fail("binding spring ", s, ": an end was removed");
  }

  // Masses (section 2): m = W^T m_bar. Points on rigid frames join their body; points embedded in
  // particles pass w_i m_bar to each parent (weight w, not w^2: momentum P = m_bar^T W v).
  m_particles.mass = m_input_mass;
  m_hard.update_rigid_offsets(m_bodies);
  if (m_settings.absorb_bound_mass_into_rigid_bodies) m_hard.absorb_masses_into_bodies(m_particles.mass, m_bodies);
  m_hard.update_rigid_offsets(m_bodies);
  m_hard.distribute_masses(m_particles.mass);
  for (Index i = 0; i < n; ++i) {
    if (kind[i] == ParticleKind::kinematic) m_particles.mass[i] = kInfinity;
    if (kind[i] == ParticleKind::free && !(m_particles.mass[i] > 0.0))
      fail("particle ", i, " has mass ", m_particles.mass[i],
           " after binding masses were distributed: a free particle needs positive mass (bind it, make it kinematic, "
           "or give it mass)");
  }
  compute_effective_masses();
  m_springs.set_damping_from_masses(m_inverse_effective_mass);

  m_hard.update_rigid_offsets(m_bodies);
  clamp_bound_rows();
  m_newmark = std::make_unique<Newmark>();
  m_finalized = true;
  m_topology_changed = false;
  ++m_set_ups;
}

void System::compute_effective_masses() {
  const Index n = m_particles.size();
  m_inverse_effective_mass.setZero(n);
  for (Index i = 0; i < n; ++i)
    if (m_particles.kind[i] == ParticleKind::free) m_inverse_effective_mass[i] = 1.0 / m_particles.mass[i];
  m_hard.inverse_effective_masses(m_particles.mass, m_bodies, m_inverse_effective_mass);
  for (Index s = 0; s < m_soft.size(); ++s) {
    const Index p = m_soft.particle[s], t = m_soft.target[s];
    double m = m_soft.mass_override[s];
    if (m == 0.0) {
      if (!(m_inverse_effective_mass[t] > 0.0))
        fail("soft binding ", s, ": target ", t,
             " has infinite effective mass (kinematic); give the soft particle a mass");
      m = 1.0 / m_inverse_effective_mass[t];
    }
    m_particles.mass[p] = m;
    m_inverse_effective_mass[p] = 1.0 / m;
  }
  m_effective_mass.resize(n);
  for (Index i = 0; i < n; ++i)
    m_effective_mass[i] = m_inverse_effective_mass[i] > 0.0 ? 1.0 / m_inverse_effective_mass[i] : kInfinity;
}

double System::effective_mass(Index particle) const {
  if (!m_finalized || m_topology_changed)
    fail("effective_mass: finalize the system first (after a topology change too)");
  if (particle < 0 || particle >= m_particles.size()) fail("effective_mass: particle ", particle, " does not exist");
  return m_effective_mass[particle];
}

double System::effective_mass_along(Index particle, const Vec3& n) const {
  return m_hard.effective_mass_along(particle, n, effective_mass(particle), m_bodies);
}

void System::apply_impulse(Index particle, const Vec3& j) {
  finalize();
  if (particle < 0 || particle >= m_particles.size()) fail("apply_impulse: particle ", particle, " does not exist");
  if (!all_finite(j)) fail("apply_impulse: impulse on particle ", particle, " is not finite");
  m_hard.apply_impulse(particle, j, m_particles, m_bodies);
  clamp_bound_rows();
  wake();
}

void System::clamp_bound_rows() {
  m_hard.update_rigid_offsets(m_bodies);
  m_hard.clamp_positions(m_particles.x, m_bodies.x);
  m_hard.clamp_velocities(m_particles.v, m_bodies.v, m_bodies.w);
  m_soft.synchronize(m_particles, true, true);
}

StepStats System::step(double dt) {
  if (!(std::isfinite(dt) && dt > 0.0)) fail("step: dt ", dt, " must be positive and finite");
  validate(m_step_settings);
  finalize();
  set_thread_count(m_step_settings.threads);
  const StepModel model{
      m_particles,     m_bodies,           m_hard,       m_soft,           m_springs,           m_forces,
      m_step_settings, m_settings.gravity, m_joint_rows, m_effective_mass, m_collision_sources, m_geometry,
      m_time};
  StepStats stats = m_newmark->step(model, dt);
  m_time += dt;
  return stats;
}

double System::stable_dt() {
  finalize();
  double dt = kInfinity;
  // Each force's bound depends on its rest data and the effective masses only, both fixed between
  // set-ups, so it is computed once (advance() asks every frame; the bending bound alone walks every
  // hinge's incidence).
  if (m_force_stable_dt.size() != m_forces.size()) {
    m_force_stable_dt.clear();
    for (const auto& f : m_forces) m_force_stable_dt.push_back(f->stable_dt(m_effective_mass));
  }
  for (std::size_t k = 0; k < m_forces.size(); ++k) {
    if (m_step_settings.implicit_elasticity && m_forces[k]->has_definite_differentials())
      continue;  // no limit when implicit
    dt = std::min(dt, m_force_stable_dt[k]);
  }
  return dt;
}

int System::substeps_for(double frame_dt, double limit) const {
  const double count = std::ceil(frame_dt / (m_step_settings.cfl * limit));
  if (count > m_step_settings.max_substeps) return 0;
  return std::max(1, static_cast<int>(count));
}

double System::visible_energy() {
  double energy = kinetic_energy();
  for (const auto& f : m_forces) energy += f->potential_energy(m_particles.x);
  return energy;
}

int System::turn_substeps(double frame_dt, double energy) {
  // What linearising at each step's start misses over a step of dt is dt^2 S (Force::turn_work_rate);
  // it is kept below turn_work_per_implicit_step of the scene's kinetic and elastic energy E:
  // substeps = ceil(frame_dt sqrt(S / (eta E))).
  // Moving along tangents also stretches elements that had no stress to turn, dt^4 Q
  // (Force::turn_stretch_rate): substeps = ceil(frame_dt (Q / (eta E))^(1/4)) bound that alike.
  // A scene with no kinetic or elastic energy has nothing to turn (its particles may still move
  // against kinematic ones): no bound then. A rate that is not a number bounds nothing either.
  double rate = 0.0, stretch = 0.0;
  for (const auto& f : m_forces) {
    rate += f->turn_work_rate(m_particles.x, m_particles.v);
    stretch += f->turn_stretch_rate(m_particles.x, m_particles.v);
  }
  const double allowed = m_step_settings.turn_work_per_implicit_step * energy;
  if (!(allowed > 0.0)) return 1;
  double count = 1.0;
  if (rate > 0.0) count = std::max(count, std::ceil(frame_dt * std::sqrt(rate / allowed)));
  if (stretch > 0.0) count = std::max(count, std::ceil(frame_dt * std::sqrt(std::sqrt(stretch / allowed))));
  if (!(count <= m_step_settings.max_substeps)) return m_step_settings.max_substeps;
  return std::max(1, static_cast<int>(count));
}

namespace {
// The particles whose momentum and energy the diagnostics count: free ones, and soft-spring ones
// (whose targets are bound) where asked.
bool counts_for_momentum(ParticleKind kind, bool include_soft) {
  return kind == ParticleKind::free || (include_soft && kind == ParticleKind::soft_spring);
}
}  // namespace

double System::rms_acceleration(double frame_dt) const {
  const Vectors3& v_start = m_frame_v_start;
  const Vectors3& body_v_start = m_frame_body_v_start;
  if (v_start.cols() != m_particles.size() || body_v_start.cols() != m_bodies.size()) return 0.0;
  double sum = 0.0, mass = 0.0;
  for (Index i = 0; i < m_particles.size(); ++i)
    if (counts_for_momentum(m_particles.kind[i], true)) {
      sum += m_particles.mass[i] * (m_particles.v.col(i) - v_start.col(i)).squaredNorm();
      mass += m_particles.mass[i];
    }
  for (Index b = 0; b < m_bodies.size(); ++b)
    if (!m_bodies.kinematic[b]) {
      sum += m_bodies.mass[b] * (m_bodies.v.col(b) - body_v_start.col(b)).squaredNorm();
      mass += m_bodies.mass[b];
    }
  if (!(mass > 0.0)) return 0.0;
  const double a = std::sqrt(sum / mass) / frame_dt;
  return std::isfinite(a) ? a : 0.0;
}

StepStats System::run_substeps(double frame_dt, int substeps) {
  const double dt = frame_dt / substeps;
  StepStats total;
  for (int i = 0; i < substeps; ++i) total += step(dt);
  return total;
}

// ---- sleeping --------------------------------------------------------------------------------
//
// The whole system sleeps or wakes as one: the step solves every unknown together (the binding
// springs, joint rows and collision groups couple them), so a sleeping part would have to enter
// the solves as prescribed motion and its neighbours' forces on it be ignored; one flag for all
// keeps the step untouched and an asleep frame at one pass over the state.

StepStats System::advance(double frame_dt) {
  if (!(std::isfinite(frame_dt) && frame_dt > 0.0))
    fail("advance: frame dt ", frame_dt, " must be positive and finite");
  validate(m_step_settings);
  if (m_asleep && !still_asleep(frame_dt)) wake();
  if (m_asleep) {
    // The rigid solver may have left the bodies a round-off twist (the wake test allows it below
    // sleep_speed): they are held, with the points on them.
    bool held = false;
    for (Index b = 0; b < m_bodies.size(); ++b)
      if (!m_bodies.kinematic[b] && !(m_bodies.v.col(b).isZero(0.0) && m_bodies.w.col(b).isZero(0.0))) {
        m_bodies.v.col(b).setZero();
        m_bodies.w.col(b).setZero();
        held = true;
      }
    if (held) clamp_bound_rows();
    m_time += frame_dt;
    StepStats stats;
    stats.asleep = true;
    return stats;
  }
  StepStats stats = advance_awake(frame_dt);
  if (!m_step_settings.sleep) return stats;
  // At rest at the end of every frame for sleep_time (frames summed, so the test does not depend on
  // the frame's length beyond its granularity).
  m_rest_time = at_rest() ? m_rest_time + frame_dt : 0.0;
  if (m_rest_time >= m_step_settings.sleep_time) fall_asleep();
  return stats;
}

void System::wake() {
  m_asleep = false;
  m_rest_time = 0.0;
  m_sleep.bounds.setEmpty();
}

double System::body_reach(Index b) const {
  double reach = std::sqrt(m_bodies.inertia.col(b).maxCoeff() / m_bodies.mass[b]);
  const RigidBindings& rigid = m_hard.rigid();
  for (Index k = 0; k < rigid.size(); ++k)
    if (rigid.body(k) == b) reach = std::max(reach, m_hard.rigid_offset_body(k).norm());
  return reach;
}

bool System::at_rest() const {
  const double speed = m_step_settings.sleep_speed;
  for (Index i = 0; i < m_particles.size(); ++i) {
    const ParticleKind kind = m_particles.kind[i];
    if (kind == ParticleKind::free || kind == ParticleKind::soft_spring) {
      if (!(m_particles.v.col(i).norm() <= speed)) return false;
    } else if (kind == ParticleKind::kinematic) {
      if (!m_particles.v.col(i).isZero(0.0)) return false;  // prescribed motion: never at rest
    }
  }
  for (Index b = 0; b < m_bodies.size(); ++b) {
    if (m_bodies.kinematic[b]) {
      if (!(m_bodies.v.col(b).isZero(0.0) && m_bodies.w.col(b).isZero(0.0))) return false;
    } else if (!(m_bodies.v.col(b).norm() + m_bodies.w.col(b).norm() * body_reach(b) <= speed)) {
      return false;
    }
  }
  return true;
}

void System::fall_asleep() {
  for (Index i = 0; i < m_particles.size(); ++i)
    if (m_particles.kind[i] == ParticleKind::free || m_particles.kind[i] == ParticleKind::soft_spring)
      m_particles.v.col(i).setZero();
  m_sleep.body_reach.resize(m_bodies.size());
  for (Index b = 0; b < m_bodies.size(); ++b) {
    if (m_bodies.kinematic[b]) continue;
    m_bodies.v.col(b).setZero();
    m_bodies.w.col(b).setZero();
    m_sleep.body_reach[b] = body_reach(b);
  }
  clamp_bound_rows();  // bound and synchronized rows at rest with their parents
  m_sleep.x = m_particles.x;
  m_sleep.v = m_particles.v;
  m_sleep.mass = m_particles.mass;
  m_sleep.body_x = m_bodies.x;
  m_sleep.body_q = m_bodies.q;
  m_sleep.body_force = m_bodies.force;
  m_sleep.body_torque = m_bodies.torque;
  m_sleep.gravity = m_settings.gravity;
  m_sleep.bounds.setEmpty();
  for (Index i = 0; i < m_particles.size(); ++i)
    if (m_particles.kind[i] != ParticleKind::removed) m_sleep.bounds.extend(Vec3(m_particles.x.col(i)));
  m_asleep = true;
}

bool System::still_asleep(double frame_dt) const {
  if (!m_step_settings.sleep || needs_set_up() || m_settings.gravity != m_sleep.gravity) return false;
  const Index n = m_particles.size();
  if (m_sleep.x.cols() != n || m_sleep.body_x.cols() != m_bodies.size()) return false;
  // Rows with a state of their own must be exactly as recorded: any change is the caller's. Bound and
  // synchronized rows follow their parents, which are tested instead.
  for (Index i = 0; i < n; ++i) {
    const ParticleKind kind = m_particles.kind[i];
    if (kind != ParticleKind::free && kind != ParticleKind::soft_spring && kind != ParticleKind::kinematic) continue;
    if (m_particles.x.col(i) != m_sleep.x.col(i) || m_particles.v.col(i) != m_sleep.v.col(i)) return false;
  }
  if (m_particles.mass.size() != m_sleep.mass.size() || m_particles.mass != m_sleep.mass) return false;
  const double speed = m_step_settings.sleep_speed;
  for (Index b = 0; b < m_bodies.size(); ++b) {
    const auto q = static_cast<std::size_t>(b);
    if (m_bodies.kinematic[b]) {
      if (m_bodies.x.col(b) != m_sleep.body_x.col(b) || m_bodies.q[q].coeffs() != m_sleep.body_q[q].coeffs() ||
          !m_bodies.v.col(b).isZero(0.0) || !m_bodies.w.col(b).isZero(0.0))
        return false;
      continue;
    }
    // A rigid solver owns dynamic bodies and leaves them round-off twists and drifts: a body wakes the
    // system when it moves as a woken scene would, or when the forces on it change.
    const double reach = m_sleep.body_reach[b];
    if (!(m_bodies.v.col(b).norm() + m_bodies.w.col(b).norm() * reach <= speed)) return false;
    const double turn = Eigen::AngleAxisd(m_bodies.q[q] * m_sleep.body_q[q].conjugate()).angle();
    if (!((m_bodies.x.col(b) - m_sleep.body_x.col(b)).norm() + turn * reach <= speed * frame_dt)) return false;
    // A change of its applied force or torque (recomputed by the rigid solver every tick, to round-off)
    // wakes it when over sleep_time it would give the body's farthest point more than sleep_speed.
    const double acceleration =
        (m_bodies.force.col(b) - m_sleep.body_force.col(b)).norm() / m_bodies.mass[b] +
        (m_bodies.torque.col(b) - m_sleep.body_torque.col(b)).norm() * reach / m_bodies.inertia.col(b).minCoeff();
    if (!(acceleration * m_step_settings.sleep_time <= speed)) return false;
  }
  return true;
}

StepStats System::advance_awake(double frame_dt) {
  const auto too_many = [&](double limit) {
    fail("advance: the stable step ", m_step_settings.cfl * limit, " s needs ",
         std::ceil(frame_dt / (m_step_settings.cfl * limit)), " substeps for a frame of ", frame_dt,
         " s, more than max_substeps = ", m_step_settings.max_substeps);
  };
  const double limit = stable_dt();  // as set
  int as_set = substeps_for(frame_dt, limit);
  if (m_step_settings.automatic && as_set > 0 && limit < kInfinity) {
    // Explicit elasticity whirled by a fast-turning body it is bound to: substeps that turn that
    // body at most kMaxExplicitTurn (System::kMaxExplicitTurn says why).
    double spin = 0.0;
    for (Index k = 0; k < m_hard.rigid_count(); ++k) spin = std::max(spin, m_bodies.w.col(m_hard.rigid_body(k)).norm());
    const double turn = std::ceil(frame_dt * spin / kMaxExplicitTurn);
    as_set = turn > m_step_settings.max_substeps ? 0 : std::max(as_set, static_cast<int>(turn));
  }
  const bool cheap_explicit = !m_step_settings.implicit_elasticity && as_set > 0 && as_set <= kCheapExplicitSubsteps;
  if (!m_step_settings.automatic) {
    if (as_set == 0) too_many(limit);
    return run_substeps(frame_dt, as_set);
  }
  // The solves' tolerance for this frame (StepSettings::relative_tolerance), put back whatever happens.
  struct RestoreTolerance {
    System& system;
    double cg_rms_tolerance;
    ~RestoreTolerance() { system.m_step_settings.cg_rms_tolerance = cg_rms_tolerance; }
  } restore_tolerance{*this, m_step_settings.cg_rms_tolerance};
  // The frame's velocity change per substep is about a dt, with a the last frame's RMS acceleration
  // (|gravity| before a first frame): what a falling, swinging or spun scene changes by, and nearly
  // nothing in one settling to rest, whose solves then tighten. Measured again at this frame's end.
  const double acceleration = m_frame_acceleration >= 0.0 ? m_frame_acceleration : m_settings.gravity.norm();
  // (Not after a frame that threw: its state is the frame's start again.)
  m_frame_v_start = m_particles.v;  // same size frame to frame: no allocation
  m_frame_body_v_start = m_bodies.v;
  struct MeasureAcceleration {
    System& system;
    double frame_dt;
    int exceptions = std::uncaught_exceptions();
    ~MeasureAcceleration() {
      if (std::uncaught_exceptions() > exceptions) return;
      system.m_frame_acceleration = system.rms_acceleration(frame_dt);
    }
  } measure{*this, frame_dt};
  // The scale is at least sleep_speed, the speed below which the scene counts as at rest: a scene at
  // rest has no acceleration, but its velocities only need to stay well below that. A solve error
  // must not keep it awake either: at most a tenth of sleep_speed.
  const auto loosen = [&](int substeps, double fraction) {
    if (substeps <= 0) return;
    const double change = std::max(acceleration * frame_dt / substeps, m_step_settings.sleep_speed);
    double rms = fraction * m_step_settings.relative_tolerance * change;
    if (m_step_settings.sleep) rms = std::min(rms, 0.1 * m_step_settings.sleep_speed);
    m_step_settings.cg_rms_tolerance = std::max(restore_tolerance.cg_rms_tolerance, rms);
  };
  if (cheap_explicit) {
    m_chose_implicit = false;
    loosen(as_set, kExplicitToleranceFactor);
    return run_substeps(frame_dt, as_set);
  }
  // The turn bound of implicit elasticity, from the state at the frame's start.
  const double energy = visible_energy();
  const int turn_substeps = this->turn_substeps(frame_dt, energy);
  if (m_step_settings.implicit_elasticity) {  // the user's choice, bounded by the turn
    if (as_set == 0) too_many(limit);
    return run_substeps(frame_dt, std::max(as_set, turn_substeps));
  }
  // Implicit elasticity: forces that can offer a definite differential stop limiting the substep.
  double implicit_limit = kInfinity;
  for (std::size_t k = 0; k < m_forces.size(); ++k)
    if (!m_forces[k]->can_offer_definite_differentials())
      implicit_limit = std::min(implicit_limit, m_force_stable_dt[k]);
  int implicit = std::max(substeps_for(frame_dt, implicit_limit), turn_substeps);
  // A force kept explicit limits the substep to its own stable step but adds nothing to the solves;
  // made implicit, its products join every CG iteration (a hinge's 12 x 12 block against a spring's
  // 6 x 6) and stiffen the system the CG solves. For a force that offers a definite differential
  // only when asked (dihedral bending's Gauss-Newton one), up to kKeepExplicitFactor times the
  // substeps explicit is the cheaper (and, at the shorter step, the more accurate): the count is raised
  // to the largest own count within that factor, and those forces stay explicit. Forces whose
  // definite differential is their own (edge springs) join the solves whenever they limit the step.
  // Where a substep's contact work (the last frame's, as CG iterations) makes substeps dear, the
  // factor shrinks by kSubstepCost / (kSubstepCost + that work): each added substep costs it too.
  const double keep_explicit_factor =
      kKeepExplicitFactor * kSubstepCost / (kSubstepCost + std::max(0.0, m_contact_iterations));
  if (implicit > 0) {
    const int fewest = implicit;
    for (std::size_t k = 0; k < m_forces.size(); ++k) {
      const int own = substeps_for(frame_dt, m_force_stable_dt[k]);
      const Force& f = *m_forces[k];
      if (f.can_offer_definite_differentials() && !f.has_definite_differentials() && own > implicit &&
          own <= keep_explicit_factor * fewest)
        implicit = own;  // every force whose own count is at most this stays explicit
    }
  }
  // Costs in CG iterations (a CG product visits the elements as a force evaluation does): a substep's
  // own work is kSubstepCost of them, plus its CG iterations, from the counts last seen. Before any
  // count, the first frame guesses: none for explicit, kImplicitIterationsGuess for implicit. Once
  // explicit has a count, an implicit step never run is tried where it takes fewer substeps (a guess
  // that favoured explicit would never be replaced by a count), and again after kRetryImplicitFrames
  // explicit frames (a count from one hard frame goes stale). A switch needs a clear gain
  // (hysteresis), so a frame on the edge does not alternate; the first choice switches from nothing
  // and takes the cheaper guess (a 40 x 40 cloth's first frame at 36 explicit substeps took 68 ms
  // where the 4 implicit ones that every later frame ran took 12).
  const bool explicit_counted = m_explicit_iterations >= 0.0;
  const bool implicit_counted = m_implicit_iterations >= 0.0;
  const bool first_choice = !explicit_counted && !implicit_counted;
  const bool try_implicit = explicit_counted && (!implicit_counted || m_explicit_frames >= kRetryImplicitFrames);
  // A scheme not yet counted is guessed to do the last frame's contact work too (contact work
  // follows the scene, not the scheme).
  const double explicit_iterations = explicit_counted ? m_explicit_iterations : m_contact_iterations;
  const double explicit_cost = as_set == 0 ? kInfinity : as_set * (kSubstepCost + explicit_iterations);
  const double implicit_iterations =
      try_implicit ? 0.0 : (implicit_counted ? m_implicit_iterations : kImplicitIterationsGuess + m_contact_iterations);
  const double implicit_cost = implicit == 0 ? kInfinity : implicit * (kSubstepCost + implicit_iterations);
  // Leaving implicit for an explicit step never counted needs twice the gain: that guess leaves out
  // the CG iterations explicit frames still spend on binding springs, joints and bodies (the cloth
  // above, its first implicit frame counted at 46 iterations a substep from rest, left for one
  // explicit frame of 36 substeps at 11 iterations each and came back).
  const double hysteresis = 1.25;
  const double leave_implicit = explicit_counted ? hysteresis : 2.0 * hysteresis;
  const bool go_implicit = try_implicit || first_choice ? implicit_cost < explicit_cost
                           : m_chose_implicit           ? implicit_cost < leave_implicit * explicit_cost
                                                        : hysteresis * implicit_cost < explicit_cost;
  // A substep's CG iterations, its contact work counted as iterations.
  const double work_per_iteration = kCgWorkPerParticle * double(std::max<Index>(1, m_particles.size()));
  const auto iterations = [&](const StepStats& s) {
    m_contact_iterations = s.contact_work / work_per_iteration / std::max(1, s.substeps);
    return double(s.cg_iterations_step1 + s.cg_iterations_step3 + s.cg_iterations_step4) / std::max(1, s.substeps) +
           m_contact_iterations;
  };
  if (!go_implicit) {
    if (as_set == 0) too_many(limit);
    m_chose_implicit = false;
    ++m_explicit_frames;
    loosen(as_set, kExplicitToleranceFactor);
    const StepStats stats = run_substeps(frame_dt, as_set);
    m_explicit_iterations = iterations(stats);
    return stats;
  }
  if (implicit == 0) too_many(implicit_limit);
  // Implicit for this frame: the setting and the forces' offers are put back whatever happens.
  struct Restore {
    System& system;
    ~Restore() {
      system.m_step_settings.implicit_elasticity = false;
      for (auto& f : system.m_forces) f->offer_definite_differentials(false);
    }
  } restore{*this};
  // Implicit elasticity is first-order accurate in the stiff modes: its error per step is far above a
  // solve to round-off, so the solves stop at relative_tolerance of a substep's velocity change.
  loosen(implicit, 1.0);
  m_step_settings.implicit_elasticity = true;
  // Only a force whose own stable step is shorter than the substep is made implicit: one stable there
  // explicitly costs a force evaluation per substep and nothing in the solves (dihedral bending on a
  // cloth whose springs set the limit: its implicit products cost more CG work than it saves).
  for (std::size_t k = 0; k < m_forces.size(); ++k) {
    const int own = substeps_for(frame_dt, m_force_stable_dt[k]);
    m_forces[k]->offer_definite_differentials(own == 0 || own > implicit);
  }
  m_chose_implicit = true;
  m_explicit_frames = 0;
  const StepStats stats = run_substeps(frame_dt, implicit);
  m_implicit_iterations = iterations(stats);
  return stats;
}

// ---- diagnostics -------------------------------------------------------------------------------

Vec3 System::linear_momentum(bool include_soft) const {
  require_finalized("momentum and energy");
  Vec3 p = Vec3::Zero();
  for (Index i = 0; i < m_particles.size(); ++i)
    if (counts_for_momentum(m_particles.kind[i], include_soft)) p += m_particles.mass[i] * m_particles.v.col(i);
  for (Index b = 0; b < m_bodies.size(); ++b)
    if (!m_bodies.kinematic[b]) p += m_bodies.mass[b] * m_bodies.v.col(b);
  return p;
}

Vec3 System::angular_momentum(bool include_soft) const {
  require_finalized("momentum and energy");
  Vec3 l = Vec3::Zero();
  for (Index i = 0; i < m_particles.size(); ++i)
    if (counts_for_momentum(m_particles.kind[i], include_soft))
      l += m_particles.mass[i] * Vec3(m_particles.x.col(i)).cross(Vec3(m_particles.v.col(i)));
  for (Index b = 0; b < m_bodies.size(); ++b)
    if (!m_bodies.kinematic[b])
      l += m_bodies.mass[b] * Vec3(m_bodies.x.col(b)).cross(Vec3(m_bodies.v.col(b))) + m_bodies.angular_momentum(b);
  return l;
}

double System::kinetic_energy(bool include_soft) const {
  require_finalized("momentum and energy");
  double e = 0.0;
  for (Index i = 0; i < m_particles.size(); ++i)
    if (counts_for_momentum(m_particles.kind[i], include_soft))
      e += 0.5 * m_particles.mass[i] * m_particles.v.col(i).squaredNorm();
  for (Index b = 0; b < m_bodies.size(); ++b)
    if (!m_bodies.kinematic[b])
      e += 0.5 * m_bodies.mass[b] * m_bodies.v.col(b).squaredNorm() +
           0.5 * m_bodies.w.col(b).dot(m_bodies.angular_momentum(b));
  return e;
}

double System::potential_energy() {
  finalize();
  double e = m_springs.potential_energy(m_particles.x);
  for (const auto& f : m_forces) e += f->potential_energy(m_particles.x);
  const Vec3& g = m_settings.gravity;
  for (Index i = 0; i < m_particles.size(); ++i)
    if (m_particles.kind[i] == ParticleKind::free) e -= m_particles.mass[i] * g.dot(m_particles.x.col(i));
  for (Index b = 0; b < m_bodies.size(); ++b)
    if (!m_bodies.kinematic[b] && m_bodies.gravity[b]) e -= m_bodies.mass[b] * g.dot(m_bodies.x.col(b));
  return e;
}

double System::max_hard_binding_drift() const { return m_hard.max_drift(m_particles.x, m_bodies); }

std::uint64_t System::state_hash() const {
  std::uint64_t h = 1469598103934665603ull;
  auto mix = [&h](const void* data, std::size_t bytes) {
    const auto* c = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) h = (h ^ c[i]) * 1099511628211ull;
  };
  mix(m_particles.x.data(), sizeof(double) * m_particles.x.size());
  mix(m_particles.v.data(), sizeof(double) * m_particles.v.size());
  mix(m_bodies.x.data(), sizeof(double) * m_bodies.x.size());
  mix(m_bodies.v.data(), sizeof(double) * m_bodies.v.size());
  mix(m_bodies.w.data(), sizeof(double) * m_bodies.w.size());
  for (const Quat& q : m_bodies.q) mix(q.coeffs().data(), sizeof(double) * 4);
  return h;
}

}  // namespace sinew
