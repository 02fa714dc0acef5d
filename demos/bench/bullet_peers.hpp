// Bullet 3.24's own two ways of hanging cloth from rigid bodies, running the benchmark curtain: the
// peers sinew is measured against.
//
// Both build the same scene as sinew: the mesh of add_cloth_grid (see curtain_bench.hpp; for odd n
// Bullet's patch can only give the mirror-image diagonals), the cloth mass lumped by triangle area,
// the rod and rings of RodAndRings, gravity along -y, every node and ring starting with the spec's
// velocity, one anchor per bound node at its pivot. Neither has a dihedral bending model.
#pragma once

#include "curtain_bench.hpp"

#include <memory>

namespace sinew::bench {

/// The classic coupling: btSoftRigidDynamicsWorld, position-based cloth (btSoftBody links solved by
/// Gauss-Seidel projection) and btSoftBody::appendAnchor to the rings (a position-level constraint
/// whose impulse also goes to the ring, one step late: the ring has already been integrated).
struct ClassicSettings {
  /// Position-solver sweeps per step (m_cfg.piterations). Bullet's default, 1, leaves centimetres of
  /// anchor drift and links stretched by more than 100 % at 40 x 40; 10 gives the classic world a fair
  /// chance.
  int piterations = 10;
  /// Anchor hardness kAHR in (0, 1]: the fraction of an anchor's position error each sweep removes.
  /// Bullet's default is 0.7; 1 projects the node fully onto its pivot every sweep (still stable here),
  /// so sinew is compared with the classic anchor at its most accurate.
  double anchor_hardness = 1.0;
  /// Link stiffness kLST in (0, 1]: the fraction of a link's length error each sweep removes. It is
  /// dimensionless and its effect depends on piterations and the step, so it cannot be derived from
  /// stretch_stiffness [N/m]; 1 (nearly inextensible) is closest to a 200 N/m cloth, whose strain under
  /// its own weight stays at a few percent.
  double link_stiffness = 1.0;
  /// Damping kDP in [0, 1): every node's velocity is (x - q)/h (1 - kDP) after the sweeps, a drag on
  /// absolute velocity. The spec's damping acts only on the rate of stretch along each edge and leaves
  /// the swing and the slide along the rod alone; any kDP > 0 damps both and removes momentum along x.
  /// The projection itself already dissipates the stretching modes, so 0 is the closest match.
  double damping = 0.0;
};

/// The deformable coupling: btDeformableMultiBodyDynamicsWorld with btDeformableBodySolver,
/// btDeformableMassSpringForce (k = stretch_stiffness per edge, damping = stretch_damping along each
/// edge, exactly the spec's model) and btDeformableGravityForce, and appendDeformableAnchor to the rings
/// (velocity-level impulses inside the rigid PGS; the node is then written onto its pivot at the end of
/// every step).
struct DeformableSettings {
  /// One linearised backward-Euler step (Newton) solved by conjugate gradients; false is the explicit
  /// path of Bullet's cloth-anchor demos, stable only for k below about m_node / h^2 (18 N/m at 40 x 40
  /// and h = 1/240 s).
  bool implicit = true;
  /// Baraff-Witkin projection of the anchored directions in the CG solve. Bullet 3.24 needs it with
  /// implicit: without it the KKT preconditioner is never built on the implicit path, the conjugate
  /// residual solve returns dv = 0 and every force (gravity included) is silently dropped.
  bool use_projection = true;
  /// Backtracking line search on the Newton step (setLineSearch).
  bool line_search = false;
  /// Newton iterations per step (protected m_maxNewtonIterations; Bullet's default 1).
  int newton_iterations = 1;
  /// Conjugate-gradient iterations per Newton step (Bullet's default 300; the explicit path's conjugate
  /// residual solver keeps its own).
  int cg_max_iterations = 300;
  /// CG stops once r.z <= tolerance * min(1, r0.z0) (preconditioned residual; Bullet's default is
  /// SIMD_EPSILON, DBL_EPSILON in this double build, so in practice it runs to cg_max_iterations).
  double cg_tolerance = 2.220446049250313e-16;
  /// Sweeps of the rigid PGS, which also carries the anchor impulses (m_solverInfo.m_numIterations).
  int solver_iterations = 10;
};

/// "bullet-classic": the curtain in Bullet's classic soft-body world.
std::unique_ptr<CurtainRun> make_classic_curtain(const CurtainSpec& spec, const ClassicSettings& settings = {});

/// "bullet-deformable": the curtain in Bullet's deformable world. Its attachment() reports, besides the
/// bound-node error after Bullet overwrites anchored nodes (0 by construction), the error just before
/// that overwrite, read at the end of btDeformableBodySolver::applyTransforms in the last step.
std::unique_ptr<CurtainRun> make_deformable_curtain(const CurtainSpec& spec, const DeformableSettings& settings = {});

}  // namespace sinew::bench
