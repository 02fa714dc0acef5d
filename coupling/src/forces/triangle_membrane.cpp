// St. Venant-Kirchhoff membrane (e.g. Volino, Magnenat-Thalmann and Faure 2009; Sifakis and Barbic
// 2012, section 3.2 for the FEM notation).
//
// Each triangle gets a rest frame in its own plane: Dm (2x2) holds the rest edges x_b - x_a,
// x_c - x_a in that frame, A = |det Dm| / 2. With Ds = [x_b - x_a, x_c - x_a] (3x2):
//   F = Ds Dm^-1 (3x2),  E = (F^T F - I) / 2,  S = 2 mu E + lambda tr(E) I,  P = F S
//   Psi = A (mu |E|_F^2 + lambda/2 tr(E)^2)
//   [f_b f_c] = -A P Dm^-T,  f_a = -(f_b + f_c)
//   dF = dDs Dm^-1,  dE = sym(F^T dF),  dP = dF S + F (2 mu dE + lambda tr(dE) I),
//   [df_b df_c] = -A dP Dm^-T.
// The frame is only a parametrisation of the rest shape; E and Psi do not depend on its choice.
//
// Damping is stiffness-proportional (Rayleigh) in strain-rate form: the dissipation potential
//   D(v) = A beta (mu |Edot|^2 + lambda/2 tr(Edot)^2),  Edot = sym(F^T Fdot),  Fdot = Vs Dm^-1
// is a positive semi-definite quadratic form in v at the cached F, so f = -dD/dv = -A beta F Sdot Dm^-T
// (Sdot = 2 mu Edot + lambda tr(Edot) I) is linear, symmetric and negative semi-definite. Rigid
// motion has Edot = 0 and is not damped; at rest the damping matrix is exactly -beta K.
#include "sinew/forces/triangle_membrane.hpp"

#include "element_support.hpp"

#include <utility>

namespace sinew {

namespace {

constexpr std::string_view kName = "triangle membrane";
// Slivers whose area is at round-off level of their longest edge squared have no usable Dm^-1.
constexpr double kDegenerateRelative = 1.0e-12;

using Mat32 = Eigen::Matrix<double, 3, 2>;
using Mat2 = Eigen::Matrix2d;

Mat32 edge_matrix(const Vectors3& x, const std::array<Index, 3>& v) {
  Mat32 ds;
  ds.col(0) = x.col(v[1]) - x.col(v[0]);
  ds.col(1) = x.col(v[2]) - x.col(v[0]);
  return ds;
}

/// Scatters H = [f_b f_c] (3x2) to the three vertices, f_a = -(f_b + f_c).
void scatter_h(const std::array<Index, 3>& v, const Mat32& h, Vectors3& f) {
  f.col(v[0]) -= h.col(0) + h.col(1);
  f.col(v[1]) += h.col(0);
  f.col(v[2]) += h.col(1);
}

/// Second Piola-Kirchhoff-like linear map S(E) = 2 mu E + lambda tr(E) I on symmetric 2x2 E.
Mat2 stress(const Mat2& e, double mu, double lambda) { return 2.0 * mu * e + (lambda * e.trace()) * Mat2::Identity(); }

}  // namespace

TriangleMembrane::TriangleMembrane(std::vector<Triangle> triangles, const Vectors3& rest_x,
                                   const TriangleMembraneSettings& settings)
    : m_triangles(std::move(triangles)), m_settings(settings), m_rest_x(rest_x) {
  detail::check_non_negative(kName, "mu", m_settings.mu);
  if (!std::isfinite(m_settings.lambda)) fail(kName, ": lambda is ", m_settings.lambda);
  if (m_settings.lambda < -m_settings.mu) {
    fail(kName, ": lambda ", m_settings.lambda, " is below -mu = ", -m_settings.mu, " (negative 2D bulk modulus)");
  }
  detail::check_non_negative(kName, "beta", m_settings.beta);

  const Index n = rest_x.cols();
  const std::size_t count = m_triangles.size();
  m_dm_inv.resize(count);
  m_area.resize(count);
  m_dt_weights.resize(count);
  m_F.resize(count);
  // Rest stiffness bound (see element_bound_stable_dt): at rest F0^T F0 = I, E = 0 and
  //   dx^T K_e dx = A (2 mu |sym(F0^T dF)|^2 + lambda tr(F0^T dF)^2) <= A (2 mu + max(lambda, 0)) |dF|^2,
  // and |dF|^2 = |sum_a dx_a g_a^T|^2 <= (sum_a |g_a|^2 / m_a) |dx|_M^2 by Cauchy-Schwarz, with g_a the
  // gradient of vertex a's shape function. Hence w_{e,a} = A (2 mu + max(lambda, 0)) |g_a|^2.
  const double modulus = 2.0 * m_settings.mu + std::max(m_settings.lambda, 0.0);
  for (std::size_t e = 0; e < count; ++e) {
    const Triangle& v = m_triangles[e];
    detail::check_element_indices("triangle", e, v, n);
    detail::check_rest_positions("triangle", e, v, rest_x);
    const Mat32 ds = edge_matrix(rest_x, v);
    const Vec3 e1 = ds.col(0);
    const Vec3 e2 = ds.col(1);
    const double area = 0.5 * e1.cross(e2).norm();
    const double longest_sq = std::max({e1.squaredNorm(), e2.squaredNorm(), (e2 - e1).squaredNorm()});
    if (!(area > kDegenerateRelative * longest_sq)) fail("triangle ", e, " is degenerate (area ", area, ")");
    // Frame: first axis along e1, second in-plane and orthogonal to it.
    const double e1_len = e1.norm();
    const double e2_along = e2.dot(e1) / e1_len;
    Mat2 dm;
    dm << e1_len, e2_along, 0.0, 2.0 * area / e1_len;
    m_dm_inv[e] = dm.inverse();
    m_area[e] = area;
    m_F[e] = ds * m_dm_inv[e];
    const Eigen::Vector2d g_b = m_dm_inv[e].row(0).transpose();
    const Eigen::Vector2d g_c = m_dm_inv[e].row(1).transpose();
    m_dt_weights[e] = {area * modulus * (g_b + g_c).squaredNorm(), area * modulus * g_b.squaredNorm(),
                       area * modulus * g_c.squaredNorm()};
  }
  detail::Incidence incidence = detail::Incidence::build(m_triangles, detail::index_span(m_triangles));
  m_incidence_offsets = std::move(incidence.offsets);
  m_incidence = std::move(incidence.elements);
}

void TriangleMembrane::validate(Index particle_count) const {
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    detail::check_element_indices("triangle", e, m_triangles[e], particle_count);
  }
}

void TriangleMembrane::update_position_state(const Vectors3& x) {
  for (std::size_t e = 0; e < m_triangles.size(); ++e) m_F[e] = edge_matrix(x, m_triangles[e]) * m_dm_inv[e];
}

double TriangleMembrane::potential_energy(const Vectors3& x) const {
  const double mu = m_settings.mu;
  const double lambda = m_settings.lambda;
  double energy = 0.0;
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    const Mat32 F = edge_matrix(x, m_triangles[e]) * m_dm_inv[e];
    const Mat2 E = 0.5 * (F.transpose() * F - Mat2::Identity());
    const double tr = E.trace();
    energy += m_area[e] * (mu * E.squaredNorm() + 0.5 * lambda * tr * tr);
  }
  return energy;
}

void TriangleMembrane::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  const double mu = m_settings.mu;
  const double lambda = m_settings.lambda;
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    const Mat32 F = edge_matrix(x, m_triangles[e]) * m_dm_inv[e];
    const Mat2 E = 0.5 * (F.transpose() * F - Mat2::Identity());
    const Mat32 P = F * stress(E, mu, lambda);
    scatter_h(m_triangles[e], (-m_area[e]) * P * m_dm_inv[e].transpose(), f);
  }
}

void TriangleMembrane::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  const double mu = m_settings.mu;
  const double lambda = m_settings.lambda;
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    const Mat32& F = m_F[e];
    const Mat2 E = 0.5 * (F.transpose() * F - Mat2::Identity());
    const Mat32 dF = edge_matrix(dx, m_triangles[e]) * m_dm_inv[e];
    const Mat2 FtdF = F.transpose() * dF;
    const Mat2 dE = 0.5 * (FtdF + FtdF.transpose());
    const Mat32 dP = dF * stress(E, mu, lambda) + F * stress(dE, mu, lambda);
    scatter_h(m_triangles[e], (-m_area[e]) * dP * m_dm_inv[e].transpose(), df);
  }
}

void TriangleMembrane::add_damping_forces(const Vectors3& v, Vectors3& f) const {
  const double beta = m_settings.beta;
  if (beta == 0.0) return;
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    const Mat32& F = m_F[e];
    const Mat32 Fdot = edge_matrix(v, m_triangles[e]) * m_dm_inv[e];
    const Mat2 FtFdot = F.transpose() * Fdot;
    const Mat2 Edot = 0.5 * (FtFdot + FtFdot.transpose());
    const Mat32 Pdot = F * stress(Edot, m_settings.mu, m_settings.lambda);
    scatter_h(m_triangles[e], (-m_area[e] * beta) * Pdot * m_dm_inv[e].transpose(), f);
  }
}

// For vertex a alone moving with v, Fdot = v g_a^T and, with u = F^T v,
//   |Edot|^2 = (|u|^2 |g_a|^2 + (u.g_a)^2) / 2,  tr(Edot) = u.g_a,
// so the trace of the 3x3 block -D_aa is A beta (mu |g_a|^2 |F|_F^2 + (mu + lambda) |F g_a|^2).
void TriangleMembrane::add_diagonal(double b, VectorXd& diag) const {
  (void)b;  // no definite differential: the implicit matrix is D
  const double beta = m_settings.beta;
  if (beta == 0.0) return;
  const double mu = m_settings.mu;
  const double lambda = m_settings.lambda;
  for (std::size_t e = 0; e < m_triangles.size(); ++e) {
    const Mat32& F = m_F[e];
    const double f_sq = F.squaredNorm();
    const Eigen::Vector2d g_b = m_dm_inv[e].row(0).transpose();
    const Eigen::Vector2d g_c = m_dm_inv[e].row(1).transpose();
    const Eigen::Vector2d g[3] = {-(g_b + g_c), g_b, g_c};
    const double scale = m_area[e] * beta / 3.0;
    for (int a = 0; a < 3; ++a) {
      diag[m_triangles[e][static_cast<std::size_t>(a)]] +=
          scale * (mu * g[a].squaredNorm() * f_sq + (mu + lambda) * (F * g[a]).squaredNorm());
    }
  }
}

// Conservative bound from the rest linearisation (weights computed in the constructor, argument in
// element_bound_stable_dt). Stretching stiffens StVK, so a strongly stretched sheet may need a
// smaller step than this.
double TriangleMembrane::stable_dt(const VectorXd& m_eff) const {
  return detail::element_bound_stable_dt(kName, m_triangles, m_dt_weights, m_incidence_offsets, m_incidence, m_eff);
}

Index TriangleMembrane::remove_elements_touching(std::span<const std::uint8_t> removed) {
  return detail::rebuild_without(*this, m_triangles, removed, m_rest_x, m_settings);
}

}  // namespace sinew
