// Non-graded red refinement of triangle meshes with T-junctions (Sifakis et al. 2007, section 2.1,
// figures 4 and 5). A chosen triangle is split into four by its edges' midpoints, all of the same
// shape (the rest state of each is its parent's scaled by one half); its neighbours are left whole,
// so a midpoint on an edge a neighbour still has whole is a T-junction: it has no complete one-ring,
// and simulated as a free node it opens a gap in the mesh. Bound to the two ends of the whole edge
// that holds it (a hard binding, x = (x_a + x_b) / 2), it stays on that edge; a T-junction on a half
// of an edge that is itself split at a T-junction is bound to that half's ends, and the bindings'
// chain is flattened (HardBindings) to the coarse edge's ends with weights 3/4 and 1/4, and so on.
//
// Tets likewise: a chosen tet is split into eight by its edges' midpoints (four corner tets and the
// inner octahedron cut along its shortest diagonal); a node that lies on an edge or a face of a tet
// it is not a vertex of is a hanging node (a T-junction in 3D), bound to the two ends of the segment
// it halves, so that flattened it sits where the coarse tet's linear field puts it.
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <map>
#include <span>
#include <utility>
#include <vector>

namespace sinew {

class System;

struct RefinedTriangles {
  Vectors3 vertices;                            ///< 3 x V: the input's vertices first, then midpoints
  std::vector<std::array<Index, 3>> triangles;  ///< each oriented as the triangle it came from
  std::vector<int> level;                       ///< per triangle: how many splits made it
  /// A vertex lying at the middle of segment (a, b) that a triangle still has whole (or that lies on
  /// such an edge through its ancestors' halves): bound to (a, b), it stays on the coarse edge.
  struct TJunction {
    Index vertex = -1;
    std::array<Index, 2> segment{-1, -1};  ///< the split edge it is the midpoint of
    std::array<Index, 2> edge{-1, -1};     ///< the whole edge holding it (segment, or an edge segment is part of)
  };
  std::vector<TJunction> t_junctions;  ///< in vertex order

  /// Per split edge (a < b): its midpoint; per half edge made by a split: the edge it is half of.
  std::map<std::pair<Index, Index>, Index> midpoint;
  std::map<std::pair<Index, Index>, std::pair<Index, Index>> half_of;
};

/// The mesh as given, unrefined: its triangles at level 0, no T-junctions. Throws sinew::Error naming
/// a triangle with an index out of range or a repeated vertex.
RefinedTriangles unrefined(const Vectors3& vertices, const std::vector<std::array<Index, 3>>& triangles);

/// One round of red refinement of triangles `chosen` (indices into mesh.triangles; repeats and order
/// do not matter): each is replaced by its four children (the corner triangles first, then the middle
/// one), the others keep their indices' order after them. Midpoints are shared between the two sides
/// of an edge, so refining both sides leaves no T-junction there. Throws naming a bad index.
RefinedTriangles red_refine(const RefinedTriangles& mesh, std::span<const Index> chosen);

/// Hard-binds each T-junction of `mesh` (particles[vertex]) to the ends of its segment with weights
/// 1/2, 1/2 (System::bind_linear; chains are flattened at set-up). Returns how many were bound.
Index bind_t_junctions(System& system, const RefinedTriangles& mesh, std::span<const Index> particles);

/// Largest distance of a T-junction from the whole edge holding it at positions x (3 x V, the mesh's
/// vertices): the gap the T-junctions open in the mesh (figure 5) [m].
double largest_t_junction_gap(const RefinedTriangles& mesh, const Vectors3& x);

struct RefinedTets {
  Vectors3 vertices;                       ///< 3 x V: the input's vertices first, then midpoints
  std::vector<std::array<Index, 4>> tets;  ///< each positively oriented (as its parent was)
  std::vector<int> level;                  ///< per tet: how many splits made it
  /// A node on an edge or a face of a tet (`host`) that it is not a vertex of. `weights` are its rest
  /// barycentric weights in the host: the linear field of the host puts it at sum w_i x_host[i].
  struct HangingNode {
    Index vertex = -1;
    std::array<Index, 2> segment{-1, -1};  ///< the split segment it is the midpoint of
    Index host = -1;
    std::array<double, 4> weights{};
  };
  std::vector<HangingNode> hanging;                   ///< in vertex order
  std::map<std::pair<Index, Index>, Index> midpoint;  ///< per split segment (a < b): its midpoint
};

/// The tet mesh as given, unrefined. Throws sinew::Error naming a tet with an index out of range, a
/// repeated vertex, or a volume that is not positive.
RefinedTets unrefined_tets(const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets);

/// One round of non-graded red refinement of tets `chosen` (indices into mesh.tets; repeats and order
/// do not matter): each is replaced by its eight children (corner tets first, then the octahedron's
/// four), the others keep their order after them; midpoints are shared between neighbours. Throws
/// naming a bad index.
RefinedTets red_refine(const RefinedTets& mesh, std::span<const Index> chosen);

/// Hard-binds each hanging node (particles[vertex]) to the ends of its segment with weights 1/2, 1/2
/// (System::bind_linear; chains are flattened at set-up). Returns how many were bound.
Index bind_hanging_nodes(System& system, const RefinedTets& mesh, std::span<const Index> particles);

/// Largest distance of a hanging node from where its host tet's linear field puts it, at positions x
/// (3 x V, the mesh's vertices): the gap the hanging nodes open in the mesh [m].
double largest_hanging_gap(const RefinedTets& mesh, const Vectors3& x);

}  // namespace sinew
