// Corotated linear elasticity on linear tets with inversion handling (Irving, Teran and Fedkiw
// 2004, "Invertible finite elements for robust simulation of large deformation", sections 4-5;
// the differential in the SVD frame follows Teran, Sifakis, Irving and Fedkiw 2005, section 5).
//
// With Ds = [x1 - x0, x2 - x0, x3 - x0], F = Ds Dm^-1 = U Sigma V^T (signed SVD: U, V rotations,
// the smallest singular value negative when det F < 0), and V_e the rest volume:
//   Psi    = V_e [mu sum_i (sigma_i - 1)^2 + lambda/2 (sum_i sigma_i - 3)^2]
//   Phat_i = 2 mu (sigma_i - 1) + lambda (sum_k sigma_k - 3),   P = U Phat V^T
//   [f1 f2 f3] = -V_e P Dm^-T,   f0 = -(f1 + f2 + f3)
// The signed SVD makes Psi a function of F that keeps growing through inversion, so an inverted
// tet is pushed back through its smallest stretch instead of settling as a reflected copy.
//
// Differential, dFhat = U^T dF V, dP = U dPhat V^T (corotated_stress.hpp).
//
// Damping is stiffness-proportional in strain-rate form with the rotation frozen at R = U V^T:
//   D(v) = V_e beta (mu |Edot|^2 + lambda/2 tr(Edot)^2),  Edot = sym(R^T Fdot),  Fdot = Vs Dm^-1,
//   f = -dD/dv = -V_e beta R (2 mu Edot + lambda tr(Edot) I) Dm^-T,
// a positive semi-definite form in v (lambda > -2 mu / 3 since nu > -1), so D is symmetric negative
// semi-definite; rigid motion (R^T Fdot skew) is not damped. At rest it is exactly -beta K.
#include "sinew/forces/corotated_tets.hpp"

#include "corotated_stress.hpp"
#include "element_support.hpp"
#include "signed_svd.hpp"

#include <algorithm>
#include <cstring>
#include <limits>
#include <utility>

namespace sinew {

namespace {

constexpr std::string_view kName = "corotated tets";
// A tet whose volume is at round-off level of its longest edge cubed has no usable Dm^-1.
constexpr double kDegenerateRelative = 1.0e-12;

Mat3 edge_matrix(const Vectors3& x, const std::array<Index, 4>& v) {
  Mat3 ds;
  ds.col(0) = x.col(v[1]) - x.col(v[0]);
  ds.col(1) = x.col(v[2]) - x.col(v[0]);
  ds.col(2) = x.col(v[3]) - x.col(v[0]);
  return ds;
}

/// Scatters H = [f1 f2 f3] (3x3) to the four vertices, f0 = -(f1 + f2 + f3).
void scatter_h(const std::array<Index, 4>& v, const Mat3& h, double* out) {
  const Vec3 first = h.rowwise().sum();
  for (int k = 0; k < 3; ++k) {
    out[3 * v[0] + k] -= first[k];
    out[3 * v[1] + k] += h(k, 0);
    out[3 * v[2] + k] += h(k, 1);
    out[3 * v[3] + k] += h(k, 2);
  }
}

// Equal to the bit: F == G would take -0 for +0, whose SVDs may differ in sign choices.
bool same_bits(const Mat3& F, const Mat3& G) { return std::memcmp(F.data(), G.data(), sizeof(double) * 9) == 0; }

// P = U P^ V^T, evaluated one way for every caller: Eigen evaluates the same product with different
// roundings when it is assigned to an existing matrix rather than constructed, and cached and fresh
// stresses must agree to the bit (runs are compared by state hashes).
Mat3 first_piola(const Mat3& U, const Vec3& phat, const Mat3& V) {
  Mat3 P = U * phat.asDiagonal() * V.transpose();
  return P;
}

}  // namespace

CorotatedTets::CorotatedTets(std::vector<Tet> tets, const Vectors3& rest_x, const CorotatedTetsSettings& settings)
    : m_tets(std::move(tets)), m_settings(settings), m_rest_x(rest_x) {
  detail::check_non_negative(kName, "young_modulus", m_settings.young_modulus);
  if (m_settings.young_modulus == 0.0) fail(kName, ": young_modulus is 0, expected > 0");
  const double nu = m_settings.poisson_ratio;
  if (std::isnan(nu)) fail(kName, ": poisson_ratio is nan");
  if (!(nu > -1.0 && nu < 0.5)) fail(kName, ": poisson_ratio ", nu, " is outside (-1, 0.5)");
  detail::check_non_negative(kName, "beta", m_settings.beta);
  const double young = m_settings.young_modulus;
  m_mu = young / (2.0 * (1.0 + nu));
  m_lambda = young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));

  const Index n = rest_x.cols();
  const std::size_t count = m_tets.size();
  const std::vector<double>& fraction = m_settings.volume_fraction;
  if (!fraction.empty() && fraction.size() != count)
    fail(kName, ": volume_fraction has ", fraction.size(), " entries for ", count, " tets");
  for (std::size_t e = 0; e < fraction.size(); ++e)
    if (!(fraction[e] > 0.0 && fraction[e] <= 1.0))
      fail(kName, ": tet ", e, " has volume_fraction ", fraction[e], ", expected in (0, 1]");
  m_dm_inv.resize(count);
  m_volume.resize(count);
  m_dt_weights.resize(count);
  m_state.resize(count);
  // Rest stiffness bound (see element_bound_stable_dt): at rest F = I and
  //   dx^T K_e dx = V_e (2 mu |sym dF|^2 + lambda tr(dF)^2) <= V_e (2 mu + max(lambda, 0)) |dF|^2,
  // the P-wave modulus, and |dF|^2 = |sum_a dx_a g_a^T|^2 <= (sum_a |g_a|^2 / m_a) |dx|_M^2 by
  // Cauchy-Schwarz, with |g_a| = 1 / (altitude at vertex a). Hence w_{e,a} = V_e (2 mu + lambda+) |g_a|^2.
  const double modulus = 2.0 * m_mu + std::max(m_lambda, 0.0);
  for (std::size_t e = 0; e < count; ++e) {
    const Tet& v = m_tets[e];
    detail::check_element_indices("tet", e, v, n);
    detail::check_rest_positions("tet", e, v, rest_x);
    const Mat3 dm = edge_matrix(rest_x, v);
    const double volume = dm.determinant() / 6.0;
    const double longest =
        std::max({dm.col(0).norm(), dm.col(1).norm(), dm.col(2).norm(), (dm.col(1) - dm.col(0)).norm(),
                  (dm.col(2) - dm.col(0)).norm(), (dm.col(2) - dm.col(1)).norm()});
    const double threshold = kDegenerateRelative * longest * longest * longest;
    if (volume < -threshold) fail("tet ", e, " is inverted (volume ", volume, ")");
    if (!(volume > threshold)) fail("tet ", e, " is degenerate (volume ", volume, ")");
    m_dm_inv[e] = dm.inverse();
    const double material = volume * (fraction.empty() ? 1.0 : fraction[e]);
    m_volume[e] = material;
    m_state[e] = {Mat3::Constant(std::numeric_limits<double>::quiet_NaN()),
                  Mat3::Identity(),
                  Mat3::Identity(),
                  Mat3::Identity(),
                  Vec3::Ones(),
                  Vec3::Zero()};
    const Mat3& g = m_dm_inv[e];  // rows 0-2: shape-function gradients of vertices 1-3
    m_dt_weights[e] = {material * modulus * g.colwise().sum().squaredNorm(),
                       material * modulus * g.row(0).squaredNorm(), material * modulus * g.row(1).squaredNorm(),
                       material * modulus * g.row(2).squaredNorm()};
  }
  detail::Incidence incidence = detail::Incidence::build(m_tets, detail::index_span(m_tets));
  m_incidence_offsets = std::move(incidence.offsets);
  m_incidence = std::move(incidence.elements);
  m_chunks = ChunkedScatter(m_tets, detail::index_span(m_tets));
}

void CorotatedTets::validate(Index particle_count) const {
  for (std::size_t e = 0; e < m_tets.size(); ++e) detail::check_element_indices("tet", e, m_tets[e], particle_count);
}

// The SVD of F is most of this force's cost (three quarters of a soft ball's step), and the step asks
// for it several times at the same positions (update_position_state, then the forces, the energy
// checks): each tet keeps the F its state was computed from and reuses it when F is the same to the
// bit, which gives exactly the bits a new SVD would.
void CorotatedTets::update_position_state(const Vectors3& x) {
  // Each tet writes its own state only: any partition gives the same bits.
  parallel::for_ranges(static_cast<Index>(m_tets.size()), [&](Index begin, Index end) {
    for (std::size_t e = static_cast<std::size_t>(begin); e < static_cast<std::size_t>(end); ++e) {
      const Mat3 F = edge_matrix(x, m_tets[e]) * m_dm_inv[e];
      TetState& s = m_state[e];
      if (same_bits(F, s.F)) continue;
      const detail::SignedSvd svd = detail::signed_svd(F);
      s.F = F;
      s.U = svd.U;
      s.V = svd.V;
      s.R = svd.U * svd.V.transpose();
      s.sigma = svd.sigma;
      s.phat = detail::corotated_diagonal_stress(svd.sigma, m_mu, m_lambda);
    }
  });
}

double CorotatedTets::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t e = 0; e < m_tets.size(); ++e) {
    const Mat3 F = edge_matrix(x, m_tets[e]) * m_dm_inv[e];
    const Vec3 sigma = same_bits(F, m_state[e].F) ? m_state[e].sigma : detail::signed_svd(F).sigma;
    energy += m_volume[e] * detail::corotated_energy_density(sigma, m_mu, m_lambda);
  }
  return energy;
}

void CorotatedTets::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  for_each_tet(f, [&](std::size_t e) {
    const Mat3 F = edge_matrix(x, m_tets[e]) * m_dm_inv[e];
    const TetState& s = m_state[e];
    const Mat3 P = same_bits(F, s.F) ? first_piola(s.U, s.phat, s.V) : [&] {
      const detail::SignedSvd svd = detail::signed_svd(F);
      return first_piola(svd.U, detail::corotated_diagonal_stress(svd.sigma, m_mu, m_lambda), svd.V);
    }();
    return Mat3((-m_volume[e]) * P * m_dm_inv[e].transpose());
  });
}

void CorotatedTets::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  for_each_tet(df, [&](std::size_t e) {
    const TetState& s = m_state[e];
    const Mat3 dF_hat = s.U.transpose() * (edge_matrix(dx, m_tets[e]) * m_dm_inv[e]) * s.V;
    const Mat3 dP_hat = detail::corotated_stress_differential(dF_hat, s.sigma, s.phat, m_mu, m_lambda);
    const Mat3 dP = s.U * dP_hat * s.V.transpose();
    return Mat3((-m_volume[e]) * dP * m_dm_inv[e].transpose());
  });
}

void CorotatedTets::add_damping_forces(const Vectors3& v, Vectors3& f) const { add_implicit_products(v, 0.0, f); }

// f += -(beta + b) V R (2 mu sym(R^T Fdot) + lambda tr(R^T Fdot) I) Dm^-T per tet: D v + b K+ v.
void CorotatedTets::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double scale = m_settings.beta + (m_settings.implicit ? b : 0.0);
  if (scale == 0.0) return;
  for_each_tet(f, [&](std::size_t e) {
    const Mat3& R = m_state[e].R;
    const Mat3 RtFdot = R.transpose() * (edge_matrix(v, m_tets[e]) * m_dm_inv[e]);
    const Mat3 Edot = 0.5 * (RtFdot + RtFdot.transpose());
    const Mat3 Sdot = 2.0 * m_mu * Edot + (m_lambda * Edot.trace()) * Mat3::Identity();
    return Mat3((-m_volume[e] * scale) * R * Sdot * m_dm_inv[e].transpose());
  });
}

template <typename TetTerm>
void CorotatedTets::for_each_tet(Vectors3& f, TetTerm&& term) const {
  m_chunks.run(f, [&](const ChunkedScatter::Chunk& chunk, double* out) {
    for (Index e = chunk.begin; e < chunk.end; ++e)
      scatter_h(m_tets[static_cast<std::size_t>(e)], term(static_cast<std::size_t>(e)), out);
  });
}

// For vertex a alone moving with v, Fdot = v g_a^T and, with u = R^T v (|u| = |v|),
//   |Edot|^2 = (|u|^2 |g_a|^2 + (u.g_a)^2) / 2,  tr(Edot) = u.g_a,
// so the trace of the 3x3 block -D_aa is V_e beta |g_a|^2 (3 mu + mu + lambda), independent of R.
void CorotatedTets::add_diagonal(double b, VectorXd& diag) const {
  const double beta = m_settings.beta + (m_settings.implicit ? b : 0.0);  // D + b K+: the same operator
  if (beta == 0.0) return;
  const double modulus = 4.0 * m_mu + m_lambda;
  for (std::size_t e = 0; e < m_tets.size(); ++e) {
    const Mat3& g = m_dm_inv[e];
    const double scale = m_volume[e] * beta * modulus / 3.0;
    const Tet& v = m_tets[e];
    diag[v[0]] += scale * g.colwise().sum().squaredNorm();
    diag[v[1]] += scale * g.row(0).squaredNorm();
    diag[v[2]] += scale * g.row(1).squaredNorm();
    diag[v[3]] += scale * g.row(2).squaredNorm();
  }
}

// Conservative bound from the rest linearisation (P-wave modulus over squared altitudes, argument
// in the constructor and element_bound_stable_dt); large compression or stretch can change the
// stiffness, which this estimate ignores.
double CorotatedTets::stable_dt(const VectorXd& m_eff) const {
  return detail::element_bound_stable_dt(kName, m_tets, m_dt_weights, m_incidence_offsets, m_incidence, m_eff);
}

Index CorotatedTets::remove_elements_touching(std::span<const std::uint8_t> removed) {
  if (m_settings.volume_fraction.empty()) return detail::rebuild_without(*this, m_tets, removed, m_rest_x, m_settings);
  // The kept tets keep their fractions.
  auto gone = [&](Index i) {
    return i < static_cast<Index>(removed.size()) && removed[static_cast<std::size_t>(i)] != 0;
  };
  std::vector<Tet> kept;
  CorotatedTetsSettings settings = m_settings;
  settings.volume_fraction.clear();
  for (std::size_t e = 0; e < m_tets.size(); ++e)
    if (std::none_of(m_tets[e].begin(), m_tets[e].end(), gone)) {
      kept.push_back(m_tets[e]);
      settings.volume_fraction.push_back(m_settings.volume_fraction[e]);
    }
  const auto dropped = static_cast<Index>(m_tets.size() - kept.size());
  if (dropped > 0) *this = CorotatedTets(std::move(kept), m_rest_x, settings);
  return dropped;
}

}  // namespace sinew
