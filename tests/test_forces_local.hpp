// Test doubles with closed-form solutions.
#pragma once

#include "sinew/force.hpp"

#include <vector>

namespace sinew::test {

/// Each listed particle hangs on a linear spring to a fixed anchor with linear damping:
/// f = -k (x - anchor) - c v. One particle on it is a harmonic oscillator with a known solution.
class AnchorSprings final : public Force, public ImplicitBlocks {
 public:
  AnchorSprings(std::vector<Index> particles, Vectors3 anchors, double k, double c)
      : m_particles(std::move(particles)), m_anchors(std::move(anchors)), m_k(k), m_c(c) {}
  std::string_view name() const override { return "anchor springs"; }
  void validate(Index n) const override {
    for (Index p : m_particles)
      if (p < 0 || p >= n) fail("anchor springs: particle ", p, " out of range");
  }
  void update_position_state(const Vectors3&) override {}
  double potential_energy(const Vectors3& x) const override {
    double e = 0;
    for (std::size_t i = 0; i < m_particles.size(); ++i)
      e += 0.5 * m_k * (x.col(m_particles[i]) - m_anchors.col(i)).squaredNorm();
    return e;
  }
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const override {
    for (std::size_t i = 0; i < m_particles.size(); ++i)
      f.col(m_particles[i]) -= m_k * (x.col(m_particles[i]) - m_anchors.col(i));
  }
  void add_elastic_differentials(const Vectors3& dx, Vectors3& df) const override {
    for (Index p : m_particles) df.col(p) -= m_k * dx.col(p);
  }
  void add_damping_forces(const Vectors3& v, Vectors3& f) const override {
    for (Index p : m_particles) f.col(p) -= m_c * v.col(p);
  }
  bool has_damping() const override { return m_c > 0; }
  double stable_dt(const VectorXd& m) const override {
    double dt = kInfinity;
    for (Index p : m_particles) dt = std::min(dt, 2.0 * std::sqrt(m[p] / m_k));
    return dt;
  }
  /// The scalar diagonal only (D = -c I per particle; no definite differential, so b is 0).
  const ImplicitBlocks* implicit_blocks() const override { return this; }
  void add_diagonal(double, VectorXd& diag) const override {
    for (Index p : m_particles) diag[p] += m_c;
  }

 private:
  std::vector<Index> m_particles;
  Vectors3 m_anchors;
  double m_k, m_c;
};

}  // namespace sinew::test
