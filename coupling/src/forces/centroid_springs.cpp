// Centroid springs: a particle p tied to the centroid of its neighbourhood N (n = |N| nodes), the
// variable-stencil recipe (an element is a Stencils row, scattered through ChunkedScatter).
//
// With weights w_p = 1 and w_j = -1/n (j in N), d = sum_a w_a x_a = x_p - c, l = |d|, u = d / l:
//   Psi   = k/2 (l - l0)^2
//   f_a   = -w_a k (l - l0) u                                  (sum_a w_a = 0: forces balance)
//   df_a  = -w_a k [u u^T + (1 - l0/l)(I - u u^T)] sum_c w_c dx_c
// an edge spring's differential (edge_springs.cpp) on the weighted difference. As there, the
// transverse factor is negative under compression, so the definite differential K+ clamps it at 0.
// Damping along u, f_a = -w_a b_d u u^T sum_c w_c v_c, is symmetric negative semi-definite
// (v^T D v = -b_d (u . sum_c w_c v_c)^2). Both enter the implicit solves of eq. 6-8 of Sifakis
// et al. 2007 through the products and the blocks -(D + b K+)_ac = w_a w_c B (see element_block).
#include "sinew/forces/centroid_springs.hpp"

#include "element_support.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

namespace sinew {

namespace {
constexpr std::string_view kName = "centroid springs";
// A rest distance below round-off of the coordinates has no usable direction.
constexpr double kZeroLengthRelative = 1.0e-12;

void check_stencil(const Stencils& stencils, Index e, Index particle_count) {
  const auto nodes = stencils[e];
  if (nodes.size() < 2)
    fail(kName, ": element ", e, " has ", nodes.size(), " nodes, expected a particle and at least one neighbour");
  for (std::size_t a = 0; a < nodes.size(); ++a) {
    if (nodes[a] < 0 || nodes[a] >= particle_count)
      fail(kName, ": element ", e, ": node index ", nodes[a], " out of range [0, ", particle_count, ")");
    for (std::size_t c = 0; c < a; ++c)
      if (nodes[a] == nodes[c]) fail(kName, ": element ", e, ": node index ", nodes[a], " is repeated");
  }
}
}  // namespace

CentroidSprings::CentroidSprings(Stencils stencils, const Vectors3& rest_x, const CentroidSpringsSettings& settings)
    : m_stencils(std::move(stencils)), m_settings(settings), m_rest_x(rest_x) {
  detail::check_non_negative(kName, "stiffness", m_settings.stiffness);
  detail::check_non_negative(kName, "damping", m_settings.damping);
  const Index count = m_stencils.size(), n = rest_x.cols();
  m_rest_length.resize(count);
  m_direction.resize(3, count);
  m_length.resize(count);
  m_transverse.setZero(count);
  m_weight_sum.setZero(n);
  m_pair_offset.assign(1, 0);
  for (Index e = 0; e < count; ++e) {
    check_stencil(m_stencils, e, n);
    const auto nodes = m_stencils[e];
    double scale = 0.0;
    for (std::size_t a = 0; a < nodes.size(); ++a) {
      if (!rest_x.col(nodes[a]).allFinite())
        fail(kName, ": element ", e, ": rest position of node ", nodes[a], " is not finite");
      scale = std::max(scale, rest_x.col(nodes[a]).cwiseAbs().maxCoeff());
      m_weight_sum[nodes[a]] += std::abs(weight(e, a));
      m_index_span = std::max(m_index_span, nodes[a] + 1);
    }
    const Vec3 d = weighted_sum(e, rest_x);
    const double l0 = d.norm();
    if (!(l0 > kZeroLengthRelative * scale) || l0 == 0.0)
      fail(kName, ": element ", e, " has zero rest length (", l0, ")");
    m_rest_length[e] = l0;
    m_length[e] = l0;
    m_direction.col(e) = d / l0;
    const auto s = static_cast<Index>(nodes.size());
    m_pair_offset.push_back(m_pair_offset.back() + s * (s - 1) / 2);
  }
  m_chunks = ChunkedScatter(m_stencils, m_index_span);
}

void CentroidSprings::validate(Index particle_count) const {
  for (Index e = 0; e < m_stencils.size(); ++e) check_stencil(m_stencils, e, particle_count);
}

double CentroidSprings::weight(Index e, std::size_t a) const {
  return a == 0 ? 1.0 : -1.0 / static_cast<double>(m_stencils[e].size() - 1);
}

Vec3 CentroidSprings::weighted_sum(Index e, const Vectors3& y) const {
  const auto nodes = m_stencils[e];
  Vec3 neighbours = Vec3::Zero();
  for (std::size_t a = 1; a < nodes.size(); ++a) neighbours += y.col(nodes[a]);
  return Vec3(y.col(nodes[0])) + weight(e, 1) * neighbours;
}

void CentroidSprings::update_position_state(const Vectors3& x) {
  parallel::for_ranges(m_stencils.size(), [&](Index e0, Index e1) {
    for (Index e = e0; e < e1; ++e) {
      const Vec3 d = weighted_sum(e, x);
      const double l = d.norm();
      m_length[e] = l;
      m_direction.col(e) = d / l;
      m_transverse[e] = std::max(0.0, 1.0 - m_rest_length[e] / l);
    }
  });
}

// Every loop below computes g = d Psi_e / d d per element and adds -w_a g into its node a, by the
// fixed chunks of m_chunks (the same sums on any thread count).
template <typename ElementTerm>
void CentroidSprings::scatter(Vectors3& f, ElementTerm&& element_term) const {
  m_chunks.run(f, [&](const ChunkedScatter::Chunk& chunk, double* out) {
    for (Index e = chunk.begin; e < chunk.end; ++e) {
      const Vec3 g = element_term(e);
      const auto nodes = m_stencils[e];
      for (std::size_t a = 0; a < nodes.size(); ++a) {
        const double w = weight(e, a);
        for (int k = 0; k < 3; ++k) out[3 * nodes[a] + k] -= w * g[k];
      }
    }
  });
}

double CentroidSprings::potential_energy(const Vectors3& x) const {
  return parallel::sum(m_stencils.size(), [&](Index e) {
    const double stretch = weighted_sum(e, x).norm() - m_rest_length[e];
    return 0.5 * m_settings.stiffness * stretch * stretch;
  });
}

void CentroidSprings::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  const double k = m_settings.stiffness;
  scatter(f, [&](Index e) -> Vec3 {
    const Vec3 d = weighted_sum(e, x);
    const double l = d.norm();
    return (k * (l - m_rest_length[e]) / l) * d;
  });
}

void CentroidSprings::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  const double k = m_settings.stiffness;
  scatter(df, [&](Index e) -> Vec3 {
    const Vec3 u = m_direction.col(e), dd = weighted_sum(e, dx);
    const double along = u.dot(dd), transverse = 1.0 - m_rest_length[e] / m_length[e];
    return k * (along * u + transverse * (dd - along * u));
  });
}

void CentroidSprings::add_damping_forces(const Vectors3& v, Vectors3& f) const {
  if (m_settings.damping == 0.0) return;
  scatter(f, [&](Index e) -> Vec3 {
    const Vec3 u = m_direction.col(e);
    return (m_settings.damping * u.dot(weighted_sum(e, v))) * u;
  });
}

void CentroidSprings::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double bk = b * m_settings.stiffness;
  if (m_settings.damping + bk == 0.0) return;
  scatter(f, [&](Index e) -> Vec3 {
    const Vec3 u = m_direction.col(e), dv = weighted_sum(e, v);
    const double along = u.dot(dv);
    return (m_settings.damping + bk) * along * u + bk * m_transverse[e] * (dv - along * u);
  });
}

Mat3 CentroidSprings::element_block(Index e, double b) const {
  const double bk = b * m_settings.stiffness;
  const Vec3 u = m_direction.col(e);
  const double transverse = bk * m_transverse[e];
  Mat3 block = (m_settings.damping + bk - transverse) * (u * u.transpose());
  block.diagonal().array() += transverse;
  return block;
}

// The trace of w_a^2 B is w_a^2 (b_d + b k (1 + 2 t+)).
void CentroidSprings::add_diagonal(double b, VectorXd& diag) const {
  const double bk = b * m_settings.stiffness;
  for (Index e = 0; e < m_stencils.size(); ++e) {
    const double trace = m_settings.damping + bk * (1.0 + 2.0 * m_transverse[e]);
    const auto nodes = m_stencils[e];
    for (std::size_t a = 0; a < nodes.size(); ++a) diag[nodes[a]] += weight(e, a) * weight(e, a) * trace / 3.0;
  }
}

bool CentroidSprings::add_diagonal_blocks(double b, Blocks& blocks) const {
  for (Index e = 0; e < m_stencils.size(); ++e) {
    const Mat3 block = element_block(e, b);
    const auto nodes = m_stencils[e];
    for (std::size_t a = 0; a < nodes.size(); ++a)
      blocks.col(nodes[a]) +=
          Eigen::Map<const Eigen::Matrix<double, 9, 1>>(Mat3(weight(e, a) * weight(e, a) * block).data());
  }
  return true;
}

// Element e's pairs (a, c), a < c in stencil order: (D + b K+)_ac = -w_a w_c B.
bool CentroidSprings::visit_pair_blocks(double b, PairBlockSink& sink) const {
  for (Index e = 0; e < m_stencils.size(); ++e) {
    const Mat3 block = element_block(e, b);
    const auto nodes = m_stencils[e];
    for (std::size_t a = 0; a < nodes.size(); ++a)
      for (std::size_t c = a + 1; c < nodes.size(); ++c)
        sink.add(nodes[a], nodes[c], Mat3(-(weight(e, a) * weight(e, c)) * block));
  }
  return true;
}

// Block k of the visit's sequence: its element by bisection of the pair offsets, then its pair.
Mat3 CentroidSprings::pair_block(Index k, double b) const {
  const auto e =
      static_cast<Index>(std::upper_bound(m_pair_offset.begin(), m_pair_offset.end(), k) - m_pair_offset.begin()) - 1;
  const auto s = m_stencils[e].size();
  Index local = k - m_pair_offset[static_cast<std::size_t>(e)];
  std::size_t a = 0;
  while (local >= static_cast<Index>(s - 1 - a)) local -= static_cast<Index>(s - 1 - a++);
  const std::size_t c = a + 1 + static_cast<std::size_t>(local);
  return Mat3(-(weight(e, a) * weight(e, c)) * element_block(e, b));
}

// Block Gershgorin on M^-1 K at rest (t = 0): element e's block (a, c) is k w_a w_c u u^T, of norm
// k |w_a| |w_c|, so node a's row sums to k |w_a| sum_c |w_c| = 2 k |w_a| (sum_c |w_c| = 1 + n / n).
// Rows with m = inf or 0 are skipped, as in edge_springs.cpp.
double CentroidSprings::stable_dt(const VectorXd& m_eff) const {
  detail::check_mass_count(kName, m_eff, m_index_span);
  double omega_sq = 0.0;
  for (Index i = 0; i < m_index_span; ++i)
    omega_sq = std::max(omega_sq, 2.0 * m_settings.stiffness * m_weight_sum[i] * detail::inverse_mass(m_eff[i]));
  return omega_sq > 0.0 ? 2.0 / std::sqrt(omega_sq) : kInfinity;
}

Index CentroidSprings::remove_elements_touching(std::span<const std::uint8_t> removed) {
  return detail::rebuild_without(*this, m_stencils, removed, m_rest_x, m_settings);
}

}  // namespace sinew
