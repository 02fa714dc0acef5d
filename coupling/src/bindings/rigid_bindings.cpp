#include "sinew/bindings/rigid_bindings.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>

namespace sinew {

void RigidBindings::add(Index id, Index particle, Index body, const Vec3& r0) {
  m_id.push_back(id);
  m_particle.push_back(particle);
  m_body.push_back(body);
  m_r0.push_back(r0);
}

void RigidBindings::remove(Index k) {
  m_particle.erase(m_particle.begin() + k);
  m_body.erase(m_body.begin() + k);
  m_r0.erase(m_r0.begin() + k);
  m_id.erase(m_id.begin() + k);
}

void RigidBindings::absorb_masses(const VectorXd& mass, RigidBodyParticles& bodies) {
  for (Index b = 0; b < bodies.size(); ++b) {
    if (bodies.kinematic[b]) continue;
    double added = 0.0;
    Vec3 moment = Vec3::Zero();
    for (Index k = 0; k < size(); ++k) {
      if (m_body[k] != b) continue;
      const double m = mass[m_particle[k]];
      added += m;
      moment += m * (bodies.x.col(b) + offset_world(k));
    }
    if (added == 0.0) continue;
    const double m0 = bodies.mass[b];
    const Vec3 c0 = bodies.x.col(b);
    const double total = m0 + added;
    const Vec3 c = (m0 * c0 + moment) / total;
    auto point_inertia = [](double m, const Vec3& d) {
      return m * (d.squaredNorm() * Mat3::Identity() - d * d.transpose());
    };
    Mat3 inertia = bodies.world_inertia(b) + point_inertia(m0, c0 - c);
    for (Index k = 0; k < size(); ++k)
      if (m_body[k] == b) inertia += point_inertia(mass[m_particle[k]], c0 + offset_world(k) - c);
    Eigen::SelfAdjointEigenSolver<Mat3> eig(inertia);
    Mat3 r = eig.eigenvectors();
    if (r.determinant() < 0) r.col(2) = -r.col(2);
    const Quat q_new(r);
    const Vec3 w = bodies.w.col(b);
    for (Index k = 0; k < size(); ++k)
      if (m_body[k] == b) m_r0[k] = q_new.conjugate() * (c0 + offset_world(k) - c);
    const Quat q_merged = q_new.normalized();
    m_absorbed.push_back(
        {b, m0, bodies.inertia.col(b), q_merged.conjugate() * (c0 - c), q_merged.conjugate() * bodies.q[b]});
    bodies.v.col(b) += w.cross(c - c0);
    bodies.x.col(b) = c;
    bodies.q[b] = q_merged;
    bodies.mass[b] = total;
    bodies.inertia.col(b) = eig.eigenvalues();
  }
}

void RigidBindings::release_masses(RigidBodyParticles& bodies) {
  for (const Absorbed& a : m_absorbed) {
    const Index b = a.body;
    const Vec3 r = bodies.q[b] * a.d;  // the body's own centre of mass, from the merged one
    bodies.v.col(b) += Vec3(bodies.w.col(b)).cross(r);
    bodies.x.col(b) += r;
    const Quat q_own = (bodies.q[b] * a.q_rel).normalized();
    for (Index k = 0; k < size(); ++k)
      if (m_body[k] == b) m_r0[k] = a.q_rel.conjugate() * (m_r0[k] - a.d);
    bodies.q[b] = q_own;
    bodies.mass[b] = a.mass;
    bodies.inertia.col(b) = a.inertia;
  }
  m_absorbed.clear();
}

void RigidBindings::update_offsets(const RigidBodyParticles& bodies) {
  m_angular.clear();
  if (m_r.cols() != size()) m_r.setZero(3, size());
  for (Index k = 0; k < size(); ++k) m_r.col(k) = bodies.q[m_body[k]] * m_r0[k];
}

void RigidBindings::set_step_arms(const std::vector<Mat3>& arm_maps, const std::vector<Mat3>& angular_maps) {
  if (m_r.cols() != size()) m_r.setZero(3, size());
  for (Index k = 0; k < size(); ++k) m_r.col(k) = arm_maps[m_body[k]] * m_r0[k];
  m_angular = angular_maps;
}

void RigidBindings::clamp_positions(Vectors3& x, const Vectors3& body_x) const {
  for (Index k = 0; k < size(); ++k) x.col(m_particle[k]) = body_x.col(m_body[k]) + m_r.col(k);
}

void RigidBindings::clamp_velocities(Vectors3& v, const Vectors3& body_v, const Vectors3& body_w) const {
  const bool mapped = !m_angular.empty();
  for (Index k = 0; k < size(); ++k) {
    const Index b = m_body[k];
    const Vec3 w = mapped ? Vec3(angular(b) * body_w.col(b)) : Vec3(body_w.col(b));
    v.col(m_particle[k]) = body_v.col(b) + w.cross(Vec3(m_r.col(k)));
  }
}

void RigidBindings::clamp_velocities(Vectors3& v, const Vectors6& twist) const {
  const bool mapped = !m_angular.empty();
  for (Index k = 0; k < size(); ++k) {
    const Index b = m_body[k];
    const auto t = twist.col(b);
    const Vec3 w = mapped ? Vec3(angular(b) * t.tail<3>()) : Vec3(t.tail<3>());
    v.col(m_particle[k]) = t.head<3>() + w.cross(Vec3(m_r.col(k)));
  }
}

void RigidBindings::distribute(Vectors3& f, Vectors6& wrench) const {
  const bool mapped = !m_angular.empty();
  for (Index k = 0; k < size(); ++k) {
    const Index b = m_body[k];
    const Vec3 fe = f.col(m_particle[k]);
    const Vec3 torque = Vec3(m_r.col(k)).cross(fe);
    auto w = wrench.col(b);
    w.head<3>() += fe;
    w.tail<3>() += mapped ? Vec3(angular(b).transpose() * torque) : torque;
    f.col(m_particle[k]).setZero();
  }
}

// The points' own masses went into their bodies (absorb_masses) or are dropped.
void RigidBindings::distribute_masses(VectorXd& mass) const {
  for (Index k = 0; k < size(); ++k) mass[m_particle[k]] = 0.0;
}

// W^T B W with W = [I  P], P = r*^T A (A = I outside a step's solves): the bound point's block seen by
// the body's twist.
void RigidBindings::add_preconditioner_blocks(DiagonalBlocks& blocks, std::vector<Mat6>& body_blocks) const {
  const bool mapped = !m_angular.empty();
  for (Index k = 0; k < size(); ++k) {
    const Mat3 d = Eigen::Map<const Mat3>(blocks.col(m_particle[k]).data());
    const Mat3 rs = cross_matrix(offset_world(k));
    const Mat3 P = mapped ? Mat3(rs.transpose() * angular(m_body[k])) : Mat3(rs.transpose());
    Mat6& block = body_blocks[m_body[k]];
    block.topLeftCorner<3, 3>() += d;
    block.topRightCorner<3, 3>() += d * P;
    block.bottomLeftCorner<3, 3>() += P.transpose() * d;
    block.bottomRightCorner<3, 3>() += P.transpose() * d * P;
  }
}

double RigidBindings::max_drift(const Vectors3& x, const RigidBodyParticles& bodies) const {
  double drift = 0.0;
  for (Index k = 0; k < size(); ++k) {
    const Index b = m_body[k];
    const Vec3 xe = bodies.x.col(b) + bodies.q[b] * m_r0[k];
    drift = std::max(drift, (xe - x.col(m_particle[k])).norm());
  }
  return drift;
}

Vec3 RigidBindings::point_velocity(Index k, const Vectors3&, const RigidBodyParticles& bodies) const {
  const Index b = m_body[k];
  return Vec3(bodies.v.col(b)) + Vec3(bodies.w.col(b)).cross(offset_world(k));
}

Vec3 RigidBindings::point_acceleration(Index k, const Particles&, const RigidBodyParticles& bodies, const Vectors3&,
                                       const Vectors6& wrench) const {
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return Vec3::Zero();
  const Vec3 alpha = bodies.world_inverse_inertia(b) * wrench.col(b).tail<3>();
  return wrench.col(b).head<3>() / bodies.mass[b] + alpha.cross(offset_world(k));
}

// The impulse matrix K's eigenvalues do not depend on the orientation (K rotates with the body), so
// its largest eigenvalue, the smallest effective mass, is a constant of the binding.
double RigidBindings::inverse_effective_mass(Index k, const VectorXd&, const RigidBodyParticles& bodies) const {
  const Mat3 K = bodies.impulse_matrix(m_body[k], offset_world(k));
  return Eigen::SelfAdjointEigenSolver<Mat3>(K).eigenvalues().maxCoeff();
}

double RigidBindings::effective_mass_along(Index k, const Vec3& n, double, const RigidBodyParticles& bodies) const {
  const Vec3 r = bodies.q[m_body[k]] * m_r0[k];
  const double inverse = n.dot(bodies.impulse_matrix(m_body[k], r) * n);
  return inverse > 0.0 ? 1.0 / inverse : kInfinity;
}

void RigidBindings::apply_impulse(Index k, const Vec3& j, Particles&, RigidBodyParticles& bodies) const {
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return;
  const Vec3 r = bodies.q[b] * m_r0[k];
  bodies.v.col(b) += j / bodies.mass[b];
  bodies.w.col(b) += bodies.world_inverse_inertia(b) * r.cross(j);
}

// The drift as the impulse m_e dv (and the matching displacement) at the point, with m_e the effective
// mass along the drift, so that the point moves by exactly the drift to first order; the world offsets
// of every frame point are refreshed for the bindings that follow.
void RigidBindings::push_drift(Index k, const Vec3& dx, const Vec3& dv, double, Particles&, RigidBodyParticles& bodies,
                               Vectors3& L_n) {
  const Index b = m_body[k];
  if (bodies.kinematic[b]) return;
  const Vec3 offset = offset_world(k);
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
      L_n.col(b) += offset.cross(j);
    }
  };
  apply(dv, false);
  apply(dx, true);
  update_offsets(bodies);
}

}  // namespace sinew
