#include "cloth.hpp"

#include "sinew/forces/dihedral_bending.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/forces/triangle_membrane.hpp"

#include <algorithm>

namespace sinew::scenes {

ClothGrid add_cloth_grid(System& system, const ClothGridSettings& s) {
  if (s.nx < 2 || s.ny < 2) fail("cloth grid: needs at least 2 x 2 nodes, got ", s.nx, " x ", s.ny);
  if (!(s.width > 0 && s.height > 0)) fail("cloth grid: width and height must be positive");
  if (!(std::isfinite(s.mass) && s.mass > 0)) fail("cloth grid: mass ", s.mass, " must be positive");
  ClothGrid grid;
  grid.nx = s.nx;
  grid.ny = s.ny;
  const double dx = s.width / (s.nx - 1), dy = s.height / (s.ny - 1);
  // Alternate the diagonal so the mesh has no preferred shear direction.
  for (int j = 0; j + 1 < s.ny; ++j)
    for (int i = 0; i + 1 < s.nx; ++i) {
      const Index a = j * s.nx + i, b = a + 1, c = a + s.nx, d = c + 1;
      if ((i + j) % 2 == 0) {
        grid.triangles.push_back({a, b, d});
        grid.triangles.push_back({a, d, c});
      } else {
        grid.triangles.push_back({a, b, c});
        grid.triangles.push_back({b, d, c});
      }
    }
  // Lumped masses: a third of each triangle's share of the total to each of its vertices.
  std::vector<double> mass(static_cast<std::size_t>(s.nx) * s.ny, 0.0);
  const double per_triangle = s.mass / static_cast<double>(grid.triangles.size());
  for (const auto& t : grid.triangles)
    for (Index v : t) mass[v] += per_triangle / 3.0;
  const Index first = system.particles().size();
  for (int j = 0; j < s.ny; ++j)
    for (int i = 0; i < s.nx; ++i)
      grid.nodes.push_back(system.add_particle(s.origin + i * dx * s.across + j * dy * s.down, Vec3::Zero(),
                                               mass[static_cast<std::size_t>(j) * s.nx + i]));
  for (auto& t : grid.triangles)
    for (Index& v : t) v += first;

  const Vectors3& rest = system.particles().x;
  if (s.stretch_stiffness > 0) {
    std::vector<EdgeSprings::Edge> edges;
    for (const auto& t : grid.triangles)
      for (int e = 0; e < 3; ++e) {
        const Index a = t[e], b = t[(e + 1) % 3];
        edges.push_back({std::min(a, b), std::max(a, b)});
      }
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    system.add_force(std::make_unique<EdgeSprings>(std::move(edges), rest,
                                                   EdgeSpringsSettings{s.stretch_stiffness, s.stretch_damping}));
  }
  std::vector<DihedralBending::Triangle> triangles(grid.triangles.begin(), grid.triangles.end());
  if (s.bending_stiffness > 0)
    system.add_force(std::make_unique<DihedralBending>(DihedralBending::hinges_from_triangles(triangles), rest,
                                                       DihedralBendingSettings{s.bending_stiffness, s.bending_damping}));
  if (s.membrane_mu > 0 || s.membrane_lambda > 0)
    system.add_force(std::make_unique<TriangleMembrane>(
        std::vector<TriangleMembrane::Triangle>(grid.triangles.begin(), grid.triangles.end()), rest,
        TriangleMembraneSettings{s.membrane_mu, s.membrane_lambda, s.membrane_damping}));
  return grid;
}

HangingCloth add_hanging_cloth(System& system, const HangingClothSettings& s) {
  HangingCloth scene;
  scene.cloth = add_cloth_grid(system, s.cloth);
  const ClothGridSettings& c = s.cloth;
  // The rod: a slender rigid body along the top edge, a little above it.
  RigidBodySettings rod;
  rod.x = c.origin + 0.5 * c.width * c.across - 0.02 * c.down;
  rod.q = Quat::FromTwoVectors(Vec3::UnitX(), c.across);
  rod.mass = s.rod_mass;
  const double length = c.width * 1.1, radius = 0.01;
  const double axial = 0.5 * s.rod_mass * radius * radius;
  const double transverse = s.rod_mass * (3 * radius * radius + length * length) / 12.0;
  rod.inertia = Vec3(axial, transverse, transverse);
  scene.rod = system.add_rigid_body(rod);
  const Vec3 normal = c.across.cross(c.down).normalized();
  for (int i = 0; i < c.nx; ++i) {
    const Index node = scene.cloth.node(i, 0);
    // A point of the rod directly above the node, tied to the node by a binding spring.
    const Index point = system.add_particle(system.particles().x.col(node), Vec3::Zero(), 0.0);
    system.bind_rigid_here(point, scene.rod);
    system.add_binding_spring({node, point, s.binding_stiffness, 1.0});
    scene.rod_points.push_back(point);
  }
  for (int end = 0; end < 2; ++end) {
    const Vec3 at = rod.x + (end == 0 ? -0.5 : 0.5) * length * c.across;
    const Index anchor = system.add_kinematic_particle(at);
    const Index point = system.add_particle(at, Vec3::Zero(), 0.0);
    system.bind_rigid_here(point, scene.rod);
    system.add_binding_spring({point, anchor, 100.0 * s.binding_stiffness, 1.0});
  }
  for (Index node : scene.cloth.nodes) system.particles().v.col(node) = s.initial_speed * normal;
  return scene;
}

}  // namespace sinew::scenes
