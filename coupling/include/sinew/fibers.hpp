// Fibers embedded in a meshfree matrix (Liu et al. 2012, section 4.3, eq. 16-18): each structure
// particle is a massless particle hard-bound to the material particles within the support radius by
// Shepard weights phi_i = W(|X - X_i|) / sum_j W(|X - X_j|), fixed at rest (sinew's hard bindings:
// positions and velocities through W, the fiber forces back through W^T, eq. 17). Its rest position
// is the embedded one, sum_i phi_i X_i, not the drawn point (Shepard weights do not reproduce linear
// fields), so a fiber is unstressed at rest. A drawn point with no material particle within h is
// outside the material: it is dropped and its fiber split there; pieces of fewer than two points go.
//
// Volume fraction (eq. 18, corrected): the material particles that carry a fiber (any weight of a
// structure particle on them) keep 1 - lambda of their matrix stencil (MeshfreeCorotated::
// set_volume_fraction), and the fiber's EA and EI are the fiber material's times lambda, one lambda
// per fiber (scaling a fiber's shares per material particle would break Newton's third law); the
// composite is (1 - lambda) matrix + lambda fiber where fibers are and matrix elsewhere, each volume
// counted once.
#pragma once

#include "sinew/forces/elastic_rods.hpp"
#include "sinew/forces/meshfree_corotated.hpp"
#include "sinew/system.hpp"

#include <vector>

namespace sinew {

struct FiberSettings {
  double stretch_stiffness = 1.0;   ///< the fiber material's EA [N]
  double bending_stiffness = 1e-4;  ///< its EI [N m^2]
  double beta = 0.0;                ///< axial damping time [s]
  double lambda = 0.5;              ///< volume fraction, in [0, 1)
  bool implicit = false;            ///< ElasticRodsSettings::implicit
};

struct EmbeddedFibers {
  std::vector<std::vector<Index>> fibers;  ///< structure particles of each (possibly split) fiber
  ElasticRods* force = nullptr;            ///< null when every point fell outside the material
  Index dropped = 0;                       ///< drawn points outside the material
  /// Per structure particle (the fibers' particles in order): its material parents and weights.
  std::vector<std::vector<Index>> parents;
  std::vector<std::vector<double>> weights;
};

/// Embeds `polylines` (each 3 x n drawn points at rest) in `matrix` (added to `system`, its material
/// particles at rest now; h its support radius), adds the fibers' ElasticRods and sets the carrying
/// particles' volume fractions. Throws sinew::Error naming a bad setting or a non-finite point.
EmbeddedFibers embed_fibers(System& system, MeshfreeCorotated& matrix, double h, const std::vector<Vectors3>& polylines,
                            const FiberSettings& settings);

}  // namespace sinew
