// The implicit system of the Newmark step's velocity solves (eq. 8, internal to sinew::Newmark):
//
//   S u = M u - h W^T (D + beta K_springs + beta_el K+) W u
//
// on the unknowns (free and soft-spring particles, dynamic rigid twists), applied matrix-free: W by
// clamping bound rows from the trial velocities (hard bindings are eliminated, not projected),
// synchronized soft rows copied from their targets, the forces' implicit products, W^T back to the
// parents. Rows without unknowns come out zero; constrained directions are projected.
#pragma once

#include "cg.hpp"
#include "constraints.hpp"
#include "preconditioner.hpp"
#include "step_model.hpp"

namespace sinew {

class ImplicitSystem final : public LinearOperator {
 public:
  ImplicitSystem(const Unknowns& unknowns, Constraints& constraints, Preconditioner& preconditioner)
      : m_unknowns(unknowns), m_constraints(constraints), m_preconditioner(preconditioner) {}
  void reset();
  /// The model, coefficients and world inertias (body_I) the products use until the next call.
  void set(const StepModel& model, const SolveCoefficients& k, const std::vector<Mat3>& body_I) {
    m_model = &model;
    m_k = k;
    m_body_I = &body_I;
  }

  void apply(const GeneralizedVector& u, GeneralizedVector& out) override { product(u, out, true); }
  /// S u with the constrained components kept: S u - c is then the constraints' reaction.
  void apply_unprojected(const GeneralizedVector& u, GeneralizedVector& out) { product(u, out, false); }
  /// out = -h W^T (D + beta K + beta_el K+) o: the implicit forces' impulse from the velocities `offset`
  /// on the bound rows alone (zero on every other row and twist). The step's points on rigid frames
  /// move with W u + o (Newmark::set_step_maps), so S u = c + out.
  void apply_bound_offset(const Vectors3& offset, GeneralizedVector& out);
  /// f = -(D + beta K + beta_el K+) v on every row, for the velocities v = W u + offset (before W^T):
  /// the implicit forces' part of what each point feels at u.
  void implicit_forces(const GeneralizedVector& u, const Vectors3& offset, Vectors3& f);
  void precondition(const GeneralizedVector& r, GeneralizedVector& z) override {
    m_preconditioner.apply(r, z, m_constraints);
  }
  double mass_norm_squared(const GeneralizedVector& r) const override { return m_preconditioner.mass_norm_squared(r); }
  void net_translation(const GeneralizedVector& r, GeneralizedVector& t) const override {
    m_preconditioner.net_translation(r, t);
  }
  void project(GeneralizedVector& u) const override { m_constraints.project(u); }
  void impose(GeneralizedVector& u) const override { m_constraints.impose_joints(u); }

 private:
  void product(const GeneralizedVector& u, GeneralizedVector& out, bool project);
  const Unknowns& m_unknowns;
  Constraints& m_constraints;
  Preconditioner& m_preconditioner;
  const StepModel* m_model = nullptr;
  SolveCoefficients m_k;
  const std::vector<Mat3>* m_body_I = nullptr;
  Vectors3 m_tmp_v, m_apply_f;
  Vectors6 m_apply_wrench;
  VectorXd m_h_mask3;        // h on the dynamic rows' coordinates (3N), 0 elsewhere
  double m_h_mask_h = -1.0;  // the h m_h_mask3 holds
};

}  // namespace sinew
