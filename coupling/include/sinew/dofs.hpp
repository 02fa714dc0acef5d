// The layout of sinew's unknowns, written down once.
//
// Particles are rows of one structure-of-arrays (x, v: 3 x N). Each row has a kind:
//   free               a full particle: 3 unknowns (its velocity) in both Newmark solves;
//   kinematic          prescribed motion, infinite mass: its velocity is a Dirichlet value;
//   hard_bound         a point embedded in parents (section 2, 5): no unknowns; x = W x_parents,
//                      v = W v_parents, forces go to the parents through W^T, mass 0 after set-up;
//   soft_spring        a full particle tied to a target by a binding spring (section 3.2): 3
//                      unknowns, mass = the target's effective mass, inherits the target's elastic
//                      and external accelerations;
//   soft_synchronized  a copy of its target, overwritten at fixed points of the step and whose drift
//                      (from collisions) is pushed back to the target's parents (section 3.1): no
//                      unknowns;
//   removed            taken out of the simulation between steps (System::remove_particles): no mass,
//                      no unknowns, no forces, state frozen; its index stays reserved so that the
//                      indices an application holds keep their meaning.
//
// Rigid-body particles are rows of a second structure-of-arrays (x_c, q, v_c, w: one column per
// body). A dynamic body has 6 unknowns, its twist (v_c, w), with mass block diag(m I, R I0 R^T)
// (section 5); a kinematic one has prescribed twist and infinite mass.
//
// The Krylov vector of the implicit solves is therefore a pair (3 x N particle block, 6 x R twist
// block). Rows without unknowns hold zeros in it: hard-bound rows are recomputed from W before
// every product and cleared after W^T, so they are eliminated, never projected; kinematic rows are
// projected to their prescribed value.
#pragma once

#include "sinew/types.hpp"

#include <cstdint>

namespace sinew {

enum class ParticleKind : std::uint8_t { free, kinematic, hard_bound, soft_spring, soft_synchronized, removed };

/// True for rows whose velocity is an unknown of the implicit solves.
inline bool is_dynamic(ParticleKind kind) { return kind == ParticleKind::free || kind == ParticleKind::soft_spring; }

/// One vector of the implicit solves: particle velocities (3 x N) and rigid twists (6 x R, linear
/// velocity in rows 0-2, angular velocity in rows 3-5).
struct GeneralizedVector {
  Vectors3 particles;
  Vectors6 rigid;

  void resize(Index particle_count, Index rigid_count) {
    particles.setZero(3, particle_count);
    rigid.setZero(6, rigid_count);
  }
  void set_zero() {
    particles.setZero();
    rigid.setZero();
  }
};

}  // namespace sinew
