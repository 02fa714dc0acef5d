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

#ifdef __SSE2__
#include <emmintrin.h>
#endif
#include <utility>

namespace sinew {

namespace {
constexpr std::string_view kName = "edge springs";
// An edge shorter than round-off of its coordinates has no usable direction.
constexpr double kZeroLengthRelative = 1.0e-12;
/// An edge's force g (3 doubles) added to its first end's coordinates (offset i in the flat array)
/// and taken from its second's (offset j).
[[gnu::always_inline]] inline void add_to_ends(double* out, Index i, Index j, const double* g) {
  out[i] += g[0];
  out[i + 1] += g[1];
  out[i + 2] += g[2];
  out[j] -= g[0];
  out[j + 1] -= g[1];
  out[j + 2] -= g[2];
}

}  // namespace

EdgeSprings::EdgeSprings(std::vector<Edge> edges, const Vectors3& rest_x, const EdgeSpringsSettings& settings)
    : m_edges(std::move(edges)), m_settings(settings), m_rest_x(rest_x) {
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
  m_implicit_state.resize(edge_count, 4);
  m_implicit_state.leftCols<3>() = m_direction.transpose();
  m_implicit_state.col(3).setZero();
  m_chunks = ChunkedScatter(m_edges, m_index_span);
}

void EdgeSprings::validate(Index particle_count) const {
  for (std::size_t e = 0; e < m_edges.size(); ++e) detail::check_element_indices("edge", e, m_edges[e], particle_count);
}

void EdgeSprings::update_position_state(const Vectors3& x) {
  m_x = x;
  parallel::for_ranges(static_cast<Index>(m_edges.size()), [&](Index e0, Index e1) {
    for (Index e = e0; e < e1; ++e) {
      const Edge& v = m_edges[static_cast<std::size_t>(e)];
      const Vec3 diff = x.col(v[1]) - x.col(v[0]);
      const double l = diff.norm();
      m_length[e] = l;
      m_direction.col(e) = diff / l;
      for (int k = 0; k < 3; ++k) m_implicit_state(e, k) = m_direction(k, e);
      m_implicit_state(e, 3) = std::max(0.0, 1.0 - m_rest_length[e] / l);
    }
  });
}

// Every per-edge loop below computes the force on the edge's first end, f_i (the second end gets
// -f_i), and scatters it straight into the nodes by the fixed chunks of m_chunks.
template <typename EdgeForce>
void EdgeSprings::scatter_edges(Vectors3& f, EdgeForce&& edge_force) const {
  m_chunks.run(f, [&](const ChunkedScatter::Chunk& chunk, double* out) {
    for (Index e = chunk.begin; e < chunk.end; ++e) {
      const Edge& v = m_edges[static_cast<std::size_t>(e)];
      const Vec3 f_i = edge_force(e, v);
      const Index i = 3 * v[0], j = 3 * v[1];
      for (int k = 0; k < 3; ++k) {
        out[i + k] += f_i[k];
        out[j + k] -= f_i[k];
      }
    }
  });
}

double EdgeSprings::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const double stretch = (x.col(m_edges[e][1]) - x.col(m_edges[e][0])).norm() - m_rest_length[static_cast<Index>(e)];
    energy += 0.5 * m_settings.stiffness * stretch * stretch;
  }
  return energy;
}

// f_i = k (l - l0) d, from the cached lengths and directions when x is the cached state (the step
// asks for forces right after update_position_state), else computed the same way from x.
void EdgeSprings::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  const double k = m_settings.stiffness;
  if (x.cols() == m_x.cols() && x == m_x) {
    scatter_edges(
        f, [&](Index e, const Edge&) -> Vec3 { return (k * (m_length[e] - m_rest_length[e])) * m_direction.col(e); });
    return;
  }
  scatter_edges(f, [&](Index e, const Edge& v) -> Vec3 {
    const Vec3 diff = x.col(v[1]) - x.col(v[0]);
    const double l = diff.norm();
    return (k * (l - m_rest_length[e])) * Vec3(diff / l);
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
  scatter_edges(f, [&](Index e, const Edge& ij) -> Vec3 {
    const Vec3 d = m_direction.col(e);
    return (-b * d.dot(v.col(ij[0]) - v.col(ij[1]))) * d;
  });
}

// f_i += [b_d d d^T + b k (d d^T + t+ (I - d d^T))] (v_j - v_i), f_j -= the same, t+ = max(0, 1 - l0/l).
// The hot loop of the implicit solves (once per CG iteration): one pass over the edges' cached
// (d, t+), scattering by the fixed chunks of m_chunks.
void EdgeSprings::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double bk = b * m_settings.stiffness;
  const double along_scale = m_settings.damping + bk;
  if (along_scale == 0.0) return;
  // Raw pointers: Eigen column accessors would reload the arrays' data pointers after every store.
  const Edge* edges = m_edges.data();
  const Index stride = m_implicit_state.rows();
  const double* d0 = m_implicit_state.data();
  const double* d1 = d0 + stride;
  const double* d2 = d1 + stride;
  const double* t = d2 + stride;
  const double* pv = v.data();
  // f_i = a d + bk t+ (dv - along d), a = (b_d + b k) along, along = d.dv, dv = v_j - v_i.
  auto scatter = [&](const ChunkedScatter::Chunk& chunk, double* out) {
    Index e = chunk.begin;
#ifdef __SSE2__
    // Two edges per register, the same IEEE operations in the same order as the scalar loop below
    // (so the same bits); the scatter stays scalar and in edge order.
    const __m128d scale = _mm_set1_pd(along_scale), stiff = _mm_set1_pd(bk);
    auto pair = [&](const double* p, Index first, Index second) {
      return _mm_loadh_pd(_mm_load_sd(p + first), p + second);
    };
    for (; e + 1 < chunk.end; e += 2) {
      const Index i0 = 3 * edges[e][0], j0 = 3 * edges[e][1];
      const Index i1 = 3 * edges[e + 1][0], j1 = 3 * edges[e + 1][1];
      const __m128d dv0 = _mm_sub_pd(pair(pv, j0, j1), pair(pv, i0, i1));
      const __m128d dv1 = _mm_sub_pd(pair(pv + 1, j0, j1), pair(pv + 1, i0, i1));
      const __m128d dv2 = _mm_sub_pd(pair(pv + 2, j0, j1), pair(pv + 2, i0, i1));
      const __m128d s0 = _mm_loadu_pd(d0 + e), s1 = _mm_loadu_pd(d1 + e), s2 = _mm_loadu_pd(d2 + e);
      const __m128d along = _mm_add_pd(_mm_add_pd(_mm_mul_pd(s0, dv0), _mm_mul_pd(s1, dv1)), _mm_mul_pd(s2, dv2));
      const __m128d transverse = _mm_mul_pd(stiff, _mm_loadu_pd(t + e));
      const __m128d a = _mm_mul_pd(scale, along);
      const __m128d f0 = _mm_add_pd(_mm_mul_pd(a, s0), _mm_mul_pd(transverse, _mm_sub_pd(dv0, _mm_mul_pd(along, s0))));
      const __m128d f1 = _mm_add_pd(_mm_mul_pd(a, s1), _mm_mul_pd(transverse, _mm_sub_pd(dv1, _mm_mul_pd(along, s1))));
      const __m128d f2 = _mm_add_pd(_mm_mul_pd(a, s2), _mm_mul_pd(transverse, _mm_sub_pd(dv2, _mm_mul_pd(along, s2))));
      double g[6];
      _mm_storeu_pd(g, _mm_unpacklo_pd(f0, f1));        // edge e: f0, f1
      _mm_storeu_pd(g + 2, _mm_shuffle_pd(f2, f0, 2));  // edge e: f2; edge e + 1: f0
      _mm_storeu_pd(g + 4, _mm_unpackhi_pd(f1, f2));    // edge e + 1: f1, f2
      add_to_ends(out, i0, j0, g);
      add_to_ends(out, i1, j1, g + 3);
    }
#endif
    for (; e < chunk.end; ++e) {
      const Index i = 3 * edges[e][0], j = 3 * edges[e][1];
      const double dv0 = pv[j] - pv[i], dv1 = pv[j + 1] - pv[i + 1], dv2 = pv[j + 2] - pv[i + 2];
      const double along = (d0[e] * dv0 + d1[e] * dv1) + d2[e] * dv2;
      const double transverse = bk * t[e];
      const double a = along_scale * along;
      const double f0 = a * d0[e] + transverse * (dv0 - along * d0[e]);
      const double f1 = a * d1[e] + transverse * (dv1 - along * d1[e]);
      const double f2 = a * d2[e] + transverse * (dv2 - along * d2[e]);
      out[i] += f0;
      out[i + 1] += f1;
      out[i + 2] += f2;
      out[j] -= f0;
      out[j + 1] -= f1;
      out[j + 2] -= f2;
    }
  };
  m_chunks.run(f, scatter);
}

// The diagonal block of both ends is b_d d d^T + b k (d d^T + t+ (I - d d^T)) (see
// add_diagonal_blocks), whose trace is b_d + b k (1 + 2 t+) for a unit d.
void EdgeSprings::add_diagonal(double b, VectorXd& diag) const {
  const double bk = b * m_settings.stiffness;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const auto ei = static_cast<Index>(e);
    const double transverse = std::max(0.0, 1.0 - m_rest_length[ei] / m_length[ei]);
    const double d = (m_settings.damping + bk * (1.0 + 2.0 * transverse)) / 3.0;
    diag[m_edges[e][0]] += d;
    diag[m_edges[e][1]] += d;
  }
}

// Both ends' diagonal block is b_d d d^T + b k (d d^T + t+ (I - d d^T)), the edge's implicit
// product matrix (the product's coupling block is its negative).
bool EdgeSprings::add_diagonal_blocks(double b, Blocks& blocks) const {
  if (m_settings.damping + b * m_settings.stiffness == 0.0) return true;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const Mat3 block = implicit_block(static_cast<Index>(e), b);
    for (Index i : m_edges[e]) blocks.col(i) += Eigen::Map<const Eigen::Matrix<double, 9, 1>>(block.data());
  }
  return true;
}

Mat3 EdgeSprings::implicit_block(Index e, double b) const {
  const double bk = b * m_settings.stiffness;
  const Vec3 d = m_direction.col(e);
  const double transverse = bk * m_implicit_state(e, 3);
  Mat3 block = (m_settings.damping + bk - transverse) * (d * d.transpose());
  block.diagonal().array() += transverse;
  return block;
}

// The coupling block of edge (i, j) is the edge's implicit product matrix itself (f_i += B (v_j - v_i)).
bool EdgeSprings::visit_pair_blocks(double b, PairBlockSink& sink) const {
  for (std::size_t e = 0; e < m_edges.size(); ++e)
    sink.add(m_edges[e][0], m_edges[e][1], implicit_block(static_cast<Index>(e), b));
  return true;
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

double EdgeSprings::turn_work_rate(const Vectors3& x, const Vectors3& v) const {
  // A spring of tension T and length l turning at rate w: over a step dt its linearised force misses
  // the arc by l (1 - cos(w dt)) ~ l (w dt)^2 / 2 along its direction, T l w^2 / 2 per dt^2.
  double sum = 0.0;
  const double k = m_settings.stiffness;
  for (std::size_t e = 0; e < m_edges.size(); ++e) {
    const Vec3 dx = x.col(m_edges[e][1]) - x.col(m_edges[e][0]);
    const double length = dx.norm();
    const double tension = k * (length - m_rest_length[Index(e)]);
    if (!(tension > 0.0)) continue;
    const Vec3 d = dx / length;
    const Vec3 dv = v.col(m_edges[e][1]) - v.col(m_edges[e][0]);
    const double rate_sq = (dv - d * d.dot(dv)).squaredNorm() / (length * length);
    sum += 0.5 * tension * length * rate_sq;
  }
  return sum;
}

Index EdgeSprings::remove_elements_touching(std::span<const std::uint8_t> removed) {
  return detail::rebuild_without(*this, m_edges, removed, m_rest_x, m_settings);
}

}  // namespace sinew
