// Particle state: structure-of-arrays, one column per particle (see dofs.hpp for the kinds).
#pragma once

#include "sinew/dofs.hpp"

#include <vector>

namespace sinew {

struct Particles {
  Vectors3 x;  ///< positions (3 x N)
  Vectors3 v;  ///< velocities (3 x N)
  /// Lumped mass after set-up: the particle's own mass plus what its hard-bound children passed to
  /// it (m = W^T m_bar, section 2); 0 for hard-bound rows, +inf for kinematic rows, the target's
  /// effective mass for soft-bound rows.
  VectorXd mass;
  std::vector<ParticleKind> kind;

  Index size() const { return static_cast<Index>(kind.size()); }
};

}  // namespace sinew
