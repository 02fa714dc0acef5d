// Fuzzing the mesh loaders, deterministically: valid seed files in every format the loaders take
// (OBJ, PLY, STL, glTF, GLB, TetGen .node/.ele) are mutated by a fixed-seed mutator (bytes flipped,
// numbers replaced by NaN, inf, 1e308, -1, 1.7 or huge integers, lines dropped, duplicated or swapped,
// tokens dropped, files truncated) and each input is loaded. The loader must return a valid mesh or
// throw sinew::Error; any other exception fails the test, and under the sanitizer build (.ci/test)
// so does any undefined behaviour or memory error. A failing input is kept in the scratch directory
// and named in the failure.
#include "sinew/mesh/mesh_io.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <iterator>
#include <random>
#include <sstream>

// LeakSanitizer's suppressions for this program: assimp 5.2 (a system library, not ours to fix) leaks
// what it allocated for an STL file it then rejects. The hook is read only in the sanitizer build.
extern "C" const char* __lsan_default_suppressions() { return "leak:libassimp.so\n"; }

namespace sinew {
namespace {

namespace fs = std::filesystem;

constexpr int kInputsPerFormat = 2000;

// Each test process writes in its own directory (ctest runs suites in parallel, and builds may share
// the machine's temporary directory).
fs::path scratch(const std::string& test) {
  const fs::path dir = fs::temp_directory_path() / ("sinew_fuzz_mesh_" + std::to_string(::getpid())) / test;
  fs::create_directories(dir);
  return dir;
}

// Removes a test's directory, and the process's once it is empty.
void clean(const fs::path& dir) {
  fs::remove_all(dir);
  std::error_code ignored;
  fs::remove(dir.parent_path(), ignored);
}

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A new file each time: rewriting one by truncation makes ext4 flush it to disk on close
// (auto_da_alloc), a wait of a millisecond or more per input.
void write_bytes(const fs::path& path, const std::string& bytes) {
  std::error_code ignored;
  fs::remove(path, ignored);
  std::ofstream(path, std::ios::binary) << bytes;
}

// Mutations drawn from std::mt19937_64, whose sequence the standard fixes (distributions are not
// fixed across standard libraries, so choices are taken modulo n from its raw output).
class Mutator {
 public:
  explicit Mutator(std::uint64_t seed) : m_rng(seed) {}

  std::size_t below(std::size_t n) { return n == 0 ? 0 : static_cast<std::size_t>(m_rng() % n); }

  // One to four mutations of `seed`; `text` adds the line and token mutations.
  std::string mutate(std::string bytes, bool text) {
    const std::size_t count = 1 + below(4);
    for (std::size_t i = 0; i < count; ++i) {
      switch (below(text ? 9 : 4)) {
        case 0: flip(bytes); break;
        case 1: truncate(bytes); break;
        case 2: insert(bytes); break;
        case 3: overwrite_word(bytes); break;
        case 4:
        case 5: replace_number(bytes); break;
        case 6: line_edit(bytes); break;
        case 7: drop_token(bytes); break;
        default: duplicate_token(bytes); break;
      }
    }
    return bytes;
  }

 private:
  void flip(std::string& b) {
    if (!b.empty()) b[below(b.size())] ^= static_cast<char>(1u << below(8));
  }
  void truncate(std::string& b) { b.resize(below(b.size() + 1)); }
  void insert(std::string& b) {
    static const std::string pieces[] = {std::string(1, '\0'), "#", "\\", "\n", " ", "/", "-", ".", "e", "\xff"};
    b.insert(below(b.size() + 1), pieces[below(std::size(pieces))]);
  }
  // A little-endian 32-bit word at a random place: the lengths and counts of binary formats.
  void overwrite_word(std::string& b) {
    static const std::uint32_t words[] = {0u, 1u, 3u, 0x7fffffffu, 0x80000000u, 0xffffffffu, 0x10000u, 0xfffffffdu};
    if (b.size() < 4) return;
    const std::size_t at = below(b.size() - 3);
    const std::uint32_t w = words[below(std::size(words))];
    for (int k = 0; k < 4; ++k) b[at + static_cast<std::size_t>(k)] = static_cast<char>((w >> (8 * k)) & 0xffu);
  }
  // Token boundaries: [begin, end) of every run of non-blank characters.
  static std::vector<std::pair<std::size_t, std::size_t>> tokens(const std::string& b) {
    std::vector<std::pair<std::size_t, std::size_t>> out;
    for (std::size_t i = 0; i < b.size();) {
      while (i < b.size() && std::isspace(static_cast<unsigned char>(b[i]))) ++i;
      const std::size_t start = i;
      while (i < b.size() && !std::isspace(static_cast<unsigned char>(b[i]))) ++i;
      if (i > start) out.emplace_back(start, i);
    }
    return out;
  }
  void replace_number(std::string& b) {
    static const char* const numbers[] = {"nan",
                                          "-nan",
                                          "inf",
                                          "-inf",
                                          "1e308",
                                          "-1e308",
                                          "1e400",
                                          "-1",
                                          "0",
                                          "1.7",
                                          "-0",
                                          "99999999999999999999",
                                          "2147483648",
                                          "4294967296",
                                          "9223372036854775807",
                                          "-9223372036854775808",
                                          "1e-320",
                                          "0x10",
                                          "+1",
                                          "1/2/3",
                                          "//",
                                          "3",
                                          "1",
                                          "2",
                                          "4",
                                          "10",
                                          "-3",
                                          "1e3",
                                          "NaN",
                                          "Infinity"};
    std::vector<std::pair<std::size_t, std::size_t>> numeric;
    for (const auto& t : tokens(b)) {
      const char c = b[t.first];
      if (std::isdigit(static_cast<unsigned char>(c)) || c == '-' || c == '.') numeric.push_back(t);
    }
    if (numeric.empty()) return;
    const auto [start, end] = numeric[below(numeric.size())];
    b.replace(start, end - start, numbers[below(std::size(numbers))]);
  }
  void line_edit(std::string& b) {
    std::vector<std::string> lines;
    std::istringstream in(b);
    for (std::string line; std::getline(in, line);) lines.push_back(line);
    if (lines.empty()) return;
    const std::size_t i = below(lines.size()), j = below(lines.size());
    switch (below(3)) {
      case 0: lines.erase(lines.begin() + static_cast<std::ptrdiff_t>(i)); break;
      case 1: lines.insert(lines.begin() + static_cast<std::ptrdiff_t>(j), lines[i]); break;
      default: std::swap(lines[i], lines[j]); break;
    }
    b.clear();
    for (const std::string& line : lines) b += line + '\n';
  }
  void drop_token(std::string& b) {
    const auto t = tokens(b);
    if (t.empty()) return;
    const auto [start, end] = t[below(t.size())];
    b.erase(start, end - start);
  }
  void duplicate_token(std::string& b) {
    const auto t = tokens(b);
    if (t.empty()) return;
    const auto [start, end] = t[below(t.size())];
    b.insert(end, " " + b.substr(start, end - start));
  }

  std::mt19937_64 m_rng;
};

// What a loaded mesh promises: finite vertices, at least one triangle, indices in range, no triangle
// without area, every vertex used. Returns the broken promise, or "".
std::string broken_promise(const mesh::TriangleMesh& m) {
  if (!m.vertices.allFinite()) return "a vertex is not finite";
  if (m.triangles.empty()) return "no triangles";
  std::vector<bool> used(static_cast<std::size_t>(m.vertices.cols()), false);
  for (const auto& t : m.triangles) {
    for (Index v : t) {
      if (v < 0 || v >= m.vertices.cols()) return "an index out of range";
      used[static_cast<std::size_t>(v)] = true;
    }
    // Collinear corners in double arithmetic (the loader's own test, relative to the longest edge, is stricter).
    const Vec3 n = (m.vertices.col(t[1]) - m.vertices.col(t[0])).cross(m.vertices.col(t[2]) - m.vertices.col(t[0]));
    if (n == Vec3::Zero()) return "a triangle without area";
  }
  for (bool u : used)
    if (!u) return "an unused vertex";
  return "";
}

std::string broken_promise(const mesh::TetMesh& m) {
  if (!m.vertices.allFinite()) return "a vertex is not finite";
  if (m.tets.empty()) return "no tets";
  for (const auto& t : m.tets) {
    for (Index v : t)
      if (v < 0 || v >= m.vertices.cols()) return "an index out of range";
    Mat3 e;
    e << m.vertices.col(t[1]) - m.vertices.col(t[0]), m.vertices.col(t[2]) - m.vertices.col(t[0]),
        m.vertices.col(t[3]) - m.vertices.col(t[0]);
    if (!(e.determinant() > 0)) return "a tet that is not positively oriented";
  }
  return "";
}

// Loads every input through `load` and checks the outcome; returns how many loaded (the rest threw
// sinew::Error), so a test can check that its mutations leave some inputs valid and reject others.
template <typename Load>
int run_inputs(const std::vector<std::string>& seeds, bool text, std::uint64_t seed, int inputs,
               const std::function<void(const std::string&)>& write_input, const std::function<void(int)>& keep,
               const Load& load) {
  Mutator mutator(seed);
  int loaded = 0, failures = 0;
  for (int i = 0; i < inputs && failures < 5; ++i) {
    write_input(mutator.mutate(seeds[mutator.below(seeds.size())], text));
    std::string problem;
    try {
      problem = broken_promise(load());
      ++loaded;
    } catch (const Error&) {
    } catch (const std::exception& e) {
      problem = std::string("threw something other than sinew::Error: ") + e.what();
    } catch (...) {
      problem = "threw something that is not a std::exception";
    }
    if (!problem.empty()) {
      ++failures;
      keep(i);
      ADD_FAILURE() << "input " << i << ": " << problem;
    }
  }
  return loaded;
}

// A 4 x 3 grid of quads, an L-shaped hexagon (concave), a triangle by negative indices, texture and
// normal references, groups, a line and a continued face line.
std::string obj_seed() {
  std::ostringstream s;
  s << "# sinew fuzz seed\nmtllib seed.mtl\no grid\n";
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 4; ++i) s << "v " << 0.25 * i << ' ' << 0.125 * i * j << ' ' << -0.25 * j << '\n';
  s << "vt 0 0\nvt 1 0\nvt 1 1\nvn 0 1 0\ng quads\nusemtl cloth\ns 1\n";
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 3; ++i) {
      const int a = 1 + j * 4 + i;
      s << "f " << a << "/1/1 " << a + 1 << "/2/1 " << a + 5 << "/3/1 " << a + 4 << "/2/1\n";
    }
  s << "o L\nv 2 0 0\nv 4 0 0\nv 4 1 0\nv 3 1 0\nv 3 2 0\nv 2 2 0\nf 13 14 15 16 \\\n 17 18\n";
  s << "v 5 0 0\nv 6 0 0\nv 5 1 0\nf -3//1 -2//1 -1//1\nl 1 2\n";
  return s.str();
}

// An ASCII PLY with a quad and a concave pentagon (assimp's exporter writes triangles only).
std::string ply_seed() {
  return "ply\nformat ascii 1.0\ncomment sinew fuzz seed\nelement vertex 9\nproperty float x\nproperty float y\n"
         "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
         "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n4 0 0\n4 4 0\n3 1 0\n2 4 0\n4 0 1 2 3\n5 4 5 6 7 8\n";
}

// A binary PLY of the same shapes, double coordinates and int indices, in either byte order.
std::string ply_binary_seed(bool little) {
  std::string out = std::string("ply\nformat ") + (little ? "binary_little_endian" : "binary_big_endian") +
                    " 1.0\nelement vertex 9\nproperty double x\nproperty double y\nproperty double z\n"
                    "element face 2\nproperty list uchar int vertex_indices\nend_header\n";
  const auto put = [&](const void* data, std::size_t size) {
    std::string bytes(static_cast<const char*>(data), size);
    if (!little) std::reverse(bytes.begin(), bytes.end());  // the machines sinew runs on are little-endian
    out += bytes;
  };
  const double xy[9][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}, {2, 0}, {4, 0}, {4, 4}, {3, 1}, {2, 4}};
  for (const auto& v : xy)
    for (double c : {v[0], v[1], 0.0}) put(&c, sizeof c);
  const std::vector<std::vector<std::int32_t>> faces{{0, 1, 2, 3}, {4, 5, 6, 7, 8}};
  for (const auto& f : faces) {
    out += static_cast<char>(f.size());
    for (std::int32_t i : f) put(&i, sizeof i);
  }
  return out;
}

// Seeds of a format written by save_triangle_meshes (assimp's exporters), beside handwritten ones.
std::vector<std::string> exported_seeds(const fs::path& dir, const std::string& extension) {
  mesh::TriangleMesh grid;
  grid.vertices.resize(3, 9);
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 3; ++i) grid.vertices.col(j * 3 + i) = Vec3(0.5 * i, 0.1 * i * j, -0.5 * j);
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 2; ++i) {
      const Index a = j * 3 + i;
      grid.triangles.push_back({a, a + 1, a + 4});
      grid.triangles.push_back({a, a + 4, a + 3});
    }
  const fs::path path = dir / ("seed" + extension);
  mesh::save_triangle_meshes(path.string(), {grid, grid}, {"one", "two"});
  return {read_bytes(path)};
}

class SurfaceFuzz : public ::testing::TestWithParam<std::string> {};

TEST_P(SurfaceFuzz, EveryInputLoadsAValidMeshOrThrowsANamedError) {
  const std::string extension = GetParam();
  const fs::path dir = scratch(extension.substr(1));
  std::vector<std::string> seeds = exported_seeds(dir, extension);
  if (extension == ".obj") seeds.push_back(obj_seed());
  if (extension == ".ply") seeds.insert(seeds.end(), {ply_seed(), ply_binary_seed(true), ply_binary_seed(false)});
  const fs::path check = dir / ("check" + extension);
  for (const std::string& s : seeds) {
    write_bytes(check, s);
    ASSERT_EQ(broken_promise(mesh::load_triangle_mesh(check.string())), "");
  }
  const fs::path input = dir / ("input" + extension);
  const bool text = extension != ".glb";
  std::uint64_t seed = 19;  // one fixed seed per format
  for (char c : extension) seed = seed * 131 + static_cast<unsigned char>(c);
  const auto start = std::chrono::steady_clock::now();
  const int loaded = run_inputs(
      seeds, text, seed, kInputsPerFormat, [&](const std::string& bytes) { write_bytes(input, bytes); },
      [&](int i) {
        const fs::path kept = dir / ("failure_" + std::to_string(i) + extension);
        fs::copy_file(input, kept, fs::copy_options::overwrite_existing);
        std::cerr << "kept " << kept << '\n';
      },
      [&] { return mesh::load_triangle_mesh(input.string()); });
  std::cerr << kInputsPerFormat << " inputs in "
            << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() << " s, " << loaded
            << " loaded\n";
  // The mutations reach both outcomes: some inputs still load, most are named errors.
  EXPECT_GT(loaded, 0);
  EXPECT_LT(loaded, kInputsPerFormat);
  if (!HasFailure()) clean(dir);
}

INSTANTIATE_TEST_SUITE_P(Formats, SurfaceFuzz, ::testing::Values(".obj", ".ply", ".stl", ".gltf", ".glb"),
                         [](const auto& test) { return test.param.substr(1); });

// The cube of test_mesh (1-based), and a 0-based one with an attribute and boundary markers per node
// and a region attribute per tet.
std::pair<std::string, std::string> cube(bool zero_based) {
  std::ostringstream node, ele;
  const int first = zero_based ? 0 : 1;
  node << "# sinew fuzz seed\n8 3 " << (zero_based ? "1 1" : "0 0") << '\n';
  for (int i = 0; i < 8; ++i) {
    node << i + first << ' ' << (i & 1) << ' ' << ((i >> 1) & 1) << ' ' << ((i >> 2) & 1);
    if (zero_based) node << ' ' << 0.5 * i << ' ' << (i % 2);
    node << '\n';
  }
  const int tets[5][4] = {{1, 2, 4, 6}, {1, 4, 3, 7}, {1, 6, 7, 5}, {4, 6, 8, 7}, {1, 4, 7, 6}};
  ele << "5 4 " << (zero_based ? 1 : 0) << '\n';
  for (int t = 0; t < 5; ++t) {
    ele << t + first;
    for (int k = 0; k < 4; ++k) ele << ' ' << tets[t][k] - 1 + first;
    if (zero_based) ele << ' ' << t;
    ele << '\n';
  }
  return {node.str(), ele.str()};
}

TEST(TetFuzz, EveryInputLoadsAValidMeshOrThrowsANamedError) {
  const fs::path dir = scratch("tet");
  const std::string stem = (dir / "input").string();
  const auto one = cube(false), zero = cube(true);
  for (const auto& [node, ele] : {one, zero}) {
    write_bytes(stem + ".node", node);
    write_bytes(stem + ".ele", ele);
    ASSERT_EQ(broken_promise(mesh::load_tet_mesh(stem)), "");
  }
  // Seeds are "node\0ele" pairs, mutated as one text, so mutations land in either file or both.
  const std::vector<std::string> seeds{one.first + '\0' + one.second, zero.first + '\0' + zero.second};
  const auto start = std::chrono::steady_clock::now();
  const int loaded = run_inputs(
      seeds, true, 1903u, kInputsPerFormat,
      [&](const std::string& bytes) {
        const std::size_t split = bytes.find('\0');
        write_bytes(stem + ".node", bytes.substr(0, split));
        write_bytes(stem + ".ele", split == std::string::npos ? "" : bytes.substr(split + 1));
      },
      [&](int i) {
        for (const char* ext : {".node", ".ele"})
          fs::copy_file(stem + ext, (dir / ("failure_" + std::to_string(i) + ext)),
                        fs::copy_options::overwrite_existing);
        std::cerr << "kept " << dir / ("failure_" + std::to_string(i)) << ".node/.ele\n";
      },
      [&] { return mesh::load_tet_mesh(stem); });
  std::cerr << kInputsPerFormat << " inputs in "
            << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() << " s, " << loaded
            << " loaded\n";
  EXPECT_GT(loaded, 0);
  EXPECT_LT(loaded, kInputsPerFormat);
  if (!HasFailure()) clean(dir);
}

}  // namespace
}  // namespace sinew
