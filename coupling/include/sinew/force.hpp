// The interface every particle force implements.
//
// A force acts on the full particle array: free particles, soft-bound particles and hard-bound rows
// alike. Forces on hard-bound rows reach the parents through W^T (Sifakis et al. 2007, eq. 1-3);
// the integrator does that, a force never needs to know which rows are bound.
//
// The core below is what every force implements: validation, the position state, energy, forces and
// their differentials, damping, the implicit products where a definite differential exists, and the
// stable step. What preconditioners may use beyond the products (diagonal and pair blocks) is a
// separate, optional capability (ImplicitBlocks), asked for through implicit_blocks().
//
// Elastic forces are explicit in the Newmark step (section 3.3), unless StepSettings::
// implicit_elasticity asks for those that offer a definite differential to enter the first velocity
// solve the way binding springs do (eq. 6-8). Damping is linear in v (f = D(x) v, D symmetric
// negative semi-definite) and is implicit in both velocity solves.
#pragma once

#include "sinew/implicit_blocks.hpp"
#include "sinew/types.hpp"

#include <cstdint>
#include <span>
#include <string_view>

namespace sinew {

class Force {
 public:
  virtual ~Force() = default;

  /// Short name used in error messages and timings, e.g. "edge springs".
  virtual std::string_view name() const = 0;

  /// Throws sinew::Error naming the bad item if any index is outside [0, particle_count) or any
  /// element is degenerate. Called once when the force joins a system.
  virtual void validate(Index particle_count) const = 0;

  /// Caches position-dependent data (rotations, directions, gradients) at positions x (3 x N).
  /// Every call below except potential_energy and add_elastic_forces uses the cached state.
  virtual void update_position_state(const Vectors3& x) = 0;

  /// Elastic potential energy at x (3 x N).
  virtual double potential_energy(const Vectors3& x) const = 0;

  /// f += f_el(x), with f_el = -dPsi/dx. x and f are 3 x N.
  virtual void add_elastic_forces(const Vectors3& x, Vectors3& f) const = 0;

  /// df += (d f_el / dx) dx at the cached state. dx and df are 3 x N.
  virtual void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const = 0;

  /// f += D v at the cached state; D symmetric negative semi-definite. v and f are 3 x N.
  virtual void add_damping_forces(const Vectors3& v, Vectors3& f) const { (void)v, (void)f; }

  /// True when the force offers a definite differential K+ (symmetric negative semi-definite; the
  /// exact differential wherever that is definite) and so may be treated implicitly.
  virtual bool has_definite_differentials() const { return false; }

  /// True for a solid's elasticity (tets, a meshfree matrix): a layer pushed into the one behind it
  /// stores its energy there, so step 3's moves are spread through it when it is implicit
  /// (StepSettings::spread_collisions). A sheet or a rod is one layer thick and has no such layer.
  virtual bool volumetric() const { return false; }

  /// Called before every step with whether the step treats this force implicitly (it has definite
  /// differentials and StepSettings::implicit_elasticity is on), before update_position_state, so
  /// that a force can cache what its implicit products need only when they are used.
  virtual void set_implicit(bool implicit) { (void)implicit; }

  /// f += D v + b K+ v at the cached state: what the implicit solve multiplies by, in one pass over
  /// the elements. Forces without a definite differential add D v only (b must then be 0).
  virtual void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
    (void)b;
    add_damping_forces(v, f);
  }

  /// True when add_damping_forces adds anything; a scene whose forces all return false and that
  /// has no binding springs runs no linear solve at all.
  virtual bool has_damping() const { return false; }

  /// Topology change between steps (System::remove_particles, System::remove_elements_touching):
  /// drops every element with a node whose flag in `removed` (one per particle) is set, leaving the
  /// force exactly as if it had been built without those elements (the same rest data, the same
  /// order of sums). Returns how many it dropped. Only called when can_remove_elements(); the
  /// default throws.
  virtual Index remove_elements_touching(std::span<const std::uint8_t> removed);
  virtual bool can_remove_elements() const { return false; }
  /// Whether any element has a node flagged in `removed`: a force that cannot remove elements stands
  /// in the way of a removal only then. The default says yes (a force that does not know).
  virtual bool touches(std::span<const std::uint8_t> removed) const {
    (void)removed;
    return true;
  }

  /// Largest step for which the explicit treatment of this elastic force stays stable, from the
  /// stiffest element and the lightest particle it touches (masses m, infinite for kinematic or
  /// zero for hard-bound rows, in which case effective masses m_eff are used). Returns +inf when
  /// the force imposes no restriction.
  virtual double stable_dt(const VectorXd& m_eff) const {
    (void)m_eff;
    return kInfinity;
  }

  /// What linearising the force at a step's start misses over the step, per squared step [J/s^2]: the
  /// force's elements turning at x with velocities v, summed. 0 when they have no direction to turn.
  virtual double turn_work_rate(const Vectors3& x, const Vectors3& v) const {
    (void)x, (void)v;
    return 0.0;
  }
  /// What moving along tangents instead of arcs stores in the force's elements over a step, per fourth
  /// power of the step [J/s^4]: an element of stiffness k and size l turning at rate w is stretched by
  /// l (w dt)^2 / 2, which stores k l^2 w^4 dt^4 / 8 even where it had no stress to turn. Summed over
  /// the elements at x with velocities v; 0 when they have no direction to turn.
  virtual double turn_stretch_rate(const Vectors3& x, const Vectors3& v) const {
    (void)x, (void)v;
    return 0.0;
  }

  /// Whether the force can offer a definite differential when asked to (offer_definite_differentials)
  /// although its own settings keep it explicit.
  virtual bool can_offer_definite_differentials() const { return has_definite_differentials(); }
  /// Asks the force to offer its definite differential (has_definite_differentials() turns true)
  /// whatever its own settings say, or gives the choice back to them. StepSettings::automatic asks
  /// between steps when it treats elasticity implicitly.
  virtual void offer_definite_differentials(bool offer) { (void)offer; }

  /// The blocks of D + b K+ for the preconditioners, when the force offers them (see
  /// implicit_blocks.hpp for what the step does without them). A force that offers them usually
  /// derives from ImplicitBlocks too and returns this.
  virtual const ImplicitBlocks* implicit_blocks() const { return nullptr; }
};

}  // namespace sinew
