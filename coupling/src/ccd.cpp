#include "sinew/ccd.hpp"

#include <algorithm>
#include <cmath>

namespace sinew::ccd {

std::array<double, 3> closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {1.0, 0.0, 0.0};
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {0.0, 1.0, 0.0};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {1.0 - v, v, 0.0};
  }
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {0.0, 0.0, 1.0};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {1.0 - w, 0.0, w};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {0.0, 1.0 - w, w};
  }
  const double denom = 1.0 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return {1.0 - v - w, v, w};
}

void closest_on_segments(const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1, double& s, double& t) {
  const Vec3 d1 = p1 - p0, d2 = q1 - q0, r = p0 - q0;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  const double tiny = 1e-30;
  if (a <= tiny && e <= tiny) {
    s = t = 0.0;
    return;
  }
  if (a <= tiny) {
    s = 0.0;
    t = std::clamp(f / e, 0.0, 1.0);
    return;
  }
  const double c = d1.dot(r);
  if (e <= tiny) {
    t = 0.0;
    s = std::clamp(-c / a, 0.0, 1.0);
    return;
  }
  const double b = d1.dot(d2), denom = a * e - b * b;
  s = denom > tiny ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
  t = (b * s + f) / e;
  if (t < 0.0) {
    t = 0.0;
    s = std::clamp(-c / a, 0.0, 1.0);
  } else if (t > 1.0) {
    t = 1.0;
    s = std::clamp((b - c) / a, 0.0, 1.0);
  }
}

namespace {

// Coefficients c[0..3] of f(t) = ((x1 - x0) x (x2 - x0)) . (x3 - x0), each x_k(t) = x_k0 + t d_k.
std::array<double, 4> coplanarity_cubic(const std::array<Vec3, 4>& x, const std::array<Vec3, 4>& d) {
  const Vec3 e1 = x[1] - x[0], e2 = x[2] - x[0], e3 = x[3] - x[0];
  const Vec3 f1 = d[1] - d[0], f2 = d[2] - d[0], f3 = d[3] - d[0];
  const Vec3 A = e1.cross(e2), B = e1.cross(f2) + f1.cross(e2), C = f1.cross(f2);
  return {A.dot(e3), A.dot(f3) + B.dot(e3), B.dot(f3) + C.dot(e3), C.dot(f3)};
}

double eval(const std::array<double, 4>& c, double t) { return ((c[3] * t + c[2]) * t + c[1]) * t + c[0]; }

// The roots of the cubic in [0, 1], in increasing order, into `roots` (at most 3): the interval is
// split at the derivative's roots into pieces on which f is monotone, and each piece whose ends
// differ in sign (or touch zero) is bisected to round-off. Returns how many.
int roots_in_unit_interval(const std::array<double, 4>& c, std::array<double, 3>& roots) {
  std::array<double, 4> knots{0.0, 1.0, 1.0, 1.0};
  int count = 1;
  // f'(t) = 3 c3 t^2 + 2 c2 t + c1.
  const double a = 3.0 * c[3], b = 2.0 * c[2], cc = c[1];
  std::array<double, 2> critical{};
  int critical_count = 0;
  if (a != 0.0) {
    const double disc = b * b - 4.0 * a * cc;
    if (disc >= 0.0) {
      const double q = -0.5 * (b + std::copysign(std::sqrt(disc), b));
      if (q != 0.0) critical[critical_count++] = q / a;
      critical[critical_count++] = q != 0.0 ? cc / q : -b / (2.0 * a);
    }
  } else if (b != 0.0) {
    critical[critical_count++] = -cc / b;
  }
  std::sort(critical.begin(), critical.begin() + critical_count);
  for (int k = 0; k < critical_count; ++k)
    if (critical[k] > 0.0 && critical[k] < 1.0) knots[count++] = critical[k];
  knots[count++] = 1.0;
  int found = 0;
  for (int k = 0; k + 1 < count; ++k) {
    double lo = knots[k], hi = knots[k + 1];
    double f_lo = eval(c, lo), f_hi = eval(c, hi);
    if (f_lo == 0.0) {
      if (found == 0 || roots[found - 1] < lo) roots[found++] = lo;
      continue;
    }
    if (f_hi == 0.0 || (f_lo < 0.0) == (f_hi < 0.0)) {
      if (f_hi == 0.0 && k + 2 == count) roots[found++] = hi;
      continue;
    }
    for (int it = 0; it < 60 && hi - lo > 1e-15; ++it) {
      const double mid = 0.5 * (lo + hi), f_mid = eval(c, mid);
      if ((f_mid < 0.0) == (f_lo < 0.0)) {
        lo = mid;
        f_lo = f_mid;
      } else {
        hi = mid;
      }
    }
    roots[found++] = 0.5 * (lo + hi);
    if (found == 3) break;
  }
  return found;
}

template <class Distance>
std::optional<double> first_contact(const std::array<Vec3, 4>& x0, const std::array<Vec3, 4>& x1, double eta,
                                    Distance&& distance) {
  std::array<Vec3, 4> d;
  for (std::size_t k = 0; k < 4; ++k) d[k] = x1[k] - x0[k];
  const std::array<double, 4> c = coplanarity_cubic(x0, d);
  // f is a triple product of lengths: against the cube of the pair's size, |f| below round-off
  // throughout means the four points stay coplanar, and only the distance can tell.
  double size = 0.0;
  for (std::size_t k = 1; k < 4; ++k) size = std::max({size, (x0[k] - x0[0]).norm(), (x1[k] - x1[0]).norm()});
  const double noise = 64.0 * 2.2e-16 * size * size * size;
  const auto at = [&](double t) {
    std::array<Vec3, 4> x;
    for (std::size_t k = 0; k < 4; ++k) x[k] = x0[k] + t * d[k];
    return distance(x);
  };
  if (std::abs(c[0]) <= noise && std::abs(c[1]) <= noise && std::abs(c[2]) <= noise && std::abs(c[3]) <= noise) {
    constexpr int kSamples = 8;
    for (int k = 0; k <= kSamples; ++k) {
      const double t = double(k) / kSamples;
      if (at(t) < eta) return t;
    }
    return std::nullopt;
  }
  std::array<double, 3> roots{};
  const int n = roots_in_unit_interval(c, roots);
  for (int k = 0; k < n; ++k)
    if (at(roots[k]) < eta) return roots[k];
  return std::nullopt;
}

}  // namespace

std::optional<double> vertex_triangle(const Vec3& p0, const Vec3& a0, const Vec3& b0, const Vec3& c0, const Vec3& p1,
                                      const Vec3& a1, const Vec3& b1, const Vec3& c1, double eta) {
  return first_contact({a0, b0, c0, p0}, {a1, b1, c1, p1}, eta, [](const std::array<Vec3, 4>& x) {
    const std::array<double, 3> w = closest_on_triangle(x[3], x[0], x[1], x[2]);
    return (x[3] - (w[0] * x[0] + w[1] * x[1] + w[2] * x[2])).norm();
  });
}

std::optional<double> edge_edge(const Vec3& p0, const Vec3& q0, const Vec3& r0, const Vec3& s0, const Vec3& p1,
                                const Vec3& q1, const Vec3& r1, const Vec3& s1, double eta) {
  return first_contact({p0, q0, r0, s0}, {p1, q1, r1, s1}, eta, [](const std::array<Vec3, 4>& x) {
    double s, t;
    closest_on_segments(x[0], x[1], x[2], x[3], s, t);
    return ((1.0 - s) * x[0] + s * x[1] - ((1.0 - t) * x[2] + t * x[3])).norm();
  });
}

void BoxGrid::cells_of(const Eigen::AlignedBox3d& box, std::array<long long, 3>& lo,
                       std::array<long long, 3>& hi) const {
  // (clamped to the 21 bits a coordinate has in a key; a box beyond is oversized anyway)
  constexpr double kLimit = double(1LL << 20) - 1.0;
  for (int a = 0; a < 3; ++a) {
    lo[a] = static_cast<long long>(std::clamp(std::floor(box.min()[a] / m_cell), -kLimit, kLimit));
    hi[a] = static_cast<long long>(std::clamp(std::floor(box.max()[a] / m_cell), -kLimit, kLimit));
  }
}

void BoxGrid::build(const std::vector<Eigen::AlignedBox3d>& boxes, double cell) {
  m_cell = cell;
  m_items.clear();
  m_oversized.clear();
  if (!(cell > 0.0) || !std::isfinite(cell)) {
    for (std::size_t k = 0; k < boxes.size(); ++k) m_oversized.push_back(static_cast<Index>(k));
    return;
  }
  // Each binned box's cells, twice: counted into buckets, then placed (a counting sort).
  const auto for_each_cell = [&](auto&& f) {
    for (std::size_t k = 0; k < boxes.size(); ++k) {
      const Eigen::AlignedBox3d& box = boxes[k];
      if (box.isEmpty()) continue;
      std::array<long long, 3> lo, hi;
      cells_of(box, lo, hi);
      if (!box.sizes().allFinite() || span(lo, hi) > kMaxCellsPerBox) continue;
      for (long long i = lo[0]; i <= hi[0]; ++i)
        for (long long j = lo[1]; j <= hi[1]; ++j)
          for (long long l = lo[2]; l <= hi[2]; ++l) f(bucket(i, j, l), static_cast<Index>(k));
    }
  };
  std::size_t entries = 0;
  for (std::size_t k = 0; k < boxes.size(); ++k) {
    const Eigen::AlignedBox3d& box = boxes[k];
    if (box.isEmpty()) continue;
    std::array<long long, 3> lo, hi;
    cells_of(box, lo, hi);
    const double cells = span(lo, hi);
    if (!box.sizes().allFinite() || cells > kMaxCellsPerBox) {
      m_oversized.push_back(static_cast<Index>(k));
      continue;
    }
    entries += static_cast<std::size_t>(cells);
  }
  std::size_t buckets = 16;
  while (buckets < entries) buckets *= 2;
  m_mask = buckets - 1;
  m_start.assign(buckets + 1, 0);
  for_each_cell([&](std::size_t b, Index) { ++m_start[b + 1]; });
  for (std::size_t b = 0; b < buckets; ++b) m_start[b + 1] += m_start[b];
  m_items.resize(entries);
  m_cursor.assign(m_start.begin(), m_start.end() - 1);
  for_each_cell([&](std::size_t b, Index item) { m_items[m_cursor[b]++] = item; });
}

}  // namespace sinew::ccd
