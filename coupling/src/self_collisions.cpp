#include "sinew/self_collisions.hpp"

#include "sinew/dofs.hpp"
#include "sinew/particles.hpp"

#include <algorithm>
#include <cmath>

namespace sinew {
namespace {

// Closest point to p on triangle (a, b, c), as barycentric weights (Ericson, Real-Time Collision
// Detection, 5.1.5).
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

// Parameters (s, t) of the closest points of segments p0 p1 and q0 q1 (Ericson 5.1.9).
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

long long cell_key(long long i, long long j, long long k) {
  // 21 bits a coordinate (cells within +-1e6 of the origin), packed.
  const long long m = (1LL << 21) - 1;
  return ((i & m) << 42) | ((j & m) << 21) | (k & m);
}

}  // namespace

SelfCollisions::SelfCollisions(const SelfCollisionSettings& settings) : m_settings(settings) {
  if (!(std::isfinite(settings.thickness) && settings.thickness > 0.0))
    fail("self collisions: thickness ", settings.thickness, " must be positive and finite");
  if (!(std::isfinite(settings.friction) && settings.friction >= 0.0))
    fail("self collisions: friction ", settings.friction, " must be non-negative and finite");
  if (settings.passes < 1) fail("self collisions: passes ", settings.passes, " must be at least 1");
}

bool SelfCollisions::respond(CollisionContext& c, const std::array<Index, 4>& points,
                             const std::array<double, 4>& weights, const Vec3& n, double gap) {
  const Particles& p = *c.particles;
  std::array<double, 4> inverse_mass{};
  double S = 0.0;
  for (std::size_t k = 0; k < 4; ++k) {
    const Index i = points[k];
    if (i < 0 || weights[k] == 0.0) continue;
    inverse_mass[k] = is_dynamic(p.kind[i]) && p.mass[i] > 0.0 ? 1.0 / p.mass[i] : 0.0;
    S += weights[k] * weights[k] * inverse_mass[k];
  }
  if (!(S > 0.0)) return false;
  Vectors3& x = *c.x;
  Vectors3& v = *c.v;
  // Apart by `gap` along n: the relative displacement sum_k w_k dx_k . n is gap.
  if (gap > 0.0)
    for (std::size_t k = 0; k < 4; ++k)
      if (inverse_mass[k] > 0.0) x.col(points[k]) += (weights[k] * inverse_mass[k] / S * gap) * n;
  Vec3 v_rel = Vec3::Zero();
  for (std::size_t k = 0; k < 4; ++k)
    if (points[k] >= 0) v_rel += weights[k] * v.col(points[k]);
  const double vn = v_rel.dot(n);
  if (vn >= 0.0) return true;
  // The approach stopped; Coulomb friction takes up to mu |vn| of the tangential slip.
  Vec3 change = -vn * n;
  const Vec3 slip = v_rel - vn * n;
  const double slip_speed = slip.norm();
  if (slip_speed > 0.0) change -= std::min(1.0, m_settings.friction * (-vn) / slip_speed) * slip;
  for (std::size_t k = 0; k < 4; ++k)
    if (inverse_mass[k] > 0.0) v.col(points[k]) += (weights[k] * inverse_mass[k] / S) * change;
  return true;
}

void SelfCollisions::bin(const CollisionContext& c) {
  const Vectors3& x = *c.x;
  const auto& triangles = c.geometry->triangles;
  const auto& segments = c.geometry->segments;
  const double pad = m_settings.thickness;
  // Padded boxes; cells as large as the largest padded triangle, so a box spans at most 2 x 2 x 2.
  m_triangle_box.resize(triangles.size());
  m_segment_box.resize(segments.size());
  m_cell = 0.0;
  for (std::size_t k = 0; k < triangles.size(); ++k) {
    Eigen::AlignedBox3d box;
    for (const Index i : triangles[k]) box.extend(Vec3(x.col(i)));
    box.min().array() -= pad;
    box.max().array() += pad;
    m_triangle_box[k] = box;
    m_cell = std::max(m_cell, box.sizes().maxCoeff());
  }
  for (std::size_t k = 0; k < segments.size(); ++k) {
    Eigen::AlignedBox3d box;
    box.extend(Vec3(x.col(segments[k][0])));
    box.extend(Vec3(x.col(segments[k][1])));
    box.min().array() -= 0.5 * pad;  // two boxes grown by half the thickness meet within it
    box.max().array() += 0.5 * pad;
    m_segment_box[k] = box;
  }
  m_triangle_grid.clear();  // (cells a moving cloth left would otherwise accumulate)
  m_segment_grid.clear();
  if (!(m_cell > 0.0) || !std::isfinite(m_cell)) return;
  const auto insert = [&](std::unordered_map<long long, std::vector<Index>>& grid, const Eigen::AlignedBox3d& box,
                          Index item) {
    const Vec3 lo = box.min() / m_cell, hi = box.max() / m_cell;
    for (long long i = std::llround(std::floor(lo.x())); i <= std::llround(std::floor(hi.x())); ++i)
      for (long long j = std::llround(std::floor(lo.y())); j <= std::llround(std::floor(hi.y())); ++j)
        for (long long l = std::llround(std::floor(lo.z())); l <= std::llround(std::floor(hi.z())); ++l)
          grid[cell_key(i, j, l)].push_back(item);
  };
  for (std::size_t k = 0; k < triangles.size(); ++k) insert(m_triangle_grid, m_triangle_box[k], static_cast<Index>(k));
  for (std::size_t k = 0; k < segments.size(); ++k) insert(m_segment_grid, m_segment_box[k], static_cast<Index>(k));
}

void SelfCollisions::process(CollisionContext& c) {
  const auto& triangles = c.geometry->triangles;
  const auto& segments = c.geometry->segments;
  m_contacts = 0;
  m_passes_run = 0;
  if (triangles.empty()) return;
  const Vectors3& x_n = *c.x_n;
  Vectors3& x = *c.x;
  const double h = m_settings.thickness;
  // A pair counts as still to resolve while it needs a push of more than this (a resting contact
  // left at the thickness by the last pass, to round-off, does not).
  const double settled = 1e-3 * h;
  // The surfaces' vertices, once each, in index order.
  m_vertices.clear();
  for (const auto& t : triangles) m_vertices.insert(m_vertices.end(), t.begin(), t.end());
  std::sort(m_vertices.begin(), m_vertices.end());
  m_vertices.erase(std::unique(m_vertices.begin(), m_vertices.end()), m_vertices.end());
  const auto corner_of = [&](Index i, const std::array<Index, 3>& t) { return i == t[0] || i == t[1] || i == t[2]; };
  m_seen.assign(segments.size(), -1);
  for (int pass = 0; pass < m_settings.passes; ++pass) {
    ++m_passes_run;
    int found = 0;
    bin(c);
    if (!(m_cell > 0.0)) return;
    // Vertex against triangle.
    for (const Index i : m_vertices) {
      const Vec3 p = x.col(i);
      const auto cell = (p / m_cell).array().floor();
      const auto it =
          m_triangle_grid.find(cell_key(std::llround(cell.x()), std::llround(cell.y()), std::llround(cell.z())));
      if (it == m_triangle_grid.end()) continue;
      for (const Index k : it->second) {
        const auto& t = triangles[static_cast<std::size_t>(k)];
        if (corner_of(i, t) || !m_triangle_box[static_cast<std::size_t>(k)].contains(p)) continue;
        const Vec3 a = x.col(t[0]), b = x.col(t[1]), cc = x.col(t[2]);
        const std::array<double, 3> w = closest_on_triangle(p, a, b, cc);
        const Vec3 q = w[0] * a + w[1] * b + w[2] * cc;
        if ((p - q).squaredNorm() >= h * h) continue;
        // The face normal, on the side the vertex was at t^n (where it lay within the plane then,
        // the side it is on now).
        Vec3 n = (b - a).cross(cc - a);
        if (!(n.squaredNorm() > 0.0)) continue;
        n.normalize();
        const Vec3 q_n = w[0] * x_n.col(t[0]) + w[1] * x_n.col(t[1]) + w[2] * x_n.col(t[2]);
        const Vec3 n_n = (x_n.col(t[1]) - x_n.col(t[0])).cross(x_n.col(t[2]) - x_n.col(t[0]));
        double side = (x_n.col(i) - q_n).dot(n_n);
        if (side == 0.0) side = (p - q).dot(n);
        if (side < 0.0) n = -n;
        const double d = (p - q).dot(n);
        if (d >= h) continue;
        if (h - d > settled) ++found;
        respond(c, {i, t[0], t[1], t[2]}, {1.0, -w[0], -w[1], -w[2]}, n, h - d);
      }
    }
    // Edge against edge: each pair once (the later edge found from the earlier), edges sharing no
    // point, closest points inside both.
    for (std::size_t e = 0; e < segments.size(); ++e) {
      const auto& s0 = segments[e];
      const Eigen::AlignedBox3d& box = m_segment_box[e];
      const Vec3 lo = box.min() / m_cell, hi = box.max() / m_cell;
      for (long long ci = std::llround(std::floor(lo.x())); ci <= std::llround(std::floor(hi.x())); ++ci)
        for (long long cj = std::llround(std::floor(lo.y())); cj <= std::llround(std::floor(hi.y())); ++cj)
          for (long long cl = std::llround(std::floor(lo.z())); cl <= std::llround(std::floor(hi.z())); ++cl) {
            const auto it = m_segment_grid.find(cell_key(ci, cj, cl));
            if (it == m_segment_grid.end()) continue;
            for (const Index f : it->second) {
              const auto fs = static_cast<std::size_t>(f);
              if (fs <= e || m_seen[fs] == static_cast<Index>(e)) continue;
              m_seen[fs] = static_cast<Index>(e);
              const Index a0 = segments[fs][0], a1 = segments[fs][1];
              if (a0 == s0[0] || a0 == s0[1] || a1 == s0[0] || a1 == s0[1]) continue;
              if (!box.intersects(m_segment_box[fs])) continue;
              double s, u;
              const Vec3 p0 = x.col(s0[0]), p1 = x.col(s0[1]), q0 = x.col(a0), q1 = x.col(a1);
              closest_on_segments(p0, p1, q0, q1, s, u);
              if (s <= 0.0 || s >= 1.0 || u <= 0.0 || u >= 1.0) continue;  // a vertex's case
              const Vec3 diff = (1.0 - s) * p0 + s * p1 - ((1.0 - u) * q0 + u * q1);
              const double dist = diff.norm();
              if (dist >= h) continue;
              const Vec3 diff_n =
                  (1.0 - s) * x_n.col(s0[0]) + s * x_n.col(s0[1]) - ((1.0 - u) * x_n.col(a0) + u * x_n.col(a1));
              Vec3 n = dist > 0.0 ? Vec3(diff / dist) : diff_n.normalized();
              if (!n.allFinite() || !(n.squaredNorm() > 0.5)) continue;
              double d = dist;
              if (diff_n.dot(n) < 0.0) {  // crossed within the step: back to the side of t^n
                n = -n;
                d = -dist;
              }
              if (h - d > settled) ++found;
              respond(c, {s0[0], s0[1], a0, a1}, {1.0 - s, s, -(1.0 - u), -u}, n, h - d);
            }
          }
    }
    // m_seen marks by edge index: a new pass starts with every mark below e again, so clear them.
    std::fill(m_seen.begin(), m_seen.end(), -1);
    if (pass == 0) m_contacts = found;
    if (found == 0) break;
  }
}

}  // namespace sinew
