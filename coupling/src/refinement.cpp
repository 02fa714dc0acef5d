#include "sinew/refinement.hpp"

#include "sinew/system.hpp"

#include <algorithm>
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

}  // namespace sinew
