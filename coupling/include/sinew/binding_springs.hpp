// Binding springs (Sifakis et al. 2007, section 3.2, eq. 5): zero-rest-length springs between two
// points, each a free, soft-bound or hard-bound particle (so also a point on a rigid frame),
//
//   f_a = -k (x_a - x_b) - c (v_a - v_b),   f_b = -f_a.
//
// Being linear in both x and v, they are integrated fully implicitly (eq. 6-8) and add no step
// restriction. The damping is multidirectional (the full relative velocity, not its projection on
// the spring), which is what linearising a zero-length spring gives. c is set from a damping ratio:
// c = 2 zeta sqrt(k mu) with mu = (1/m_a + 1/m_b)^-1 the reduced effective mass, so zeta = 1 is
// critical damping whatever the masses.
#pragma once

#include "sinew/types.hpp"

#include <vector>

namespace sinew {

struct BindingSpringSettings {
  Index a = -1;                ///< first point (particle row)
  Index b = -1;                ///< second point (particle row)
  double stiffness = 0.0;      ///< k [N/m], > 0
  double damping_ratio = 1.0;  ///< zeta; 1 = critical from the effective masses
};

class BindingSprings {
 public:
  /// Validates (finite, positive k, zeta >= 0, a != b) and appends; returns the spring's index.
  Index add(const BindingSpringSettings& settings);

  /// c = 2 zeta sqrt(k mu) from inverse effective masses of the rows (0 for infinite mass).
  void set_damping_from_masses(const VectorXd& inverse_effective_mass);

  Index size() const { return static_cast<Index>(m_a.size()); }
  Index a(Index s) const { return m_a[s]; }
  Index b(Index s) const { return m_b[s]; }
  double stiffness(Index s) const { return m_k[s]; }
  double damping(Index s) const { return m_c[s]; }

  /// Switches a spring off (it then exerts nothing) or back on.
  void set_active(Index s, bool active) {
    m_k_active[s] = active ? m_k[s] : 0.0, m_c_active[s] = active ? m_c[s] : 0.0, m_active[s] = active;
  }
  /// Switches a spring off for good: its index stays reserved, its ends are no longer checked or used.
  void remove(Index s) {
    set_active(s, false);
    m_removed[s] = true;
  }
  bool removed(Index s) const { return m_removed[s]; }
  bool active(Index s) const { return m_active[s]; }
  void set_ends(Index s, Index a, Index b) { m_a[s] = a, m_b[s] = b; }
  /// The force on end a, -k (x_a - x_b) - c (v_a - v_b); end b carries its opposite.
  Vec3 force(Index s, const Vectors3& x, const Vectors3& v) const {
    return -m_k_active[s] * (x.col(m_a[s]) - x.col(m_b[s])) - m_c_active[s] * (v.col(m_a[s]) - v.col(m_b[s]));
  }

  /// f += -K x: the elastic part at positions x (3 x N).
  void add_elastic_forces(const Vectors3& x, Vectors3& f) const;
  /// f += -(alpha C + beta K) v: damping (alpha = 1, beta = 0), or the implicit operator's combined
  /// term with beta = h for the stiffness part of eq. 8.
  void add_linear_forces(const Vectors3& v, double alpha, double beta, Vectors3& f) const;
  /// diag += alpha c + beta k on both rows (Jacobi preconditioner of the implicit system).
  void add_diagonal(double alpha, double beta, VectorXd& diag) const;
  /// Potential energy sum k/2 |x_a - x_b|^2.
  double potential_energy(const Vectors3& x) const;
  /// Largest spring stretch |x_a - x_b|.
  double max_stretch(const Vectors3& x) const;

 private:
  std::vector<Index> m_a, m_b;
  std::vector<double> m_k, m_zeta, m_c;
  std::vector<double> m_k_active, m_c_active;  // k and c, or 0 while switched off
  std::vector<bool> m_active;
  std::vector<bool> m_removed;
};

}  // namespace sinew
