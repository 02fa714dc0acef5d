// Preconditioned conjugate gradients on the Newmark step's implicit systems, and the vector work
// they do, parallel over fixed ranges (sinew/parallel.hpp: the same bits for any thread count).
#pragma once

#include "sinew/dofs.hpp"
#include "sinew/parallel.hpp"

#include <algorithm>

namespace sinew {

using FlatMap = Eigen::Map<VectorXd, Eigen::Aligned16>;
using ConstFlatMap = Eigen::Map<const VectorXd, Eigen::Aligned16>;

/// Runs body(i0, i1) over fixed ranges of a flat particle block of n doubles (3 per particle); the
/// ranges start at even offsets so that maps of them stay 16-byte aligned.
template <typename Body>
void for_flat_ranges(Index n, Body&& body) {
  const bool parallel = n >= 3 * parallel::kMinParallelLightItems;
  parallel::for_ranges_when(parallel, (n + 1) / 2, [&](Index p0, Index p1) { body(2 * p0, std::min(n, 2 * p1)); });
}

double dot(const GeneralizedVector& a, const GeneralizedVector& b);
/// y += alpha x.
void axpy(double alpha, const GeneralizedVector& x, GeneralizedVector& y);
/// p = z + beta p.
void update_direction(const GeneralizedVector& z, double beta, GeneralizedVector& p);
/// The largest |component| (order-independent, so any partition gives the same value).
double max_abs(const GeneralizedVector& v);

/// A symmetric positive definite system S y = c on the unknowns, with constrained directions.
class LinearOperator {
 public:
  /// out = S u (zero on rows without unknowns, projected).
  virtual void apply(const GeneralizedVector& u, GeneralizedVector& out) = 0;
  /// z = P^-1 r, projected.
  virtual void precondition(const GeneralizedVector& r, GeneralizedVector& z) = 0;
  /// r^T M^-1 r / M (Preconditioner::mass_norm_squared): its root bounds the RMS velocity error.
  virtual double mass_norm_squared(const GeneralizedVector& r) const = 0;
  /// The uniform translation that gives back r's net linear momentum (Preconditioner::net_translation).
  virtual void net_translation(const GeneralizedVector& r, GeneralizedVector& t) const = 0;
  /// Zeroes rows without unknowns and constrained directions.
  virtual void project(GeneralizedVector& u) const = 0;
  /// Sets the constrained directions to their prescribed values (joint rows' targets).
  virtual void impose(GeneralizedVector& u) const = 0;

 protected:
  ~LinearOperator() = default;
};

struct SolveResult {
  int iterations = 0;
  double residual = 0;
  bool converged = true;
  bool took_alternative = false;  ///< the solve started from its alternative guess
};

/// When a solve takes its alternative guess: only when that is exact to 1e-3 of the tolerance
/// (max-norm of the preconditioned residual, and better than the first), or, unless the first guess
/// already meets the tolerance, when the alternative does or its r . z (r^T P^-1 r, P the
/// preconditioner: the energy norm CG reduces, an estimate of the initial error's A-norm) is the
/// smaller. Chosen by the max-norm, the guess with the smaller peak sometimes needed more iterations
/// (30x30 multigrid cloth at 1/60 s, tol 1e-2: 536 against 401 over 40 solves).
enum class Alternative { if_exact, if_smaller };

class ConjugateGradients {
 public:
  void resize(Index particle_count, Index rigid_count);
  /// Solves S y = c to the max-norm tolerance on z = P^-1 r, or until the bound sqrt(r^T M^-1 r / M) on
  /// the RMS velocity error is at most rms_tolerance (0: never), y holding the initial guess; with
  /// `alternative`, a second guess taken instead by `rule`. Without `iterate` (no implicit term: S is
  /// the mass matrix, which the preconditioner inverts exactly) one preconditioned correction.
  /// Throws naming step `step` when an iteration turns non-finite.
  SolveResult solve(LinearOperator& op, const GeneralizedVector& c, GeneralizedVector& y, double tolerance,
                    double rms_tolerance, int max_iterations, bool iterate, GeneralizedVector* alternative,
                    Alternative rule, long step);

 private:
  GeneralizedVector m_r, m_z, m_p, m_q;
};

}  // namespace sinew
