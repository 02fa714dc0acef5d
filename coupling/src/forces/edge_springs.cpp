// Edge springs (e.g. Baraff and Witkin 1998, section 4; Choi and Ko 2002 for the transverse term).
//
// For an edge (i, j) with l = |x_j - x_i| and d = (x_j - x_i) / l:
//   Psi   = k/2 (l - l0)^2
//   f_i   = k (l - l0) d,                      f_j = -f_i
//   df_i  = k [d d^T + (1 - l0/l)(I - d d^T)] (dx_j - dx_i),   df_j = -df_i
// The transverse term (1 - l0/l)(I - d d^T) is the stiffness of rotating a pre-stretched spring;
// it is negative under compression, so the differential is exact but indefinite there. The definite
// differential K+ used by implicit solves clamps it at zero (a compressed spring's transverse
// stiffness is dropped), which is the exact differential for every stretched spring.
//
// Damping acts along the current direction only, so rigid rotation is not damped:
//   f_i = -b d d^T (v_i - v_j),  f_j = -f_i,
// which is symmetric negative semi-definite (a sum of -b (d (v_i - v_j))^2 quadratic forms).
#include "sinew/forces/edge_springs.hpp"

#include "element_support.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace sinew {

namespace {
constexpr std::string_view kName = "edge springs";
// An edge shorter than round-off of its coordinates has no usable direction.
constexpr double kZeroLengthRelative = 1.0e-12;
}  // namespace

EdgeSprings::EdgeSprings(std::vector<Edge> edges, const Vectors3& rest_x, const EdgeSpringsSettings& settings)
    : m_edges(std::move(edges)), m_settings(settings) {
  detail::check_non_negative(kName, "stiffness", m_settings.stiffness);
  detail::check_non_negative(kName, "damping", m_settings.damping);

  const Index n = rest_x.cols();
  const auto edge_count = static_cast<Index>(m_edges.size());
  m_rest_length.resize(edge_count);
  m_direction.resize(3, edge_count);
  m_length.resize(edge_count);
  m_stiffness_sum.setZero(n);
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const Edge& v = m_edges[e];
    detail::check_element_indices("edge", e, v, n);
    detail::check_rest_positions("edge", e, v, rest_x);
    const Vec3 xi = rest_x.col(v[0]);
    const Vec3 xj = rest_x.col(v[1]);
    const Vec3 diff = xj - xi;
    const double l0 = diff.norm();
    const double scale = std::max(xi.cwiseAbs().maxCoeff(), xj.cwiseAbs().maxCoeff());
    if (!(l0 > kZeroLengthRelative * scale) || l0 == 0.0) fail("edge ", e, " has zero rest length (", l0, ")");
    const auto ei = static_cast<Index>(e);
    m_rest_length[ei] = l0;
    m_direction.col(ei) = diff / l0;
    m_length[ei] = l0;
    m_stiffness_sum[v[0]] += m_settings.stiffness;
    m_stiffness_sum[v[1]] += m_settings.stiffness;
  }
  m_index_span = detail::index_span(m_edges);
  m_scatter = ScatterGather<2>(m_edges, m_index_span);
}

void EdgeSprings::validate(Index particle_count) const {
  for (std::size_t e = 0; e < m_edges.size(); ++e) detail::check_element_indices("edge", e, m_edges[e], particle_count);
}

void EdgeSprings::update_position_state(const Vectors3& x) {
  parallel::for_ranges(static_cast<Index>(m_edges.size()), [&](Index e0, Index e1) {
    for (Index e = e0; e < e1; ++e) {
      const Edge& v = m_edges[static_cast<std::size_t>(e)];
      const Vec3 diff = x.col(v[1]) - x.col(v[0]);
      const double l = diff.norm();
      m_length[e] = l;
      m_direction.col(e) = diff / l;
    }
  });
}

// Every per-edge loop below computes the force on the edge's first end, f_i (the second end gets
// -f_i), in parallel over edges into the edge's own slots; each node then gathers its slots.
template <typename EdgeForce>
void EdgeSprings::scatter_gather(Vectors3& f, EdgeForce&& edge_force) const {
  parallel::for_ranges(static_cast<Index>(m_edges.size()), [&](Index e0, Index e1) {
    for (Index e = e0; e < e1; ++e) {
      const Vec3 f_i = edge_force(e, m_edges[static_cast<std::size_t>(e)]);
      m_scatter.slot(e, 0) = f_i;
      m_scatter.slot(e, 1) = -f_i;
    }
  });
  m_scatter.gather_add(f);
}

double EdgeSprings::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const double stretch = (x.col(m_edges[e][1]) - x.col(m_edges[e][0])).norm() - m_rest_length[static_cast<Index>(e)];
    energy += 0.5 * m_settings.stiffness * stretch * stretch;
  }
  return energy;
}

void EdgeSprings::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  const double k = m_settings.stiffness;
  scatter_gather(f, [&](Index e, const Edge& v) -> Vec3 {
    const Vec3 diff = x.col(v[1]) - x.col(v[0]);
    const double l = diff.norm();
    return (k * (l - m_rest_length[e]) / l) * diff;
  });
}

void EdgeSprings::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  const double k = m_settings.stiffness;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const auto ei = static_cast<Index>(e);
    const Edge& v = m_edges[e];
    const Vec3 d = m_direction.col(ei);
    const Vec3 ddx = dx.col(v[1]) - dx.col(v[0]);
    const double along = d.dot(ddx);
    const double transverse = 1.0 - m_rest_length[ei] / m_length[ei];
    // k [d d^T + t (I - d d^T)] ddx without forming the matrix.
    const Vec3 df_i = k * (along * d + transverse * (ddx - along * d));
    df.col(v[0]) += df_i;
    df.col(v[1]) -= df_i;
  }
}

void EdgeSprings::add_damping_forces(const Vectors3& v, Vectors3& f) const {
  const double b = m_settings.damping;
  if (b == 0.0) return;
  scatter_gather(f, [&](Index e, const Edge& ij) -> Vec3 {
    const Vec3 d = m_direction.col(e);
    return (-b * d.dot(v.col(ij[0]) - v.col(ij[1]))) * d;
  });
}

// f_i += [b_d d d^T + b k (d d^T + t+ (I - d d^T))] (v_j - v_i), f_j -= the same, t+ = max(0, 1 - l0/l).
void EdgeSprings::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double bk = b * m_settings.stiffness;
  const double along_scale = m_settings.damping + bk;
  if (along_scale == 0.0) return;
  if (bk == 0.0) {
    scatter_gather(f, [&](Index e, const Edge& ij) -> Vec3 {
      const Vec3 d = m_direction.col(e);
      return (along_scale * d.dot(v.col(ij[1]) - v.col(ij[0]))) * d;
    });
    return;
  }
  scatter_gather(f, [&](Index e, const Edge& ij) -> Vec3 {
    const Vec3 d = m_direction.col(e);
    const Vec3 dv = v.col(ij[1]) - v.col(ij[0]);
    const double along = d.dot(dv);
    const double transverse = bk * std::max(0.0, 1.0 - m_rest_length[e] / m_length[e]);
    return (along_scale * along) * d + transverse * (dv - along * d);
  });
}

void EdgeSprings::add_implicit_diagonal(double b, VectorXd& diag) const {
  const double bk = b * m_settings.stiffness;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const auto ei = static_cast<Index>(e);
    const double transverse = std::max(0.0, 1.0 - m_rest_length[ei] / m_length[ei]);
    const double d = (m_settings.damping + bk * (1.0 + 2.0 * transverse)) / 3.0;
    diag[m_edges[e][0]] += d;
    diag[m_edges[e][1]] += d;
  }
}

void EdgeSprings::add_damping_diagonal(VectorXd& diag) const {
  // The diagonal block of both ends is -b d d^T, whose trace is -b for a unit d.
  const double third = m_settings.damping / 3.0;
  if (third == 0.0) return;
  for (const Edge& v : m_edges) {
    diag[v[0]] += third;
    diag[v[1]] += third;
  }
}

// Block Gershgorin on M^-1 K with K the material stiffness k d d^T per spring (the transverse
// term vanishes at rest, and is what makes the bound "at rest"): every 3x3 block of spring (i, j)
// has spectral norm k, so an eigenvalue satisfies omega^2 <= (sum of k at i) / m_i (diagonal) +
// (sum of k at i) / m_i (off-diagonal) for some dynamic row i. Rows with m = inf (kinematic) or
// m = 0 (no dynamics) are eliminated from M^-1 K and skipped.
double EdgeSprings::stable_dt(const VectorXd& m_eff) const {
  detail::check_mass_count(kName, m_eff, m_index_span);
  double omega_sq = 0.0;
  for (Index i = 0; i < m_index_span; ++i) {
    omega_sq = std::max(omega_sq, 2.0 * m_stiffness_sum[i] * detail::inverse_mass(m_eff[i]));
  }
  return omega_sq > 0.0 ? 2.0 / std::sqrt(omega_sq) : kInfinity;
}

}  // namespace sinew
