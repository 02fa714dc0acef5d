// Dihedral-angle bending: discrete shells (Grinspun, Hirani, Desbrun and Schroeder 2003, eq. 3-4)
// with the angle gradient of Bridson, Marino and Fedkiw 2003 (section 4).
//
// Per hinge, with w = 3 |e0|^2 / (A1 + A2) (rest edge and rest wing areas) and
// delta = theta - theta0 wrapped to [-pi, pi]:
//   Psi  = k_b w delta^2
//   f    = -2 k_b w delta g,     g = d theta / dx  (12-vector)
//   df   = -2 k_b w (g g^T + delta d^2 theta / dx^2) dx
// With e = x1 - x0, n1 = e x (x2 - x0), n2 = (x3 - x0) x e (Bridson's u_i up to sign):
//   g2 = -|e| n1 / |n1|^2,   g3 = -|e| n2 / |n2|^2,
//   g0 = ((x2 - x1).e / |e|^2) g2 + ((x3 - x1).e / |e|^2) g3,
//   g1 = ((x0 - x2).e / |e|^2) g2 + ((x0 - x3).e / |e|^2) g3,
// which sum to zero and annihilate rotations, as an angle's gradient must.
// theta = atan2(sin, cos) of the normals rather than acos(n1.n2) keeps full precision near flat
// (where acos loses half the digits) and near fully folded, and gives the sign.
//
// The differential is forward-mode automatic differentiation of this same force kernel with a dual
// number seeded by dx: exact to round-off without a hand-written Hessian of theta (Tamstorf and
// Grinspun 2013 give one), and elastic forces are explicit in the step, so its cost is off the hot
// path. Wrapping delta only shifts it by a constant, so it does not change the derivative; it puts
// the energy's one discontinuity opposite the rest angle instead of at theta = +-pi.
//
// Damping penalises the angle rate, D(v) = c w (g.v)^2 / 2, f = -c w g g^T v: symmetric negative
// semi-definite and blind to rigid motion (g is orthogonal to translations and rotations).
#include "sinew/forces/dihedral_bending.hpp"

#include "dual.hpp"
#include "element_support.hpp"

#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <numbers>
#include <tuple>
#include <utility>

namespace sinew {

namespace {

using detail::Dual;
using detail::Vec;
using Mat34 = Eigen::Matrix<double, 3, 4>;

constexpr std::string_view kName = "dihedral bending";
constexpr double kDegenerateRelative = 1.0e-12;

template <typename T>
struct HingeKinematics {
  T delta;  ///< theta - theta0 in (-pi, pi]
  Vec<T> grad[4];
};

/// atan2(y, x) for the angle difference: for |y| <= x / 8 (within 7.1 degrees of the rest angle,
/// where a cloth's hinges spend nearly all their time) the odd Taylor series of atan(y / x) to
/// t^17, whose first omitted term is below 3e-18 of the result (under a fiftieth of an ulp); else,
/// and for non-finite input, the library's atan2. About four times cheaper than atan2 on the common
/// path, which made atan2 a third of the bending force's cost.
constexpr double kAtanSeries[9] = {1.0 / 17.0, -1.0 / 15.0, 1.0 / 13.0, -1.0 / 11.0, 1.0 / 9.0,
                                   -1.0 / 7.0, 1.0 / 5.0,   -1.0 / 3.0, 1.0};
double angle_of(double y, double x) {
  if (x > 0.0 && std::abs(y) <= 0.125 * x) {
    const double t = y / x, z = t * t;
    double p = kAtanSeries[0];
    for (int c = 1; c < 9; ++c) p = p * z + kAtanSeries[c];
    return t * p;
  }
  return std::atan2(y, x);
}
Dual angle_of(Dual y, Dual x) { return atan2(y, x); }

template <typename T>
T hinge_angle(const Vec<T> (&p)[4]) {
  const Vec<T> e = p[1] - p[0];
  const Vec<T> n1 = cross(e, p[2] - p[0]);
  const Vec<T> n2 = cross(p[3] - p[0], e);
  using std::atan2;
  using std::sqrt;
  return atan2(dot(cross(n1, n2), e), dot(n1, n2) * sqrt(dot(e, e)));
}

/// The kinematics at positions p of a hinge whose rest angle is theta0 = atan2(rest_sin, rest_cos)
/// (any positive multiple of (cos theta0, sin theta0)).
template <typename T>
HingeKinematics<T> hinge_kinematics(const Vec<T> (&p)[4], const T& rest_cos, const T& rest_sin) {
  using std::sqrt;
  const Vec<T> e = p[1] - p[0];
  const T e_sq = dot(e, e);
  const T e_len = sqrt(e_sq);
  const Vec<T> n1 = cross(e, p[2] - p[0]);
  const Vec<T> n2 = cross(p[3] - p[0], e);
  HingeKinematics<T> k;
  using std::atan2;
  // sin and cos of theta times |n1| |n2| |e| (the angle needs only their ratio: no division by |e|),
  // turned back by theta0: sin and cos of delta, up to the same positive factor.
  const T sin_theta = dot(cross(n1, n2), e), cos_theta = dot(n1, n2) * e_len;
  k.delta = angle_of(sin_theta * rest_cos - cos_theta * rest_sin, cos_theta * rest_cos + sin_theta * rest_sin);
  const Vec<T> g2 = n1 * (-e_len / dot(n1, n1));
  const Vec<T> g3 = n2 * (-e_len / dot(n2, n2));
  const T inv_e_sq = T(1.0) / e_sq;
  k.grad[0] = g2 * (dot(p[2] - p[1], e) * inv_e_sq) + g3 * (dot(p[3] - p[1], e) * inv_e_sq);
  k.grad[1] = g2 * (dot(p[0] - p[2], e) * inv_e_sq) + g3 * (dot(p[0] - p[3], e) * inv_e_sq);
  k.grad[2] = g2;
  k.grad[3] = g3;
  return k;
}

/// theta - theta0 wrapped to [-pi, pi] (see the comment at the top). Both angles lie in (-pi, pi], so
/// one shift by 2 pi is enough (cheaper than std::remainder on the hot path).
double wrapped_difference(double theta, double theta0) {
  constexpr double pi = std::numbers::pi;
  const double delta = theta - theta0;
  return delta > pi ? delta - 2.0 * pi : (delta < -pi ? delta + 2.0 * pi : delta);
}

Vec<double> to_vec(const Eigen::Ref<const Vec3>& x) { return {x.x(), x.y(), x.z()}; }

void gather_hinge(const Vectors3& x, const std::array<Index, 4>& v, Vec<double> (&p)[4]) {
  for (std::size_t a = 0; a < 4; ++a) p[a] = to_vec(x.col(v[a]));
}

#ifdef __SSE2__
// Two hinges per register for hinge_kinematics: every operation lane-wise the same IEEE operation
// as in the scalar kernel (and atan2 the same library call per lane), so a hinge gets the same bits
// whichever lane, or the scalar path, evaluates it.
struct Lanes {
  __m128d v;
  Lanes() = default;
  Lanes(__m128d value) : v(value) {}                       // NOLINT: implicit, as a scalar from its value
  explicit Lanes(double value) : v(_mm_set1_pd(value)) {}  // both lanes
  friend Lanes operator+(Lanes a, Lanes b) { return {_mm_add_pd(a.v, b.v)}; }
  friend Lanes operator-(Lanes a, Lanes b) { return {_mm_sub_pd(a.v, b.v)}; }
  friend Lanes operator-(Lanes a) { return {_mm_xor_pd(a.v, _mm_set1_pd(-0.0))}; }  // exact, as scalar negation
  friend Lanes operator*(Lanes a, Lanes b) { return {_mm_mul_pd(a.v, b.v)}; }
  friend Lanes operator/(Lanes a, Lanes b) { return {_mm_div_pd(a.v, b.v)}; }
};
Lanes sqrt(Lanes a) { return {_mm_sqrt_pd(a.v)}; }
// Both lanes on the series path in the register (the same operations as the scalar angle_of, so
// the same bits); otherwise lane by lane.
Lanes angle_of(Lanes y, Lanes x) {
  const __m128d abs_y = _mm_andnot_pd(_mm_set1_pd(-0.0), y.v);
  const __m128d near =
      _mm_and_pd(_mm_cmpgt_pd(x.v, _mm_setzero_pd()), _mm_cmple_pd(abs_y, _mm_mul_pd(_mm_set1_pd(0.125), x.v)));
  if (_mm_movemask_pd(near) == 3) {
    const __m128d t = _mm_div_pd(y.v, x.v), z = _mm_mul_pd(t, t);
    __m128d p = _mm_set1_pd(kAtanSeries[0]);
    for (int c = 1; c < 9; ++c) p = _mm_add_pd(_mm_mul_pd(p, z), _mm_set1_pd(kAtanSeries[c]));
    return {_mm_mul_pd(t, p)};
  }
  alignas(16) double ys[2], xs[2];
  _mm_store_pd(ys, y.v);
  _mm_store_pd(xs, x.v);
  return {_mm_set_pd(angle_of(ys[1], xs[1]), angle_of(ys[0], xs[0]))};
}
#endif

/// out(h, delta, grad) for every hinge h in [h0, h1), in order, at positions x: two hinges at a
/// time where SSE2 is available (the same values as one at a time).
template <typename Out>
void for_each_hinge_kinematics(const std::vector<DihedralBending::Hinge>& hinges,
                               const std::vector<std::array<double, 2>>& rest, const Vectors3& x, Index h0, Index h1,
                               Out&& out) {
  Index h = h0;
#ifdef __SSE2__
  const double* px = x.data();
  for (; h + 1 < h1; h += 2) {
    const auto& first = hinges[static_cast<std::size_t>(h)];
    const auto& second = hinges[static_cast<std::size_t>(h + 1)];
    Vec<Lanes> p[4];
    for (std::size_t a = 0; a < 4; ++a) {
      const double* u = px + 3 * first[a];
      const double* w = px + 3 * second[a];
      p[a] = {{_mm_loadh_pd(_mm_load_sd(u), w)},
              {_mm_loadh_pd(_mm_load_sd(u + 1), w + 1)},
              {_mm_loadh_pd(_mm_load_sd(u + 2), w + 2)}};
    }
    const auto& r0 = rest[static_cast<std::size_t>(h)];
    const auto& r1 = rest[static_cast<std::size_t>(h + 1)];
    const HingeKinematics<Lanes> k =
        hinge_kinematics(p, Lanes(_mm_set_pd(r1[0], r0[0])), Lanes(_mm_set_pd(r1[1], r0[1])));
    // Back to one hinge per lane: [l] is delta, then the gradient's 12 components.
    alignas(16) double lanes[13][2];
    _mm_store_pd(lanes[0], k.delta.v);
    for (std::size_t a = 0; a < 4; ++a) {
      _mm_store_pd(lanes[1 + 3 * a], k.grad[a].x.v);
      _mm_store_pd(lanes[2 + 3 * a], k.grad[a].y.v);
      _mm_store_pd(lanes[3 + 3 * a], k.grad[a].z.v);
    }
    for (int l = 0; l < 2; ++l) {
      const Vec<double> grad[4] = {{lanes[1][l], lanes[2][l], lanes[3][l]},
                                   {lanes[4][l], lanes[5][l], lanes[6][l]},
                                   {lanes[7][l], lanes[8][l], lanes[9][l]},
                                   {lanes[10][l], lanes[11][l], lanes[12][l]}};
      out(h + l, lanes[0][l], grad);
    }
  }
#endif
  for (; h < h1; ++h) {
    Vec<double> p[4];
    gather_hinge(x, hinges[static_cast<std::size_t>(h)], p);
    const auto& r = rest[static_cast<std::size_t>(h)];
    const HingeKinematics<double> k = hinge_kinematics(p, r[0], r[1]);
    out(h, k.delta, k.grad);
  }
}

}  // namespace

std::vector<DihedralBending::Hinge> DihedralBending::hinges_from_triangles(const std::vector<Triangle>& triangles) {
  struct HalfEdge {
    Index lo, hi;  // undirected key
    Index triangle;
    Index from, to;  // direction in the triangle's winding
    Index opposite;
  };
  std::vector<HalfEdge> half_edges;
  half_edges.reserve(3 * triangles.size());
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& v = triangles[t];
    for (std::size_t a = 0; a < 3; ++a) {
      if (v[a] < 0) fail("triangle ", t, ": vertex index ", v[a], " is negative");
      if (v[a] == v[(a + 1) % 3]) fail("triangle ", t, ": vertex index ", v[a], " is repeated");
    }
    for (std::size_t a = 0; a < 3; ++a) {
      const Index from = v[a];
      const Index to = v[(a + 1) % 3];
      half_edges.push_back({std::min(from, to), std::max(from, to), static_cast<Index>(t), from, to, v[(a + 2) % 3]});
    }
  }
  std::sort(half_edges.begin(), half_edges.end(), [](const HalfEdge& a, const HalfEdge& b) {
    return std::tie(a.lo, a.hi, a.triangle) < std::tie(b.lo, b.hi, b.triangle);
  });
  std::vector<Hinge> hinges;
  for (std::size_t begin = 0; begin < half_edges.size();) {
    std::size_t end = begin + 1;
    while (end < half_edges.size() && half_edges[end].lo == half_edges[begin].lo &&
           half_edges[end].hi == half_edges[begin].hi) {
      ++end;
    }
    if (end - begin > 2) {
      fail("edge (", half_edges[begin].lo, ", ", half_edges[begin].hi, ") is shared by ", end - begin, " triangles (",
           half_edges[begin].triangle, ", ", half_edges[begin + 1].triangle, ", ", half_edges[begin + 2].triangle,
           ", ...); dihedral bending needs a manifold mesh");
    }
    if (end - begin == 2) {
      const HalfEdge& first = half_edges[begin];
      hinges.push_back({first.from, first.to, first.opposite, half_edges[begin + 1].opposite});
    }
    begin = end;
  }
  return hinges;
}

double DihedralBending::dihedral_angle(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3) {
  const Vec<double> p[4] = {to_vec(x0), to_vec(x1), to_vec(x2), to_vec(x3)};
  return hinge_angle(p);
}

DihedralBending::DihedralBending(std::vector<Hinge> hinges, const Vectors3& rest_x,
                                 const DihedralBendingSettings& settings)
    : m_hinges(std::move(hinges)), m_settings(settings), m_rest_x(rest_x) {
  detail::check_non_negative(kName, "stiffness", m_settings.stiffness);
  detail::check_non_negative(kName, "damping", m_settings.damping);

  const Index n = rest_x.cols();
  const std::size_t count = m_hinges.size();
  m_rest_angle.resize(count);
  m_rest_direction.resize(count);
  m_weight.resize(count);
  m_dt_weights.resize(count);
  m_x = rest_x;
  m_grad.resize(count);
  for (std::size_t h = 0; h < count; ++h) {
    const Hinge& v = m_hinges[h];
    detail::check_element_indices("hinge", h, v, n);
    detail::check_rest_positions("hinge", h, v, rest_x);
    const Vec3 x0 = rest_x.col(v[0]);
    const Vec3 e = rest_x.col(v[1]) - x0;
    const Vec3 a2 = rest_x.col(v[2]) - x0;
    const Vec3 a3 = rest_x.col(v[3]) - x0;
    const double e_sq = e.squaredNorm();
    const double scale_sq = std::max({e_sq, a2.squaredNorm(), a3.squaredNorm()});
    if (!(e_sq > kDegenerateRelative * kDegenerateRelative * scale_sq)) {
      fail("hinge ", h, ": shared edge (", v[0], ", ", v[1], ") has zero rest length");
    }
    const double area1 = 0.5 * e.cross(a2).norm();
    const double area2 = 0.5 * a3.cross(e).norm();
    if (!(area1 > kDegenerateRelative * scale_sq)) {
      fail("hinge ", h, ": triangle (", v[0], ", ", v[1], ", ", v[2], ") is degenerate (area ", area1, ")");
    }
    if (!(area2 > kDegenerateRelative * scale_sq)) {
      fail("hinge ", h, ": triangle (", v[0], ", ", v[1], ", ", v[3], ") is degenerate (area ", area2, ")");
    }
    m_weight[h] = 3.0 * e_sq / (area1 + area2);

    Vec<double> p[4];
    gather_hinge(rest_x, v, p);
    // The rest angle's direction as the kinematics compute it, scaled by a power of two (exactly) to
    // order one: at the rest shape the turned-back sine is then exactly zero (y x0 - x y0 with
    // y = y0, x = x0), so a hinge at rest feels no force.
    {
      const Vec<double> edge = p[1] - p[0];
      const Vec<double> n1 = cross(edge, p[2] - p[0]);
      const Vec<double> n2 = cross(p[3] - p[0], edge);
      const double sin_theta = dot(cross(n1, n2), edge), cos_theta = dot(n1, n2) * std::sqrt(dot(edge, edge));
      m_rest_angle[h] = std::atan2(sin_theta, cos_theta);
      const int exponent = -std::ilogb(std::max(std::abs(sin_theta), std::abs(cos_theta)));
      m_rest_direction[h] = {std::ldexp(cos_theta, exponent), std::ldexp(sin_theta, exponent)};
    }
    const HingeKinematics<double> k = hinge_kinematics(p, m_rest_direction[h][0], m_rest_direction[h][1]);
    // At rest delta = 0, so K_e = 2 k_b w g g^T (rank one) and its largest eigenvalue in the mass
    // norm is exactly 2 k_b w sum_a |g_a|^2 / m_a: w_{e,a} = 2 k_b w |g_a|^2 (element_bound_stable_dt).
    for (std::size_t a = 0; a < 4; ++a) {
      m_dt_weights[h][a] = 2.0 * m_settings.stiffness * m_weight[h] * dot(k.grad[a], k.grad[a]);
      m_grad[h].col(static_cast<Index>(a)) = Vec3(k.grad[a].x, k.grad[a].y, k.grad[a].z);
    }
  }
  detail::Incidence incidence = detail::Incidence::build(m_hinges, detail::index_span(m_hinges));
  m_incidence_offsets = std::move(incidence.offsets);
  m_incidence = std::move(incidence.elements);
  // The slot 4 h + a of each incidence entry: where node i sits in hinge h.
  m_incidence_slot.resize(m_incidence.size());
  for (std::size_t i = 0; i + 1 < m_incidence_offsets.size(); ++i)
    for (Index k = m_incidence_offsets[i]; k < m_incidence_offsets[i + 1]; ++k) {
      const Index h = m_incidence[static_cast<std::size_t>(k)];
      const Hinge& hinge = m_hinges[static_cast<std::size_t>(h)];
      m_incidence_slot[static_cast<std::size_t>(k)] =
          4 * h + (std::find(hinge.begin(), hinge.end(), static_cast<Index>(i)) - hinge.begin());
    }
  m_node_ggt.setZero(9, static_cast<Index>(m_incidence_offsets.size()) - 1);
  m_delta.assign(count, 0.0);  // the cached state starts at rest (m_x, m_grad above)
  cache_node_gradients();
  m_scatter = ScatterGather<4>(m_hinges, detail::index_span(m_hinges));
  m_chunks = ChunkedScatter(m_hinges, detail::index_span(m_hinges));
}

void DihedralBending::validate(Index particle_count) const {
  for (std::size_t h = 0; h < m_hinges.size(); ++h) {
    detail::check_element_indices("hinge", h, m_hinges[h], particle_count);
  }
}

void DihedralBending::update_position_state(const Vectors3& x) {
  // Without damping or implicit treatment only the differential needs cached state, and it needs
  // positions alone: skip the angle gradients (an atan2 and two normalisations per hinge, every solve).
  m_x = x;
  m_grad_valid = false;
  if (m_settings.damping == 0.0 && !m_implicit) return;
  parallel::for_ranges(static_cast<Index>(m_hinges.size()), [&](Index h0, Index h1) {
    for_each_hinge_kinematics(m_hinges, m_rest_direction, x, h0, h1,
                              [&](Index hi, double delta, const Vec<double>(&grad)[4]) {
                                const auto h = static_cast<std::size_t>(hi);
                                m_delta[h] = delta;
                                for (std::size_t a = 0; a < 4; ++a)
                                  m_grad[h].col(static_cast<Index>(a)) = Vec3(grad[a].x, grad[a].y, grad[a].z);
                              });
  });
  cache_node_gradients();
}

// Each node's sum of w g_a g_a^T over its hinges (the diagonal blocks up to the factor c), in the
// hinges' order; the six distinct entries of the symmetric block summed, then mirrored.
void DihedralBending::cache_node_gradients() {
  const auto nodes = static_cast<Index>(m_incidence_offsets.size()) - 1;
  const double* pg = m_grad.empty() ? nullptr : m_grad[0].data();
  parallel::for_ranges(nodes, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      double xx = 0.0, xy = 0.0, xz = 0.0, yy = 0.0, yz = 0.0, zz = 0.0;
      for (Index k = m_incidence_offsets[static_cast<std::size_t>(i)];
           k < m_incidence_offsets[static_cast<std::size_t>(i) + 1]; ++k) {
        const Index slot = m_incidence_slot[static_cast<std::size_t>(k)];  // 4 h + a
        const double* g = pg + 3 * slot;
        const double w = m_weight[static_cast<std::size_t>(slot / 4)];
        const double wx = w * g[0], wy = w * g[1], wz = w * g[2];
        xx += wx * g[0];
        xy += wx * g[1];
        xz += wx * g[2];
        yy += wy * g[1];
        yz += wy * g[2];
        zz += wz * g[2];
      }
      double* block = m_node_ggt.col(i).data();  // column-major 3x3
      block[0] = xx;
      block[1] = block[3] = xy;
      block[2] = block[6] = xz;
      block[4] = yy;
      block[5] = block[7] = yz;
      block[8] = zz;
    }
  });
  m_grad_valid = true;
}

double DihedralBending::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t h = 0; h < m_hinges.size(); ++h) {
    Vec<double> p[4];
    gather_hinge(x, m_hinges[h], p);
    const double delta = wrapped_difference(hinge_angle(p), m_rest_angle[h]);
    energy += m_settings.stiffness * m_weight[h] * delta * delta;
  }
  return energy;
}

void DihedralBending::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  // At the cached state (the step asks for forces right after update_position_state) the angles and
  // gradients are already known: no second evaluation per hinge. Parallel over hinges into each
  // hinge's own slots, then gathered per node (deterministic; a direct scatter into the nodes measured
  // slower, its read-modify-writes of shared nodes stalling one another).
  const bool cached = m_grad_valid && x.cols() == m_x.cols() && x == m_x;
  const double k_b = m_settings.stiffness;
  double* slots = m_scatter.values().data();  // 12 per hinge: its force on vertex 0 .. 3
  parallel::for_ranges(static_cast<Index>(m_hinges.size()), [&](Index h0, Index h1) {
    if (cached) {
      for (Index hi = h0; hi < h1; ++hi) {
        const auto h = static_cast<std::size_t>(hi);
        const double scale = -2.0 * k_b * m_weight[h] * m_delta[h];
        const double* g = m_grad[h].data();
        for (int c = 0; c < 12; ++c) slots[12 * hi + c] = scale * g[c];
      }
      return;
    }
    for_each_hinge_kinematics(m_hinges, m_rest_direction, x, h0, h1,
                              [&](Index hi, double delta, const Vec<double>(&grad)[4]) {
                                const double scale = -2.0 * k_b * m_weight[static_cast<std::size_t>(hi)] * delta;
                                double* out = slots + 12 * hi;
                                for (std::size_t a = 0; a < 4; ++a) {
                                  out[3 * a] = scale * grad[a].x;
                                  out[3 * a + 1] = scale * grad[a].y;
                                  out[3 * a + 2] = scale * grad[a].z;
                                }
                              });
  });
  m_scatter.gather_add(f);
}

void DihedralBending::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  for (std::size_t h = 0; h < m_hinges.size(); ++h) {
    Vec<Dual> p[4];
    for (std::size_t a = 0; a < 4; ++a) {
      const Index i = m_hinges[h][a];
      p[a] = {Dual(m_x(0, i), dx(0, i)), Dual(m_x(1, i), dx(1, i)), Dual(m_x(2, i), dx(2, i))};
    }
    const HingeKinematics<Dual> k = hinge_kinematics(p, Dual(m_rest_direction[h][0]), Dual(m_rest_direction[h][1]));
    const Dual scale = k.delta * (-2.0 * m_settings.stiffness * m_weight[h]);
    for (std::size_t a = 0; a < 4; ++a) {
      const Vec<Dual> f_a = k.grad[a] * scale;
      df.col(m_hinges[h][a]) += Vec3(f_a.x.d, f_a.y.d, f_a.z.d);
    }
  }
}

// Damping is the implicit products with b = 0: f += -c w g (g . v).
void DihedralBending::add_damping_forces(const Vectors3& v, Vectors3& f) const { add_implicit_products(v, 0.0, f); }

// f += -(c + 2 b k_b) w g (g . v): damping of the angle's rate plus b K+ v. One pass over the
// hinges' cached gradients: each hinge's scaled rate -c w (g . v), scattered as rate g_a into its
// four nodes by fixed chunks of hinges (deterministic on any thread count).
void DihedralBending::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double c = m_settings.damping + 2.0 * b * m_settings.stiffness;
  if (c == 0.0) return;
  if (!m_implicit && m_settings.damping == 0.0)
    fail("dihedral bending: implicit products need set_implicit(true) first");
  const double* pv = v.data();
  const double* pg = m_grad.empty() ? nullptr : m_grad[0].data();  // 12 per hinge: g_0 .. g_3
  const double* weight = m_weight.data();
  const Hinge* hinges = m_hinges.data();
  m_chunks.run(f, [&](const ChunkedScatter::Chunk& chunk, double* out) {
    for (Index h = chunk.begin; h < chunk.end; ++h) {
      const Hinge& hinge = hinges[h];
      const double* g = pg + 12 * h;
      const Index i0 = 3 * hinge[0], i1 = 3 * hinge[1], i2 = 3 * hinge[2], i3 = 3 * hinge[3];
      // d theta / dt = g . v, as a tree of four independent per-vertex terms (no serial chain of adds).
      const double r0 = (g[0] * pv[i0] + g[1] * pv[i0 + 1]) + g[2] * pv[i0 + 2];
      const double r1 = (g[3] * pv[i1] + g[4] * pv[i1 + 1]) + g[5] * pv[i1 + 2];
      const double r2 = (g[6] * pv[i2] + g[7] * pv[i2 + 1]) + g[8] * pv[i2 + 2];
      const double r3 = (g[9] * pv[i3] + g[10] * pv[i3 + 1]) + g[11] * pv[i3 + 2];
      const double rate = -c * weight[h] * ((r0 + r1) + (r2 + r3));
      for (int k = 0; k < 3; ++k) {
        out[i0 + k] += rate * g[k];
        out[i1 + k] += rate * g[3 + k];
        out[i2 + k] += rate * g[6 + k];
        out[i3 + k] += rate * g[9 + k];
      }
    }
  });
}

void DihedralBending::add_diagonal(double b, VectorXd& diag) const {
  const double c = m_settings.damping + 2.0 * b * m_settings.stiffness;
  if (c == 0.0) return;
  for (std::size_t h = 0; h < m_hinges.size(); ++h)
    for (std::size_t a = 0; a < 4; ++a)
      diag[m_hinges[h][a]] += c * m_weight[h] * m_grad[h].col(static_cast<Index>(a)).squaredNorm() / 3.0;
}

// The diagonal blocks: c times each node's sum of w g_a g_a^T, cached with the gradients.
bool DihedralBending::add_diagonal_blocks(double b, Blocks& blocks) const {
  const double c = m_settings.damping + 2.0 * b * m_settings.stiffness;
  if (c == 0.0) return true;
  if (!m_grad_valid) fail("dihedral bending: implicit diagonal blocks need set_implicit(true) or damping first");
  blocks.leftCols(m_node_ggt.cols()) += c * m_node_ggt;
  return true;
}

// Each hinge couples its four nodes pairwise: -(c + 2 b k_b) w g_a g_b^T for a < b (six pairs).
bool DihedralBending::visit_pair_blocks(double b, PairBlockSink& sink) const {
  const double c = m_settings.damping + 2.0 * b * m_settings.stiffness;
  for (std::size_t h = 0; h < m_hinges.size(); ++h) {
    const Mat34& g = m_grad[h];
    const double scale = -c * m_weight[h];
    for (Index a = 0; a < 4; ++a)
      for (Index bb = a + 1; bb < 4; ++bb) {
        const Mat3 block = scale * (g.col(a) * g.col(bb).transpose());
        sink.add(m_hinges[h][static_cast<std::size_t>(a)], m_hinges[h][static_cast<std::size_t>(bb)], block);
      }
  }
  return true;
}

// Block k of the sequence above: hinge k / 6, node pair k % 6 in the order (0,1) (0,2) (0,3) (1,2)
// (1,3) (2,3), computed as the visit computes it.
Mat3 DihedralBending::pair_block(Index k, double b) const {
  static constexpr Index kFirst[6] = {0, 0, 0, 1, 1, 2}, kSecond[6] = {1, 2, 3, 2, 3, 3};
  const double c = m_settings.damping + 2.0 * b * m_settings.stiffness;
  const auto h = static_cast<std::size_t>(k / 6);
  const Index p = k % 6;
  const Mat34& g = m_grad[h];
  const double scale = -c * m_weight[h];
  return scale * (g.col(kFirst[p]) * g.col(kSecond[p]).transpose());
}

// Conservative bound from the rest linearisation (exact per hinge, see the constructor; summed per
// particle in element_bound_stable_dt). Away from rest the delta * Hessian(theta) term adds
// stiffness of either sign, which this estimate ignores.
double DihedralBending::stable_dt(const VectorXd& m_eff) const {
  return detail::element_bound_stable_dt(kName, m_hinges, m_dt_weights, m_incidence_offsets, m_incidence, m_eff);
}

Index DihedralBending::remove_elements_touching(std::span<const std::uint8_t> removed) {
  return detail::rebuild_without(*this, m_hinges, removed, m_rest_x, m_settings);
}

}  // namespace sinew
