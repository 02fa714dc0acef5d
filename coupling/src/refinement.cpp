#include "sinew/refinement.hpp"

#include "sinew/embedding.hpp"
#include "sinew/system.hpp"

#include <algorithm>
#include <functional>
#include <set>

namespace sinew {

namespace {

std::pair<Index, Index> key(Index a, Index b) { return a < b ? std::pair{a, b} : std::pair{b, a}; }

// Distance from p to segment (a, b).
double segment_distance(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double length2 = ab.squaredNorm();
  const double t = length2 > 0.0 ? std::clamp((p - a).dot(ab) / length2, 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

// The T-junctions of a mesh: each midpoint whose split edge, or an edge that edge is a half of, a
// triangle still has whole.
void find_t_junctions(RefinedTriangles& mesh) {
  std::set<std::pair<Index, Index>> edges;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k)
      edges.insert(key(t[static_cast<std::size_t>(k)], t[static_cast<std::size_t>((k + 1) % 3)]));
  mesh.t_junctions.clear();
  for (const auto& [segment, vertex] : mesh.midpoint) {
    std::pair<Index, Index> e = segment;
    while (!edges.count(e)) {
      const auto up = mesh.half_of.find(e);
      if (up == mesh.half_of.end()) break;
      e = up->second;
    }
    if (edges.count(e)) mesh.t_junctions.push_back({vertex, {segment.first, segment.second}, {e.first, e.second}});
  }
  std::sort(
      mesh.t_junctions.begin(), mesh.t_junctions.end(),
      [](const RefinedTriangles::TJunction& a, const RefinedTriangles::TJunction& b) { return a.vertex < b.vertex; });
}

}  // namespace

RefinedTriangles unrefined(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles) {
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const auto& v = triangles[t];
    for (const Index i : v)
      if (i < 0 || i >= vertices.cols())
        fail("triangle ", t, ": vertex ", i, " does not exist (there are ", vertices.cols(), ")");
    if (v[0] == v[1] || v[1] == v[2] || v[0] == v[2]) fail("triangle ", t, " repeats a vertex");
  }
  RefinedTriangles mesh;
  mesh.vertices = vertices;
  mesh.triangles = triangles;
  mesh.level.assign(triangles.size(), 0);
  return mesh;
}

RefinedTriangles red_refine(const RefinedTriangles& mesh, std::span<const Index> chosen) {
  const Index count = static_cast<Index>(mesh.triangles.size());
  std::vector<std::uint8_t> split(mesh.triangles.size(), 0);
  for (const Index t : chosen) {
    if (t < 0 || t >= count) fail("red_refine: triangle ", t, " does not exist (there are ", count, ")");
    split[static_cast<std::size_t>(t)] = 1;
  }
  RefinedTriangles out;
  out.midpoint = mesh.midpoint;
  out.half_of = mesh.half_of;
  std::vector<Vec3> added;
  const auto middle = [&](Index a, Index b) {
    const auto k = key(a, b);
    const auto found = out.midpoint.find(k);
    if (found != out.midpoint.end()) return found->second;
    const Index m = mesh.vertices.cols() + static_cast<Index>(added.size());
    added.push_back(0.5 * (mesh.vertices.col(a) + mesh.vertices.col(b)));
    out.midpoint.emplace(k, m);
    out.half_of.emplace(key(a, m), k);
    out.half_of.emplace(key(m, b), k);
    return m;
  };
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    if (!split[t]) continue;
    const auto [a, b, c] = mesh.triangles[t];
    const Index ab = middle(a, b), bc = middle(b, c), ca = middle(c, a);
    const int level = mesh.level[t] + 1;
    for (const std::array<Index, 3>& child : {std::array<Index, 3>{a, ab, ca}, std::array<Index, 3>{ab, b, bc},
                                              std::array<Index, 3>{ca, bc, c}, std::array<Index, 3>{ab, bc, ca}}) {
      out.triangles.push_back(child);
      out.level.push_back(level);
    }
  }
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    if (!split[t]) {
      out.triangles.push_back(mesh.triangles[t]);
      out.level.push_back(mesh.level[t]);
    }
  out.vertices.resize(3, mesh.vertices.cols() + static_cast<Index>(added.size()));
  out.vertices.leftCols(mesh.vertices.cols()) = mesh.vertices;
  for (std::size_t k = 0; k < added.size(); ++k)
    out.vertices.col(mesh.vertices.cols() + static_cast<Index>(k)) = added[k];
  find_t_junctions(out);
  return out;
}

Index bind_t_junctions(System& system, const RefinedTriangles& mesh, std::span<const Index> particles) {
  if (static_cast<Index>(particles.size()) != mesh.vertices.cols())
    fail("bind_t_junctions: ", particles.size(), " particles for ", mesh.vertices.cols(), " vertices");
  const std::array<double, 2> half{0.5, 0.5};
  for (const auto& t : mesh.t_junctions) {
    const std::array<Index, 2> ends{particles[static_cast<std::size_t>(t.segment[0])],
                                    particles[static_cast<std::size_t>(t.segment[1])]};
    system.bind_linear(particles[static_cast<std::size_t>(t.vertex)], ends, half);
  }
  return static_cast<Index>(mesh.t_junctions.size());
}

double largest_t_junction_gap(const RefinedTriangles& mesh, const Vectors3& x) {
  double gap = 0.0;
  for (const auto& t : mesh.t_junctions)
    gap = std::max(gap, segment_distance(x.col(t.vertex), x.col(t.edge[0]), x.col(t.edge[1])));
  return gap;
}

// ---- tets ---------------------------------------------------------------------------------------

namespace {

double signed_volume(const Vectors3& x, const std::array<Index, 4>& t) {
  Mat3 e;
  e << x.col(t[1]) - x.col(t[0]), x.col(t[2]) - x.col(t[0]), x.col(t[3]) - x.col(t[0]);
  return e.determinant() / 6.0;
}

// The hanging nodes of a mesh: every existing midpoint on an edge of a tet, and on its faces' red
// splits, recursively (a face split as a neighbour's children split it is four red sub-triangles).
void find_hanging_nodes(RefinedTets& mesh) {
  std::map<Index, RefinedTets::HangingNode> found;
  std::map<Index, std::pair<Index, Index>> segment_of;
  for (const auto& [segment, vertex] : mesh.midpoint) segment_of.emplace(vertex, segment);
  const auto middle = [&](Index a, Index b) {
    const auto it = mesh.midpoint.find(key(a, b));
    return it == mesh.midpoint.end() ? Index{-1} : it->second;
  };
  for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
    const auto& tet = mesh.tets[t];
    const auto mark = [&](Index m) {
      if (found.count(m)) return;
      RefinedTets::HangingNode node;
      node.vertex = m;
      const auto segment = segment_of.at(m);
      node.segment = {segment.first, segment.second};
      node.host = static_cast<Index>(t);
      node.weights = tet_weights(mesh.vertices.col(tet[0]), mesh.vertices.col(tet[1]), mesh.vertices.col(tet[2]),
                                 mesh.vertices.col(tet[3]), mesh.vertices.col(m));
      found.emplace(m, node);
    };
    std::function<void(Index, Index)> edge = [&](Index a, Index b) {
      const Index m = middle(a, b);
      if (m < 0) return;
      mark(m);
      edge(a, m);
      edge(m, b);
    };
    std::function<void(Index, Index, Index)> face = [&](Index a, Index b, Index c) {
      const Index ab = middle(a, b), bc = middle(b, c), ca = middle(c, a);
      if (ab < 0 || bc < 0 || ca < 0) return;  // not split red: its edges were marked on their own
      face(a, ab, ca);
      face(ab, b, bc);
      face(ca, bc, c);
      face(ab, bc, ca);
      edge(ab, bc);
      edge(bc, ca);
      edge(ca, ab);
    };
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j) edge(tet[static_cast<std::size_t>(i)], tet[static_cast<std::size_t>(j)]);
    face(tet[0], tet[1], tet[2]);
    face(tet[0], tet[1], tet[3]);
    face(tet[0], tet[2], tet[3]);
    face(tet[1], tet[2], tet[3]);
  }
  mesh.hanging.clear();
  for (const auto& [vertex, node] : found) mesh.hanging.push_back(node);
}

}  // namespace

RefinedTets unrefined_tets(const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets) {
  for (std::size_t t = 0; t < tets.size(); ++t) {
    const auto& v = tets[t];
    for (const Index i : v)
      if (i < 0 || i >= vertices.cols())
        fail("tet ", t, ": vertex ", i, " does not exist (there are ", vertices.cols(), ")");
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j)
        if (v[static_cast<std::size_t>(i)] == v[static_cast<std::size_t>(j)]) fail("tet ", t, " repeats a vertex");
    const double volume = signed_volume(vertices, v);
    if (!(volume > 0.0)) fail("tet ", t, " has volume ", volume, " (it must be positive)");
  }
  RefinedTets mesh;
  mesh.vertices = vertices;
  mesh.tets = tets;
  mesh.level.assign(tets.size(), 0);
  return mesh;
}

RefinedTets red_refine(const RefinedTets& mesh, std::span<const Index> chosen) {
  const Index count = static_cast<Index>(mesh.tets.size());
  std::vector<std::uint8_t> split(mesh.tets.size(), 0);
  for (const Index t : chosen) {
    if (t < 0 || t >= count) fail("red_refine: tet ", t, " does not exist (there are ", count, ")");
    split[static_cast<std::size_t>(t)] = 1;
  }
  RefinedTets out;
  out.midpoint = mesh.midpoint;
  std::vector<Vec3> added;
  const auto position = [&](Index v) {
    return v < mesh.vertices.cols() ? Vec3(mesh.vertices.col(v))
                                    : added[static_cast<std::size_t>(v - mesh.vertices.cols())];
  };
  const auto middle = [&](Index a, Index b) {
    const auto k = key(a, b);
    const auto found = out.midpoint.find(k);
    if (found != out.midpoint.end()) return found->second;
    const Index m = mesh.vertices.cols() + static_cast<Index>(added.size());
    added.push_back(0.5 * (position(a) + position(b)));
    out.midpoint.emplace(k, m);
    return m;
  };
  const auto push = [&](std::array<Index, 4> t, int level) {
    Mat3 e;
    e << position(t[1]) - position(t[0]), position(t[2]) - position(t[0]), position(t[3]) - position(t[0]);
    if (e.determinant() < 0.0) std::swap(t[2], t[3]);
    out.tets.push_back(t);
    out.level.push_back(level);
  };
  for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
    if (!split[t]) continue;
    const auto [a, b, c, d] = mesh.tets[t];
    const Index ab = middle(a, b), ac = middle(a, c), ad = middle(a, d), bc = middle(b, c), bd = middle(b, d),
                cd = middle(c, d);
    const int level = mesh.level[t] + 1;
    push({a, ab, ac, ad}, level);
    push({ab, b, bc, bd}, level);
    push({ac, bc, c, cd}, level);
    push({ad, bd, cd, d}, level);
    // The octahedron: four tets around its shortest diagonal, each with two neighbours on its
    // equator (ties to the first, for the same mesh every run).
    const std::array<std::array<Index, 6>, 3> ways{
        {{ab, cd, ac, ad, bd, bc}, {ac, bd, ab, ad, cd, bc}, {ad, bc, ab, ac, cd, bd}}};
    std::size_t best = 0;
    for (std::size_t w = 1; w < ways.size(); ++w)
      if ((position(ways[w][0]) - position(ways[w][1])).squaredNorm() <
          (position(ways[best][0]) - position(ways[best][1])).squaredNorm())
        best = w;
    const auto& o = ways[best];
    for (int k = 0; k < 4; ++k)
      push({o[0], o[1], o[static_cast<std::size_t>(2 + k)], o[static_cast<std::size_t>(2 + (k + 1) % 4)]}, level);
  }
  for (std::size_t t = 0; t < mesh.tets.size(); ++t)
    if (!split[t]) {
      out.tets.push_back(mesh.tets[t]);
      out.level.push_back(mesh.level[t]);
    }
  out.vertices.resize(3, mesh.vertices.cols() + static_cast<Index>(added.size()));
  out.vertices.leftCols(mesh.vertices.cols()) = mesh.vertices;
  for (std::size_t k = 0; k < added.size(); ++k)
    out.vertices.col(mesh.vertices.cols() + static_cast<Index>(k)) = added[k];
  find_hanging_nodes(out);
  return out;
}

Index bind_hanging_nodes(System& system, const RefinedTets& mesh, std::span<const Index> particles) {
  if (static_cast<Index>(particles.size()) != mesh.vertices.cols())
    fail("bind_hanging_nodes: ", particles.size(), " particles for ", mesh.vertices.cols(), " vertices");
  const std::array<double, 2> half{0.5, 0.5};
  for (const auto& node : mesh.hanging) {
    const std::array<Index, 2> ends{particles[static_cast<std::size_t>(node.segment[0])],
                                    particles[static_cast<std::size_t>(node.segment[1])]};
    system.bind_linear(particles[static_cast<std::size_t>(node.vertex)], ends, half);
  }
  return static_cast<Index>(mesh.hanging.size());
}

double largest_hanging_gap(const RefinedTets& mesh, const Vectors3& x) {
  double gap = 0.0;
  for (const auto& node : mesh.hanging) {
    const auto& host = mesh.tets[static_cast<std::size_t>(node.host)];
    Vec3 p = Vec3::Zero();
    for (int k = 0; k < 4; ++k)
      p += node.weights[static_cast<std::size_t>(k)] * x.col(host[static_cast<std::size_t>(k)]);
    gap = std::max(gap, (x.col(node.vertex) - p).norm());
  }
  return gap;
}

}  // namespace sinew
