// Elastic rods without twist: see the header for the energies. The bending terms' derivatives are
// taken on the hinge's edges e and f (then to the vertices: x_{i-1} gets -d/de, x_i d/de - d/df,
// x_{i+1} d/df). With n = e x f and D = |ebar||fbar| + e . f, kappa = 2 n / D, and for a fixed vector
// a, phi = a . kappa has
//   dphi/de = 2 (f x a) / D - 2 (a . n) f / D^2,      dphi/df = 2 (a x e) / D - 2 (a . n) e / D^2,
// and, along (de, df) with dn = de x f + e x df, dD = de . f + e . df, the derivative of that pair
//   d/de: 2 (df x a) / D - 2 (a . dn) f / D^2 - 2 (f x a) dD / D^2 - 2 (a . n) df / D^2 + 4 (a . n) dD f / D^3
//   d/df: 2 (a x de) / D - 2 (a . dn) e / D^2 - 2 (a x e) dD / D^2 - 2 (a . n) de / D^2 + 4 (a . n) dD e / D^3.
// E_b = EI (psi - psibar)^2 / Lbar, psi = |kappa|, has gradient (2 EI / Lbar) c grad(kappa . kappa)/2
// with c = 1 - psibar / psi, i.e. (2 EI / Lbar) c dphi|_{a = kappa}, and differential
//   (2 EI / Lbar) [c (H_phi|_{a = kappa} + dphi|_{a = dkappa}) + psibar (kappa . dkappa) / psi^3 dphi|_{a = kappa}].
#include "sinew/forces/elastic_rods.hpp"

#include "element_support.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace sinew {

namespace {

constexpr std::string_view kName = "elastic rods";
// Below this |kappa| a curved hinge's bending direction is undefined: no bending force there.
constexpr double kFlat = 1e-12;
// A rest turning below this (|kappa| ~ the angle) is straight: round-off of a collinear rest shape.
constexpr double kStraight = 1e-10;

using HingeGeometry = ElasticRods::HingeState;

HingeGeometry geometry(const Vec3& xa, const Vec3& xb, const Vec3& xc, double e_rest, double f_rest) {
  HingeGeometry g;
  g.e = xb - xa;
  g.f = xc - xb;
  g.n = g.e.cross(g.f);
  // Folded back on itself (e . f -> -|ebar||fbar|) the curvature is unbounded; kept finite.
  g.D = std::max(e_rest * f_rest + g.e.dot(g.f), 1e-12 * e_rest * f_rest);
  g.kappa = 2.0 * g.n / g.D;
  g.psi = g.kappa.norm();
  return g;
}

// d(a . kappa)/de and /df.
std::pair<Vec3, Vec3> phi_gradient(const HingeGeometry& g, const Vec3& a) {
  const double an = a.dot(g.n), D2 = g.D * g.D;
  return {2.0 * g.f.cross(a) / g.D - 2.0 * an * g.f / D2, 2.0 * a.cross(g.e) / g.D - 2.0 * an * g.e / D2};
}

Vec3 kappa_differential(const HingeGeometry& g, const Vec3& de, const Vec3& df) {
  const Vec3 dn = de.cross(g.f) + g.e.cross(df);
  const double dD = de.dot(g.f) + g.e.dot(df);
  return 2.0 * dn / g.D - 2.0 * g.n * dD / (g.D * g.D);
}

// The derivative of phi_gradient(g, a) along (de, df), a fixed.
std::pair<Vec3, Vec3> phi_hessian(const HingeGeometry& g, const Vec3& a, const Vec3& de, const Vec3& df) {
  const Vec3 dn = de.cross(g.f) + g.e.cross(df);
  const double dD = de.dot(g.f) + g.e.dot(df);
  const double an = a.dot(g.n), adn = a.dot(dn);
  const double D = g.D, D2 = D * D, D3 = D2 * D;
  const Vec3 he = 2.0 * df.cross(a) / D - 2.0 * adn * g.f / D2 - 2.0 * g.f.cross(a) * dD / D2 - 2.0 * an * df / D2 +
                  4.0 * an * dD * g.f / D3;
  const Vec3 hf = 2.0 * a.cross(de) / D - 2.0 * adn * g.e / D2 - 2.0 * a.cross(g.e) * dD / D2 - 2.0 * an * de / D2 +
                  4.0 * an * dD * g.e / D3;
  return {he, hf};
}

}  // namespace

ElasticRods::ElasticRods(std::vector<std::vector<Index>> fibers, const Vectors3& rest_x,
                         const ElasticRodsSettings& settings)
    : m_fibers(std::move(fibers)), m_settings(settings) {
  detail::check_non_negative(kName, "stretch_stiffness", m_settings.stretch_stiffness);
  detail::check_non_negative(kName, "bending_stiffness", m_settings.bending_stiffness);
  detail::check_non_negative(kName, "beta", m_settings.beta);
  for (std::size_t k = 0; k < m_fibers.size(); ++k) {
    const std::vector<Index>& p = m_fibers[k];
    if (p.size() < 2) fail(kName, ": fiber ", k, " has ", p.size(), " particles, expected at least 2");
    std::vector<Index> sorted = p;
    std::sort(sorted.begin(), sorted.end());
    for (std::size_t i = 0; i < sorted.size(); ++i) {
      if (sorted[i] < 0 || sorted[i] >= rest_x.cols())
        fail(kName, ": fiber ", k, ": particle ", sorted[i], " is outside the ", rest_x.cols(), " rest positions");
      if (i > 0 && sorted[i] == sorted[i - 1]) fail(kName, ": fiber ", k, ": particle ", sorted[i], " appears twice");
    }
    for (std::size_t i = 0; i + 1 < p.size(); ++i) {
      const double rest = (rest_x.col(p[i + 1]) - rest_x.col(p[i])).norm();
      if (!(rest > 0.0 && std::isfinite(rest)))
        fail(kName, ": fiber ", k, ": edge ", i, " (particles ", p[i], ", ", p[i + 1], ") has rest length ", rest);
    }
  }
  m_rest = rest_x;
  rebuild();
  update_position_state(rest_x);
}

// The terms of every fiber from the rest positions: the same computation for the terms a break
// leaves, so they keep their rest data to the bit.
void ElasticRods::rebuild() {
  m_edges.clear();
  m_hinges.clear();
  m_edge_offset.assign(1, 0);
  m_hinge_offset.assign(1, 0);
  for (const std::vector<Index>& p : m_fibers) {
    const std::size_t first = m_edges.size();
    for (std::size_t i = 0; i + 1 < p.size(); ++i)
      m_edges.push_back({p[i], p[i + 1], (m_rest.col(p[i + 1]) - m_rest.col(p[i])).norm()});
    for (std::size_t i = 1; i + 1 < p.size(); ++i) {
      Hinge h{p[i - 1], p[i], p[i + 1], m_edges[first + i - 1].rest, m_edges[first + i].rest, 0.0};
      h.psi_rest = geometry(m_rest.col(h.a), m_rest.col(h.b), m_rest.col(h.c), h.e_rest, h.f_rest).psi;
      if (h.psi_rest < kStraight) h.psi_rest = 0.0;  // straight to round-off: the smooth form
      m_hinges.push_back(h);
    }
    m_edge_offset.push_back(m_edges.size());
    m_hinge_offset.push_back(m_hinges.size());
  }
  if (m_x.cols() > 0) update_position_state(m_x);  // the remaining terms' states at the last positions
}

void ElasticRods::break_fiber(std::size_t k, std::size_t edge) {
  if (k >= m_fibers.size()) fail(kName, ": break: no fiber ", k, " (", m_fibers.size(), " fibers)");
  std::vector<Index>& p = m_fibers[k];
  if (edge + 1 >= p.size()) fail(kName, ": break: fiber ", k, " has no edge ", edge, " (", p.size() - 1, " edges)");
  std::vector<Index> tail(p.begin() + static_cast<std::ptrdiff_t>(edge) + 1, p.end());
  p.resize(edge + 1);
  // A piece of one particle has no terms left: it is dropped from the list, and the tail takes the
  // fiber's place (else it follows the head).
  std::size_t at = k + 1;
  if (p.size() < 2) {
    m_fibers.erase(m_fibers.begin() + static_cast<std::ptrdiff_t>(k));
    at = k;
  }
  if (tail.size() >= 2) m_fibers.insert(m_fibers.begin() + static_cast<std::ptrdiff_t>(at), tail);
  rebuild();
}

std::size_t ElasticRods::break_stretched(const Vectors3& x, double strain) {
  if (!(strain > 0.0)) fail(kName, ": break_stretched: strain ", strain, " must be positive");
  std::size_t broken = 0, k = 0;
  while (k < m_fibers.size()) {
    const std::vector<Index>& p = m_fibers[k];
    std::size_t at = p.size();
    for (std::size_t i = 0; i + 1 < p.size() && at == p.size(); ++i)
      if ((x.col(p[i + 1]) - x.col(p[i])).norm() > (1.0 + strain) * (m_rest.col(p[i + 1]) - m_rest.col(p[i])).norm())
        at = i;
    if (at == p.size()) {
      ++k;
      continue;
    }
    break_fiber(k, at);
    ++broken;
    // The head (edges before `at`, none stretched) is done when it was kept; the tail is next: at
    // k + 1, or at k when the head was dropped.
    if (at >= 1) ++k;
  }
  return broken;
}

void ElasticRods::validate(Index particle_count) const {
  for (std::size_t k = 0; k < m_fibers.size(); ++k)
    for (const Index p : m_fibers[k])
      if (p >= particle_count)
        fail(kName, ": fiber ", k, ": particle ", p, " is outside the system's ", particle_count, " particles");
}

double ElasticRods::edge_energy(const Edge& e, const Vectors3& x) const {
  const double stretch = (x.col(e.b) - x.col(e.a)).norm() - e.rest;
  return 0.5 * m_settings.stretch_stiffness * stretch * stretch / e.rest;
}

double ElasticRods::hinge_energy(const Hinge& h, const Vectors3& x) const {
  const HingeGeometry g = geometry(x.col(h.a), x.col(h.b), x.col(h.c), h.e_rest, h.f_rest);
  const double bend = g.psi - h.psi_rest;
  return m_settings.bending_stiffness * bend * bend / (h.e_rest + h.f_rest);
}

double ElasticRods::fiber_energy(std::size_t k, const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t i = m_edge_offset[k]; i < m_edge_offset[k + 1]; ++i) energy += edge_energy(m_edges[i], x);
  for (std::size_t i = m_hinge_offset[k]; i < m_hinge_offset[k + 1]; ++i) energy += hinge_energy(m_hinges[i], x);
  return energy;
}

double ElasticRods::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t k = 0; k < m_fibers.size(); ++k) energy += fiber_energy(k, x);
  return energy;
}

void ElasticRods::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  const double EA = m_settings.stretch_stiffness, EI = m_settings.bending_stiffness;
  for (const Edge& e : m_edges) {
    const Vec3 d = x.col(e.b) - x.col(e.a);
    const double l = d.norm();
    const Vec3 grad = (EA / e.rest) * (l - e.rest) / l * d;
    f.col(e.a) += grad;
    f.col(e.b) -= grad;
  }
  if (EI == 0.0) return;
  for (const Hinge& h : m_hinges) {
    const HingeGeometry g = geometry(x.col(h.a), x.col(h.b), x.col(h.c), h.e_rest, h.f_rest);
    if (h.psi_rest > 0.0 && g.psi < kFlat) continue;
    const double c = h.psi_rest > 0.0 ? 1.0 - h.psi_rest / g.psi : 1.0;
    const auto [ge, gf] = phi_gradient(g, g.kappa);
    const double scale = 2.0 * EI / (h.e_rest + h.f_rest) * c;
    f.col(h.a) += scale * ge;
    f.col(h.b) += scale * (gf - ge);
    f.col(h.c) -= scale * gf;
  }
}

void ElasticRods::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  add_edge_products(dx, 1.0, false, df);
  add_hinge_products(dx, 1.0, true, df);
}

void ElasticRods::update_position_state(const Vectors3& x) {
  m_x = x;
  m_edge_direction.resize(m_edges.size());
  m_edge_length.resize(m_edges.size());
  for (std::size_t i = 0; i < m_edges.size(); ++i) {
    const Vec3 d = x.col(m_edges[i].b) - x.col(m_edges[i].a);
    m_edge_length[i] = d.norm();
    m_edge_direction[i] = d / m_edge_length[i];
  }
  m_hinge_state.resize(m_hinges.size());
  for (std::size_t i = 0; i < m_hinges.size(); ++i) {
    const Hinge& h = m_hinges[i];
    m_hinge_state[i] = geometry(x.col(h.a), x.col(h.b), x.col(h.c), h.e_rest, h.f_rest);
  }
}

// out += scale K dx over the edges at the cached state: the exact differential, or with `clamped`
// the transverse term only where stretched (definite).
void ElasticRods::add_edge_products(const Vectors3& dx, double scale, bool clamped, Vectors3& out) const {
  const double EA = m_settings.stretch_stiffness;
  for (std::size_t i = 0; i < m_edges.size(); ++i) {
    const Edge& e = m_edges[i];
    const Vec3& u = m_edge_direction[i];
    const Vec3 dd = dx.col(e.b) - dx.col(e.a);
    const double along = u.dot(dd);
    const double transverse = 1.0 - e.rest / m_edge_length[i];
    const Vec3 k =
        (scale * EA / e.rest) * ((clamped ? std::max(0.0, transverse) : transverse) * (dd - along * u) + along * u);
    out.col(e.a) += k;
    out.col(e.b) -= k;
  }
}

// out += scale K dx over the hinges at the cached state: with `exact` the differential
//   c (H_phi|kappa + J^T J) + psibar (kappa . J dx) / psi^3 J^T kappa,
// else its Gauss-Newton part with c clamped at 0 (definite; see add_implicit_products).
void ElasticRods::add_hinge_products(const Vectors3& dx, double scale, bool exact, Vectors3& out) const {
  const double EI = m_settings.bending_stiffness;
  if (EI == 0.0) return;
  for (std::size_t i = 0; i < m_hinges.size(); ++i) {
    const Hinge& h = m_hinges[i];
    const HingeGeometry& g = m_hinge_state[i];
    if (h.psi_rest > 0.0 && g.psi < kFlat) continue;
    const Vec3 de = dx.col(h.b) - dx.col(h.a), dfv = dx.col(h.c) - dx.col(h.b);
    const Vec3 dkappa = kappa_differential(g, de, dfv);
    auto [ge, gf] = phi_gradient(g, dkappa);  // J^T J dx
    if (exact) {
      const auto [he, hf] = phi_hessian(g, g.kappa, de, dfv);
      ge += he;
      gf += hf;
    }
    if (h.psi_rest > 0.0) {
      const double c = 1.0 - h.psi_rest / g.psi;
      const double dc = h.psi_rest * g.kappa.dot(dkappa) / (g.psi * g.psi * g.psi);
      const auto [pe, pf] = phi_gradient(g, g.kappa);
      const double kept = exact ? c : std::max(0.0, c);
      ge = kept * ge + dc * pe;
      gf = kept * gf + dc * pf;
    }
    const double k = scale * 2.0 * EI / (h.e_rest + h.f_rest);
    out.col(h.a) += k * ge;
    out.col(h.b) += k * (gf - ge);
    out.col(h.c) -= k * gf;
  }
}

void ElasticRods::add_damping_forces(const Vectors3& v, Vectors3& f) const {
  if (m_settings.beta == 0.0) return;
  for (std::size_t i = 0; i < m_edges.size(); ++i) {
    const Edge& e = m_edges[i];
    const Vec3& u = m_edge_direction[i];
    const double rate = u.dot(v.col(e.b) - v.col(e.a));
    const Vec3 force = (m_settings.beta * m_settings.stretch_stiffness / e.rest * rate) * u;
    f.col(e.a) += force;
    f.col(e.b) -= force;
  }
}

// D v + b K+ v. K+ keeps each edge's axial stiffness and its transverse term only where stretched
// (EA / |ebar| [u u^T + max(0, 1 - |ebar| / l) (I - u u^T)]), and each hinge's Gauss-Newton part
// (2 EI / Lbar) [max(c, 0) J^T J + psibar / psi^3 (J^T kappa)(kappa^T J)], J = dkappa: both positive
// semi-definite, so the forces' K+ is negative semi-definite; the exact differential where the
// curvature terms vanish (straight, at rest).
void ElasticRods::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  add_damping_forces(v, f);
  if (!m_settings.implicit || b == 0.0) return;
  add_edge_products(v, b, true, f);
  add_hinge_products(v, b, false, f);
}

// An edge's squared turning rate |dv_perp|^2 / l^2, l its length (not below its rest length: a
// crumpled edge cannot turn faster than its neighbours carry it); `length` is set to l.
double ElasticRods::edge_turn_sq(const Vectors3& x, const Vectors3& v, Index a, Index b, double rest,
                                 double& length) const {
  const Vec3 d = x.col(b) - x.col(a);
  const double actual = d.norm();
  length = std::max(actual, rest);
  if (!(actual > 0.0)) return 0.0;
  const Vec3 u = d / actual;
  const Vec3 dv = v.col(b) - v.col(a);
  return (dv - u * u.dot(dv)).squaredNorm() / (length * length);
}

// What the step's linearisation misses (Force::turn_work_rate), as EdgeSprings counts it: an edge of
// tension (or compression) T and length l turning at rate w misses T l w^2 / 2 per squared step (its
// geometric stiffness, which the clamped differential leaves out); a hinge whose moment
// dE/dpsi = 2 EI (psi - psibar) / Lbar acts through edges turning at w_e and w_f misses about
// |dE/dpsi| (w_e^2 + w_f^2) / 2 (the Gauss-Newton differential leaves out dE/dpsi times psi's
// second derivative, of order 1 / l^2 per edge). Explicit rods linearise nothing: 0.
double ElasticRods::turn_work_rate(const Vectors3& x, const Vectors3& v) const {
  if (!m_settings.implicit) return 0.0;  // explicit: nothing linearised
  double sum = 0.0;
  for (const Edge& e : m_edges) {
    double length = 0.0;
    const double w_sq = edge_turn_sq(x, v, e.a, e.b, e.rest, length);
    const double actual = (x.col(e.b) - x.col(e.a)).norm();
    sum += 0.5 * std::abs(m_settings.stretch_stiffness * (actual - e.rest) / e.rest) * length * w_sq;
  }
  for (const Hinge& h : m_hinges) {
    const double psi = geometry(x.col(h.a), x.col(h.b), x.col(h.c), h.e_rest, h.f_rest).psi;
    const double moment = 2.0 * m_settings.bending_stiffness * std::abs(psi - h.psi_rest) / (h.e_rest + h.f_rest);
    double length = 0.0;
    sum += 0.5 * moment *
           (edge_turn_sq(x, v, h.a, h.b, h.e_rest, length) + edge_turn_sq(x, v, h.b, h.c, h.f_rest, length));
  }
  return sum;
}

// Force::turn_stretch_rate: an edge of stiffness EA / |ebar| and length l turning at w is stretched by
// l (w dt)^2 / 2 along tangents, storing EA l^2 w^4 dt^4 / (8 |ebar|) (l and w as edge_turn_sq has them).
double ElasticRods::turn_stretch_rate(const Vectors3& x, const Vectors3& v) const {
  if (!m_settings.implicit) return 0.0;
  double sum = 0.0;
  for (const Edge& e : m_edges) {
    double length = 0.0;
    const double w_sq = edge_turn_sq(x, v, e.a, e.b, e.rest, length);
    sum += m_settings.stretch_stiffness * length * length * w_sq * w_sq / (8.0 * e.rest);
  }
  return sum;
}

// At rest, per edge x^T K x <= EA / |ebar| |de|^2 <= EA / |ebar| (1/m_a + 1/m_b) |x|_M^2; per hinge
// (straight) K = (2 EI / Lbar) J^T J with |dkappa| <= |de| / |ebar| + |df| / |fbar|, so
// |dkappa|^2 <= 2 (|de|^2 / |ebar|^2 + |df|^2 / |fbar|^2) and |de|^2 <= 2 (|dx_a|^2 + |dx_b|^2).
// At a curved rest shape psi = 2 tan(phi / 2) changes (1 + psibar^2 / 4) times as fast with the
// angle, so its hinge is given (1 + psibar^2 / 4)^2 times that, and twice again for the coupling of
// the lengths to the turn. omega^2 is at most the largest sum over the terms a particle is in
// (element_bound_stable_dt's argument).
double ElasticRods::stable_dt(const VectorXd& m_eff) const {
  Index span = 0;
  for (const auto& fiber : m_fibers) span = std::max(span, *std::max_element(fiber.begin(), fiber.end()) + 1);
  detail::check_mass_count(kName, m_eff, span);
  const auto inv = [&](Index i) { return detail::inverse_mass(m_eff[i]); };
  std::vector<double> sum(static_cast<std::size_t>(m_eff.size()), 0.0);
  for (const Edge& e : m_edges) {
    const double lambda = m_settings.stretch_stiffness / e.rest * (inv(e.a) + inv(e.b));
    sum[static_cast<std::size_t>(e.a)] += lambda;
    sum[static_cast<std::size_t>(e.b)] += lambda;
  }
  for (const Hinge& h : m_hinges) {
    const double curved = 1.0 + 0.25 * h.psi_rest * h.psi_rest;
    const double scale =
        2.0 * m_settings.bending_stiffness / (h.e_rest + h.f_rest) * (h.psi_rest > 0.0 ? 2.0 * curved * curved : 1.0);
    const double lambda =
        scale * 4.0 * ((inv(h.a) + inv(h.b)) / (h.e_rest * h.e_rest) + (inv(h.b) + inv(h.c)) / (h.f_rest * h.f_rest));
    for (const Index i : {h.a, h.b, h.c}) sum[static_cast<std::size_t>(i)] += lambda;
  }
  double omega_sq = 0.0;
  for (std::size_t i = 0; i < sum.size(); ++i)
    if (inv(static_cast<Index>(i)) > 0.0) omega_sq = std::max(omega_sq, sum[i]);
  return omega_sq > 0.0 ? 2.0 / std::sqrt(omega_sq) : kInfinity;
}

}  // namespace sinew
