#include "sinew/plasticity.hpp"

#include <algorithm>
#include <cmath>
#include <map>

namespace sinew {

namespace {

// Barycentric weights of p in tet (a, b, c, d); false when the tet is (nearly) flat.
bool weights_in(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, const Vec3& p, std::array<double, 4>& w) {
  Mat3 m;
  m << b - a, c - a, d - a;
  const double det = m.determinant();
  const double scale = (b - a).norm() * (c - a).norm() * (d - a).norm();
  if (!(std::abs(det) > 1e-12 * scale)) return false;
  const Vec3 u = m.inverse() * (p - a);
  w = {1.0 - u.sum(), u[0], u[1], u[2]};
  return true;
}

// Weights at or above -kInside count as inside: a point on a face shared by two tets is in either.
constexpr double kInside = 1e-12;
// A spring brought back to L_y is L_y long to round-off; it yields again only past L_y (1 + kSlack).
constexpr double kSlack = 1e-12;
// Bisection steps along a move that would leave the material: the stop is found to 2^-40 of it.
constexpr int kBisections = 40;

}  // namespace

struct PlasticSurface::Material {
  Vectors3 vertices;
  std::vector<std::array<Index, 3>> triangles;
  std::unique_ptr<SurfaceInside> inside;
};

PlasticSurface::PlasticSurface(const Vectors3& rest_vertices, std::vector<std::array<Index, 4>> tets,
                               std::vector<Index> vertex_particles, const Vectors3& material_vertices,
                               const std::vector<std::array<Index, 3>>& material_triangles, double yield_length)
    : m_rest(rest_vertices),
      m_tets(std::move(tets)),
      m_particle_of(std::move(vertex_particles)),
      m_material(std::make_unique<Material>()),
      m_yield_length(yield_length) {
  if (!(std::isfinite(yield_length) && yield_length > 0.0))
    fail("plastic surface: yield length ", yield_length, " must be positive and finite");
  if (static_cast<Index>(m_particle_of.size()) != m_rest.cols())
    fail("plastic surface: ", m_particle_of.size(), " vertex particles for ", m_rest.cols(), " rest vertices");
  for (std::size_t t = 0; t < m_tets.size(); ++t)
    for (const Index v : m_tets[t])
      if (v < 0 || v >= m_rest.cols())
        fail("plastic surface: tet ", t, " has vertex ", v, ", which is not a rest vertex (there are ", m_rest.cols(),
             ")");
  m_material->vertices = material_vertices;
  m_material->triangles = material_triangles;
  m_material->inside = std::make_unique<SurfaceInside>(m_material->vertices, m_material->triangles);
  // Face neighbours: the tet across the face opposite each vertex.
  std::map<std::array<Index, 3>, std::pair<Index, int>> open;
  m_neighbour.assign(m_tets.size(), {-1, -1, -1, -1});
  for (std::size_t t = 0; t < m_tets.size(); ++t)
    for (int j = 0; j < 4; ++j) {
      std::array<Index, 3> face{};
      for (int k = 0, n = 0; k < 4; ++k)
        if (k != j) face[static_cast<std::size_t>(n++)] = m_tets[t][static_cast<std::size_t>(k)];
      std::sort(face.begin(), face.end());
      const auto [it, fresh] = open.try_emplace(face, static_cast<Index>(t), j);
      if (!fresh) {
        m_neighbour[t][static_cast<std::size_t>(j)] = it->second.first;
        m_neighbour[static_cast<std::size_t>(it->second.first)][static_cast<std::size_t>(it->second.second)] =
            static_cast<Index>(t);
      }
    }
}

PlasticSurface::~PlasticSurface() = default;
PlasticSurface::PlasticSurface(PlasticSurface&&) noexcept = default;
PlasticSurface& PlasticSurface::operator=(PlasticSurface&&) noexcept = default;

Index PlasticSurface::add_target(System& system, const Vec3& X) {
  if (!all_finite(X)) fail("plastic surface: target rest point (", X.transpose(), ") is not finite");
  std::array<double, 4> w{};
  const Index tet = locate(nullptr, X, -1, w);
  if (tet < 0) fail("plastic surface: no tet holds the target rest point (", X.transpose(), ")");
  std::array<Index, 4> parents{};
  for (int k = 0; k < 4; ++k)
    parents[static_cast<std::size_t>(k)] =
        m_particle_of[static_cast<std::size_t>(m_tets[static_cast<std::size_t>(tet)][static_cast<std::size_t>(k)])];
  const Index particle = system.add_embedded_point(parents, w);
  m_targets.push_back({particle, -1, tet, w});
  return particle;
}

void PlasticSurface::track(Index soft, Index target) {
  Target& t = target_of(target);
  t.soft = soft;
}

PlasticSurface::Target& PlasticSurface::target_of(Index particle) {
  for (Target& t : m_targets)
    if (t.particle == particle) return t;
  fail("plastic surface: particle ", particle, " is not one of its targets (make it with add_target)");
}

Vec3 PlasticSurface::material_point(Index target) const {
  for (const Target& t : m_targets)
    if (t.particle == target) return rest_point(t.tet, t.weights);
  fail("plastic surface: particle ", target, " is not one of its targets");
}

Vec3 PlasticSurface::rest_point(Index tet, const std::array<double, 4>& weights) const {
  Vec3 X = Vec3::Zero();
  for (int k = 0; k < 4; ++k)
    X += weights[static_cast<std::size_t>(k)] *
         m_rest.col(m_tets[static_cast<std::size_t>(tet)][static_cast<std::size_t>(k)]);
  return X;
}

Index PlasticSurface::locate(const Vectors3* x, const Vec3& p, Index start, std::array<double, 4>& weights) const {
  auto corner = [&](Index t, int k) {
    const Index v = m_tets[static_cast<std::size_t>(t)][static_cast<std::size_t>(k)];
    return Vec3(x != nullptr ? x->col(m_particle_of[static_cast<std::size_t>(v)]) : m_rest.col(v));
  };
  auto weights_of = [&](Index t, std::array<double, 4>& w) {
    return weights_in(corner(t, 0), corner(t, 1), corner(t, 2), corner(t, 3), p, w);
  };
  std::array<double, 4> w{};
  // The walk: across the face opposite the most negative weight, a bounded number of times (a
  // deformed mesh may have inverted tets, where a walk can circle).
  Index t = start;
  for (int steps = 0; t >= 0 && steps < 256; ++steps) {
    if (!weights_of(t, w)) break;
    const auto lowest = std::min_element(w.begin(), w.end());
    if (*lowest >= -kInside) {
      weights = w;
      return t;
    }
    t = m_neighbour[static_cast<std::size_t>(t)][static_cast<std::size_t>(lowest - w.begin())];
  }
  // Every tet, the first (in order) that holds p.
  for (std::size_t s = 0; s < m_tets.size(); ++s)
    if (weights_of(static_cast<Index>(s), w) && *std::min_element(w.begin(), w.end()) >= -kInside) {
      weights = w;
      return static_cast<Index>(s);
    }
  return -1;
}

YieldStats PlasticSurface::yield(System& system) {
  YieldStats stats;
  const Vectors3& x = system.particles().x;
  for (Target& t : m_targets) {
    if (t.soft < 0) continue;
    const Vec3 from = x.col(t.particle);
    const Vec3 d = x.col(t.soft) - from;
    const double length = d.norm();
    if (!(length > m_yield_length * (1.0 + kSlack))) continue;
    const Vec3 step = d * (1.0 - m_yield_length / length);
    // The rest point the target would move to along a fraction s of `step`, if a tet holds it.
    std::array<double, 4> w{};
    auto place = [&](double s, Index& tet, std::array<double, 4>& weights) {
      tet = locate(&x, from + s * step, t.tet, weights);
      return tet >= 0 && m_material->inside->inside(rest_point(tet, weights));
    };
    Index tet = -1;
    bool stopped = false;
    if (!place(1.0, tet, w)) {
      // Leaves the material: bisect for the last place inside it along the move.
      stopped = true;
      double inside = 0.0, outside = 1.0;
      Index inside_tet = -1;
      std::array<double, 4> inside_w{};
      for (int k = 0; k < kBisections; ++k) {
        const double s = 0.5 * (inside + outside);
        Index trial = -1;
        std::array<double, 4> trial_w{};
        if (place(s, trial, trial_w)) {
          inside = s;
          inside_tet = trial;
          inside_w = trial_w;
        } else {
          outside = s;
        }
      }
      if (inside_tet < 0) continue;  // no step along the move stays in the material
      tet = inside_tet;
      w = inside_w;
    }
    const Vec3 before = rest_point(t.tet, t.weights);
    std::array<Index, 4> parents{};
    for (int k = 0; k < 4; ++k)
      parents[static_cast<std::size_t>(k)] =
          m_particle_of[static_cast<std::size_t>(m_tets[static_cast<std::size_t>(tet)][static_cast<std::size_t>(k)])];
    system.reembed(t.particle, parents, w);
    t.tet = tet;
    t.weights = w;
    ++stats.moved;
    if (stopped) ++stats.stopped;
    stats.largest_move = std::max(stats.largest_move, (rest_point(tet, w) - before).norm());
  }
  return stats;
}

}  // namespace sinew
