// Cutting a tet mesh with duplicated, partially filled elements (Sifakis et al. 2007, section 4 and
// figure 11, after the virtual node algorithm of Molino et al. 2004), for cuts by planes that pass
// through the whole body.
//
// The planes split space into cells (a cell is a sign pattern, one side of each plane); the material
// of one cell is one piece. A tet holding material of k pieces is copied k times, each copy holding
// its piece's part of the tet (its fill, the clipped volume's share) and embedding nothing else. Each copy's four
// nodes are copies too, one per (vertex, piece): the copies of a piece share their nodes and so hold
// together, while different pieces share none and come apart. A node of a copy that lies outside its
// piece (a virtual node) carries the elasticity and mass of the part of the tet its piece fills;
// the piece's surface, the original surface clipped by the planes, is embedded in its copies by
// barycentric weights (locate) and drawn from there.
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <vector>

namespace sinew {

struct CutPlane {
  Vec3 point = Vec3::Zero();
  Vec3 normal = Vec3::UnitX();  ///< any length but zero
};

struct CutTets {
  Vectors3 vertices;                       ///< 3 x V': one copy of an input vertex per piece using it
  std::vector<std::array<Index, 4>> tets;  ///< one copy of an input tet per piece it holds material of
  std::vector<double> fill;                ///< per copy: its piece's part of the tet's material, in (0, 1]
  std::vector<Index> piece;                ///< per copy: the piece (numbered as first met, tet by tet)
  std::vector<Index> source_tet;           ///< per copy: the input tet it copies
  std::vector<Index> source_vertex;        ///< per vertex copy: the input vertex it copies
  std::vector<std::uint32_t> cell;         ///< per piece: its sign pattern (bit p: in front of plane p)
  std::vector<CutPlane> planes;

  Index pieces() const { return static_cast<Index>(cell.size()); }
  /// The piece holding rest point X (by its side of each plane), or -1 if no piece has that pattern.
  Index piece_of(const Vec3& X) const;
  /// A copy of piece `p` holding rest point X and X's barycentric weights there: the copy whose
  /// smallest weight is largest (a point in a sliver too thin to be copied gets the copy next to it,
  /// weights slightly outside [0, 1]). -1 if the piece has no copy.
  Index locate(Index p, const Vec3& X, std::array<double, 4>& weights) const;
};

/// Cuts tets (vertices 3 x V, positively oriented; `fill` per tet in (0, 1], empty: all 1) by
/// `planes` (at most 32). Each tet is clipped by the planes in turn (split into tets on each side),
/// and a copy is made for each piece holding more than 1e-9 of its volume, with fill the input fill
/// times that piece's exact share of the volume. Throws sinew::Error naming a bad plane or tet.
CutTets cut_by_planes(const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets,
                      const std::vector<double>& fill, std::span<const CutPlane> planes);

}  // namespace sinew
