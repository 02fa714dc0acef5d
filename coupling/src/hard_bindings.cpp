#include "sinew/hard_bindings.hpp"

#include <algorithm>
#include <utility>

namespace sinew {

namespace {

// Throws naming binding `id` unless its parents and weights make a barycentric embedding.
void check_linear(Index id, Index particle, std::span<const Index> parents, std::span<const double> weights) {
  if (parents.empty()) fail("binding ", id, ": no parents");
  if (parents.size() != weights.size())
    fail("binding ", id, ": ", parents.size(), " parents but ", weights.size(), " weights");
  double sum = 0.0;
  for (std::size_t i = 0; i < weights.size(); ++i) {
    if (!std::isfinite(weights[i])) fail("binding ", id, ": weight ", i, " is ", weights[i]);
    if (parents[i] == particle) fail("binding ", id, ": particle ", particle, " is its own parent");
    sum += weights[i];
  }
  // Weights are barycentric: they must reproduce constants (a translated parent set moves the bound
  // point by the same amount), which is what makes W^T conserve momentum.
  if (std::abs(sum - 1.0) > 1e-9) fail("binding ", id, ": weights sum to ", sum, ", expected 1");
}

}  // namespace

void HardBindings::add_linear(Index particle, std::span<const Index> parents, std::span<const double> weights) {
  const Index id = m_added;
  check_linear(id, particle, parents, weights);
  m_linear.add(id, particle, parents, weights);
  ++m_added;
}

void HardBindings::replace_linear(Index particle, std::span<const Index> parents, std::span<const double> weights) {
  const Index k = linear_binding_of(particle);
  if (k < 0) fail("re-embedding: particle ", particle, " is not a point embedded in particles");
  check_linear(m_linear.id(k), particle, parents, weights);
  for (const Index parent : parents)
    if (is_bound(parent))
      fail("binding ", m_linear.id(k), ": parent ", parent, " of particle ", particle,
           " is itself hard-bound; re-embed in free particles");
  m_linear.replace(k, parents, weights);
}

void HardBindings::add_rigid(Index particle, Index body, const Vec3& r0) {
  const Index id = m_added;
  if (!all_finite(r0)) fail("binding ", id, ": rigid offset is not finite");
  m_rigid.add(id, particle, body, r0);
  ++m_added;
}

bool HardBindings::remove(Index particle) {
  for (BindingKind* kind : mutable_kinds())
    for (Index k = 0; k < kind->size(); ++k)
      if (kind->particle(k) == particle) {
        kind->remove(k);
        return true;
      }
  return false;
}

void HardBindings::rebuild_lookup(Index particle_count) {
  m_kind_of.assign(static_cast<std::size_t>(particle_count), -1);
  m_index_in_kind.assign(static_cast<std::size_t>(particle_count), -1);
  auto mark = [&](int kind, Index k, Index particle, Index id) {
    if (particle < 0 || particle >= particle_count)
      fail("binding ", id, ": bound particle ", particle, " out of range [0, ", particle_count, ")");
    if (m_kind_of[particle] >= 0) fail("binding ", id, ": particle ", particle, " is bound twice");
    m_kind_of[particle] = static_cast<std::int8_t>(kind);
    m_index_in_kind[particle] = k;
  };
  const auto all = kinds();
  for (std::size_t kind = 0; kind < all.size(); ++kind)
    for (Index k = 0; k < all[kind]->size(); ++k)
      mark(static_cast<int>(kind), k, all[kind]->particle(k), all[kind]->id(k));
}

void HardBindings::flatten(Index particle_count, Index rigid_count) {
  // Mixed bindings are resolved afresh from their parents (a frame point may have been unbound since).
  for (Index k = 0; k < m_mixed.size(); ++k)
    m_linear.add(m_mixed.id(k), m_mixed.particle(k), m_mixed.parents(k), m_mixed.weights(k));
  m_mixed.clear();
  for (Index k = 0; k < m_rigid.size(); ++k)
    if (m_rigid.body(k) < 0 || m_rigid.body(k) >= rigid_count)
      fail("binding ", m_rigid.id(k), ": rigid body ", m_rigid.body(k), " out of range [0, ", rigid_count, ")");
  for (Index k = 0; k < m_linear.size(); ++k)
    for (Index p : m_linear.parents(k))
      if (p < 0 || p >= particle_count)
        fail("binding ", m_linear.id(k), ": parent ", p, " out of range [0, ", particle_count, ")");
  rebuild_lookup(particle_count);

  LinearBindings flat;
  Chain chain;
  std::vector<Index> parents, frame;
  std::vector<double> weights;
  // Sorted by parent, repeated parents (two chains reaching the same node) merged: a fixed order.
  const auto merge = [&](std::vector<Term>& terms, bool on_frame) {
    std::sort(terms.begin(), terms.end(), [](const Term& a, const Term& b) { return a.parent < b.parent; });
    const std::size_t first = parents.size();
    for (std::size_t i = 0; i < terms.size(); ++i) {
      if (i > 0 && parents.size() > first && terms[i].parent == parents.back()) {
        weights.back() += terms[i].weight;
      } else {
        parents.push_back(terms[i].parent);
        weights.push_back(terms[i].weight);
        frame.push_back(on_frame ? m_index_in_kind[terms[i].parent] : -1);
      }
    }
  };
  for (Index k = 0; k < m_linear.size(); ++k) {
    const Index id = m_linear.id(k);
    resolve_chain(k, chain);
    parents.clear();
    weights.clear();
    frame.clear();
    if (chain.rigid_body >= 0 && chain.terms.empty()) {
      // A point embedded among points of one rigid frame is itself a point of that frame:
      // sum_i w_i (x_c + R r0_i) = x_c + R sum_i w_i r0_i because sum_i w_i = 1.
      m_rigid.add(id, m_linear.particle(k), chain.rigid_body, chain.rigid_r0 / chain.rigid_weight);
      continue;
    }
    merge(chain.terms, false);
    if (chain.rigid_body >= 0) {
      // Free particles and one frame's points: W stays linear in the particles and the body's twist.
      merge(chain.frame_terms, true);
      m_mixed.add(id, m_linear.particle(k), parents, weights, frame, chain.rigid_body);
      continue;
    }
    flat.add(id, m_linear.particle(k), parents, weights);
  }
  m_linear = std::move(flat);
  m_mixed.set_frames(&m_rigid);
  rebuild_lookup(particle_count);
}

// Expands linear binding k until its parents are unbound: terms on unbound particles, or the rigid
// frame points reached, summed as one offset. A chain longer than the number of bindings must revisit
// a binding, i.e. it is a cycle.
void HardBindings::resolve_chain(Index k, Chain& chain) const {
  const Index id = m_linear.id(k);
  chain.terms.clear();
  for (std::size_t i = 0; i < m_linear.parents(k).size(); ++i)
    chain.terms.push_back({m_linear.parents(k)[i], m_linear.weights(k)[i]});
  chain.frame_terms.clear();
  chain.rigid_body = -1;
  chain.rigid_r0 = Vec3::Zero();
  chain.rigid_weight = 0.0;
  const Index max_depth = size() + 1;
  for (Index depth = 0;; ++depth) {
    if (depth > max_depth) fail("binding ", id, ": chain of bindings forms a cycle");
    bool expanded = false;
    chain.next.clear();
    for (const Term& t : chain.terms) {
      const int kind = m_kind_of[t.parent];
      const Index code = m_index_in_kind[t.parent];
      if (kind < 0) {
        chain.next.push_back(t);
      } else if (kind == 0) {
        expanded = true;
        for (std::size_t i = 0; i < m_linear.parents(code).size(); ++i)
          chain.next.push_back({m_linear.parents(code)[i], t.weight * m_linear.weights(code)[i]});
      } else if (kind != 1) {
        fail("binding ", id, ": parent ", t.parent, " is a ", kind_of(t.parent)->name(),
             ", which cannot be the parent of an embedded point");
      } else {
        if (chain.rigid_body >= 0 && chain.rigid_body != m_rigid.body(code))
          fail("binding ", id, ": parents lie on different rigid bodies (", chain.rigid_body, " and ",
               m_rigid.body(code), ")");
        chain.rigid_body = m_rigid.body(code);
        chain.frame_terms.push_back(t);
        chain.rigid_r0 += t.weight * m_rigid.offset_body(code);
        chain.rigid_weight += t.weight;
      }
    }
    chain.terms.swap(chain.next);
    if (!expanded) break;
  }
}

void HardBindings::update_rigid_offsets(const RigidBodyParticles& bodies) {
  for (BindingKind* kind : mutable_kinds()) kind->update_offsets(bodies);
}

void HardBindings::set_step_arms(const std::vector<Mat3>& arm_maps, const std::vector<Mat3>& angular_maps) {
  for (BindingKind* kind : mutable_kinds()) kind->set_step_arms(arm_maps, angular_maps);
}

void HardBindings::clamp_positions(Vectors3& x, const Vectors3& body_x) const {
  for (const BindingKind* kind : kinds()) kind->clamp_positions(x, body_x);
}

void HardBindings::clamp_velocities(Vectors3& v, const Vectors6& twist) const {
  for (const BindingKind* kind : kinds()) kind->clamp_velocities(v, twist);
}

void HardBindings::clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const {
  for (const BindingKind* kind : kinds()) kind->clamp_velocities(v, body_v, body_w);
}

// W^T passes visit the kinds backwards: a mixed point's share on frame points reaches their rows
// before RigidBindings carries those rows to the bodies.
void HardBindings::distribute(Vectors3& f, Vectors6& wrench) const {
  const auto all = kinds();
  for (auto kind = all.rbegin(); kind != all.rend(); ++kind) (*kind)->distribute(f, wrench);
}

void HardBindings::distribute_masses(VectorXd& mass) const {
  const auto all = kinds();
  for (auto kind = all.rbegin(); kind != all.rend(); ++kind) (*kind)->distribute_masses(mass);
}

void HardBindings::add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const {
  const auto all = kinds();
  for (auto kind = all.rbegin(); kind != all.rend(); ++kind) (*kind)->add_preconditioner_blocks(blocks, body_blocks);
}

void HardBindings::inverse_effective_masses(const VectorXd& mass, const RigidBodyParticles& bodies,
                                            VectorXd& inverse_mass) const {
  for (const BindingKind* kind : kinds())
    for (Index k = 0; k < kind->size(); ++k)
      inverse_mass[kind->particle(k)] = kind->inverse_effective_mass(k, mass, bodies);
}

double HardBindings::max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const {
  double drift = 0.0;
  for (const BindingKind* kind : kinds()) drift = std::max(drift, kind->max_drift(x, bodies));
  return drift;
}

void HardBindings::record_bound_rows(const Vectors3& f, Vectors3& out, bool add) const {
  for (const BindingKind* kind : kinds())
    for (Index k = 0; k < kind->size(); ++k) {
      const Index i = kind->particle(k);
      out.col(i) = (add ? Vec3(out.col(i)) : Vec3::Zero()) + Vec3(f.col(i));
    }
}

Vec3 HardBindings::point_acceleration(Index particle, const Particles& p, const RigidBodyParticles& bodies,
                                      const Vectors3& f, const Vectors6& wrench) const {
  if (const BindingKind* kind = kind_of(particle))
    return kind->point_acceleration(m_index_in_kind[particle], p, bodies, f, wrench);
  return p.kind[particle] == ParticleKind::kinematic ? Vec3::Zero() : Vec3(f.col(particle) / p.mass[particle]);
}

double HardBindings::effective_mass_along(Index particle, const Vec3& n, double scalar,
                                          const RigidBodyParticles& bodies) const {
  if (const BindingKind* kind = kind_of(particle))
    return kind->effective_mass_along(m_index_in_kind[particle], n, scalar, bodies);
  return scalar;
}

Vec3 HardBindings::point_velocity(Index particle, const Vectors3& v, const RigidBodyParticles& bodies) const {
  if (const BindingKind* kind = kind_of(particle)) return kind->point_velocity(m_index_in_kind[particle], v, bodies);
  return v.col(particle);
}

void HardBindings::apply_impulse(Index particle, const Vec3& j, Particles& p, RigidBodyParticles& bodies) const {
  if (const BindingKind* kind = kind_of(particle)) return kind->apply_impulse(m_index_in_kind[particle], j, p, bodies);
  if (p.kind[particle] != ParticleKind::kinematic) p.v.col(particle) += j / p.mass[particle];
}

void HardBindings::push_drift(Index particle, const Vec3& dx, const Vec3& dv, Particles& p, RigidBodyParticles& bodies,
                              const VectorXd& effective_mass, Vectors3& L_n) {
  if (kind_of(particle) != nullptr) {
    const int kind = m_kind_of[particle];
    mutable_kinds()[static_cast<std::size_t>(kind)]->push_drift(m_index_in_kind[particle], dx, dv,
                                                                effective_mass[particle], p, bodies, L_n);
    return;
  }
  if (p.kind[particle] == ParticleKind::kinematic) return;  // a prescribed target cannot move
  p.x.col(particle) += dx;
  p.v.col(particle) += dv;
}

}  // namespace sinew
