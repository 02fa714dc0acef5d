#include "sinew/bindings/linear_bindings.hpp"

#include <algorithm>

namespace sinew {

void LinearBindings::add(Index id, Index particle, std::span<const Index> parents, std::span<const double> weights) {
  m_id.push_back(id);
  m_particle.push_back(particle);
  m_parent.insert(m_parent.end(), parents.begin(), parents.end());
  m_weight.insert(m_weight.end(), weights.begin(), weights.end());
  m_offset.push_back(static_cast<Index>(m_parent.size()));
}

void LinearBindings::remove(Index k) {
  const Index begin = m_offset[k], end = m_offset[k + 1];
  m_parent.erase(m_parent.begin() + begin, m_parent.begin() + end);
  m_weight.erase(m_weight.begin() + begin, m_weight.begin() + end);
  m_offset.erase(m_offset.begin() + k + 1);
  for (std::size_t j = static_cast<std::size_t>(k) + 1; j < m_offset.size(); ++j) m_offset[j] -= end - begin;
  m_particle.erase(m_particle.begin() + k);
  m_id.erase(m_id.begin() + k);
}

void LinearBindings::replace(Index k, std::span<const Index> parents, std::span<const double> weights) {
  const Index begin = m_offset[k], end = m_offset[k + 1];
  const Index grow = static_cast<Index>(parents.size()) - (end - begin);
  if (grow > 0) {
    m_parent.insert(m_parent.begin() + end, static_cast<std::size_t>(grow), Index{0});
    m_weight.insert(m_weight.begin() + end, static_cast<std::size_t>(grow), 0.0);
  } else if (grow < 0) {
    m_parent.erase(m_parent.begin() + end + grow, m_parent.begin() + end);
    m_weight.erase(m_weight.begin() + end + grow, m_weight.begin() + end);
  }
  for (std::size_t j = static_cast<std::size_t>(k) + 1; j < m_offset.size(); ++j) m_offset[j] += grow;
  std::copy(parents.begin(), parents.end(), m_parent.begin() + begin);
  std::copy(weights.begin(), weights.end(), m_weight.begin() + begin);
}

void LinearBindings::clear() {
  m_id.clear();
  m_particle.clear();
  m_offset.assign(1, 0);
  m_parent.clear();
  m_weight.clear();
}

void LinearBindings::clamp(Vectors3& y) const {
  for (Index k = 0; k < size(); ++k) {
    Vec3 ye = Vec3::Zero();
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) ye += m_weight[j] * y.col(m_parent[j]);
    y.col(m_particle[k]) = ye;
  }
}

void LinearBindings::clamp_positions(Vectors3& x, const Vectors3&) const { clamp(x); }
void LinearBindings::clamp_velocities(Vectors3& v, const Vectors3&, const Vectors3&) const { clamp(v); }
void LinearBindings::clamp_velocities(Vectors3& v, const Vectors6&) const { clamp(v); }

void LinearBindings::distribute(Vectors3& f, Vectors6&) const {
  for (Index k = 0; k < size(); ++k) {
    const Vec3 fe = f.col(m_particle[k]);
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) f.col(m_parent[j]) += m_weight[j] * fe;
    f.col(m_particle[k]).setZero();
  }
}

void LinearBindings::distribute_masses(VectorXd& mass) const {
  for (Index k = 0; k < size(); ++k) {
    const Index p = m_particle[k];
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) mass[m_parent[j]] += m_weight[j] * mass[p];
    mass[p] = 0.0;
  }
}

void LinearBindings::add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>&) const {
  auto block_of = [&](Index i) { return Eigen::Map<Mat3>(blocks.col(i).data()); };
  for (Index k = 0; k < size(); ++k) {
    const Mat3 d = block_of(m_particle[k]);
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) block_of(m_parent[j]) += (m_weight[j] * m_weight[j]) * d;
  }
}

double LinearBindings::max_drift(const Vectors3& x, const RigidBodyParticles&) const {
  double drift = 0.0;
  for (Index k = 0; k < size(); ++k) {
    Vec3 xe = Vec3::Zero();
    for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) xe += m_weight[j] * x.col(m_parent[j]);
    drift = std::max(drift, (xe - x.col(m_particle[k])).norm());
  }
  return drift;
}

Vec3 LinearBindings::point_velocity(Index k, const Vectors3& v, const RigidBodyParticles&) const {
  Vec3 u = Vec3::Zero();
  for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) u += m_weight[j] * v.col(m_parent[j]);
  return u;
}

Vec3 LinearBindings::point_acceleration(Index k, const Particles& p, const RigidBodyParticles&, const Vectors3& f,
                                        const Vectors6&) const {
  Vec3 a = Vec3::Zero();
  for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) a += (m_weight[j] / p.mass[m_parent[j]]) * f.col(m_parent[j]);
  return a;
}

double LinearBindings::inverse_effective_mass(Index k, const VectorXd& mass, const RigidBodyParticles&) const {
  double inverse = 0.0;
  for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) inverse += m_weight[j] * m_weight[j] / mass[m_parent[j]];
  return inverse;
}

double LinearBindings::effective_mass_along(Index, const Vec3&, double scalar, const RigidBodyParticles&) const {
  return scalar;
}

void LinearBindings::apply_impulse(Index k, const Vec3& j, Particles& p, RigidBodyParticles&) const {
  for (Index i = m_offset[k]; i < m_offset[k + 1]; ++i)
    if (p.kind[m_parent[i]] != ParticleKind::kinematic) p.v.col(m_parent[i]) += (m_weight[i] / p.mass[m_parent[i]]) * j;
}

// dx_i = w_i (m_e / m_i) dx on each parent (section 2's impulse rule applied to a displacement).
void LinearBindings::push_drift(Index k, const Vec3& dx, const Vec3& dv, double m_e, Particles& p, RigidBodyParticles&,
                                Vectors3&) {
  if (!std::isfinite(m_e)) return;
  for (Index j = m_offset[k]; j < m_offset[k + 1]; ++j) {
    const Index parent = m_parent[j];
    if (p.kind[parent] == ParticleKind::kinematic) continue;
    const double c = m_weight[j] * m_e / p.mass[parent];
    p.x.col(parent) += c * dx;
    p.v.col(parent) += c * dv;
  }
}

}  // namespace sinew
