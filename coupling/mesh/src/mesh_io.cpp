#include "sinew/mesh/mesh_io.hpp"

#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>

namespace sinew::mesh {

namespace {

void collect(const aiScene* scene, const aiNode* node, const aiMatrix4x4& parent, TriangleMesh& out,
             std::vector<Vec3>& vertices) {
  const aiMatrix4x4 transform = parent * node->mTransformation;
  for (unsigned m = 0; m < node->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[node->mMeshes[m]];
    const Index base = static_cast<Index>(vertices.size());
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D p = transform * mesh->mVertices[v];
      vertices.emplace_back(p.x, p.y, p.z);
    }
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines after triangulation
      out.triangles.push_back({base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]});
    }
  }
  for (unsigned c = 0; c < node->mNumChildren; ++c) collect(scene, node->mChildren[c], transform, out, vertices);
}

}  // namespace

TriangleMesh load_triangle_mesh(const std::string& path) {
  if (!std::filesystem::exists(path)) fail("mesh file '", path, "': no such file");
  Assimp::Importer importer;
  // Simulation needs connectivity: drop normals, texture coordinates and colours first so that vertices
  // that share a position are joined (STL and flat-shaded files repeat them per face).
  importer.SetPropertyInteger(AI_CONFIG_PP_RVC_FLAGS, aiComponent_NORMALS | aiComponent_TANGENTS_AND_BITANGENTS |
                                                          aiComponent_TEXCOORDS | aiComponent_COLORS);
  const aiScene* scene =
      importer.ReadFile(path, aiProcess_RemoveComponent | aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                  aiProcess_FindDegenerates | aiProcess_SortByPType);
  if (!scene || !scene->mRootNode) fail("mesh file '", path, "': ", importer.GetErrorString());
  TriangleMesh out;
  std::vector<Vec3> vertices;
  collect(scene, scene->mRootNode, aiMatrix4x4(), out, vertices);
  if (out.triangles.empty()) fail("mesh file '", path, "': contains no triangles");
  out.vertices.resize(3, static_cast<Index>(vertices.size()));
  for (std::size_t i = 0; i < vertices.size(); ++i) {
    if (!all_finite(vertices[i])) fail("mesh file '", path, "': vertex ", i, " is not finite");
    out.vertices.col(static_cast<Index>(i)) = vertices[i];
  }
  return out;
}

void save_triangle_meshes(const std::string& path, const std::vector<TriangleMesh>& meshes,
                          const std::vector<std::string>& names) {
  const std::string extension = std::filesystem::path(path).extension().string();
  const std::map<std::string, std::string> formats{
      {".obj", "obj"}, {".ply", "ply"}, {".stl", "stl"}, {".gltf", "gltf2"}, {".glb", "glb2"}};
  const auto format = formats.find(extension);
  if (format == formats.end()) fail("mesh file '", path, "': unknown extension (use .obj, .ply, .stl, .gltf or .glb)");
  // The exporter takes ownership of the scene's arrays through aiScene's destructor.
  aiScene scene;
  scene.mRootNode = new aiNode("sinew");
  scene.mNumMaterials = 1;
  scene.mMaterials = new aiMaterial* [1] { new aiMaterial() };
  scene.mNumMeshes = static_cast<unsigned>(meshes.size());
  scene.mMeshes = new aiMesh*[meshes.size()];
  scene.mRootNode->mNumChildren = static_cast<unsigned>(meshes.size());
  scene.mRootNode->mChildren = new aiNode*[meshes.size()];
  for (std::size_t m = 0; m < meshes.size(); ++m) {
    const TriangleMesh& in = meshes[m];
    auto* mesh = new aiMesh();
    scene.mMeshes[m] = mesh;
    mesh->mMaterialIndex = 0;
    mesh->mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
    mesh->mNumVertices = static_cast<unsigned>(in.vertices.cols());
    mesh->mVertices = new aiVector3D[mesh->mNumVertices];
    for (Index v = 0; v < in.vertices.cols(); ++v)
      mesh->mVertices[v] = aiVector3D(static_cast<ai_real>(in.vertices(0, v)), static_cast<ai_real>(in.vertices(1, v)),
                                      static_cast<ai_real>(in.vertices(2, v)));
    mesh->mNumFaces = static_cast<unsigned>(in.triangles.size());
    mesh->mFaces = new aiFace[mesh->mNumFaces];
    for (std::size_t f = 0; f < in.triangles.size(); ++f) {
      aiFace& face = mesh->mFaces[f];
      face.mNumIndices = 3;
      face.mIndices = new unsigned[3];
      for (int k = 0; k < 3; ++k)
        face.mIndices[k] = static_cast<unsigned>(in.triangles[f][static_cast<std::size_t>(k)]);
    }
    auto* node = new aiNode(m < names.size() ? names[m] : "mesh" + std::to_string(m));
    node->mParent = scene.mRootNode;
    node->mNumMeshes = 1;
    node->mMeshes = new unsigned[1]{static_cast<unsigned>(m)};
    scene.mRootNode->mChildren[m] = node;
  }
  Assimp::Exporter exporter;
  if (exporter.Export(&scene, format->second, path) != aiReturn_SUCCESS)
    fail("mesh file '", path, "': ", exporter.GetErrorString());
}

namespace {

// Reads the non-comment lines of a TetGen file.
std::vector<std::vector<double>> read_table(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail("tet mesh file '", path, "': cannot be opened");
  std::vector<std::vector<double>> rows;
  std::string line;
  while (std::getline(in, line)) {
    line = line.substr(0, line.find('#'));
    std::istringstream fields(line);
    std::vector<double> row;
    std::string token;
    while (fields >> token) {
      try {
        std::size_t used = 0;
        row.push_back(std::stod(token, &used));
        if (used != token.size()) throw std::invalid_argument(token);
      } catch (const std::exception&) {
        fail("tet mesh file '", path, "': '", token, "' on line ", rows.size() + 1, " is not a number");
      }
    }
    if (!row.empty()) rows.push_back(std::move(row));
  }
  if (rows.empty()) fail("tet mesh file '", path, "': empty");
  return rows;
}

}  // namespace

TetMesh load_tet_mesh(const std::string& stem) {
  const std::string node_path = stem + ".node", ele_path = stem + ".ele";
  const auto nodes = read_table(node_path);
  const auto eles = read_table(ele_path);
  const auto count = static_cast<std::size_t>(nodes[0][0]);
  if (nodes[0].size() < 2 || nodes[0][1] != 3)
    fail("tet mesh file '", node_path, "': header must declare 3 dimensions");
  if (nodes.size() != count + 1)
    fail("tet mesh file '", node_path, "': header says ", count, " nodes, found ", nodes.size() - 1);
  TetMesh out;
  out.vertices.resize(3, static_cast<Index>(count));
  const Index first = count > 0 ? static_cast<Index>(nodes[1][0]) : 0;  // TetGen numbers from 0 or 1
  for (std::size_t i = 0; i < count; ++i) {
    if (nodes[i + 1].size() < 4) fail("tet mesh file '", node_path, "': node line ", i + 1, " has fewer than 4 fields");
    out.vertices.col(static_cast<Index>(i)) = Vec3(nodes[i + 1][1], nodes[i + 1][2], nodes[i + 1][3]);
  }
  const auto tets = static_cast<std::size_t>(eles[0][0]);
  if (eles[0].size() < 2 || eles[0][1] != 4) fail("tet mesh file '", ele_path, "': only 4-node tets are supported");
  if (eles.size() != tets + 1)
    fail("tet mesh file '", ele_path, "': header says ", tets, " tets, found ", eles.size() - 1);
  for (std::size_t t = 0; t < tets; ++t) {
    const auto& row = eles[t + 1];
    if (row.size() < 5) fail("tet mesh file '", ele_path, "': tet ", t, " has fewer than 4 nodes");
    std::array<Index, 4> tet;
    for (int k = 0; k < 4; ++k) {
      tet[static_cast<std::size_t>(k)] = static_cast<Index>(row[static_cast<std::size_t>(k) + 1]) - first;
      if (tet[static_cast<std::size_t>(k)] < 0 || tet[static_cast<std::size_t>(k)] >= static_cast<Index>(count))
        fail("tet mesh file '", ele_path, "': tet ", t, " refers to node ", row[static_cast<std::size_t>(k) + 1],
             ", which does not exist");
    }
    Mat3 edges;
    edges << out.vertices.col(tet[1]) - out.vertices.col(tet[0]), out.vertices.col(tet[2]) - out.vertices.col(tet[0]),
        out.vertices.col(tet[3]) - out.vertices.col(tet[0]);
    const double volume = edges.determinant() / 6.0;
    const double scale = edges.colwise().norm().maxCoeff();
    if (!(std::abs(volume) > 1e-12 * scale * scale * scale))
      fail("tet mesh file '", ele_path, "': tet ", t, " is degenerate (volume ", volume, ")");
    if (volume < 0) std::swap(tet[2], tet[3]);
    out.tets.push_back(tet);
  }
  return out;
}

TriangleMesh boundary(const TetMesh& mesh) {
  // Each face keyed by its sorted vertices; faces seen once are on the boundary. Oriented so the
  // tet's fourth vertex is behind it.
  std::map<std::array<Index, 3>, std::pair<int, std::array<Index, 3>>> faces;
  for (const auto& t : mesh.tets) {
    const std::array<std::array<Index, 3>, 4> local{
        {{t[0], t[2], t[1]}, {t[0], t[1], t[3]}, {t[0], t[3], t[2]}, {t[1], t[2], t[3]}}};
    for (const auto& f : local) {
      std::array<Index, 3> key = f;
      std::sort(key.begin(), key.end());
      auto& entry = faces[key];
      ++entry.first;
      entry.second = f;
    }
  }
  TriangleMesh out;
  out.vertices = mesh.vertices;
  for (const auto& [key, entry] : faces)
    if (entry.first == 1) out.triangles.push_back(entry.second);
  return out;
}

}  // namespace sinew::mesh
