// Elastic fibers as discrete elastic rods without twist (Liu et al. 2012, section 4.1, eq. 5-8 and
// the appendix, with the corrections of its notes), parameterised by the stretching and bending
// stiffnesses EA [N] and EI [N m^2], so that refining a fiber does not change how stiff it is.
//
// A fiber is a polyline of particles x_0 .. x_n with rest edges ebar and, at each interior vertex,
// the edges e = x_i - x_{i-1}, f = x_{i+1} - x_i:
//   stretching  E_s = EA / 2 (|e| - |ebar|)^2 / |ebar|                       (per edge: EA eps^2 |ebar| / 2)
//   bending     E_b = EI (psi - psibar)^2 / Lbar,  Lbar = |ebar| + |fbar|,
//               kappa = 2 e x f / (|ebar| |fbar| + e . f),  psi = |kappa|
// kappa is eq. 6's curvature binormal with the rest lengths in its denominator (the paper's
// "inextensible" appendix form), |kappa| = 2 tan(phi / 2) at rest lengths; EI kappa^2 / Lbar is the
// discrete rod's EI kappa^2 / (2 l_vor), i.e. the paper's K_b = 2 EI, and eq. 8's K_s = EA / (2 |ebar|).
// psibar is |kappa| of the rest shape, so curved fibers keep their rest turning angles (the paper's
// tan form, in psi). The bending energy is blind to the plane of a turn: a curved fiber may turn
// its bend about its own axis for free (the paper's limitation, kept; no material frames).
// Every term's gradient and differential are exact, at all three vertices (the appendix gives only
// the middle vertex's with lengths frozen). Where psibar > 0 and psi -> 0 the energy has a cone; a
// vertex with psi below 1e-12 takes no bending force there (its direction is undefined).
//
// Damping is along each edge (beta EA / |ebar| times the edge's stretching rate), which leaves rigid
// motion undamped.
#pragma once

#include "sinew/force.hpp"

#include <vector>

namespace sinew {

struct ElasticRodsSettings {
  double stretch_stiffness = 1.0;   ///< EA [N]
  double bending_stiffness = 1e-4;  ///< EI [N m^2]
  double beta = 0.0;                ///< axial strain-rate damping time [s]
  /// Offer a definite differential (stretching's clamped, bending's Gauss-Newton part), so that
  /// StepSettings::implicit_elasticity (or the automatic scheme) treats the fibers implicitly.
  bool implicit = false;
};

class ElasticRods final : public Force {
 public:
  /// `fibers`: each a polyline of at least two particle indices; rest_x: 3 x N rest positions (the
  /// rest lengths and rest turning angles). Throws sinew::Error naming a bad setting, a fiber with
  /// fewer than two particles, an out-of-range or repeated particle within a fiber, or a zero-length
  /// rest edge.
  ElasticRods(std::vector<std::vector<Index>> fibers, const Vectors3& rest_x, const ElasticRodsSettings& settings = {});

  std::string_view name() const override { return "elastic rods"; }
  void validate(Index particle_count) const override;
  bool touches(std::span<const std::uint8_t> removed) const override {
    for (const auto& fiber : m_fibers)
      for (const Index p : fiber)
        if (removed[static_cast<std::size_t>(p)]) return true;
    return false;
  }
  void update_position_state(const Vectors3& x) override;
  double potential_energy(const Vectors3& x) const override;
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override;
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override;
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override;
  bool has_damping() const override { return m_settings.beta > 0.0; }
  bool has_definite_differentials() const override { return m_settings.implicit; }
  void add_implicit_products(const Vectors3& v, double b, Vectors3& f) const override;
  double stable_dt(const VectorXd& m_eff) const override;
  double turn_work_rate(const Vectors3& x, const Vectors3& v) const override;
  double turn_stretch_rate(const Vectors3& x, const Vectors3& v) const override;

  const std::vector<std::vector<Index>>& fibers() const { return m_fibers; }
  /// The energy of fiber k's stretching and bending terms at x.
  double fiber_energy(std::size_t k, const Vectors3& x) const;
  /// Breaking (figure 10): fiber k splits at its edge `edge` (between its particles edge and edge + 1)
  /// into two fibers; that edge's stretching term and the bending terms of the two hinges that use it
  /// go, every other term stays as it was (rest data to the bit), so the energy drops by exactly the
  /// removed terms and nothing moves. A piece of one particle is dropped. Between steps.
  void break_fiber(std::size_t k, std::size_t edge);
  /// Breaks every fiber at its first edge stretched past (1 + strain) of its rest length, again in
  /// the pieces; returns how many breaks.
  std::size_t break_stretched(const Vectors3& x, double strain);

  /// A hinge's edges e, f, n = e x f, D = |ebar||fbar| + e . f, kappa = 2 n / D and psi = |kappa|.
  struct HingeState {
    Vec3 e, f, n, kappa;
    double D = 0.0, psi = 0.0;
  };

 private:
  struct Edge {
    Index a = -1, b = -1;
    double rest = 0.0;
  };
  struct Hinge {
    Index a = -1, b = -1, c = -1;  // x_{i-1}, x_i, x_{i+1}
    double e_rest = 0.0, f_rest = 0.0, psi_rest = 0.0;
  };
  void rebuild();
  void add_edge_products(const Vectors3& dx, double scale, bool clamped, Vectors3& out) const;
  void add_hinge_products(const Vectors3& dx, double scale, bool exact, Vectors3& out) const;
  double edge_energy(const Edge& e, const Vectors3& x) const;
  double hinge_energy(const Hinge& h, const Vectors3& x) const;
  double edge_turn_sq(const Vectors3& x, const Vectors3& v, Index a, Index b, double rest, double& length) const;

  std::vector<std::vector<Index>> m_fibers;
  ElasticRodsSettings m_settings;
  std::vector<Edge> m_edges;
  std::vector<Hinge> m_hinges;
  std::vector<std::size_t> m_edge_offset, m_hinge_offset;  // per fiber, into m_edges and m_hinges
  Vectors3 m_rest;                                         // the rest positions
  // The state at the last positions (update_position_state; a break refreshes it for the terms left),
  // which the differentials, products and damping of every solve iteration use.
  Vectors3 m_x;
  std::vector<Vec3> m_edge_direction;
  std::vector<double> m_edge_length;
  std::vector<HingeState> m_hinge_state;
};

}  // namespace sinew
