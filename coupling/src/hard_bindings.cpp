#include "sinew/hard_bindings.hpp"

#include <algorithm>
#include <numeric>
#include <utility>

namespace sinew {

void HardBindings::add_linear(Index particle, std::span<const Index> parents,
                              std::span<const double> weights) {
  const Index id = m_added;
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
  m_linear_id.push_back(id);
  m_linear_particle.push_back(particle);
  m_parent.insert(m_parent.end(), parents.begin(), parents.end());
  m_weight.insert(m_weight.end(), weights.begin(), weights.end());
  m_offset.push_back(static_cast<Index>(m_parent.size()));
  ++m_added;
}

void HardBindings::add_rigid(Index particle, Index body, const Vec3& r0) {
  const Index id = m_added;
  if (!all_finite(r0)) fail("binding ", id, ": rigid offset is not finite");
  m_rigid_id.push_back(id);
  m_rigid_particle.push_back(particle);
  m_rigid_body.push_back(body);
  m_r0.push_back(r0);
  ++m_added;
}

bool HardBindings::remove(Index particle) {
  for (Index k = 0; k < linear_count(); ++k) {
    if (m_linear_particle[k] != particle) continue;
    const Index begin = m_offset[k], end = m_offset[k + 1];
    m_parent.erase(m_parent.begin() + begin, m_parent.begin() + end);
    m_weight.erase(m_weight.begin() + begin, m_weight.begin() + end);
    m_offset.erase(m_offset.begin() + k + 1);
    for (std::size_t j = static_cast<std::size_t>(k) + 1; j < m_offset.size(); ++j) m_offset[j] -= end - begin;
    m_linear_particle.erase(m_linear_particle.begin() + k);
    m_linear_id.erase(m_linear_id.begin() + k);
    return true;
  }
  for (Index k = 0; k < rigid_count(); ++k) {
    if (m_rigid_particle[k] != particle) continue;
    m_rigid_particle.erase(m_rigid_particle.begin() + k);
    m_rigid_body.erase(m_rigid_body.begin() + k);
    m_r0.erase(m_r0.begin() + k);
    m_rigid_id.erase(m_rigid_id.begin() + k);
    return true;
  }
  return false;
}

std::span<const Index> HardBindings::linear_parents(Index k) const {
  return {m_parent.data() + m_offset[k], static_cast<std::size_t>(m_offset[k + 1] - m_offset[k])};
}

std::span<const double> HardBindings::linear_weights(Index k) const {
  return {m_weight.data() + m_offset[k], static_cast<std::size_t>(m_offset[k + 1] - m_offset[k])};
}

void HardBindings::rebuild_lookup(Index particle_count) {
  m_binding_of.assign(static_cast<std::size_t>(particle_count), unbound);
  auto mark = [&](Index particle, Index code, Index id) {
    if (particle < 0 || particle >= particle_count)
      fail("binding ", id, ": bound particle ", particle, " out of range [0, ", particle_count, ")");
    if (m_binding_of[particle] != unbound) fail("binding ", id, ": particle ", particle, " is bound twice");
    m_binding_of[particle] = code;
  };
  for (Index k = 0; k < linear_count(); ++k) mark(m_linear_particle[k], k, m_linear_id[k]);
  for (Index k = 0; k < rigid_count(); ++k) mark(m_rigid_particle[k], -(k + 1), m_rigid_id[k]);
}

void HardBindings::flatten(Index particle_count, Index rigid_count) {
  for (Index k = 0; k < this->rigid_count(); ++k)
    if (m_rigid_body[k] < 0 || m_rigid_body[k] >= rigid_count)
      fail("binding ", m_rigid_id[k], ": rigid body ", m_rigid_body[k], " out of range [0, ", rigid_count, ")");
  for (Index k = 0; k < linear_count(); ++k)
    for (Index p : linear_parents(k))
      if (p < 0 || p >= particle_count)
        fail("binding ", m_linear_id[k], ": parent ", p, " out of range [0, ", particle_count, ")");
  rebuild_lookup(particle_count);

  // Expand every linear binding until its parents are unbound. A chain longer than the number of
  // bindings must revisit a binding, i.e. it is a cycle.
  struct Term { Index parent; double weight; };
  std::vector<Index> new_particle, new_offset{0}, new_parent, new_id;
  std::vector<double> new_weight;
  std::vector<Term> terms, next;
  const Index max_depth = size() + 1;
  for (Index k = 0; k < linear_count(); ++k) {
    terms.clear();
    for (std::size_t i = 0; i < linear_parents(k).size(); ++i)
      terms.push_back({linear_parents(k)[i], linear_weights(k)[i]});
    Index rigid_body_of_chain = -1;
    Vec3 rigid_r0 = Vec3::Zero();
    double rigid_weight = 0.0;
    for (Index depth = 0;; ++depth) {
      if (depth > max_depth) fail("binding ", m_linear_id[k], ": chain of bindings forms a cycle");
      bool expanded = false;
      next.clear();
      for (const Term& t : terms) {
        const Index code = m_binding_of[t.parent];
        if (code == unbound) {
          next.push_back(t);
        } else if (code >= 0) {
          expanded = true;
          for (std::size_t i = 0; i < linear_parents(code).size(); ++i)
            next.push_back({linear_parents(code)[i], t.weight * linear_weights(code)[i]});
        } else {
          const Index r = -code - 1;
          if (rigid_body_of_chain >= 0 && rigid_body_of_chain != m_rigid_body[r])
            fail("binding ", m_linear_id[k], ": parents lie on different rigid bodies (",
                 rigid_body_of_chain, " and ", m_rigid_body[r], ")");
          rigid_body_of_chain = m_rigid_body[r];
          rigid_r0 += t.weight * m_r0[r];
          rigid_weight += t.weight;
        }
      }
      terms.swap(next);
      if (!expanded) break;
    }
    if (rigid_body_of_chain >= 0) {
      // A point embedded among points of one rigid frame is itself a point of that frame:
      // sum_i w_i (x_c + R r0_i) = x_c + R sum_i w_i r0_i because sum_i w_i = 1.
      if (!terms.empty())
        fail("binding ", m_linear_id[k], ": parents mix a rigid frame and free particles, which is not a linear map");
      m_rigid_id.push_back(m_linear_id[k]);
      m_rigid_particle.push_back(m_linear_particle[k]);
      m_rigid_body.push_back(rigid_body_of_chain);
      m_r0.push_back(rigid_r0 / rigid_weight);
      continue;
    }
    // Merge repeated parents (two chains reaching the same node) in a fixed, sorted order.
    std::sort(terms.begin(), terms.end(), [](const Term& a, const Term& b) { return a.parent < b.parent; });
    new_particle.push_back(m_linear_particle[k]);
    new_id.push_back(m_linear_id[k]);
    for (std::size_t i = 0; i < terms.size(); ++i) {
      if (i > 0 && terms[i].parent == new_parent.back()) {
        new_weight.back() += terms[i].weight;
      } else {
        new_parent.push_back(terms[i].parent);
        new_weight.push_back(terms[i].weight);
      }
    }
    new_offset.push_back(static_cast<Index>(new_parent.size()));
  }
  m_linear_particle = std::move(new_particle);
  m_offset = std::move(new_offset);
  m_parent = std::move(new_parent);
  m_weight = std::move(new_weight);
  m_linear_id = std::move(new_id);
  rebuild_lookup(particle_count);
  m_r.setZero(3, this->rigid_count());
}

void HardBindings::update_rigid_offsets(const RigidBodyParticles& bodies) {
  if (m_r.cols() != rigid_count()) m_r.setZero(3, rigid_count());
  for (Index k = 0; k < rigid_count(); ++k) m_r.col(k) = bodies.q[m_rigid_body[k]] * m_r0[k];
}

void HardBindings::clamp_positions(Vectors3& x, const Vectors3& body_x) const {
  clamp_linear(x);
  for (Index k = 0; k < rigid_count(); ++k)
    x.col(m_rigid_particle[k]) = body_x.col(m_rigid_body[k]) + m_r.col(k);
}

void HardBindings::clamp_linear(Vectors3& v) const {
  for (Index k = 0; k < linear_count(); ++k) {
    Vec3 ve = Vec3::Zero();
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) ve += m_weight[j] * v.col(m_parent[j]);
    v.col(m_linear_particle[k]) = ve;
  }
}

void HardBindings::clamp_velocities(Vectors3& v, const Vectors6& twist) const {
  clamp_linear(v);
  for (Index k = 0; k < rigid_count(); ++k) {
    const auto t = twist.col(m_rigid_body[k]);
    const Vec3 w = t.tail<3>();
    v.col(m_rigid_particle[k]) = t.head<3>() + w.cross(Vec3(m_r.col(k)));
  }
}

void HardBindings::clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const {
  clamp_linear(v);
  for (Index k = 0; k < rigid_count(); ++k) {
    const Index b = m_rigid_body[k];
    v.col(m_rigid_particle[k]) = body_v.col(b) + Vec3(body_w.col(b)).cross(Vec3(m_r.col(k)));
  }
}

void HardBindings::distribute(Vectors3& f, Vectors6& wrench) const {
  for (Index k = 0; k < linear_count(); ++k) {
    const Vec3 fe = f.col(m_linear_particle[k]);
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) f.col(m_parent[j]) += m_weight[j] * fe;
    f.col(m_linear_particle[k]).setZero();
  }
  for (Index k = 0; k < rigid_count(); ++k) {
    const Vec3 fe = f.col(m_rigid_particle[k]);
    auto w = wrench.col(m_rigid_body[k]);
    w.head<3>() += fe;
    w.tail<3>() += Vec3(m_r.col(k)).cross(fe);
    f.col(m_rigid_particle[k]).setZero();
  }
}

Vec3 HardBindings::embedded_acceleration(Index particle, const Vectors3& a, const Vectors6& rigid_a) const {
  const Index code = binding_of(particle);
  if (code == unbound) return a.col(particle);
  if (code >= 0) {
    Vec3 ae = Vec3::Zero();
    for (Index j = m_offset[code]; j < m_offset[code + 1]; ++j) ae += m_weight[j] * a.col(m_parent[j]);
    return ae;
  }
  const Index k = -code - 1;
  const auto t = rigid_a.col(m_rigid_body[k]);
  return t.head<3>() + Vec3(t.tail<3>()).cross(Vec3(m_r.col(k)));
}

double HardBindings::inverse_effective_mass_linear(Index k, const VectorXd& mass) const {
  double inverse = 0.0;
  for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) inverse += m_weight[j] * m_weight[j] / mass[m_parent[j]];
  return inverse;
}

}  // namespace sinew
