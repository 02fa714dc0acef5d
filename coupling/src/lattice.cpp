#include "sinew/lattice.hpp"

#include "sinew/embedding.hpp"

#include <algorithm>
#include <cmath>

namespace sinew {

namespace {

// Side of p against the edge a -> b in the (y, z) plane, as if p were at (p.y + eps, p.z + eps^2):
// the exact orientation when it is not zero, else the sign its perturbation gives (the derivative
// along y, -(b.z - a.z), then along z, b.y - a.y). Zero only when the edge projects to a point.
int perturbed_side(const Vec3& a, const Vec3& b, const Vec3& p) {
  const double o = (b.y() - a.y()) * (p.z() - a.z()) - (b.z() - a.z()) * (p.y() - a.y());
  if (o != 0.0) return o > 0.0 ? 1 : -1;
  if (b.z() != a.z()) return b.z() < a.z() ? 1 : -1;
  if (b.y() != a.y()) return b.y() > a.y() ? 1 : -1;
  return 0;
}

// Centroids, in barycentric coordinates, of the 64 tets of two rounds of red refinement: every
// child of a red refinement has an eighth of its parent's volume, so the 64 points are an
// equal-weight quadrature of the tet.
std::vector<std::array<double, 4>> refinement_centroids() {
  using Bary = std::array<double, 4>;
  using Tet = std::array<Bary, 4>;
  const auto mid = [](const Bary& a, const Bary& b) {
    Bary m;
    for (int k = 0; k < 4; ++k) m[k] = 0.5 * (a[k] + b[k]);
    return m;
  };
  const auto refine = [&](const Tet& t) {
    const Bary m01 = mid(t[0], t[1]), m02 = mid(t[0], t[2]), m03 = mid(t[0], t[3]);
    const Bary m12 = mid(t[1], t[2]), m13 = mid(t[1], t[3]), m23 = mid(t[2], t[3]);
    // The four corners, and the octahedron cut along its diagonal m02 - m13 around the ring
    // m01, m03, m23, m12 (consecutive ones share a corner of the parent).
    return std::array<Tet, 8>{Tet{t[0], m01, m02, m03}, Tet{m01, t[1], m12, m13}, Tet{m02, m12, t[2], m23},
                              Tet{m03, m13, m23, t[3]}, Tet{m02, m13, m01, m03},  Tet{m02, m13, m03, m23},
                              Tet{m02, m13, m23, m12},  Tet{m02, m13, m12, m01}};
  };
  const Tet unit{Bary{1, 0, 0, 0}, Bary{0, 1, 0, 0}, Bary{0, 0, 1, 0}, Bary{0, 0, 0, 1}};
  std::vector<Bary> points;
  for (const Tet& child : refine(unit))
    for (const Tet& grandchild : refine(child)) {
      Bary c{};
      for (const Bary& corner : grandchild)
        for (int k = 0; k < 4; ++k) c[k] += 0.25 * corner[k];
      points.push_back(c);
    }
  return points;
}

}  // namespace

SurfaceInside::SurfaceInside(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles)
    : m_x(vertices), m_triangles(triangles) {
  if (triangles.empty()) fail("closed surface: it has no triangles");
  for (Index v = 0; v < vertices.cols(); ++v)
    if (!vertices.col(v).allFinite()) fail("closed surface: vertex ", v, " is not finite");
  std::vector<std::array<Index, 2>> edges;
  edges.reserve(3 * triangles.size());
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const auto& tri = triangles[t];
    for (int k = 0; k < 3; ++k) {
      if (tri[k] < 0 || tri[k] >= vertices.cols())
        fail("closed surface: triangle ", t, " refers to vertex ", tri[k], ", which does not exist");
      if (tri[k] == tri[(k + 1) % 3]) fail("closed surface: triangle ", t, " repeats vertex ", tri[k]);
      edges.push_back({std::min(tri[k], tri[(k + 1) % 3]), std::max(tri[k], tri[(k + 1) % 3])});
    }
  }
  // Closed: every edge in exactly two triangles (a hole's rim is in one, a fin's spine in three).
  std::sort(edges.begin(), edges.end());
  for (std::size_t e = 0; e < edges.size();) {
    std::size_t run = e;
    while (run < edges.size() && edges[run] == edges[e]) ++run;
    if (run - e != 2)
      fail("closed surface: edge (", edges[e][0], ", ", edges[e][1], ") is used by ", run - e,
           " triangle(s), expected 2: the surface is not closed");
    e = run;
  }
  double volume = 0.0;
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(kInfinity), hi = -lo;
  double extent = 0.0;
  for (const auto& tri : triangles) {
    const Vec3 a = vertices.col(tri[0]), b = vertices.col(tri[1]), c = vertices.col(tri[2]);
    volume += a.dot(b.cross(c)) / 6.0;
    Eigen::Vector2d t_lo = Eigen::Vector2d::Constant(kInfinity), t_hi = -t_lo;
    for (const Vec3& p : {a, b, c}) {
      t_lo = t_lo.cwiseMin(p.tail<2>());
      t_hi = t_hi.cwiseMax(p.tail<2>());
    }
    lo = lo.cwiseMin(t_lo);
    hi = hi.cwiseMax(t_hi);
    extent += (t_hi - t_lo).maxCoeff();
  }
  m_volume = std::abs(volume);
  // Bins the mean size of a triangle's shadow, at most 1024 a side.
  const double size = (hi - lo).maxCoeff();
  m_cell = std::max(extent / double(triangles.size()), size / 1024.0);
  if (!(m_cell > 0.0)) m_cell = 1.0;  // a flat surface: one bin (it encloses nothing anyway)
  m_min = lo;
  m_ny = static_cast<int>(std::floor((hi.x() - lo.x()) / m_cell)) + 1;
  m_nz = static_cast<int>(std::floor((hi.y() - lo.y()) / m_cell)) + 1;
  const auto bin_range = [&](double a, double b, int n) {
    const int i0 = std::clamp(static_cast<int>(std::floor(a / m_cell)), 0, n - 1);
    const int i1 = std::clamp(static_cast<int>(std::floor(b / m_cell)), 0, n - 1);
    return std::array<int, 2>{i0, i1};
  };
  m_offsets.assign(static_cast<std::size_t>(m_ny) * m_nz + 1, 0);
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<Index> cursor;
    if (pass == 1) {
      for (std::size_t b = 1; b < m_offsets.size(); ++b) m_offsets[b] += m_offsets[b - 1];
      m_items.resize(static_cast<std::size_t>(m_offsets.back()));
      cursor.assign(m_offsets.begin(), m_offsets.end() - 1);
    }
    for (std::size_t t = 0; t < triangles.size(); ++t) {
      const auto& tri = triangles[t];
      double y0 = kInfinity, y1 = -kInfinity, z0 = kInfinity, z1 = -kInfinity;
      for (Index v : tri) {
        y0 = std::min(y0, vertices(1, v) - lo.x());
        y1 = std::max(y1, vertices(1, v) - lo.x());
        z0 = std::min(z0, vertices(2, v) - lo.y());
        z1 = std::max(z1, vertices(2, v) - lo.y());
      }
      const auto ys = bin_range(y0, y1, m_ny), zs = bin_range(z0, z1, m_nz);
      for (int k = zs[0]; k <= zs[1]; ++k)
        for (int j = ys[0]; j <= ys[1]; ++j) {
          const std::size_t b = static_cast<std::size_t>(k) * m_ny + j;
          if (pass == 0) ++m_offsets[b + 1];
          else m_items[static_cast<std::size_t>(cursor[b]++)] = static_cast<Index>(t);
        }
    }
  }
}

bool SurfaceInside::inside(const Vec3& p) const {
  const double y = (p.y() - m_min.x()) / m_cell, z = (p.z() - m_min.y()) / m_cell;
  if (!(y >= 0.0 && z >= 0.0 && y < m_ny && z < m_nz)) return false;  // outside every shadow (or NaN)
  const std::size_t b = static_cast<std::size_t>(std::floor(z)) * m_ny + static_cast<std::size_t>(std::floor(y));
  bool in = false;
  for (Index k = m_offsets[b]; k < m_offsets[b + 1]; ++k) {
    const auto& tri = m_triangles[static_cast<std::size_t>(m_items[static_cast<std::size_t>(k)])];
    // Each edge's side in one vertex order (lower index first), whichever triangle asks.
    int side[3];
    for (int e = 0; e < 3; ++e) {
      const Index u = tri[e], w = tri[(e + 1) % 3];
      side[e] = u < w ? perturbed_side(m_x.col(u), m_x.col(w), p) : -perturbed_side(m_x.col(w), m_x.col(u), p);
    }
    if (side[0] == 0 || side[0] != side[1] || side[1] != side[2]) continue;
    // The ray meets the triangle's plane at x: barycentric interpolation by the sub-areas.
    const Vec3 a = m_x.col(tri[0]), bb = m_x.col(tri[1]), c = m_x.col(tri[2]);
    const auto area = [&](const Vec3& u, const Vec3& w) {
      return (w.y() - u.y()) * (p.z() - u.z()) - (w.z() - u.z()) * (p.y() - u.y());
    };
    const double wa = area(bb, c), wb = area(c, a), wc = area(a, bb);
    const double sum = wa + wb + wc;
    if (sum == 0.0) continue;  // seen edge-on: the neighbours decide
    const double x = (wa * a.x() + wb * bb.x() + wc * c.x()) / sum;
    if (x > p.x()) in = !in;
  }
  return in;
}

EmbeddedLattice bcc_lattice(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles,
                            double spacing) {
  if (!(std::isfinite(spacing) && spacing > 0.0))
    fail("BCC lattice: spacing ", spacing, " must be positive and finite");
  const SurfaceInside surface(vertices, triangles);
  const Vec3 lo = vertices.rowwise().minCoeff(), hi = vertices.rowwise().maxCoeff();
  // One cell of margin on every side: every surface point lies in a cell whose six faces are shared
  // with other cells, so the tets around it are all there.
  const Vec3 origin = lo - Vec3::Constant(spacing);
  std::array<Index, 3> n{};
  double cells = 1.0;
  for (int d = 0; d < 3; ++d) {
    const double count = std::ceil((hi[d] - lo[d]) / spacing) + 2.0;
    cells *= count;
    if (!(cells <= kMaxLatticeCells))
      fail("BCC lattice: spacing ", spacing, " m makes more than ", kMaxLatticeCells, " cells around a surface of ",
           (hi - lo).transpose(), " m");
    n[d] = std::max<Index>(static_cast<Index>(count), 3);
  }
  const Index cell_count = n[0] * n[1] * n[2];
  const Index corner_count = (n[0] + 1) * (n[1] + 1) * (n[2] + 1);
  const auto corner = [&](Index i, Index j, Index k) { return i + (n[0] + 1) * (j + (n[1] + 1) * k); };
  const auto centre = [&](Index i, Index j, Index k) { return corner_count + i + n[0] * (j + n[1] * k); };
  const auto position = [&](Index node) -> Vec3 {
    if (node < corner_count) {
      const Index i = node % (n[0] + 1), j = (node / (n[0] + 1)) % (n[1] + 1), k = node / ((n[0] + 1) * (n[1] + 1));
      return origin + spacing * Vec3(double(i), double(j), double(k));
    }
    const Index c = node - corner_count;
    const Index i = c % n[0], j = (c / n[0]) % n[1], k = c / (n[0] * n[1]);
    return origin + spacing * Vec3(double(i) + 0.5, double(j) + 0.5, double(k) + 0.5);
  };
  // Tet id = (axis d, cell, edge): the cell's centre, its neighbour's across the face at the cell's
  // upper side along d, and edge `edge` of that face (around it, in the plane of the other axes).
  const auto tet_of = [&](Index id, bool& exists) {
    const Index edge = id % 4, cell = (id / 4) % cell_count, d = id / (4 * cell_count);
    std::array<Index, 3> c{cell % n[0], (cell / n[0]) % n[1], cell / (n[0] * n[1])};
    exists = c[d] + 1 < n[d];
    std::array<Index, 4> t{};
    if (!exists) return t;
    std::array<Index, 3> next = c;
    ++next[d];
    t[0] = centre(c[0], c[1], c[2]);
    t[1] = centre(next[0], next[1], next[2]);
    const int u = (d + 1) % 3, w = (d + 2) % 3;
    static constexpr int ring[5][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}, {0, 0}};
    for (int e = 0; e < 2; ++e) {
      std::array<Index, 3> p = next;  // the face's corners are at the upper cell's lower side
      p[u] += ring[edge + e][0];
      p[w] += ring[edge + e][1];
      t[2 + e] = corner(p[0], p[1], p[2]);
    }
    Mat3 m;
    m << position(t[1]) - position(t[0]), position(t[2]) - position(t[0]), position(t[3]) - position(t[0]);
    if (m.determinant() < 0.0) std::swap(t[2], t[3]);
    return t;
  };
  const Index tet_ids = 3 * cell_count * 4;

  // Cells a triangle's box reaches (padded by a thousandth of a cell): elsewhere the surface does not
  // pass, and a tet in two such cells is wholly inside or wholly outside, as its centres are.
  std::vector<std::uint8_t> near(static_cast<std::size_t>(cell_count), 0);
  const double pad = 1e-3 * spacing;
  for (const auto& tri : triangles) {
    Vec3 t_lo = Vec3::Constant(kInfinity), t_hi = -t_lo;
    for (Index v : tri) {
      t_lo = t_lo.cwiseMin(Vec3(vertices.col(v)));
      t_hi = t_hi.cwiseMax(Vec3(vertices.col(v)));
    }
    std::array<Index, 3> a{}, b{};
    for (int d = 0; d < 3; ++d) {
      a[d] = std::clamp(static_cast<Index>(std::floor((t_lo[d] - pad - origin[d]) / spacing)), Index{0}, n[d] - 1);
      b[d] = std::clamp(static_cast<Index>(std::floor((t_hi[d] + pad - origin[d]) / spacing)), Index{0}, n[d] - 1);
    }
    for (Index k = a[2]; k <= b[2]; ++k)
      for (Index j = a[1]; j <= b[1]; ++j)
        for (Index i = a[0]; i <= b[0]; ++i) near[static_cast<std::size_t>(i + n[0] * (j + n[1] * k))] = 1;
  }
  std::vector<std::int8_t> centre_inside(static_cast<std::size_t>(cell_count), -1);  // -1: not asked yet
  const auto centre_in = [&](Index cell) {
    std::int8_t& in = centre_inside[static_cast<std::size_t>(cell)];
    if (in < 0) in = surface.inside(position(corner_count + cell)) ? 1 : 0;
    return in == 1;
  };

  // Each surface vertex's host: of the 24 tets around its cell, the one it is deepest in.
  const Index vertex_count = vertices.cols();
  std::vector<Index> host_id(static_cast<std::size_t>(vertex_count), -1);
  std::vector<std::array<double, 4>> host_weights(static_cast<std::size_t>(vertex_count));
  for (Index v = 0; v < vertex_count; ++v) {
    const Vec3 p = vertices.col(v);
    std::array<Index, 3> c{};
    for (int d = 0; d < 3; ++d)
      c[d] = std::clamp(static_cast<Index>(std::floor((p[d] - origin[d]) / spacing)), Index{1}, n[d] - 2);
    double best = -kInfinity;
    for (int d = 0; d < 3; ++d)
      for (int side = 0; side < 2; ++side) {
        std::array<Index, 3> below = c;
        below[d] -= side;  // the face below the cell belongs to the cell below
        const Index cell = below[0] + n[0] * (below[1] + n[1] * below[2]);
        for (Index edge = 0; edge < 4; ++edge) {
          const Index id = (d * cell_count + cell) * 4 + edge;
          bool exists = false;
          const std::array<Index, 4> t = tet_of(id, exists);
          if (!exists) continue;
          const auto w = tet_weights(position(t[0]), position(t[1]), position(t[2]), position(t[3]), p);
          const double depth = *std::min_element(w.begin(), w.end());
          if (depth > best) {
            best = depth;
            host_id[static_cast<std::size_t>(v)] = id;
            host_weights[static_cast<std::size_t>(v)] = w;
          }
        }
      }
    if (!(best > -1e-9)) fail("BCC lattice: surface vertex ", v, " at ", p.transpose(), " lies in no tet");
  }
  std::vector<Index> hosted = host_id;
  std::sort(hosted.begin(), hosted.end());

  static const std::vector<std::array<double, 4>> quadrature = refinement_centroids();
  EmbeddedLattice out;
  std::vector<Index> kept_ids;
  std::vector<Index> node_of(static_cast<std::size_t>(corner_count + cell_count), -1);
  for (Index id = 0; id < tet_ids; ++id) {
    bool exists = false;
    const std::array<Index, 4> t = tet_of(id, exists);
    if (!exists) continue;
    const Index cell_a = t[0] - corner_count, cell_b = t[1] - corner_count;
    double fill;
    if (!near[static_cast<std::size_t>(cell_a)] && !near[static_cast<std::size_t>(cell_b)]) {
      fill = centre_in(cell_a) ? 1.0 : 0.0;
    } else {
      const Vec3 x[4] = {position(t[0]), position(t[1]), position(t[2]), position(t[3])};
      int count = 0;
      for (const auto& w : quadrature)
        if (surface.inside(w[0] * x[0] + w[1] * x[1] + w[2] * x[2] + w[3] * x[3])) ++count;
      fill = double(count) / double(quadrature.size());
    }
    const bool hosts = std::binary_search(hosted.begin(), hosted.end(), id);
    if (!(fill > 0.0) && !hosts) continue;
    kept_ids.push_back(id);
    out.fill.push_back(std::max(fill, 0.5 / double(quadrature.size())));
    out.tets.push_back(t);
  }
  // The nodes the kept tets use, in lattice order.
  for (const auto& t : out.tets)
    for (Index v : t) node_of[static_cast<std::size_t>(v)] = 0;
  Index count = 0;
  for (Index& v : node_of)
    if (v == 0) v = count++;
  out.vertices.resize(3, count);
  for (Index v = 0; v < corner_count + cell_count; ++v)
    if (node_of[static_cast<std::size_t>(v)] >= 0) out.vertices.col(node_of[static_cast<std::size_t>(v)]) = position(v);
  for (auto& t : out.tets)
    for (Index& v : t) v = node_of[static_cast<std::size_t>(v)];
  out.host.resize(static_cast<std::size_t>(vertex_count));
  out.weights = std::move(host_weights);
  for (Index v = 0; v < vertex_count; ++v)
    out.host[static_cast<std::size_t>(v)] = static_cast<Index>(
        std::lower_bound(kept_ids.begin(), kept_ids.end(), host_id[static_cast<std::size_t>(v)]) - kept_ids.begin());
  return out;
}

}  // namespace sinew
