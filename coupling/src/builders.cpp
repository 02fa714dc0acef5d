#include "sinew/builders.hpp"

#include "sinew/forces/corotated_tets.hpp"
#include "sinew/forces/dihedral_bending.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/forces/triangle_membrane.hpp"

#include <algorithm>
#include <utility>

namespace sinew {

namespace {

// The faces of a tet mesh that belong to one tet only, oriented outward (as the face sits in its
// tet with positive volume: the opposite vertex behind it), in particle indices, in a fixed order.
std::vector<std::array<Index, 3>> boundary_triangles(const std::vector<std::array<Index, 4>>& tets,
                                                     const std::vector<Index>& particle) {
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  struct Face {
    std::array<Index, 3> sorted, oriented;
  };
  std::vector<Face> faces;
  for (const auto& t : tets)
    for (const auto& f : kFaces) {
      Face face;
      face.oriented = {particle[t[f[0]]], particle[t[f[1]]], particle[t[f[2]]]};
      face.sorted = face.oriented;
      std::sort(face.sorted.begin(), face.sorted.end());
      faces.push_back(face);
    }
  std::stable_sort(faces.begin(), faces.end(), [](const Face& a, const Face& b) { return a.sorted < b.sorted; });
  std::vector<std::array<Index, 3>> boundary;
  for (std::size_t i = 0; i < faces.size();) {
    std::size_t j = i + 1;
    while (j < faces.size() && faces[j].sorted == faces[i].sorted) ++j;
    if (j - i == 1) boundary.push_back(faces[i].oriented);
    i = j;
  }
  return boundary;
}

// Every material field finite and non-negative (a force whose stiffness is 0 is left out; a negative
// or NaN one is an error, not a silently missing force), named in the message.
void check_material(const ClothMaterial& s) {
  if (!(std::isfinite(s.mass) && s.mass > 0)) fail("cloth: mass ", s.mass, " must be positive and finite");
  const std::pair<const char*, double> fields[] = {{"stretch_stiffness", s.stretch_stiffness},
                                                   {"stretch_damping", s.stretch_damping},
                                                   {"bending_stiffness", s.bending_stiffness},
                                                   {"bending_damping", s.bending_damping},
                                                   {"membrane_mu", s.membrane_mu},
                                                   {"membrane_lambda", s.membrane_lambda},
                                                   {"membrane_damping", s.membrane_damping}};
  for (const auto& [name, value] : fields)
    if (!(std::isfinite(value) && value >= 0.0))
      fail("cloth: ", name, " = ", value, " must be non-negative and finite");
}

void check_vertices(const char* what, const Vectors3& vertices) {
  for (Index v = 0; v < vertices.cols(); ++v)
    if (!vertices.col(v).allFinite()) fail(what, ": vertex ", v, " is not finite (", vertices.col(v).transpose(), ")");
}

}  // namespace

ClothGrid add_cloth_grid(System& system, const ClothGridSettings& s) {
  if (s.nx < 2 || s.ny < 2) fail("cloth grid: needs at least 2 x 2 nodes, got ", s.nx, " x ", s.ny);
  if (!(std::isfinite(s.width) && std::isfinite(s.height) && s.width > 0 && s.height > 0))
    fail("cloth grid: width ", s.width, " and height ", s.height, " must be positive and finite");
  if (!(all_finite(s.origin) && all_finite(s.across) && all_finite(s.down)))
    fail("cloth grid: origin, across and down must be finite");
  if (!(s.across.cross(s.down).norm() > 1e-12 * s.across.norm() * s.down.norm()))
    fail("cloth grid: across (", s.across.transpose(), ") and down (", s.down.transpose(),
         ") must be non-zero and not parallel");
  check_material(s);
  ClothGrid grid;
  grid.nx = s.nx;
  grid.ny = s.ny;
  const double dx = s.width / (s.nx - 1), dy = s.height / (s.ny - 1);
  Vectors3 vertices(3, static_cast<Index>(s.nx) * s.ny);
  for (int j = 0; j < s.ny; ++j)
    for (int i = 0; i < s.nx; ++i) vertices.col(j * s.nx + i) = s.origin + i * dx * s.across + j * dy * s.down;
  // Alternate the diagonal so the mesh has no preferred shear direction.
  std::vector<std::array<Index, 3>> triangles;
  for (int j = 0; j + 1 < s.ny; ++j)
    for (int i = 0; i + 1 < s.nx; ++i) {
      const Index a = j * s.nx + i, b = a + 1, c = a + s.nx, d = c + 1;
      if ((i + j) % 2 == 0) {
        triangles.push_back({a, b, d});
        triangles.push_back({a, d, c});
      } else {
        triangles.push_back({a, b, c});
        triangles.push_back({b, d, c});
      }
    }
  grid.nodes = add_cloth_mesh(system, vertices, triangles, s);
  for (auto t : triangles) grid.triangles.push_back({grid.nodes[t[0]], grid.nodes[t[1]], grid.nodes[t[2]]});
  return grid;
}

std::vector<Index> add_cloth_mesh(System& system, const Vectors3& vertices,
                                  const std::vector<std::array<Index, 3>>& triangles, const ClothMaterial& s) {
  check_material(s);
  check_vertices("cloth", vertices);
  if (triangles.empty()) fail("cloth: no triangles");
  const Index count = vertices.cols();
  // Lumped masses: a third of each triangle's area share of the total to each of its vertices.
  std::vector<double> area(triangles.size());
  double total = 0.0;
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    for (Index v : triangles[t])
      if (v < 0 || v >= count) fail("cloth: triangle ", t, " refers to vertex ", v, ", which does not exist");
    const auto& tri = triangles[t];
    area[t] =
        0.5 * (vertices.col(tri[1]) - vertices.col(tri[0])).cross(vertices.col(tri[2]) - vertices.col(tri[0])).norm();
    total += area[t];
  }
  if (!(total > 0)) fail("cloth: the mesh has no area");
  std::vector<double> mass(static_cast<std::size_t>(count), 0.0);
  for (std::size_t t = 0; t < triangles.size(); ++t)
    for (Index v : triangles[t]) mass[static_cast<std::size_t>(v)] += s.mass * area[t] / total / 3.0;
  std::vector<Index> particle(static_cast<std::size_t>(count));
  for (Index v = 0; v < count; ++v)
    particle[static_cast<std::size_t>(v)] = system.add_particle(vertices.col(v), Vec3::Zero(), mass[v]);
  std::vector<std::array<Index, 3>> mapped;
  for (const auto& t : triangles) mapped.push_back({particle[t[0]], particle[t[1]], particle[t[2]]});

  const Vectors3& rest = system.particles().x;
  if (s.stretch_stiffness > 0) {
    std::vector<EdgeSprings::Edge> edges;
    for (const auto& t : mapped)
      for (int e = 0; e < 3; ++e) {
        const Index a = t[e], b = t[(e + 1) % 3];
        edges.push_back({std::min(a, b), std::max(a, b)});
      }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    system.add_force(std::make_unique<EdgeSprings>(std::move(edges), rest,
                                                   EdgeSpringsSettings{s.stretch_stiffness, s.stretch_damping}));
  }
  std::vector<DihedralBending::Triangle> bending_triangles(mapped.begin(), mapped.end());
  if (s.bending_stiffness > 0)
    system.add_force(std::make_unique<DihedralBending>(
        DihedralBending::hinges_from_triangles(bending_triangles), rest,
        DihedralBendingSettings{s.bending_stiffness, s.bending_damping, s.bending_implicit}));
  if (s.membrane_mu > 0 || s.membrane_lambda > 0)
    system.add_force(std::make_unique<TriangleMembrane>(
        std::vector<TriangleMembrane::Triangle>(mapped.begin(), mapped.end()), rest,
        TriangleMembraneSettings{s.membrane_mu, s.membrane_lambda, s.membrane_damping}));
  system.add_collision_surface(mapped);
  return particle;
}

std::vector<Index> add_volume(System& system, const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets,
                              const VolumeMaterial& m) {
  if (!(std::isfinite(m.density) && m.density > 0)) fail("volume: density ", m.density, " must be positive");
  if (tets.empty()) fail("volume: no tets");
  check_vertices("volume", vertices);
  const Index count = vertices.cols();
  std::vector<double> mass(static_cast<std::size_t>(count), 0.0);
  for (std::size_t t = 0; t < tets.size(); ++t) {
    for (Index v : tets[t])
      if (v < 0 || v >= count) fail("volume: tet ", t, " refers to vertex ", v, ", which does not exist");
    Mat3 e;
    e << vertices.col(tets[t][1]) - vertices.col(tets[t][0]), vertices.col(tets[t][2]) - vertices.col(tets[t][0]),
        vertices.col(tets[t][3]) - vertices.col(tets[t][0]);
    const double volume = e.determinant() / 6.0;  // CorotatedTets rejects non-positive ones by name
    for (Index v : tets[t]) mass[static_cast<std::size_t>(v)] += m.density * std::abs(volume) / 4.0;
  }
  std::vector<Index> particle(static_cast<std::size_t>(count));
  for (Index v = 0; v < count; ++v) {
    if (!(mass[static_cast<std::size_t>(v)] > 0)) fail("volume: vertex ", v, " belongs to no tet");
    particle[static_cast<std::size_t>(v)] =
        system.add_particle(vertices.col(v), Vec3::Zero(), mass[static_cast<std::size_t>(v)]);
  }
  std::vector<CorotatedTets::Tet> mapped;
  for (const auto& t : tets) mapped.push_back({particle[t[0]], particle[t[1]], particle[t[2]], particle[t[3]]});
  CorotatedTetsSettings settings;
  settings.young_modulus = m.young_modulus;
  settings.poisson_ratio = m.poisson_ratio;
  settings.beta = m.damping;
  settings.implicit = m.implicit;
  system.add_force(std::make_unique<CorotatedTets>(std::move(mapped), system.particles().x, settings));
  system.add_collision_surface(boundary_triangles(tets, particle));
  return particle;
}

EmbeddedVolume add_embedded_volume(System& system, const Vectors3& surface_vertices,
                                   const std::vector<std::array<Index, 3>>& triangles, double spacing,
                                   const VolumeMaterial& m) {
  if (!(std::isfinite(m.density) && m.density > 0)) fail("embedded volume: density ", m.density, " must be positive");
  EmbeddedVolume out;
  out.embedding = bcc_lattice(surface_vertices, triangles, spacing);
  const EmbeddedLattice& lattice = out.embedding;
  const Index count = lattice.vertices.cols();
  std::vector<double> mass(static_cast<std::size_t>(count), 0.0);
  for (std::size_t t = 0; t < lattice.tets.size(); ++t) {
    const auto& tet = lattice.tets[t];
    Mat3 e;
    e << lattice.vertices.col(tet[1]) - lattice.vertices.col(tet[0]),
        lattice.vertices.col(tet[2]) - lattice.vertices.col(tet[0]),
        lattice.vertices.col(tet[3]) - lattice.vertices.col(tet[0]);
    const double material = m.density * e.determinant() / 6.0 * lattice.fill[t];
    for (Index v : tet) mass[static_cast<std::size_t>(v)] += material / 4.0;
  }
  out.lattice.resize(static_cast<std::size_t>(count));
  for (Index v = 0; v < count; ++v)
    out.lattice[static_cast<std::size_t>(v)] =
        system.add_particle(lattice.vertices.col(v), Vec3::Zero(), mass[static_cast<std::size_t>(v)]);
  std::vector<CorotatedTets::Tet> mapped;
  mapped.reserve(lattice.tets.size());
  for (const auto& t : lattice.tets)
    mapped.push_back({out.lattice[static_cast<std::size_t>(t[0])], out.lattice[static_cast<std::size_t>(t[1])],
                      out.lattice[static_cast<std::size_t>(t[2])], out.lattice[static_cast<std::size_t>(t[3])]});
  CorotatedTetsSettings settings;
  settings.young_modulus = m.young_modulus;
  settings.poisson_ratio = m.poisson_ratio;
  settings.beta = m.damping;
  settings.implicit = m.implicit;
  settings.volume_fraction = lattice.fill;
  system.add_force(std::make_unique<CorotatedTets>(mapped, system.particles().x, settings));
  system.add_collision_surface(boundary_triangles(lattice.tets, out.lattice));
  out.surface.resize(static_cast<std::size_t>(surface_vertices.cols()));
  for (Index v = 0; v < surface_vertices.cols(); ++v) {
    const auto& host = mapped[static_cast<std::size_t>(lattice.host[static_cast<std::size_t>(v)])];
    const auto& w = lattice.weights[static_cast<std::size_t>(v)];
    // At W x_parents, which is the vertex to round-off, so that the binding moves nothing at set-up.
    Vec3 x = Vec3::Zero();
    for (int k = 0; k < 4; ++k)
      x += w[static_cast<std::size_t>(k)] * system.particles().x.col(host[static_cast<std::size_t>(k)]);
    const Index p = system.add_particle(x, Vec3::Zero(), 0.0);
    system.bind_linear(p, host, w);
    out.surface[static_cast<std::size_t>(v)] = p;
  }
  return out;
}

}  // namespace sinew
