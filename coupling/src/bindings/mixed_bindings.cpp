#include "sinew/bindings/mixed_bindings.hpp"

#include "sinew/types.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>

namespace sinew {

void MixedBindings::add(Index id, Index particle, std::span<const Index> parents, std::span<const double> weights,
                        std::span<const Index> frame, Index body) {
  m_map.add(id, particle, parents, weights);
  m_body.push_back(body);
  m_frame.insert(m_frame.end(), frame.begin(), frame.end());
  m_offset.push_back(static_cast<Index>(m_frame.size()));
}

void MixedBindings::remove(Index k) {
  const Index begin = m_offset[k], end = m_offset[k + 1];
  m_frame.erase(m_frame.begin() + begin, m_frame.begin() + end);
  m_offset.erase(m_offset.begin() + k + 1);
  for (std::size_t j = static_cast<std::size_t>(k) + 1; j < m_offset.size(); ++j) m_offset[j] -= end - begin;
  m_body.erase(m_body.begin() + k);
  m_map.remove(k);
}

void MixedBindings::clear() {
  m_map.clear();
  m_body.clear();
  m_offset.assign(1, 0);
  m_frame.clear();
}

// W: the frame parents' rows were written by RigidBindings just before (HardBindings visits this kind
// after it in every W pass); W^T: RigidBindings, visited after, carries them on to the body's wrench.
void MixedBindings::clamp_positions(Vectors3& x, const Vectors3& body_x) const { m_map.clamp_positions(x, body_x); }
void MixedBindings::clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const {
  m_map.clamp_velocities(v, body_v, body_w);
}
void MixedBindings::clamp_velocities(Vectors3& v, const Vectors6& twist) const { m_map.clamp_velocities(v, twist); }
void MixedBindings::distribute(Vectors3& f, Vectors6& wrench) const { m_map.distribute(f, wrench); }
void MixedBindings::add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const {
  m_map.add_preconditioner_blocks(blocks, body_blocks);
}

void MixedBindings::distribute_masses(VectorXd& mass) const {
  for (Index k = 0; k < size(); ++k) {
    const Index p = particle(k);
    if (mass[p] == 0.0) continue;
    for (std::size_t i = 0; i < parents(k).size(); ++i)
      if (frame(k, i) >= 0)
        fail("binding ", id(k), ": particle ", p, " has mass ", mass[p], " but hangs partly on rigid body ", m_body[k],
             "'s frame points, which cannot take it; give it no mass, or embed it in free particles only");
  }
  m_map.distribute_masses(mass);
}

double MixedBindings::max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const {
  double drift = 0.0;
  for (Index k = 0; k < size(); ++k) {
    Vec3 xe = Vec3::Zero();
    const Index b = m_body[k];
    for (std::size_t i = 0; i < parents(k).size(); ++i)
      xe += weights(k)[i] * (frame(k, i) >= 0 ? Vec3(bodies.x.col(b) + bodies.q[b] * m_frames->offset_body(frame(k, i)))
                                              : Vec3(x.col(parents(k)[i])));
    drift = std::max(drift, (xe - x.col(particle(k))).norm());
  }
  return drift;
}

double MixedBindings::frame_share(Index k, Vec3& moment) const {
  double share = 0.0;
  moment.setZero();
  for (std::size_t i = 0; i < parents(k).size(); ++i)
    if (frame(k, i) >= 0) {
      share += weights(k)[i];
      moment += weights(k)[i] * m_frames->offset_world(frame(k, i));
    }
  return share;
}

Mat3 MixedBindings::frame_impulse_matrix(Index k, const RigidBodyParticles& bodies) const {
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return Mat3::Zero();
  Vec3 moment;
  const double share = frame_share(k, moment);
  const Mat3 S = cross_matrix(moment);
  return (share * share / bodies.mass[b]) * Mat3::Identity() + S.transpose() * bodies.world_inverse_inertia(b) * S;
}

Vec3 MixedBindings::point_velocity(Index k, const Vectors3& v, const RigidBodyParticles& bodies) const {
  Vec3 u = Vec3::Zero();
  for (std::size_t i = 0; i < parents(k).size(); ++i)
    u += weights(k)[i] *
         (frame(k, i) >= 0 ? m_frames->point_velocity(frame(k, i), v, bodies) : Vec3(v.col(parents(k)[i])));
  return u;
}

Vec3 MixedBindings::point_acceleration(Index k, const Particles& p, const RigidBodyParticles& bodies, const Vectors3& f,
                                       const Vectors6& wrench) const {
  Vec3 a = Vec3::Zero();
  for (std::size_t i = 0; i < parents(k).size(); ++i) {
    const Index parent = parents(k)[i];
    if (frame(k, i) >= 0) a += weights(k)[i] * m_frames->point_acceleration(frame(k, i), p, bodies, f, wrench);
    else if (p.kind[parent] != ParticleKind::kinematic) a += (weights(k)[i] / p.mass[parent]) * f.col(parent);
  }
  return a;
}

// 1/m_e = sum_F w_i^2 / m_i plus the frame share's w_B^2 K (its largest eigenvalue: the smallest
// effective mass over directions, as RigidBindings takes it).
double MixedBindings::inverse_effective_mass(Index k, const VectorXd& mass, const RigidBodyParticles& bodies) const {
  double inverse = 0.0;
  for (std::size_t i = 0; i < parents(k).size(); ++i)
    if (frame(k, i) < 0) inverse += weights(k)[i] * weights(k)[i] / mass[parents(k)[i]];
  return inverse + Eigen::SelfAdjointEigenSolver<Mat3>(frame_impulse_matrix(k, bodies)).eigenvalues().maxCoeff();
}

// The free parents' part, 1/scalar less the frame share's largest eigenvalue, plus the frame share
// along n.
double MixedBindings::effective_mass_along(Index k, const Vec3& n, double scalar,
                                           const RigidBodyParticles& bodies) const {
  const Mat3 K = frame_impulse_matrix(k, bodies);
  const double free = 1.0 / scalar - Eigen::SelfAdjointEigenSolver<Mat3>(K).eigenvalues().maxCoeff();
  const double inverse = std::max(free, 0.0) + n.dot(K * n);
  return inverse > 0.0 ? 1.0 / inverse : kInfinity;
}

void MixedBindings::apply_impulse(Index k, const Vec3& j, Particles& p, RigidBodyParticles& bodies) const {
  for (std::size_t i = 0; i < parents(k).size(); ++i)
    if (frame(k, i) < 0 && p.kind[parents(k)[i]] != ParticleKind::kinematic)
      p.v.col(parents(k)[i]) += (weights(k)[i] / p.mass[parents(k)[i]]) * j;
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return;
  Vec3 moment;
  const double share = frame_share(k, moment);
  bodies.v.col(b) += (share / bodies.mass[b]) * j;
  bodies.w.col(b) += bodies.world_inverse_inertia(b) * moment.cross(j);
}

// Section 3.1's push-back: the free parents as LinearBindings moves them, the body by the impulse
// m_e dv at the point (w_B of it, and its moment s x about the centre; the matching displacement
// likewise); then the frame points' world offsets follow the body. m_e is the scalar effective mass
// (the frame share's stiffest direction), so the point moves by at most dx: it under-corrects along
// the frame share's softer directions, as a scalar push-back does.
void MixedBindings::push_drift(Index k, const Vec3& dx, const Vec3& dv, double m_e, Particles& p,
                               RigidBodyParticles& bodies, Vectors3& L_n) {
  if (!std::isfinite(m_e)) return;
  for (std::size_t i = 0; i < parents(k).size(); ++i) {
    const Index parent = parents(k)[i];
    if (frame(k, i) >= 0 || p.kind[parent] == ParticleKind::kinematic) continue;
    const double c = weights(k)[i] * m_e / p.mass[parent];
    p.x.col(parent) += c * dx;
    p.v.col(parent) += c * dv;
  }
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return;
  Vec3 moment;
  const double share = frame_share(k, moment);
  const Mat3 inverse_inertia = bodies.world_inverse_inertia(b);
  const Vec3 jv = m_e * dv, jx = m_e * dx;  // the impulses at the point
  bodies.v.col(b) += (share / bodies.mass[b]) * jv;
  bodies.w.col(b) += inverse_inertia * moment.cross(jv);
  L_n.col(b) += moment.cross(jv);
  bodies.x.col(b) += (share / bodies.mass[b]) * jx;
  bodies.q[b] = (rotation_from_vector(inverse_inertia * moment.cross(jx)) * bodies.q[b]).normalized();
  m_frames->update_offsets(bodies);
}

}  // namespace sinew
