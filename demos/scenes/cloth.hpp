// Scene builders shared by the demos, the benchmarks and the tests: a scene is written once.
#pragma once

#include "sinew/builders.hpp"
#include "sinew/forces/triangle_membrane.hpp"
#include "sinew/refinement.hpp"

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

namespace sinew::scenes {

// The builders live in the library (sinew/builders.hpp); scenes use them by their short names.
using sinew::add_cloth_grid;
using sinew::add_cloth_mesh;
using sinew::add_embedded_volume;
using sinew::add_volume;
using sinew::ClothGrid;
using sinew::ClothGridSettings;
using sinew::ClothMaterial;
using sinew::EmbeddedVolume;
using sinew::VolumeMaterial;

/// The core scene of the benchmark and the core demo: a cloth hung by its top row from a dynamic
/// rigid rod through implicit binding springs between each top node and a point on the rod; the rod
/// hangs from two fixed anchors by binding springs at its ends; a sideways push starts a swing.
struct HangingClothSettings {
  ClothGridSettings cloth;
  double rod_mass = 0.5;           ///< [kg]
  double binding_stiffness = 1e5;  ///< [N/m], critically damped
  double initial_speed = 1.0;      ///< sideways (along the cloth normal) [m/s]
};

struct HangingCloth {
  ClothGrid cloth;
  Index rod = -1;
  std::vector<Index> rod_points;  ///< hard-bound points on the rod, one per top node
};

HangingCloth add_hanging_cloth(System& system, const HangingClothSettings& settings);

/// A closed triangle surface: vertices 3 x V, triangles indexing them, oriented outwards.
struct ClosedSurface {
  Vectors3 vertices;
  std::vector<std::array<Index, 3>> triangles;
};

/// A sphere of `radius` [m] about `centre`: an icosahedron whose faces are split in four `levels`
/// times, the new vertices pushed onto the sphere (20 * 4^levels triangles).
ClosedSurface sphere_surface(int levels, double radius, const Vec3& centre = Vec3::Zero());

/// The surface of the box [lo, hi], each face an n x n grid of squares split in two, outward-facing;
/// vertices shared along the edges (a closed surface).
ClosedSurface box_surface(const Vec3& lo, const Vec3& hi, int n);

/// The triangles of a surface given to add_embedded_volume, indexing the particles of its embedded
/// vertices (what a scene draws).
std::vector<std::array<Index, 3>> embedded_skin(const EmbeddedVolume& volume,
                                                const std::vector<std::array<Index, 3>>& triangles);

/// A capsule's surface: the cylinder of `radius` around the segment [a, b] closed by hemispheres,
/// `around` vertices on each ring, `along` bands on the cylinder and `cap` bands on each hemisphere
/// (its pole one vertex); outward-facing, vertices shared (a closed surface).
ClosedSurface capsule_surface(const Vec3& a, const Vec3& b, double radius, int around, int along, int cap);

/// A box of nx x ny x nz cubes of edge h from `lo`, each split into six tets around its main diagonal
/// (Kuhn), so that neighbouring cubes' faces match; positively oriented. Vertex (i, j, k) is column
/// (k (ny + 1) + j) (nx + 1) + i.
void kuhn_block(const Vec3& lo, int nx, int ny, int nz, double h, Vectors3& vertices,
                std::vector<std::array<Index, 4>>& tets);

/// The triangles of an nx x ny grid of vertices numbered j * nx + i, each cell split along its
/// diagonal from (i, j) to (i + 1, j + 1).
std::vector<std::array<Index, 3>> grid_triangles(int nx, int ny);

/// Figure 5's sheet: a strip of `width` x `height` in the x-y plane from `origin` (its lower left
/// corner), nx x ny nodes, two triangles a cell, red-refined once where a triangle's centre is within
/// 0.3 width of the middle and twice within 0.15: T-junctions along both borders of each level.
RefinedTriangles refined_strip(int nx, int ny, double width, double height, const Vec3& origin = Vec3::Zero());

/// Red-refines `mesh` once for each reach in turn (figure 4): the triangles whose centre c has
/// distance(c) < reach.
RefinedTriangles refine_near(RefinedTriangles mesh, std::span<const double> reaches,
                             const std::function<double(const Vec3&)>& distance);

/// A soft-bound copy of a refined surface (figure 7): a particle at each vertex of a refined triangle
/// (level > 0), tied to that vertex's target by a binding spring of `stiffness` (it inherits the
/// target's elastic accelerations), colliding only with the groups in `mask`, and a membrane
/// (mu = lambda = membrane_mu; none for 0) among them so that a small body dents the copy instead of
/// parting it.
struct SoftCopy {
  std::vector<Index> soft, soft_target;    ///< the soft particles and their targets
  std::vector<Index> drawn;                ///< per vertex: its soft particle, or its target
  std::vector<std::array<Index, 3>> skin;  ///< every triangle of the mesh, drawn from `drawn`
  TriangleMembrane* membrane = nullptr;    ///< null when membrane_mu is 0
};
/// `mass` is each soft particle's own mass; 0 gives it its target's effective mass (SoftBindingSettings).
SoftCopy add_soft_copy(System& system, const RefinedTriangles& mesh, const std::vector<Index>& targets,
                       double stiffness, std::uint32_t mask, double membrane_mu, double mass = 0.0);

}  // namespace sinew::scenes
