// Volumes from any closed surface (Sifakis et al. 2007, section 2): a non-conforming body-centred
// cubic (BCC) tet lattice around a closed triangle mesh, the tets kept where they hold material, and
// the surface's vertices embedded in them by barycentric weights, for hard bindings (section 2's
// "embedded" points, x = W x_parents) to a lattice that carries the mass and the elasticity.
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <vector>

namespace sinew {

/// Inside or outside a closed triangle mesh, by the parity of the crossings of a ray along +x. The
/// triangles are binned by their (y, z) extent, so a query visits the few whose shadow holds the point.
/// A ray through an edge or a vertex is decided as if the point were moved by (0, eps, eps^2)
/// (simulation of simplicity), with each edge's side computed once in one vertex order, so that
/// the two triangles of an edge never both count a crossing or both miss it.
class SurfaceInside {
 public:
  /// vertices: 3 x V; triangles index its columns. Throws sinew::Error (naming the item) when a
  /// vertex is not finite, an index is out of range, or the surface is not closed: every edge must
  /// be used by exactly two triangles. Orientation does not matter.
  SurfaceInside(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles);
  /// True when p is inside the surface (points on it go either way).
  bool inside(const Vec3& p) const;
  /// The volume the surface encloses, by the divergence theorem over its triangles (|sum of the
  /// signed volumes of the tetrahedra from the origin|, so either consistent orientation gives it).
  double enclosed_volume() const { return m_volume; }

 private:
  const Vectors3& m_x;
  const std::vector<std::array<Index, 3>>& m_triangles;
  double m_volume = 0.0;
  Eigen::Vector2d m_min = Eigen::Vector2d::Zero();  ///< (y, z) of the bins' corner
  double m_cell = 1.0;
  int m_ny = 1, m_nz = 1;
  std::vector<Index> m_offsets;  ///< bin b holds m_items[m_offsets[b] .. m_offsets[b + 1])
  std::vector<Index> m_items;
};

/// A BCC lattice around a surface: corners of cubic cells of edge `spacing` and their centres; each
/// tet joins the centres of two face-neighbouring cells and one edge of their common face (12 tets a
/// cell, all congruent, no sliver). Kept: the tets any of whose 64 quadrature points (the centroids of
/// two rounds of red refinement, equal volumes) is inside, and those holding a surface vertex.
struct EmbeddedLattice {
  Vectors3 vertices;                       ///< 3 x N, the lattice nodes the kept tets use
  std::vector<std::array<Index, 4>> tets;  ///< positively oriented
  /// Per tet, the part of its volume inside the surface (quadrature over its 64 points), at least
  /// 1/128: a tet kept for a surface vertex holds some material even where no point sees it.
  std::vector<double> fill;
  std::vector<Index> host;                     ///< per surface vertex, the tet that holds it
  std::vector<std::array<double, 4>> weights;  ///< per surface vertex, its barycentric weights in host
};

/// Builds the lattice of cells of edge `spacing` [m] around a closed surface (vertices 3 x V).
/// Throws sinew::Error naming the problem: a spacing that is not positive and finite, one so small
/// that the lattice would pass kMaxLatticeCells cells, or a surface SurfaceInside refuses.
EmbeddedLattice bcc_lattice(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles,
                            double spacing);

inline constexpr double kMaxLatticeCells = 8e6;

}  // namespace sinew
