#include "sinew/soft_bindings.hpp"

namespace sinew {

bool SoftBindings::has_synchronized() const {
  for (SoftCoupling c : coupling)
    if (c == SoftCoupling::synchronized) return true;
  return false;
}

void SoftBindings::synchronize(Particles& p, bool positions, bool velocities) const {
  for (Index k = 0; k < size(); ++k) {
    if (coupling[k] != SoftCoupling::synchronized) continue;
    if (positions) p.x.col(particle[k]) = p.x.col(target[k]);
    if (velocities) p.v.col(particle[k]) = p.v.col(target[k]);
  }
}

void SoftBindings::synchronize(Vectors3& y) const {
  for (Index k = 0; k < size(); ++k)
    if (coupling[k] == SoftCoupling::synchronized) y.col(particle[k]) = y.col(target[k]);
}

void SoftBindings::gather_synchronized(Vectors3& f) const {
  for (Index k = 0; k < size(); ++k) {
    if (coupling[k] != SoftCoupling::synchronized) continue;
    f.col(target[k]) += f.col(particle[k]);
    f.col(particle[k]).setZero();
  }
}

void SoftBindings::gather_synchronized(Eigen::Matrix<double, 9, Eigen::Dynamic>& blocks) const {
  for (Index k = 0; k < size(); ++k)
    if (coupling[k] == SoftCoupling::synchronized) {
      blocks.col(target[k]) += blocks.col(particle[k]);
      blocks.col(particle[k]).setZero();
    }
}

// Parent accelerations a = M^-1 F (zero for kinematic parents, 1/inf = 0), read at the target through
// its binding (HardBindings::point_acceleration).
Vec3 SoftBindings::map_forces(const Particles& p, const RigidBodyParticles& bodies, const HardBindings& hard,
                              Vectors3& f, const Vectors6& wrench) const {
  Vec3 mapped_total = Vec3::Zero();
  for (Index k = 0; k < size(); ++k) {
    if (coupling[k] != SoftCoupling::spring) continue;
    const Vec3 a = hard.point_acceleration(target[k], p, bodies, f, wrench);
    const Vec3 f_mapped = p.mass[particle[k]] * a;
    f.col(particle[k]) += f_mapped;
    mapped_total += f_mapped;
  }
  return mapped_total;
}

// Section 3.1: drift dx = x_s - x_e, dv = v_s - v_e goes to the target's parents through its binding
// (HardBindings::push_drift), or directly to a free target.
void SoftBindings::push_drift(Particles& p, RigidBodyParticles& bodies, HardBindings& hard,
                              const VectorXd& effective_mass, Vectors3& L_n) const {
  for (Index k = 0; k < size(); ++k) {
    if (coupling[k] != SoftCoupling::synchronized) continue;
    const Index sp = particle[k], t = target[k];
    const Vec3 dx = p.x.col(sp) - p.x.col(t);
    const Vec3 dv = p.v.col(sp) - p.v.col(t);
    if (dx.isZero(0.0) && dv.isZero(0.0)) continue;
    hard.push_drift(t, dx, dv, p, bodies, effective_mass, L_n);
  }
}

}  // namespace sinew
