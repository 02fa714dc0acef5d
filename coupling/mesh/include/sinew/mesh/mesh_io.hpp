// Mesh files for sinew: triangle meshes in OBJ and PLY (read here, in double precision) and in STL,
// glTF and the other formats assimp reads (through assimp, whose positions are float in Debian's
// build), and tetrahedral meshes in TetGen's .node/.ele format (double precision). Errors name the
// file, the line where the format has lines, and the item (coupling/mesh/README.md lists what each
// loader accepts and rejects).
#pragma once

#include "sinew/types.hpp"

#include <array>
#include <string>
#include <vector>

namespace sinew::mesh {

struct TriangleMesh {
  Vectors3 vertices;                            ///< 3 x V
  std::vector<std::array<Index, 3>> triangles;  ///< indices into vertices
};

struct TetMesh {
  Vectors3 vertices;                       ///< 3 x V
  std::vector<std::array<Index, 4>> tets;  ///< positively oriented
};

/// Loads every mesh of a file as one triangle mesh. OBJ (.obj) and PLY (.ply, ASCII or binary) are
/// read here and keep their doubles and vertex order; other extensions go through assimp (coincident
/// vertices joined, node transforms applied). Polygons are cut into triangles by ear clipping, concave
/// ones included. Vertices that no face uses are dropped. Throws sinew::Error naming the file (and the
/// line and item) when it is missing or unreadable, has no triangles, a non-finite coordinate, an index
/// that is not an integer in range, a face that repeats a vertex, has no area or crosses itself.
TriangleMesh load_triangle_mesh(const std::string& path);

/// Writes triangle meshes as one file; the format follows the extension (.obj, .ply, .stl, .gltf,
/// .glb). Each mesh becomes a named node.
void save_triangle_meshes(const std::string& path, const std::vector<TriangleMesh>& meshes,
                          const std::vector<std::string>& names);

/// Loads a TetGen mesh from `stem`.node and `stem`.ele, numbered from 0 or 1 as the first node is.
/// Node lines must be in order, tets numbered alike, every coordinate finite, every index an integer
/// naming a node; inverted tets are reoriented; degenerate ones are an error naming the tet and line.
TetMesh load_tet_mesh(const std::string& stem);

/// The boundary triangles of a tet mesh (faces used by one tet), oriented outwards.
TriangleMesh boundary(const TetMesh& mesh);

}  // namespace sinew::mesh
