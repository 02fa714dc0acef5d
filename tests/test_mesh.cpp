// Mesh files: round trips in every supported format, TetGen tet meshes, precision, polygons and named errors.
#include "sinew/mesh/mesh_io.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <tuple>

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

std::string write(const std::string& name, const std::string& text) {
  const std::string path = scratch(name).string();
  std::ofstream(path) << text;
  return path;
}

// A malformed OBJ line is named by file, line and item, not skipped: a vertex line with two
// coordinates used to be dropped, shifting every later index by one; an unused NaN vertex, an index
// of 1.7 or 0 and an unknown statement loaded without a word.
TEST(MeshFiles, MalformedObjLinesAreNamed) {
  const std::string square = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";
  const std::vector<std::pair<std::string, std::string>> cases{
      {"v 0 0 0\nv 5 5\nv 1 0 0\nv 0 1 0\nf 1 3 4\n", "bad_v.obj', line 2: vertex 2 has 2 values, expected x y z"},
      {square + "v nan 0 0\nf 1 2 3\n", "line 5: vertex 5 x 'nan' is not a finite number"},
      {square + "v 0 1e400 0\nf 1 2 3\n", "line 5: vertex 5 y '1e400' is not a finite number"},
      {square + "f 1 2 3.7\n", "line 5: face 1 vertex index '3.7' is not an integer"},
      {square + "f 1 2 0\n", "line 5: face 1 refers to vertex 0, which does not exist"},
      {square + "f 1 2 -5\n", "line 5: face 1 refers to vertex -5, which does not exist (4 so far)"},
      {square + "f 1 2 9\n", "line 5: face 1 refers to vertex 9, which does not exist (4 in the file)"},
      {square + "f 1 2/7 3\n", "line 5: face 1 refers to texture coordinate 7, which does not exist"},
      {square + "f 1 2\n", "line 5: face 1 has 2 corners, expected 3 or more"},
      {square + "f 1 1 2\n", "line 5: face 1 uses one vertex twice"},
      {square + "v 2 0 0\nf 1 2 5\n", "line 6: face 1 has no area"},
      {square + "vv 1 2 3\nf 1 2 3\n", "line 5: unknown statement 'vv'"},
  };
  for (const auto& [text, message] : cases)
    EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(write("bad_v.obj", text)); }).find(message), std::string::npos)
        << text << "\n"
        << error_of([&] { mesh::load_triangle_mesh(write("bad_v.obj", text)); });
}

// OBJ is read in double precision: 1e-9 m apart at 1 km stays 1e-9 m apart (float steps by 6e-5 m
// there). Negative indices, v/vt/vn corners, comments and continued lines are read as the format says.
TEST(MeshFiles, ObjKeepsDoublesAndTheFileVertexOrder) {
  const std::string path = write("km.obj",
                                 "# a triangle 1 km out\nv 1000.000000001 2000 -3000\nvt 0 0\nvn 0 0 1\n"
                                 "v 5 5 5  # used by no face: dropped\n"
                                 "v 1000.000000002 2000.5 -3000\nv 1000.5 2000 \\\n -3000.000000001\n"
                                 "f -4/1/1 -2//1 \\\n -1/1\n");
  const mesh::TriangleMesh m = mesh::load_triangle_mesh(path);
  ASSERT_EQ(m.vertices.cols(), 3);
  ASSERT_EQ(m.triangles.size(), 1u);
  EXPECT_EQ(m.triangles[0], (std::array<Index, 3>{0, 1, 2}));
  EXPECT_EQ(m.vertices.col(0), Vec3(1000.000000001, 2000, -3000));
  EXPECT_EQ(m.vertices.col(1), Vec3(1000.000000002, 2000.5, -3000));
  EXPECT_EQ(m.vertices.col(2), Vec3(1000.5, 2000, -3000.000000001));
  EXPECT_NEAR(m.vertices(0, 1) - m.vertices(0, 0), 1e-9, 1e-12);
}

// PLY is read here too (assimp rounded its doubles to float): a big-endian binary file keeps its
// doubles exactly; a header that ends inside a comment line (on which assimp looped forever) is named.
TEST(MeshFiles, PlyKeepsDoublesAndNamesATruncatedHeader) {
  std::string ply =
      "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
      "property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const double xyz[] = {1000.000000001, 2000, -3000, 1000.000000002, 2000.5, -3000, 1000.5, 2000, -3000.000000001};
  for (double c : xyz) {
    std::uint64_t bits;
    std::memcpy(&bits, &c, sizeof c);
    for (int k = 7; k >= 0; --k) ply += static_cast<char>((bits >> (8 * k)) & 0xff);
  }
  ply += std::string("\x03\0\0\0\0\0\0\0\x01\0\0\0\x02", 13);
  const mesh::TriangleMesh m = mesh::load_triangle_mesh(write("km.ply", ply));
  ASSERT_EQ(m.vertices.cols(), 3);
  ASSERT_EQ(m.triangles.size(), 1u);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(m.vertices(i % 3, i / 3), xyz[i]);
  const std::string truncated = write("truncated.ply", "ply\nformat ascii 1.0\ncomment");
  EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(truncated); }).find("the header has no end_header line"),
            std::string::npos);
}

// Polygons as OBJ and as PLY faces, each with its outline in the z = 0 plane.
class Polygons : public ::testing::TestWithParam<std::string> {};

std::string write_polygon(const std::string& name, const std::vector<Vec3>& corners) {
  std::ostringstream text;
  if (name.size() > 4 && name.substr(name.size() - 4) == ".ply") {
    text << "ply\nformat ascii 1.0\nelement vertex " << corners.size()
         << "\nproperty float x\nproperty float y\nproperty float z\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n";
    for (const Vec3& c : corners) text << c.x() << ' ' << c.y() << ' ' << c.z() << '\n';
    text << corners.size();
    for (std::size_t i = 0; i < corners.size(); ++i) text << ' ' << i;
  } else {
    for (const Vec3& c : corners) text << "v " << c.x() << ' ' << c.y() << ' ' << c.z() << '\n';
    text << 'f';
    for (std::size_t i = 0; i < corners.size(); ++i) text << ' ' << i + 1;
  }
  return write(name, text.str() + "\n");
}

// Concave polygons come out as triangles that cover them once: the triangles' areas add up to the
// polygon's (shoelace) area and every triangle keeps the polygon's winding. assimp's triangulation
// gave the L-shaped hexagon an inverted, overlapping triangle (areas summing to 4 for an area of 3).
TEST_P(Polygons, ConcavePolygonsAreCutIntoTrianglesThatCoverThemOnce) {
  const std::vector<std::vector<Vec3>> shapes{
      {{0, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 1, 0}, {1, 2, 0}, {0, 2, 0}},  // L
      {{0, 0, 0}, {2, 1, 0}, {4, 0, 0}, {2, 4, 0}},                        // dart
      {{0, 0, 0},
       {5, 0, 0},
       {5, 3, 0},
       {4, 3, 0},
       {4, 1, 0},
       {3, 1, 0},
       {3, 3, 0},
       {2, 3, 0},
       {2, 1, 0},
       {1, 1, 0},
       {1, 3, 0},
       {0, 3, 0}},                                                         // comb
      {{0, 4, 0}, {2, 1, 0}, {4, 4, 0}, {4, 0, 0}, {0, 0, 0}},             // clockwise, notched
      {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {2, 2, 0}, {1, 1, 0}, {0, 2, 0}},  // a corner on a straight edge
  };
  for (const auto& shape : shapes) {
    double expected = 0;  // signed, anticlockwise positive
    for (std::size_t i = 0; i < shape.size(); ++i) expected += 0.5 * shape[i].cross(shape[(i + 1) % shape.size()]).z();
    const mesh::TriangleMesh m = mesh::load_triangle_mesh(write_polygon("polygon" + GetParam(), shape));
    ASSERT_EQ(m.triangles.size(), shape.size() - 2);
    double sum = 0;
    for (const auto& t : m.triangles) {
      const double signed_area =
          0.5 * (m.vertices.col(t[1]) - m.vertices.col(t[0])).cross(m.vertices.col(t[2]) - m.vertices.col(t[0])).z();
      EXPECT_GT(signed_area * expected, 0.0) << "a triangle against the polygon's winding";
      sum += std::abs(signed_area);
    }
    EXPECT_NEAR(sum, std::abs(expected), 1e-12) << shape.size() << " corners";
  }
}

// A polygon that crosses itself has no triangulation that covers it once: it is named, not fanned.
TEST_P(Polygons, SelfCrossingPolygonsAreNamed) {
  const std::string bowtie = write_polygon("bowtie" + GetParam(), {{0, 0, 0}, {2, 2, 0}, {2, 0, 0}, {0, 1, 0}});
  EXPECT_NE(error_of([&] { mesh::load_triangle_mesh(bowtie); }).find("crosses or touches itself"), std::string::npos)
      << error_of([&] { mesh::load_triangle_mesh(bowtie); });
}

INSTANTIATE_TEST_SUITE_P(Formats, Polygons, ::testing::Values(".obj", ".ply"),
                         [](const auto& test) { return test.param.substr(1); });

// A face that uses one vertex twice is named in the formats read through assimp too (assimp's
// FindDegenerates used to drop it without a word): here an STL facet with two corners at one point.
TEST(MeshFiles, DegenerateFacesAreNamedInEveryFormat) {
  const std::string stl = write("degenerate.stl",
                                "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                                "endloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                                "vertex 1 0 0\nendloop\nendfacet\nendsolid s\n");
  EXPECT_NE(
      error_of([&] { mesh::load_triangle_mesh(stl); }).find("degenerate.stl': mesh 0 face 1 uses one vertex twice"),
      std::string::npos)
      << error_of([&] { mesh::load_triangle_mesh(stl); });
}

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
std::string write_cube(const std::string& name, const std::string& ele_override = "",
                       const std::string& node_override = "") {
  const std::string stem = scratch(name).string();
  std::ofstream node(stem + ".node");
  node << "# unit cube\n";
  if (node_override.empty()) {
    node << "8 3 0 0\n";
    for (int i = 0; i < 8; ++i)
      node << i + 1 << ' ' << (i & 1) << ' ' << ((i >> 1) & 1) << ' ' << ((i >> 2) & 1) << '\n';
  } else {
    node << node_override;
  }
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

// Indices are read as integers: 1.7 is not truncated to 1, and NaN, infinities, 1e308 and -1 are
// named instead of converted (a float-to-integer conversion out of range is undefined behaviour).
TEST(TetMeshFiles, IndicesMustBeIntegersInRange) {
  const std::vector<std::pair<std::string, std::string>> cases{
      {"1 4 0\n1 1.7 2 4 6\n", "line 2: tet 0 node '1.7' is not an integer"},
      {"1 4 0\n1 1 2 nan 6\n", "line 2: tet 0 node 'nan' is not an integer"},
      {"1 4 0\n1 1 2 4 inf\n", "line 2: tet 0 node 'inf' is not an integer"},
      {"1 4 0\n1 1 1e308 4 6\n", "line 2: tet 0 node '1e308' is not an integer"},
      {"1 4 0\n1 -1 2 4 6\n", "line 2: tet 0 refers to node -1, which does not exist (nodes 1 to 8)"},
      {"1 4 0\n1 1 2 4 99999999999999999999\n", "line 2: tet 0 node '99999999999999999999' is out of range"},
      {"1.5 4 0\n1 1 2 4 6\n", "line 1: tet count '1.5' is not an integer"},
      {"1 10 0\n1 1 2 4 6\n", "line 1: only 4-node tets are supported, the header says 10"},
      {"1 4 0\n1 1 2 4\n", "line 2: tet 0 has 4 fields, expected its number, 4 nodes and 0 attributes"},
      {"1 4 1\n1 1 2 4 6 nan\n", "line 2: tet 0 attribute 1 'nan' is not a finite number"},
  };
  for (const auto& [ele, message] : cases)
    EXPECT_NE(error_of([&] { mesh::load_tet_mesh(write_cube("ints", ele)); }).find("ints.ele', " + message),
              std::string::npos)
        << ele << "\n"
        << error_of([&] { mesh::load_tet_mesh(write_cube("ints", ele)); });
}

// Node lines are in order and numbered from 0 or 1 as the first one is, the tets numbered alike; every
// coordinate is finite, used or not; a node line holds exactly the fields its header declares.
TEST(TetMeshFiles, NodesAreInOrderConsistentlyNumberedAndFinite) {
  const std::string four = "4 3 0 0\n";
  const std::string tet = "1 4 0\n1 1 2 3 4\n";
  const std::string ok_nodes = "1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n";
  ASSERT_EQ(mesh::load_tet_mesh(write_cube("order", tet, four + ok_nodes)).tets.size(), 1u);
  const std::vector<std::tuple<std::string, std::string, std::string>> cases{
      {four + "1 0 0 0\n3 0 1 0\n2 1 0 0\n4 0 0 1\n", tet, ".node', line 4: node numbered 3 where 2 was expected"},
      {four + "0 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n", tet, ".node', line 4: node numbered 2 where 1 was expected"},
      {four + "2 0 0 0\n3 1 0 0\n4 0 1 0\n5 0 0 1\n", tet, ".node', line 3: the first node is numbered 2"},
      {four + "0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n", tet, ".ele', line 2: tet numbered 1 where 0 was expected"},
      {"5 3 0 0\n" + ok_nodes + "5 nan 0 0\n", tet, ".node', line 7: node 5 x 'nan' is not a finite number"},
      {four + ok_nodes.substr(0, 16) + "3 0 1\n4 0 0 1\n", tet,
       ".node', line 5: node 3 has 3 fields, expected its number, x, y, z, 0 attributes and 0 boundary markers"},
      {"4 3 0 1\n1 0 0 0 0\n2 1 0 0 1\n3 0 1 0 1.5\n4 0 0 1 0\n", tet,
       ".node', line 5: node 3 boundary marker '1.5' is not an integer"},
      {"nan 3 0 0\n" + ok_nodes, tet, ".node', line 2: node count 'nan' is not an integer"},
      {"4 2 0 0\n" + ok_nodes, tet, ".node', line 2: header must declare 3 dimensions, not 2"},
  };
  for (const auto& [node, ele, message] : cases)
    EXPECT_NE(error_of([&] { mesh::load_tet_mesh(write_cube("order", ele, node)); }).find("order" + message),
              std::string::npos)
        << node << ele << "\n"
        << error_of([&] { mesh::load_tet_mesh(write_cube("order", ele, node)); });
}

}  // namespace
}  // namespace sinew
