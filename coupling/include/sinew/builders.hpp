// Builders for deformables: a cloth from a grid or from any triangle mesh, a soft volume from a tet
// mesh. Each adds particles with lumped masses and only the forces its material asks for.
#pragma once

#include "sinew/lattice.hpp"
#include "sinew/system.hpp"

#include <array>
#include <vector>

namespace sinew {

/// What a cloth is made of; only the forces with a non-zero stiffness are added.
struct ClothMaterial {
  double mass = 0.5;                 ///< total [kg], lumped by area
  double stretch_stiffness = 200.0;  ///< edge springs k [N/m]; 0 leaves them out
  double stretch_damping = 0.05;     ///< edge springs b [N s/m]
  double bending_stiffness = 1e-4;   ///< dihedral bending k_b [N m]; 0 leaves it out
  double bending_damping = 0.0;
  /// DihedralBendingSettings::implicit: with StepSettings::implicit_elasticity, bending joins the
  /// solves (its Gauss-Newton differential) and stops limiting the substep.
  bool bending_implicit = false;
  double membrane_mu = 0.0;  ///< StVK membrane [N/m]; 0 leaves it out
  double membrane_lambda = 0.0;
  double membrane_damping = 0.0;  ///< strain-rate damping [s]
};

struct ClothGridSettings : ClothMaterial {
  int nx = 40;                         ///< nodes along the width
  int ny = 40;                         ///< nodes along the height
  double width = 2.0;                  ///< [m]
  double height = 2.0;                 ///< [m]
  Vec3 origin = Vec3(-1.0, 2.0, 0.0);  ///< position of node (0, 0), the top-left corner
  Vec3 across = Vec3::UnitX();         ///< direction of increasing i
  Vec3 down = -Vec3::UnitY();          ///< direction of increasing j
};

/// A cloth made from any triangle mesh (vertices 3 x V, triangles indexing them): one particle per
/// vertex with area-lumped mass, and the material's forces. Returns the particle of each vertex.
std::vector<Index> add_cloth_mesh(System& system, const Vectors3& vertices,
                                  const std::vector<std::array<Index, 3>>& triangles, const ClothMaterial& material);

/// A soft volume from a tet mesh: one particle per vertex with volume-lumped mass, and corotated
/// linear FEM with inversion handling. Returns the particle of each vertex.
struct VolumeMaterial {
  double density = 1000.0;     ///< [kg/m^3]
  double young_modulus = 5e4;  ///< [Pa]
  double poisson_ratio = 0.3;
  double damping = 0.01;  ///< stiffness-proportional damping [s]
  /// CorotatedTetsSettings::implicit: with StepSettings::implicit_elasticity (or the automatic scheme
  /// choosing it), the tets join the solves through their warped stiffness and stop limiting the
  /// substep.
  bool implicit = false;
};
std::vector<Index> add_volume(System& system, const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets,
                              const VolumeMaterial& material);

/// A soft volume from any closed surface (Sifakis et al. 2007, section 2): a BCC lattice of cells of
/// edge `spacing` around it (bcc_lattice), one particle per lattice node with the mass of the
/// material its tets hold (density x volume x fill, a quarter to each node), corotated linear FEM
/// scaled by each tet's fill (CorotatedTetsSettings::volume_fraction), and one particle per surface
/// vertex, hard-bound to the nodes of the tet that holds it by its barycentric weights (x = W x_parents;
/// massless, so the lattice carries all the mass). The lattice's boundary faces are the collision
/// surface; the embedded surface is what a picture draws. Throws sinew::Error naming the problem
/// (bcc_lattice's, or the material's).
struct EmbeddedVolume {
  std::vector<Index> lattice;  ///< particle of each lattice node (embedding.vertices' columns)
  std::vector<Index> surface;  ///< particle of each surface vertex
  EmbeddedLattice embedding;   ///< the lattice at rest, its tets' fills, each vertex's host and weights
};
EmbeddedVolume add_embedded_volume(System& system, const Vectors3& surface_vertices,
                                   const std::vector<std::array<Index, 3>>& triangles, double spacing,
                                   const VolumeMaterial& material);

struct ClothGrid {
  int nx = 0, ny = 0;
  std::vector<Index> nodes;  ///< particle index of node (i, j) at [j * nx + i]
  std::vector<std::array<Index, 3>> triangles;
  Index node(int i, int j) const { return nodes[static_cast<std::size_t>(j) * nx + i]; }
};

/// Adds a rectangular cloth to the system: particles with area-lumped masses and the forces the
/// settings ask for (edge springs on the triangle edges, dihedral bending, StVK membrane).
ClothGrid add_cloth_grid(System& system, const ClothGridSettings& settings);

}  // namespace sinew
