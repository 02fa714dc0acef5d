// Mesh files for sinew: triangle meshes through assimp (OBJ, PLY, STL, glTF and the rest assimp
// reads) and tetrahedral meshes in TetGen's .node/.ele format. Errors name the file and the problem.
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

/// Loads every mesh of a file as one triangle mesh (polygons triangulated, coincident vertices
/// joined, node transforms applied). Throws sinew::Error naming the file when it is missing,
/// unreadable, or has no triangles.
TriangleMesh load_triangle_mesh(const std::string& path);

/// Writes triangle meshes as one file; the format follows the extension (.obj, .ply, .stl, .gltf,
/// .glb). Each mesh becomes a named node.
void save_triangle_meshes(const std::string& path, const std::vector<TriangleMesh>& meshes,
                          const std::vector<std::string>& names);

/// Loads a TetGen mesh from `stem`.node and `stem`.ele (1- or 0-based indices as the files declare).
/// Inverted tets are reoriented; degenerate ones are an error naming the tet.
TetMesh load_tet_mesh(const std::string& stem);

/// The boundary triangles of a tet mesh (faces used by one tet), oriented outwards.
TriangleMesh boundary(const TetMesh& mesh);

}  // namespace sinew::mesh
