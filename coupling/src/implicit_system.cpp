#include "implicit_system.hpp"

namespace sinew {

void ImplicitSystem::reset() {
  m_tmp_v.setZero(3, m_unknowns.n);
  m_apply_f.setZero(3, m_unknowns.n);
  m_apply_wrench.setZero(6, m_unknowns.r);
  m_h_mask3.setZero(3 * m_unknowns.n);
  m_h_mask_h = -1.0;
}

void ImplicitSystem::product(const GeneralizedVector& u, GeneralizedVector& out, bool project) {
  const StepModel& s = *m_model;
  const Index n = m_unknowns.n;
  const double h = m_k.h;
  parallel::for_light_ranges(n, [&](Index i0, Index i1) {
    m_tmp_v.middleCols(i0, i1 - i0) = u.particles.middleCols(i0, i1 - i0);
    m_apply_f.middleCols(i0, i1 - i0).setZero();
  });
  s.hard.clamp_velocities(m_tmp_v, u.rigid);
  s.soft.synchronize(m_tmp_v);
  m_apply_wrench.setZero();
  for (const auto& f : s.forces) f->add_implicit_products(m_tmp_v, implicit_b(*f, m_k.beta_el), m_apply_f);
  s.springs.add_linear_forces(m_tmp_v, 1.0, m_k.beta, m_apply_f);
  s.soft.gather_synchronized(m_apply_f);
  s.hard.distribute(m_apply_f, m_apply_wrench);

  // Rows without unknowns have zero mass and mask, so they come out zero here (the projection below
  // then only has bodies and collision constraints to handle on the particle block).
  if (m_h_mask_h != h) {
    for (Index i = 0; i < n; ++i) m_h_mask3.segment<3>(3 * i).setConstant(h * m_unknowns.dynamic_mask[i]);
    m_h_mask_h = h;
  }
  {
    const double* pm = m_unknowns.dof_mass3.data();
    const double* ph = m_h_mask3.data();
    const double* pu = u.particles.data();
    const double* pf = m_apply_f.data();
    double* po = out.particles.data();
    for_flat_ranges(3 * n, [&](Index i0, Index i1) {
      const Index l = i1 - i0;
      FlatMap(po + i0, l) = ConstFlatMap(pm + i0, l).cwiseProduct(ConstFlatMap(pu + i0, l)) -
                            ConstFlatMap(ph + i0, l).cwiseProduct(ConstFlatMap(pf + i0, l));
    });
  }
  const std::vector<Mat3>& body_I = *m_body_I;
  for (Index b = 0; b < m_unknowns.r; ++b) {
    if (!m_unknowns.dynamic_body[b]) {
      out.rigid.col(b).setZero();
      continue;
    }
    out.rigid.col(b).head<3>() = s.bodies.mass[b] * u.rigid.col(b).head<3>() - h * m_apply_wrench.col(b).head<3>();
    out.rigid.col(b).tail<3>() = body_I[b] * u.rigid.col(b).tail<3>() - h * m_apply_wrench.col(b).tail<3>();
  }
  if (project) m_constraints.project_constraints(out);
}

void ImplicitSystem::implicit_forces(const GeneralizedVector& u, const Vectors3& offset, Vectors3& f) {
  const StepModel& s = *m_model;
  m_tmp_v = u.particles;
  s.hard.clamp_velocities(m_tmp_v, u.rigid);
  m_tmp_v += offset;
  s.soft.synchronize(m_tmp_v);
  f.setZero();
  for (const auto& force : s.forces) force->add_implicit_products(m_tmp_v, implicit_b(*force, m_k.beta_el), f);
  s.springs.add_linear_forces(m_tmp_v, 1.0, m_k.beta, f);
}

void ImplicitSystem::apply_bound_offset(const Vectors3& offset, GeneralizedVector& out) {
  const StepModel& s = *m_model;
  const double h = m_k.h;
  m_tmp_v = offset;
  m_apply_f.setZero();
  m_apply_wrench.setZero();
  s.soft.synchronize(m_tmp_v);
  for (const auto& f : s.forces) f->add_implicit_products(m_tmp_v, implicit_b(*f, m_k.beta_el), m_apply_f);
  s.springs.add_linear_forces(m_tmp_v, 1.0, m_k.beta, m_apply_f);
  s.soft.gather_synchronized(m_apply_f);
  s.hard.distribute(m_apply_f, m_apply_wrench);
  for (Index i = 0; i < m_unknowns.n; ++i) out.particles.col(i) = (h * m_unknowns.dynamic_mask[i]) * m_apply_f.col(i);
  for (Index b = 0; b < m_unknowns.r; ++b)
    out.rigid.col(b) = m_unknowns.dynamic_body[b] ? Vec6(h * m_apply_wrench.col(b)) : Vec6::Zero();
}

}  // namespace sinew
