#include "cloth.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>

namespace sinew::scenes {

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

ClosedSurface sphere_surface(int levels, double radius, const Vec3& centre) {
  if (levels < 0 || levels > 8) fail("sphere surface: levels ", levels, " must be in [0, 8]");
  if (!(std::isfinite(radius) && radius > 0.0)) fail("sphere surface: radius ", radius, " must be positive and finite");
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                         {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  std::vector<std::array<Index, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                         {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                         {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                         {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (Vec3& p : v) p.normalize();
  for (int l = 0; l < levels; ++l) {
    // Each edge's midpoint once: edges sorted by their ends, looked up by binary search.
    std::vector<std::array<Index, 3>> edges;  // (lower, higher, new vertex)
    for (const auto& tri : f)
      for (int e = 0; e < 3; ++e)
        edges.push_back({std::min(tri[e], tri[(e + 1) % 3]), std::max(tri[e], tri[(e + 1) % 3]), -1});
    std::sort(edges.begin(), edges.end());
    edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
    for (auto& e : edges) {
      v.push_back((v[static_cast<std::size_t>(e[0])] + v[static_cast<std::size_t>(e[1])]).normalized());
      e[2] = static_cast<Index>(v.size() - 1);
    }
    const auto midpoint = [&](Index a, Index b) {
      const std::array<Index, 3> key{std::min(a, b), std::max(a, b), -1};
      return std::lower_bound(edges.begin(), edges.end(), key)->at(2);
    };
    std::vector<std::array<Index, 3>> g;
    g.reserve(4 * f.size());
    for (const auto& tri : f) {
      const Index a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
      g.push_back({tri[0], a, c});
      g.push_back({tri[1], b, a});
      g.push_back({tri[2], c, b});
      g.push_back({a, b, c});
    }
    f = std::move(g);
  }
  ClosedSurface s;
  s.vertices.resize(3, static_cast<Index>(v.size()));
  for (std::size_t i = 0; i < v.size(); ++i) s.vertices.col(static_cast<Index>(i)) = centre + radius * v[i];
  s.triangles = std::move(f);
  return s;
}

ClosedSurface box_surface(const Vec3& lo, const Vec3& hi, int n) {
  ClosedSurface box;
  std::map<std::array<int, 3>, Index> index;  // grid point (i, j, k) on the surface -> vertex
  std::vector<Vec3> points;
  const auto vertex = [&](std::array<int, 3> g) {
    const auto [found, added] = index.emplace(g, static_cast<Index>(points.size()));
    if (added) {
      Vec3 p;
      for (int a = 0; a < 3; ++a) p[a] = lo[a] + (hi[a] - lo[a]) * g[static_cast<std::size_t>(a)] / n;
      points.push_back(p);
    }
    return found->second;
  };
  for (int a = 0; a < 3; ++a) {
    const int u = (a + 1) % 3, v = (a + 2) % 3;  // e_u x e_v = e_a
    for (const int side : {0, n})
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
          const auto at = [&](int di, int dj) {
            std::array<int, 3> g{};
            g[static_cast<std::size_t>(a)] = side;
            g[static_cast<std::size_t>(u)] = i + di;
            g[static_cast<std::size_t>(v)] = j + dj;
            return vertex(g);
          };
          const Index p00 = at(0, 0), p10 = at(1, 0), p11 = at(1, 1), p01 = at(0, 1);
          if (side == n) {
            box.triangles.push_back({p00, p10, p11});
            box.triangles.push_back({p00, p11, p01});
          } else {
            box.triangles.push_back({p00, p11, p10});
            box.triangles.push_back({p00, p01, p11});
          }
        }
  }
  box.vertices.resize(3, static_cast<Index>(points.size()));
  for (std::size_t k = 0; k < points.size(); ++k) box.vertices.col(static_cast<Index>(k)) = points[k];
  return box;
}

std::vector<std::array<Index, 3>> embedded_skin(const EmbeddedVolume& volume,
                                                const std::vector<std::array<Index, 3>>& triangles) {
  std::vector<std::array<Index, 3>> skin;
  skin.reserve(triangles.size());
  for (const auto& t : triangles)
    skin.push_back({volume.surface[static_cast<std::size_t>(t[0])], volume.surface[static_cast<std::size_t>(t[1])],
                    volume.surface[static_cast<std::size_t>(t[2])]});
  return skin;
}

ClosedSurface capsule_surface(const Vec3& a, const Vec3& b, double radius, int around, int along, int cap) {
  const Vec3 axis = (b - a).normalized();
  const double half = 0.5 * (b - a).norm();
  const Vec3 centre = 0.5 * (a + b);
  // e1, e2, axis right-handed: the rings run counter-clockwise seen from b.
  const Vec3 e1 = (std::abs(axis.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY()).cross(axis).normalized();
  const Vec3 e2 = axis.cross(e1);
  // The rings from a's pole to b's, as (position along the axis, radius).
  std::vector<std::pair<double, double>> rings;
  for (int k = 1; k <= cap; ++k) {
    const double phi = -0.5 * std::numbers::pi + 0.5 * std::numbers::pi * k / cap;
    rings.emplace_back(-half + radius * std::sin(phi), radius * std::cos(phi));
  }
  for (int j = 1; j <= along; ++j) rings.emplace_back(-half + 2.0 * half * j / along, radius);
  for (int k = 1; k < cap; ++k) {
    const double phi = 0.5 * std::numbers::pi * k / cap;
    rings.emplace_back(half + radius * std::sin(phi), radius * std::cos(phi));
  }
  const Index n_rings = static_cast<Index>(rings.size());
  ClosedSurface capsule;
  capsule.vertices.resize(3, 2 + n_rings * around);
  capsule.vertices.col(0) = centre - (half + radius) * axis;
  for (Index r = 0; r < n_rings; ++r)
    for (int i = 0; i < around; ++i) {
      const double theta = 2.0 * std::numbers::pi * i / around;
      const auto [t, rho] = rings[static_cast<std::size_t>(r)];
      capsule.vertices.col(1 + r * around + i) =
          centre + t * axis + rho * (std::cos(theta) * e1 + std::sin(theta) * e2);
    }
  const Index top = 1 + n_rings * around;
  capsule.vertices.col(top) = centre + (half + radius) * axis;
  const auto ring = [&](Index r, int i) { return 1 + r * around + (i % around); };
  for (int i = 0; i < around; ++i) {
    capsule.triangles.push_back({0, ring(0, i + 1), ring(0, i)});
    for (Index r = 0; r + 1 < n_rings; ++r) {
      capsule.triangles.push_back({ring(r, i), ring(r, i + 1), ring(r + 1, i + 1)});
      capsule.triangles.push_back({ring(r, i), ring(r + 1, i + 1), ring(r + 1, i)});
    }
    capsule.triangles.push_back({ring(n_rings - 1, i), ring(n_rings - 1, i + 1), top});
  }
  return capsule;
}

void kuhn_block(const Vec3& lo, int nx, int ny, int nz, double h, Vectors3& vertices,
                std::vector<std::array<Index, 4>>& tets) {
  const auto id = [&](int i, int j, int k) { return Index((k * (ny + 1) + j) * (nx + 1) + i); };
  vertices.resize(3, (nx + 1) * (ny + 1) * (nz + 1));
  for (int k = 0; k <= nz; ++k)
    for (int j = 0; j <= ny; ++j)
      for (int i = 0; i <= nx; ++i) vertices.col(id(i, j, k)) = lo + h * Vec3(i, j, k);
  const int orders[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  tets.clear();
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        for (const auto& order : orders) {
          std::array<int, 3> at{i, j, k};
          std::array<Index, 4> t{};
          t[0] = id(at[0], at[1], at[2]);
          for (int step = 0; step < 3; ++step) {
            ++at[static_cast<std::size_t>(order[step])];
            t[static_cast<std::size_t>(step + 1)] = id(at[0], at[1], at[2]);
          }
          Mat3 e;
          e << vertices.col(t[1]) - vertices.col(t[0]), vertices.col(t[2]) - vertices.col(t[0]),
              vertices.col(t[3]) - vertices.col(t[0]);
          if (e.determinant() < 0.0) std::swap(t[2], t[3]);
          tets.push_back(t);
        }
}

std::vector<std::array<Index, 3>> grid_triangles(int nx, int ny) {
  std::vector<std::array<Index, 3>> triangles;
  for (int j = 0; j + 1 < ny; ++j)
    for (int i = 0; i + 1 < nx; ++i) {
      const Index a = j * nx + i, b = a + 1, c = a + nx + 1, d = a + nx;
      triangles.push_back({a, b, c});
      triangles.push_back({a, c, d});
    }
  return triangles;
}

RefinedTriangles refined_strip(int nx, int ny, double width, double height, const Vec3& origin) {
  Vectors3 v(3, nx * ny);
  for (int j = 0; j < ny; ++j)
    for (int i = 0; i < nx; ++i) v.col(j * nx + i) = origin + Vec3(width * i / (nx - 1), height * j / (ny - 1), 0);
  RefinedTriangles mesh = unrefined(v, grid_triangles(nx, ny));
  const double middle = origin.x() + 0.5 * width;
  for (int level = 0; level < 2; ++level) {
    const double reach = (level == 0 ? 0.3 : 0.15) * width;
    std::vector<Index> chosen;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& tri = mesh.triangles[t];
      const double x = (mesh.vertices(0, tri[0]) + mesh.vertices(0, tri[1]) + mesh.vertices(0, tri[2])) / 3.0;
      if (std::abs(x - middle) < reach && mesh.level[t] == level) chosen.push_back(static_cast<Index>(t));
    }
    mesh = red_refine(mesh, chosen);
  }
  return mesh;
}

RefinedTriangles refine_near(RefinedTriangles mesh, std::span<const double> reaches,
                             const std::function<double(const Vec3&)>& distance) {
  for (const double reach : reaches) {
    std::vector<Index> chosen;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      Vec3 c = Vec3::Zero();
      for (const Index v : mesh.triangles[t]) c += mesh.vertices.col(v) / 3.0;
      if (distance(c) < reach) chosen.push_back(static_cast<Index>(t));
    }
    mesh = red_refine(mesh, chosen);
  }
  return mesh;
}

SoftCopy add_soft_copy(System& system, const RefinedTriangles& mesh, const std::vector<Index>& targets,
                       double stiffness, std::uint32_t mask, double membrane_mu, double mass) {
  SoftCopy copy;
  std::vector<char> refined(static_cast<std::size_t>(mesh.vertices.cols()), 0);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    if (mesh.level[t] > 0)
      for (const Index v : mesh.triangles[t]) refined[static_cast<std::size_t>(v)] = 1;
  copy.drawn = targets;
  for (Index v = 0; v < mesh.vertices.cols(); ++v) {
    if (!refined[static_cast<std::size_t>(v)]) continue;
    const Index s = system.add_particle(mesh.vertices.col(v), Vec3::Zero(), 0.0);
    SoftBindingSettings binding;
    binding.particle = s;
    binding.target = targets[static_cast<std::size_t>(v)];
    binding.coupling = SoftCoupling::spring;
    binding.stiffness = stiffness;
    binding.mass = mass;
    system.add_soft_binding(binding);
    system.set_collision_filter(s, kDefaultCollisionGroup, mask);
    copy.soft.push_back(s);
    copy.soft_target.push_back(binding.target);
    copy.drawn[static_cast<std::size_t>(v)] = s;
  }
  std::vector<std::array<Index, 3>> skin_of_soft;
  for (const auto& tri : mesh.triangles) {
    const std::array<Index, 3> drawn{copy.drawn[static_cast<std::size_t>(tri[0])],
                                     copy.drawn[static_cast<std::size_t>(tri[1])],
                                     copy.drawn[static_cast<std::size_t>(tri[2])]};
    copy.skin.push_back(drawn);
    if (refined[static_cast<std::size_t>(tri[0])] && refined[static_cast<std::size_t>(tri[1])] &&
        refined[static_cast<std::size_t>(tri[2])])
      skin_of_soft.push_back(drawn);
  }
  // Section 3.1: soft-bound particles may carry forces of their own.
  if (!(membrane_mu > 0.0)) return copy;
  TriangleMembraneSettings membrane;
  membrane.mu = membrane_mu;
  membrane.lambda = membrane_mu;
  copy.membrane = &system.add_force(std::make_unique<TriangleMembrane>(skin_of_soft, system.particles().x, membrane));
  return copy;
}

}  // namespace sinew::scenes
