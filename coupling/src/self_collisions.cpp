#include "sinew/self_collisions.hpp"

#include "sinew/ccd.hpp"

#include "sinew/dofs.hpp"
#include "sinew/particles.hpp"

#include <algorithm>
#include <cmath>

namespace sinew {

using ccd::closest_on_segments;
using ccd::closest_on_triangle;

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
  const double pad = 2.0 * m_settings.thickness;  // the reach of the near pairs
  // Padded boxes, binned in cells the mean size of the boxes (a stretched triangle spans more cells;
  // a cell the size of the largest box would fill every cell with the items of many).
  m_triangle_box.resize(triangles.size());
  m_segment_box.resize(segments.size());
  m_cell = 0.0;
  double segment_cell = 0.0;
  for (std::size_t k = 0; k < triangles.size(); ++k) {
    Eigen::AlignedBox3d box;
    for (const Index i : triangles[k]) box.extend(Vec3(x.col(i)));
    box.min().array() -= pad;
    box.max().array() += pad;
    m_triangle_box[k] = box;
    m_cell += box.sizes().maxCoeff();
  }
  if (!triangles.empty()) m_cell /= double(triangles.size());
  for (std::size_t k = 0; k < segments.size(); ++k) {
    Eigen::AlignedBox3d box;
    box.extend(Vec3(x.col(segments[k][0])));
    box.extend(Vec3(x.col(segments[k][1])));
    box.min().array() -= 0.5 * pad;  // two boxes grown by half the reach meet within it
    box.max().array() += 0.5 * pad;
    m_segment_box[k] = box;
    segment_cell += box.sizes().maxCoeff();
  }
  if (!segments.empty()) segment_cell /= double(segments.size());
  m_triangle_grid.build(m_triangle_box, m_cell);
  m_segment_grid.build(m_segment_box, segment_cell);
  m_work += double(triangles.size() + segments.size());
}

void SelfCollisions::process(CollisionContext& c) {
  const auto& triangles = c.geometry->triangles;
  const auto& segments = c.geometry->segments;
  m_contacts = 0;
  m_passes_run = 0;
  m_crossings = m_zone_points = m_zone_rounds_run = m_unresolved = 0;
  m_work = 0.0;
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
  // The narrow phase of one pair: responds when the pair is closer than the thickness and returns
  // whether it is closer than twice that (a pair a later pass must look at again).
  int found = 0;
  const auto vertex_triangle = [&](Index i, Index k) {
    const auto& t = triangles[static_cast<std::size_t>(k)];
    const Vec3 p = x.col(i), a = x.col(t[0]), b = x.col(t[1]), cc = x.col(t[2]);
    const std::array<double, 3> w = closest_on_triangle(p, a, b, cc);
    const Vec3 q = w[0] * a + w[1] * b + w[2] * cc;
    const double distance2 = (p - q).squaredNorm();
    if (distance2 >= 4.0 * h * h) return false;
    if (distance2 >= h * h) return true;
    // The face normal, on the side the vertex was at t^n (where it lay within the plane then, the
    // side it is on now).
    Vec3 n = (b - a).cross(cc - a);
    if (!(n.squaredNorm() > 0.0)) return true;
    n.normalize();
    const Vec3 q_n = w[0] * x_n.col(t[0]) + w[1] * x_n.col(t[1]) + w[2] * x_n.col(t[2]);
    const Vec3 n_n = (x_n.col(t[1]) - x_n.col(t[0])).cross(x_n.col(t[2]) - x_n.col(t[0]));
    double side = (x_n.col(i) - q_n).dot(n_n);
    if (side == 0.0) side = (p - q).dot(n);
    if (side < 0.0) n = -n;
    const double d = (p - q).dot(n);
    if (d >= h) return true;
    if (h - d > settled) ++found;
    respond(c, {i, t[0], t[1], t[2]}, {1.0, -w[0], -w[1], -w[2]}, n, h - d);
    return true;
  };
  const auto edge_edge = [&](Index e, Index f) {
    const auto& s0 = segments[static_cast<std::size_t>(e)];
    const Index a0 = segments[static_cast<std::size_t>(f)][0], a1 = segments[static_cast<std::size_t>(f)][1];
    double s, u;
    const Vec3 p0 = x.col(s0[0]), p1 = x.col(s0[1]), q0 = x.col(a0), q1 = x.col(a1);
    closest_on_segments(p0, p1, q0, q1, s, u);
    const Vec3 diff = (1.0 - s) * p0 + s * p1 - ((1.0 - u) * q0 + u * q1);
    const double dist = diff.norm();
    if (dist >= 2.0 * h) return false;
    if (s <= 0.0 || s >= 1.0 || u <= 0.0 || u >= 1.0) return true;  // a vertex's case, for now
    if (dist >= h) return true;
    const Vec3 diff_n = (1.0 - s) * x_n.col(s0[0]) + s * x_n.col(s0[1]) - ((1.0 - u) * x_n.col(a0) + u * x_n.col(a1));
    Vec3 n = dist > 0.0 ? Vec3(diff / dist) : diff_n.normalized();
    if (!n.allFinite() || !(n.squaredNorm() > 0.5)) return true;
    double d = dist;
    if (diff_n.dot(n) < 0.0) {  // crossed within the step: back to the side of t^n
      n = -n;
      d = -dist;
    }
    if (h - d > settled) ++found;
    respond(c, {s0[0], s0[1], a0, a1}, {1.0 - s, s, -(1.0 - u), -u}, n, h - d);
    return true;
  };
  // The first pass finds the pairs through the grids; the later ones revisit those it found within
  // twice the thickness (a pair further apart than that is not brought within the thickness by the
  // pushes of a few passes; one that is, the continuous test below still sees).
  m_near_vertex_triangle.clear();
  m_near_edge_edge.clear();
  bin(c);
  if (m_cell > 0.0) {
    ++m_passes_run;
    m_seen.assign(segments.size(), -1);
    // Vertex against triangle.
    for (const Index i : m_vertices) {
      const Vec3 p = x.col(i);
      m_triangle_grid.query(Eigen::AlignedBox3d(p, p), [&](Index k) {
        ++m_work;
        const auto& t = triangles[static_cast<std::size_t>(k)];
        if (corner_of(i, t) || !m_triangle_box[static_cast<std::size_t>(k)].contains(p)) return;
        if (vertex_triangle(i, k)) m_near_vertex_triangle.push_back({i, k});
      });
    }
    // Edge against edge: each pair once (the later edge found from the earlier), edges sharing no
    // point, closest points inside both.
    for (std::size_t e = 0; e < segments.size(); ++e) {
      const auto& s0 = segments[e];
      const Eigen::AlignedBox3d& box = m_segment_box[e];
      m_segment_grid.query(box, [&](Index f) {
        ++m_work;
        const auto fs = static_cast<std::size_t>(f);
        if (fs <= e || m_seen[fs] == static_cast<Index>(e)) return;
        m_seen[fs] = static_cast<Index>(e);
        const Index a0 = segments[fs][0], a1 = segments[fs][1];
        if (a0 == s0[0] || a0 == s0[1] || a1 == s0[0] || a1 == s0[1]) return;
        if (!box.intersects(m_segment_box[fs])) return;
        if (edge_edge(static_cast<Index>(e), f)) m_near_edge_edge.push_back({static_cast<Index>(e), f});
      });
    }
    m_contacts = found;
    for (int pass = 1; pass < m_settings.passes && found > 0; ++pass) {
      ++m_passes_run;
      found = 0;
      m_work += double(m_near_vertex_triangle.size() + m_near_edge_edge.size());
      for (const auto& [i, k] : m_near_vertex_triangle) vertex_triangle(i, k);
      for (const auto& [e, f] : m_near_edge_edge) edge_edge(e, f);
    }
  }
  if (m_settings.continuous) resolve_crossings(c);
  ++m_totals.steps;
  m_totals.contacts += m_contacts;
  m_totals.crossings += m_crossings;
  m_totals.zone_points += m_zone_points;
  m_totals.unresolved += m_unresolved;
}

// The continuous guarantee, after Provot's and Bridson et al.'s rigid impact zones. Every point
// moves on a straight line from x^n to x over the step; a pair found touching on those paths
// (ccd::vertex_triangle, ccd::edge_edge) joins its points into one zone, and each zone moves as a
// rigid body from x^n: its centre of mass by the zone's mean displacement u_c, its points turned
// about it by the rotation vector theta = I^-1 sum_i m_i r_i x (u_i - u_c), with r_i = x_i^n - c^n
// and I = sum_i m_i (|r_i|^2 1 - r_i r_i^T) (a pseudo-inverse where the zone is collinear), so the
// zone keeps the linear momentum of its displacements exactly and their angular momentum about
// the centre. On the straight path from x^n to the rigid end, the zone's points at time t are the
// image of x^n under the affine map (1 - t) 1 + t R, plus a translation; that map is invertible
// while R turns by less than pi, and an invertible affine map makes no new coplanarity, so a zone
// with no touching pair at t^n has none inside it over the step (|theta| is capped at pi / 2). Zones
// that touch other points merge with them, round after round, until no pair touches: then no
// triangle pair intersects at the end of the step that did not at its start. Velocities change
// with the positions: dv = dx / dt, so the zone's relative approach is gone.
//
// A zone holding points the contact cannot move (kinematic or hard-bound) moves its free points
// with their mean displacement instead (a rigid translation when they move together, as points
// bound to one body that does not turn); where they do not move together, pairs may still touch
// and are counted in unresolved().
void SelfCollisions::resolve_crossings(CollisionContext& c) {
  const Particles& p = *c.particles;
  const auto n = static_cast<std::size_t>(p.size());
  m_x_proposed = *c.x;
  m_parent.assign(n, -1);
  m_changed.assign(n, 1);  // the first round tests every pair
  m_triangle_seen.assign(c.geometry->triangles.size(), -1);
  for (int round = 0; round < m_settings.zone_rounds; ++round) {
    const int found = find_crossings(c);
    if (round == 0) m_crossings = found;
    if (found == 0) return;
    ++m_zone_rounds_run;
    for (const auto& pair : m_pairs) {
      const Index root = zone_of(pair[0]);
      for (std::size_t k = 1; k < 4; ++k) {
        const Index other = zone_of(pair[k]);
        if (other != root) m_parent[static_cast<std::size_t>(other)] = root;
      }
    }
    move_zones(c);
  }
  m_unresolved = find_crossings(c);
}

Index SelfCollisions::zone_of(Index i) {
  auto& parent = m_parent[static_cast<std::size_t>(i)];
  if (parent < 0 || parent == i) {
    parent = i;
    return i;
  }
  const Index root = zone_of(parent);
  parent = root;
  return root;
}

int SelfCollisions::find_crossings(const CollisionContext& c) {
  const auto& triangles = c.geometry->triangles;
  const auto& segments = c.geometry->segments;
  const Vectors3& x_n = *c.x_n;
  const Vectors3& x = *c.x;
  // Pairs closer than this at a coplanarity time touch: far below the thickness, far above the
  // round-off of a bisected root.
  const double eta = 1e-3 * m_settings.thickness;
  m_pairs.clear();
  std::fill(m_triangle_seen.begin(), m_triangle_seen.end(), -1);
  const auto swept = [&](const auto& points) {
    Eigen::AlignedBox3d box;
    for (const Index i : points) {
      box.extend(Vec3(x_n.col(i)));
      box.extend(Vec3(x.col(i)));
    }
    box.min().array() -= eta;
    box.max().array() += eta;
    return box;
  };
  m_swept_triangle_box.resize(triangles.size());
  m_swept_segment_box.resize(segments.size());
  double size = 0.0;
  for (std::size_t k = 0; k < triangles.size(); ++k) {
    m_swept_triangle_box[k] = swept(triangles[k]);
    size += m_swept_triangle_box[k].sizes().maxCoeff();
  }
  for (std::size_t k = 0; k < segments.size(); ++k) m_swept_segment_box[k] = swept(segments[k]);
  // Cells twice the mean swept triangle: a fast triangle spans more of them (or goes to the list
  // every query sees).
  const double cell = triangles.empty() ? 0.0 : 2.0 * size / double(triangles.size());
  m_swept_triangle_grid.build(m_swept_triangle_box, cell);
  m_swept_segment_grid.build(m_swept_segment_box, cell);
  m_work += double(triangles.size() + segments.size());
  const auto changed = [&](Index i) { return m_changed[static_cast<std::size_t>(i)] != 0; };
  // Vertex against triangle.
  for (const Index i : m_vertices) {
    const Eigen::AlignedBox3d path(x_n.col(i).cwiseMin(x.col(i)), x_n.col(i).cwiseMax(x.col(i)));
    m_swept_triangle_grid.query(path, [&](Index k) {
      ++m_work;
      const auto ks = static_cast<std::size_t>(k);
      if (m_triangle_seen[ks] == i) return;
      m_triangle_seen[ks] = i;
      const auto& t = triangles[ks];
      if (i == t[0] || i == t[1] || i == t[2]) return;
      if (!(changed(i) || changed(t[0]) || changed(t[1]) || changed(t[2]))) return;
      if (!m_swept_triangle_box[ks].intersects(path)) return;
      m_work += kContinuousTestWork;
      if (ccd::vertex_triangle(x_n.col(i), x_n.col(t[0]), x_n.col(t[1]), x_n.col(t[2]), x.col(i), x.col(t[0]),
                               x.col(t[1]), x.col(t[2]), eta))
        m_pairs.push_back({i, t[0], t[1], t[2]});
    });
  }
  // Edge against edge, each pair once.
  m_seen.assign(segments.size(), -1);
  for (std::size_t e = 0; e < segments.size(); ++e) {
    const auto& s0 = segments[e];
    const Eigen::AlignedBox3d& box = m_swept_segment_box[e];
    m_swept_segment_grid.query(box, [&](Index f) {
      ++m_work;
      const auto fs = static_cast<std::size_t>(f);
      if (fs <= e || m_seen[fs] == static_cast<Index>(e)) return;
      m_seen[fs] = static_cast<Index>(e);
      const Index a0 = segments[fs][0], a1 = segments[fs][1];
      if (a0 == s0[0] || a0 == s0[1] || a1 == s0[0] || a1 == s0[1]) return;
      if (!(changed(s0[0]) || changed(s0[1]) || changed(a0) || changed(a1))) return;
      if (!box.intersects(m_swept_segment_box[fs])) return;
      m_work += kContinuousTestWork;
      if (ccd::edge_edge(x_n.col(s0[0]), x_n.col(s0[1]), x_n.col(a0), x_n.col(a1), x.col(s0[0]), x.col(s0[1]),
                         x.col(a0), x.col(a1), eta))
        m_pairs.push_back({s0[0], s0[1], a0, a1});
    });
  }
  return static_cast<int>(m_pairs.size());
}

void SelfCollisions::move_zones(CollisionContext& c) {
  const Particles& p = *c.particles;
  const Vectors3& x_n = *c.x_n;
  Vectors3& x = *c.x;
  Vectors3& v = *c.v;
  const auto movable = [&](Index i) { return is_dynamic(p.kind[i]) && p.mass[i] > 0.0; };
  // Members grouped by zone, in index order within each (a deterministic order for the sums).
  m_zone_member.clear();
  for (Index i = 0; i < p.size(); ++i)
    if (m_parent[static_cast<std::size_t>(i)] >= 0) m_zone_member.push_back({zone_of(i), i});
  std::sort(m_zone_member.begin(), m_zone_member.end());
  std::fill(m_changed.begin(), m_changed.end(), 0);
  m_zone_points = 0;
  for (std::size_t begin = 0; begin < m_zone_member.size();) {
    std::size_t end = begin;
    while (end < m_zone_member.size() && m_zone_member[end][0] == m_zone_member[begin][0]) ++end;
    // The zone's fixed points' mean displacement, or its rigid motion.
    Vec3 fixed_u = Vec3::Zero();
    int fixed = 0;
    double mass = 0.0;
    Vec3 centre = Vec3::Zero(), u_c = Vec3::Zero();
    for (std::size_t k = begin; k < end; ++k) {
      const Index i = m_zone_member[k][1];
      const Vec3 u = m_x_proposed.col(i) - x_n.col(i);
      if (!movable(i)) {
        fixed_u += u;
        ++fixed;
        continue;
      }
      mass += p.mass[i];
      centre += p.mass[i] * x_n.col(i);
      u_c += p.mass[i] * u;
    }
    Vec3 theta = Vec3::Zero();
    if (fixed > 0) {
      u_c = fixed_u / fixed;
    } else if (mass > 0.0) {
      centre /= mass;
      u_c /= mass;
      Mat3 inertia = Mat3::Zero();
      Vec3 spin = Vec3::Zero();
      for (std::size_t k = begin; k < end; ++k) {
        const Index i = m_zone_member[k][1];
        const Vec3 r = x_n.col(i) - centre;
        inertia += p.mass[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
        spin += p.mass[i] * r.cross(Vec3(m_x_proposed.col(i) - x_n.col(i)) - u_c);
      }
      theta = inertia.completeOrthogonalDecomposition().solve(spin);
      const double angle = theta.norm();
      constexpr double kMaxTurn = 0.5 * 3.14159265358979323846;
      if (!std::isfinite(angle)) theta.setZero();
      else if (angle > kMaxTurn) theta *= kMaxTurn / angle;
    }
    const double angle = theta.norm();
    const Mat3 R = angle > 0.0 ? Mat3(Eigen::AngleAxisd(angle, theta / angle)) : Mat3::Identity();
    for (std::size_t k = begin; k < end; ++k) {
      const Index i = m_zone_member[k][1];
      if (!movable(i)) continue;
      const Vec3 target = fixed > 0 ? Vec3(x_n.col(i) + u_c) : Vec3(centre + u_c + R * (x_n.col(i) - centre));
      const Vec3 dx = target - x.col(i);
      if (dx.squaredNorm() == 0.0) continue;
      x.col(i) = target;
      v.col(i) += dx / c.dt;
      m_changed[static_cast<std::size_t>(i)] = 1;
    }
    m_zone_points += static_cast<int>(end - begin);
    begin = end;
  }
}

}  // namespace sinew
