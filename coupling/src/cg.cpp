#include "cg.hpp"

#include <cmath>
#include <string>
#include <utility>
#include <vector>

namespace sinew {

/// Reductions split the particle block into fixed blocks of 3 kReductionBlock doubles (aligned, as
/// every Eigen allocation is), whatever the thread count; each block's sum is Eigen's vectorised
/// dot, whose association depends only on the block's length and alignment, and the blocks are
/// added in order: the same bits for any thread count.
double dot(const GeneralizedVector& a, const GeneralizedVector& b) {
  const Index n = a.particles.size();
  const double* pa = a.particles.data();
  const double* pb = b.particles.data();
  constexpr Index block = 3 * parallel::kReductionBlock;
  const Index blocks = (n + block - 1) / block;
  thread_local std::vector<double> partial;
  partial.assign(static_cast<std::size_t>(blocks), 0.0);
  double* out = partial.data();
  parallel::for_ranges_when(n >= 3 * parallel::kMinParallelLightItems, blocks, [&](Index b0, Index b1) {
    for (Index k = b0; k < b1; ++k) {
      const Index begin = k * block, length = std::min(n, begin + block) - begin;
      out[k] = ConstFlatMap(pa + begin, length).dot(ConstFlatMap(pb + begin, length));
    }
  });
  double total = 0.0;
  for (Index k = 0; k < blocks; ++k) total += out[k];
  return total + a.rigid.cwiseProduct(b.rigid).sum();
}

void axpy(double alpha, const GeneralizedVector& x, GeneralizedVector& y) {
  const double* px = x.particles.data();
  double* py = y.particles.data();
  for_flat_ranges(x.particles.size(),
                  [&](Index i0, Index i1) { FlatMap(py + i0, i1 - i0) += alpha * ConstFlatMap(px + i0, i1 - i0); });
  y.rigid += alpha * x.rigid;
}

void update_direction(const GeneralizedVector& z, double beta, GeneralizedVector& p) {
  const double* pz = z.particles.data();
  double* pp = p.particles.data();
  for_flat_ranges(z.particles.size(), [&](Index i0, Index i1) {
    FlatMap(pp + i0, i1 - i0) = ConstFlatMap(pz + i0, i1 - i0) + beta * FlatMap(pp + i0, i1 - i0);
  });
  p.rigid = z.rigid + beta * p.rigid;
}

double max_abs(const GeneralizedVector& v) {
  const Index n = v.particles.size();
  const double* pv = v.particles.data();
  const int parts = n >= 3 * parallel::kMinParallelLightItems ? std::max(1, thread_count()) : 1;
  thread_local std::vector<double> part;
  part.assign(static_cast<std::size_t>(parts), 0.0);
  double* out = part.data();
  parallel::for_ranges_when(parts > 1, parts, [&](Index p0, Index p1) {
    for (Index p = p0; p < p1; ++p) {
      const Index i0 = n * p / parts, i1 = n * (p + 1) / parts;
      out[p] = i1 > i0 ? Eigen::Map<const VectorXd>(pv + i0, i1 - i0).cwiseAbs().maxCoeff() : 0.0;
    }
  });
  double m = v.rigid.size() > 0 ? v.rigid.cwiseAbs().maxCoeff() : 0.0;
  for (double x : part) m = std::max(m, x);
  return m;
}

// Where v first holds a non-finite value, as "<prefix>particle i)" or "<prefix>rigid body b)"; empty
// when it is finite: what a failed solve names.
static std::string where_non_finite(const GeneralizedVector& v, const char* prefix) {
  for (Index i = 0; i < v.particles.cols(); ++i)
    if (!v.particles.col(i).allFinite()) return std::string(prefix) + "particle " + std::to_string(i) + ")";
  for (Index b = 0; b < v.rigid.cols(); ++b)
    if (!v.rigid.col(b).allFinite()) return std::string(prefix) + "rigid body " + std::to_string(b) + ")";
  return {};
}

void ConjugateGradients::resize(Index particle_count, Index rigid_count) {
  for (GeneralizedVector* g : {&m_r, &m_z, &m_p, &m_q}) g->resize(particle_count, rigid_count);
}

// Preconditioned conjugate gradients on the symmetric positive definite S = M + h W^T(D + beta K)W
// (symmetric in the plain inner product; the paper's mass inner product form is the same iteration).
// Constrained directions (kinematic rows and bodies, collision constraints, joint rows) keep their
// initial values.
SolveResult ConjugateGradients::solve(LinearOperator& op, const GeneralizedVector& c, GeneralizedVector& y,
                                      double tolerance, double rms_tolerance, int max_iterations, bool iterate,
                                      GeneralizedVector* alternative, Alternative rule, long step) {
  SolveResult result;
  op.impose(y);
  if (alternative) op.impose(*alternative);
  op.apply(y, m_q);
  m_r.particles = c.particles - m_q.particles;
  m_r.rigid = c.rigid - m_q.rigid;
  op.project(m_r);
  op.precondition(m_r, m_z);
  if (!iterate) {
    // No implicit term: S is M (diagonal for particles, diag(m I, I) per body), solved exactly.
    y.particles += m_z.particles;
    y.rigid += m_z.rigid;
    return result;
  }
  if (c.particles.cols() == 0 && c.rigid.cols() == 0) return result;
  result.residual = max_abs(m_z);
  // A non-finite residual compares false with the tolerance and would pass for converged.
  if (!std::isfinite(result.residual))
    fail("Newmark step ", step, ": the linear solve's residual is not finite",
         where_non_finite(c, " (the right-hand side, the forces and momentum, of "),
         where_non_finite(y, " (the initial guess, of "), where_non_finite(m_q, " (the operator's product, of "));
  if (alternative) {
    // The alternative's preconditioned residual, in m_p (r) and m_q (z). Alternative::if_exact (the
    // first step's M^-1 c): taken only when it is exact to well below the tolerance (1e-3 of it: no
    // iteration needed, and no answer merely at the tolerance's edge) and beats the first guess;
    // preferring it whenever its residual was smaller gained no iterations on the cloth there.
    // Alternative::if_smaller (step 1's trials): the first guess is kept when it already meets the
    // tolerance, the alternative taken when it does, else the one with the smaller r . z.
    op.apply(*alternative, m_q);
    m_p.particles = c.particles - m_q.particles;
    m_p.rigid = c.rigid - m_q.rigid;
    op.project(m_p);
    op.precondition(m_p, m_q);
    const double alternative_residual = max_abs(m_q);
    const bool take =
        rule == Alternative::if_smaller
            ? result.residual > tolerance && (alternative_residual <= tolerance || dot(m_p, m_q) < dot(m_r, m_z))
            : alternative_residual <= 1e-3 * tolerance && alternative_residual < result.residual;
    if (take) {
      y.particles = alternative->particles;
      y.rigid = alternative->rigid;
      std::swap(m_r, m_p);
      std::swap(m_z, m_q);
      result.residual = alternative_residual;
      result.took_alternative = true;
    }
  }
  m_p.particles = m_z.particles;
  m_p.rigid = m_z.rigid;
  double rz = dot(m_r, m_z);
  // The RMS bound holds in the mass norm, where a stiff pair's common motion (which the preconditioner's
  // blocks, stiff in it, understate in z) counts at its true velocity.
  const auto rms_met = [&] {
    return rms_tolerance > 0.0 && op.mass_norm_squared(m_r) <= rms_tolerance * rms_tolerance;
  };
  bool stopped_on_rms = false;
  while (result.residual > tolerance) {
    if (rms_met()) {
      stopped_on_rms = true;
      break;
    }
    if (result.iterations >= max_iterations) {
      result.converged = false;
      break;
    }
    op.apply(m_p, m_q);
    const double pq = dot(m_p, m_q);
    if (!(pq > 0.0)) {
      if (!std::isfinite(pq))
        fail("Newmark step ", step, ": conjugate gradients produced a non-finite value",
             where_non_finite(c, " (the right-hand side, the forces and momentum, of "),
             where_non_finite(y, " (the solution so far, of "), where_non_finite(m_q, " (the operator's product, of "));
      break;  // the remaining residual lies in S's null space: nothing more to gain
    }
    const double alpha = rz / pq;
    axpy(alpha, m_p, y);
    axpy(-alpha, m_q, m_r);
    op.precondition(m_r, m_z);
    const double rz_new = dot(m_r, m_z);
    const double beta_cg = rz_new / rz;
    rz = rz_new;
    update_direction(m_z, beta_cg, m_p);
    ++result.iterations;
    result.residual = max_abs(m_z);
    if (!std::isfinite(result.residual))
      fail("Newmark step ", step, ": conjugate gradients produced a non-finite value",
           where_non_finite(m_z, " (the residual, of "));
  }
  // Stopped on the RMS bound, the residual still carries net momentum sum(r) (the system's minus the
  // answer's, for translation-invariant forces): a uniform translation of sum(r) / M gives it back,
  // so a loose solve still moves the centre of mass exactly. It is no larger than the RMS bound
  // (Cauchy-Schwarz: |sum r| <= sqrt(r^T M^-1 r) sqrt(M)).
  if (stopped_on_rms) {
    op.net_translation(m_r, m_q);
    op.project(m_q);
    axpy(1.0, m_q, y);
  }
  return result;
}

}  // namespace sinew
