#include "sinew/binding_springs.hpp"

namespace sinew {

Index BindingSprings::add(const BindingSpringSettings& s) {
  const Index id = size();
  if (!(std::isfinite(s.stiffness) && s.stiffness > 0.0))
    fail("binding spring ", id, ": stiffness ", s.stiffness, " must be positive and finite");
  if (!(std::isfinite(s.damping_ratio) && s.damping_ratio >= 0.0))
    fail("binding spring ", id, ": damping ratio ", s.damping_ratio, " must be non-negative and finite");
  if (s.a < 0 || s.b < 0) fail("binding spring ", id, ": endpoint index is negative");
  if (s.a == s.b) fail("binding spring ", id, ": both ends are particle ", s.a);
  m_a.push_back(s.a);
  m_b.push_back(s.b);
  m_k.push_back(s.stiffness);
  m_zeta.push_back(s.damping_ratio);
  m_c.push_back(0.0);
  m_k_active.push_back(s.stiffness);
  m_c_active.push_back(0.0);
  m_active.push_back(true);
  m_removed.push_back(false);
  return id;
}

void BindingSprings::set_damping_from_masses(const VectorXd& inverse_effective_mass) {
  for (Index s = 0; s < size(); ++s) {
    if (m_removed[s]) continue;
    const double inverse_mu = inverse_effective_mass[m_a[s]] + inverse_effective_mass[m_b[s]];
    if (!(inverse_mu > 0.0)) fail("binding spring ", s, " connects two points of infinite mass");
    m_c[s] = 2.0 * m_zeta[s] * std::sqrt(m_k[s] / inverse_mu);
    m_c_active[s] = m_active[s] ? m_c[s] : 0.0;
  }
}

void BindingSprings::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  for (Index s = 0; s < size(); ++s) {
    const Vec3 fa = -m_k_active[s] * (x.col(m_a[s]) - x.col(m_b[s]));
    f.col(m_a[s]) += fa;
    f.col(m_b[s]) -= fa;
  }
}

void BindingSprings::add_linear_forces(const Vectors3& v, double alpha, double beta, Vectors3& f) const {
  for (Index s = 0; s < size(); ++s) {
    const Vec3 fa = -(alpha * m_c_active[s] + beta * m_k_active[s]) * (v.col(m_a[s]) - v.col(m_b[s]));
    f.col(m_a[s]) += fa;
    f.col(m_b[s]) -= fa;
  }
}

void BindingSprings::add_diagonal(double alpha, double beta, VectorXd& diag) const {
  for (Index s = 0; s < size(); ++s) {
    const double d = alpha * m_c_active[s] + beta * m_k_active[s];
    diag[m_a[s]] += d;
    diag[m_b[s]] += d;
  }
}

double BindingSprings::potential_energy(const Vectors3& x) const {
  double e = 0.0;
  for (Index s = 0; s < size(); ++s) e += 0.5 * m_k_active[s] * (x.col(m_a[s]) - x.col(m_b[s])).squaredNorm();
  return e;
}

double BindingSprings::max_stretch(const Vectors3& x) const {
  double m = 0.0;
  for (Index s = 0; s < size(); ++s)
    if (m_active[s]) m = std::max(m, (x.col(m_a[s]) - x.col(m_b[s])).norm());
  return m;
}

}  // namespace sinew
