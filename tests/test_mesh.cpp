// Mesh files: assimp round trips in every supported format, TetGen tet meshes, and named errors.
#include "sinew/mesh/mesh_io.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace sinew {
namespace {

namespace fs = std::filesystem;
using test::error_of;

fs::path scratch(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / "sinew_test_mesh";
  fs::create_directories(dir);
  return dir / name;
}

mesh::TriangleMesh grid(int n) {
  mesh::TriangleMesh m;
  m.vertices.resize(3, n * n);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) m.vertices.col(j * n + i) = Vec3(0.25 * i, 0.1 * i * j, -0.25 * j);
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const Index a = j * n + i;
      m.triangles.push_back({a, a + 1, a + n + 1});
      m.triangles.push_back({a, a + n + 1, a + n});
    }
  return m;
}

double area(const mesh::TriangleMesh& m) {
  double total = 0;
  for (const auto& t : m.triangles)
    total +=
        0.5 * (m.vertices.col(t[1]) - m.vertices.col(t[0])).cross(m.vertices.col(t[2]) - m.vertices.col(t[0])).norm();
  return total;
}

class MeshRoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(MeshRoundTrip, SavedMeshLoadsBackTheSame) {
  const mesh::TriangleMesh original = grid(4);
  const std::string path = scratch("grid" + GetParam()).string();
  mesh::save_triangle_meshes(path, {original}, {"cloth"});
  const mesh::TriangleMesh loaded = mesh::load_triangle_mesh(path);
  EXPECT_EQ(loaded.triangles.size(), original.triangles.size());
  EXPECT_EQ(loaded.vertices.cols(), original.vertices.cols());  // shared vertices joined again (STL repeats them)
  EXPECT_NEAR(area(loaded), area(original), 1e-5);
}

INSTANTIATE_TEST_SUITE_P(Formats, MeshRoundTrip, ::testing::Values(".obj", ".ply", ".stl", ".gltf", ".glb"),
                         [](const auto& test) { return test.param.substr(1); });

TEST(MeshFiles, BadFilesAreNamed) {
  const std::string missing = scratch("missing.obj").string();
  EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(missing); }).find("missing.obj': no such file"), std::string::npos);
  const std::string garbage = scratch("garbage.ply").string();
  std::ofstream(garbage) << "ply\nthis is not a ply header\n";
  EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(garbage); }).find("garbage.ply'"), std::string::npos);
  const std::string points = scratch("points.obj").string();
  std::ofstream(points) << "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
  EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(points); }).find("points.obj'"), std::string::npos);
  EXPECT_NE(
      error_of([&] { mesh::save_triangle_meshes(scratch("x.abc").string(), {grid(2)}, {}); }).find("unknown extension"),
      std::string::npos);
}

// A unit cube as five tets in TetGen's format (1-based), one of them listed inverted.
std::string write_cube(const std::string& name, const std::string& ele_override = "") {
  const std::string stem = scratch(name).string();
  std::ofstream node(stem + ".node");
  node << "# unit cube\n8 3 0 0\n";
  for (int i = 0; i < 8; ++i) node << i + 1 << ' ' << (i & 1) << ' ' << ((i >> 1) & 1) << ' ' << ((i >> 2) & 1) << '\n';
  std::ofstream ele(stem + ".ele");
  ele << (ele_override.empty() ? "5 4 0\n1 1 2 4 6\n2 1 4 3 7\n3 1 6 7 5\n4 4 6 8 7\n5 1 4 7 6\n" : ele_override);
  return stem;
}

TEST(TetMeshFiles, CubeHasUnitVolumeAndAClosedOutwardBoundary) {
  const mesh::TetMesh cube = mesh::load_tet_mesh(write_cube("cube"));
  ASSERT_EQ(cube.tets.size(), 5u);
  double volume = 0;
  for (const auto& t : cube.tets) {
    Mat3 e;
    e << cube.vertices.col(t[1]) - cube.vertices.col(t[0]), cube.vertices.col(t[2]) - cube.vertices.col(t[0]),
        cube.vertices.col(t[3]) - cube.vertices.col(t[0]);
    EXPECT_GT(e.determinant(), 0.0);  // reoriented where the file had them inverted
    volume += e.determinant() / 6;
  }
  EXPECT_NEAR(volume, 1.0, 1e-12);
  const mesh::TriangleMesh skin = mesh::boundary(cube);
  EXPECT_EQ(skin.triangles.size(), 12u);
  EXPECT_NEAR(area(skin), 6.0, 1e-12);
  // Divergence theorem: outward faces enclose the volume with a positive sign.
  double enclosed = 0;
  for (const auto& t : skin.triangles)
    enclosed += skin.vertices.col(t[0]).dot(Vec3(skin.vertices.col(t[1])).cross(Vec3(skin.vertices.col(t[2])))) / 6;
  EXPECT_NEAR(enclosed, 1.0, 1e-12);
}

TEST(TetMeshFiles, BadFilesAreNamed) {
  EXPECT_NE(error_of([] { mesh::load_tet_mesh(scratch("nothing").string()); }).find("nothing.node': cannot be opened"),
            std::string::npos);
  EXPECT_NE(error_of([] { mesh::load_tet_mesh(write_cube("words", "1 4 0\n1 1 2 x 4\n")); }).find("'x'"),
            std::string::npos);
  EXPECT_NE(
      error_of([] { mesh::load_tet_mesh(write_cube("range", "1 4 0\n1 1 2 3 99\n")); }).find("tet 0 refers to node 99"),
      std::string::npos);
  EXPECT_NE(error_of([] { mesh::load_tet_mesh(write_cube("flat", "1 4 0\n1 1 2 3 4\n")); }).find("tet 0 is degenerate"),
            std::string::npos);
}

}  // namespace
}  // namespace sinew
