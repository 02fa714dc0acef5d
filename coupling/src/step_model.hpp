// What the Newmark step sees of a sinew::System: its state and model by reference, built for each
// step (System::step), so that the step reads and writes the system through this view only.
#pragma once

#include "sinew/system.hpp"

#include <memory>
#include <span>
#include <vector>

namespace sinew {

struct StepModel {
  Particles& particles;
  RigidBodyParticles& bodies;
  HardBindings& hard;
  const SoftBindings& soft;
  const BindingSprings& springs;
  std::span<const std::unique_ptr<Force>> forces;
  const StepSettings& settings;
  const Vec3& gravity;
  std::vector<JointRow>& joint_rows;  ///< the step updates unilateral rows' gaps
  const VectorXd& effective_mass;     ///< per row, +inf for kinematic
  std::span<const std::unique_ptr<CollisionSource>> collision_sources;
  const CollisionGeometry& geometry;
  double time;  ///< t^n
};

/// The coefficients of one implicit solve, S = M - h W^T (D + beta K_springs + beta_el K+_elastic) W
/// (eq. 8 with h = dt/2): beta = h for the binding springs' stiffness when it is implicit, beta_el = h
/// for elastic forces with a definite differential under StepSettings::implicit_elasticity, else 0.
struct SolveCoefficients {
  double h = 0.0, beta = 0.0, beta_el = 0.0;
};

/// The unknowns' layout for one topology: which particle rows and rigid bodies have velocities the
/// solves find (dofs.hpp), and their masses.
struct Unknowns {
  Index n = 0, r = 0;
  VectorXd dof_mass;                       ///< mass of dynamic rows, 0 elsewhere
  VectorXd dynamic_mask;                   ///< 1 on dynamic rows, 0 elsewhere
  VectorXd dof_mass3;                      ///< dof_mass per coordinate (3N)
  std::vector<std::uint8_t> dynamic_body;  ///< 1 on dynamic bodies, 0 on kinematic ones

  void build(const Particles& p, const RigidBodyParticles& bodies) {
    n = p.size();
    r = bodies.size();
    dof_mass.setZero(n);
    dynamic_mask.setZero(n);
    for (Index i = 0; i < n; ++i) {
      if (!is_dynamic(p.kind[i])) continue;
      dof_mass[i] = p.mass[i];
      dynamic_mask[i] = 1.0;
    }
    dynamic_body.assign(static_cast<std::size_t>(r), 0);
    for (Index b = 0; b < r; ++b) dynamic_body[b] = bodies.kinematic[b] ? 0 : 1;
    dof_mass3.setZero(3 * n);
    for (Index i = 0; i < n; ++i) dof_mass3.segment<3>(3 * i).setConstant(dof_mass[i]);
  }
};

}  // namespace sinew
