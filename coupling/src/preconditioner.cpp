#include "preconditioner.hpp"

#include "sinew/parallel.hpp"

namespace sinew {

void Preconditioner::reset(const Unknowns& unknowns) {
  m_unknowns = &unknowns;
  const Index n = unknowns.n;
  m_body_preconditioner.assign(static_cast<std::size_t>(unknowns.r), Mat6::Zero());
  m_diag.setZero(n);
  m_diag_blocks.setZero(9, n);
  m_inverse_blocks.setZero(9, n);
  m_multigrid.reset();
  m_use_multigrid = false;
}

// Block Jacobi: each particle's 3x3 diagonal block m I + h (D_ii + beta_el K+_ii + springs) (forces
// without blocks contribute a multiple of the identity from their scalar diagonal), hard-bound rows'
// blocks passed to their parents through W^T W (a 6x6 block per rigid body). The 3x3 blocks matter
// for cloth: an edge spring is stiff along its direction only, so a node's block is stiff in the
// cloth's plane and soft across it, which a scalar diagonal cannot express.
void Preconditioner::build(const StepModel& model, const std::vector<Mat3>& body_I, const SolveCoefficients& k,
                           bool jacobi) {
  const Unknowns& u = *m_unknowns;
  const double h = k.h;
  m_diag_blocks.setZero();
  if (jacobi) {
    m_diag.setZero();
    for (const auto& f : model.forces)
      if (const ImplicitBlocks* blocks = f->implicit_blocks()) {
        const double b = implicit_b(*f, k.beta_el);
        if (!blocks->add_diagonal_blocks(b, m_diag_blocks)) blocks->add_diagonal(b, m_diag);
      }
    m_diag_blocks *= h;
    m_diag *= h;
    model.springs.add_diagonal(h, h * k.beta, m_diag);
    for (Index i = 0; i < u.n; ++i) {
      m_diag_blocks(0, i) += m_diag[i];
      m_diag_blocks(4, i) += m_diag[i];
      m_diag_blocks(8, i) += m_diag[i];
    }
    model.soft.gather_synchronized(m_diag_blocks);
  }
  m_body_mass_inverse.resize(static_cast<std::size_t>(u.r));
  m_dynamic_mass = u.dof_mass.sum();
  for (Index b = 0; b < u.r; ++b) {
    Mat6& block = m_body_preconditioner[b];
    block.setZero();
    block.topLeftCorner<3, 3>() = model.bodies.mass[b] * Mat3::Identity();
    block.bottomRightCorner<3, 3>() = body_I[b];
    m_body_mass_inverse[b] = u.dynamic_body[b] ? Mat6(block.inverse()) : Mat6::Zero();
    if (u.dynamic_body[b]) m_dynamic_mass += model.bodies.mass[b];
  }
  if (jacobi) model.hard.add_preconditioner_blocks(m_diag_blocks, m_body_preconditioner);
  for (Index i = 0; i < u.n; ++i) {
    Eigen::Map<Mat3> inverse(m_inverse_blocks.col(i).data());
    if (u.dynamic_mask[i] > 0.0) {
      Mat3 block = Eigen::Map<const Mat3>(m_diag_blocks.col(i).data());
      block.diagonal().array() += u.dof_mass[i];
      inverse = block.inverse();
    } else {
      inverse.setZero();
    }
  }
  for (Index b = 0; b < u.r; ++b)
    m_body_preconditioner[b] = u.dynamic_body[b] ? Mat6(m_body_preconditioner[b].inverse()) : Mat6::Zero();
  m_use_multigrid = jacobi && model.settings.multigrid;
  if (m_use_multigrid) build_multigrid(model, h, k.beta_el);
}

// The coarse operators: the full diagonal blocks (mass included) and every force's pair blocks of
// S = M - h F, restricted to the particle unknowns.
void Preconditioner::build_multigrid(const StepModel& model, double h, double beta_el) {
  const Unknowns& u = *m_unknowns;
  for (Index i = 0; i < u.n; ++i) {
    auto block = m_diag_blocks.col(i);
    block[0] += u.dof_mass[i];
    block[4] += u.dof_mass[i];
    block[8] += u.dof_mass[i];
  }
  m_multigrid.begin(u.dynamic_mask, m_diag_blocks, -h);
  // Level 1 gathers the forces' blocks in parallel once the hierarchy exists; the first update
  // (which records the pairs) and forces that offer no single blocks go through the visits.
  m_pair_sources.clear();
  std::size_t counted = 0;
  for (const auto& f : model.forces)
    if (const ImplicitBlocks* blocks = f->implicit_blocks(); blocks && blocks->pair_block_count() > 0) {
      m_pair_sources.push_back({blocks, implicit_b(*f, beta_el)});
      counted += static_cast<std::size_t>(blocks->pair_block_count());
    }
  m_multigrid.reserve(counted);
  auto pass = [&] {
    if (!m_multigrid.gather(m_pair_sources))
      for (const auto& f : model.forces)
        if (const ImplicitBlocks* blocks = f->implicit_blocks())
          blocks->visit_pair_blocks(implicit_b(*f, beta_el), m_multigrid);
    m_multigrid.end();
  };
  pass();
  if (m_multigrid.needs_blocks_again()) {  // the first update: the pairs chose level 1, now its blocks
    m_multigrid.begin(u.dynamic_mask, m_diag_blocks, -h);
    pass();
  }
}

// One pass in a fixed order: the same bits for any thread count (a pass over r, against the CG
// iteration's products and reductions).
double Preconditioner::mass_norm_squared(const GeneralizedVector& r) const {
  const Unknowns& u = *m_unknowns;
  double sum = 0.0;
  for (Index i = 0; i < u.n; ++i)
    if (u.dof_mass[i] > 0.0) sum += r.particles.col(i).squaredNorm() / u.dof_mass[i];
  for (Index b = 0; b < u.r; ++b) sum += r.rigid.col(b).dot(m_body_mass_inverse[b] * r.rigid.col(b));
  return m_dynamic_mass > 0.0 ? sum / m_dynamic_mass : 0.0;
}

void Preconditioner::net_translation(const GeneralizedVector& r, GeneralizedVector& t) const {
  const Unknowns& u = *m_unknowns;
  Vec3 sum = Vec3::Zero();
  for (Index i = 0; i < u.n; ++i)
    if (u.dof_mass[i] > 0.0) sum += r.particles.col(i);
  for (Index b = 0; b < u.r; ++b)
    if (u.dynamic_body[b]) sum += r.rigid.col(b).head<3>();
  const Vec3 c = m_dynamic_mass > 0.0 ? Vec3(sum / m_dynamic_mass) : Vec3::Zero();
  for (Index i = 0; i < u.n; ++i) t.particles.col(i) = u.dof_mass[i] > 0.0 ? c : Vec3::Zero();
  for (Index b = 0; b < u.r; ++b) {
    t.rigid.col(b).setZero();
    if (u.dynamic_body[b]) t.rigid.col(b).head<3>() = c;
  }
}

// Rows without unknowns have zero inverse blocks, so z is zero there without projecting.
void Preconditioner::apply(const GeneralizedVector& r, GeneralizedVector& z, const Constraints& constraints) {
  const Index n = m_unknowns->n;
  if (m_use_multigrid) {
    m_multigrid.apply(r.particles, z.particles, m_inverse_blocks);
  } else {
    const double* pb = m_inverse_blocks.data();
    const double* pr = r.particles.data();
    double* pz = z.particles.data();
    parallel::for_light_ranges(n, [&](Index i0, Index i1) {
      for (Index i = i0; i < i1; ++i) {
        const double* B = pb + 9 * i;
        const double r0 = pr[3 * i], r1 = pr[3 * i + 1], r2 = pr[3 * i + 2];
        pz[3 * i] = B[0] * r0 + B[3] * r1 + B[6] * r2;
        pz[3 * i + 1] = B[1] * r0 + B[4] * r1 + B[7] * r2;
        pz[3 * i + 2] = B[2] * r0 + B[5] * r1 + B[8] * r2;
      }
    });
  }
  for (Index b = 0; b < m_unknowns->r; ++b) z.rigid.col(b) = m_body_preconditioner[b] * r.rigid.col(b);
  constraints.project_constraints(z);
}

}  // namespace sinew
