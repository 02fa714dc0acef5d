#include "sinew/mesh/mesh_io.hpp"

#include <assimp/config.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <sstream>

namespace sinew::mesh {

namespace {

// Where a message points: the kind of file, its path and, in the text formats read here, the line.
struct Place {
  const char* kind;  // "mesh file" or "tet mesh file"
  const std::string& path;
  std::size_t line = 0;  // from 1; 0 for the file as a whole
};

std::ostream& operator<<(std::ostream& out, const Place& place) {
  out << place.kind << " '" << place.path << "'";
  if (place.line > 0) out << ", line " << place.line;
  return out;
}

// A statement of a text file: its whitespace-separated fields and the line it starts on.
struct Statement {
  std::size_t line;
  std::vector<std::string> fields;
};

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

// The statements of a text file whose comments run from '#' to the end of the line. With
// `continuations`, a line ending in '\' goes on on the next one (OBJ).
std::vector<Statement> read_statements(const Place& file, bool continuations) {
  std::ifstream in(file.path, std::ios::binary);
  if (!in) fail(file, ": cannot be opened");
  std::vector<Statement> statements;
  std::string line, text;
  std::size_t number = 0, start = 0;
  bool continued = false;
  const auto finish = [&] {
    Statement s{start, {}};
    for (std::size_t i = 0; i < text.size();) {
      while (i < text.size() && is_space(text[i])) ++i;
      std::size_t end = i;
      while (end < text.size() && !is_space(text[end])) ++end;
      if (end > i) s.fields.emplace_back(text, i, end - i);
      i = end;
    }
    if (!s.fields.empty()) statements.push_back(std::move(s));
    text.clear();
  };
  while (std::getline(in, line)) {
    ++number;
    if (!continued) start = number;
    line.resize(std::min(line.size(), line.find('#')));
    while (!line.empty() && is_space(line.back())) line.pop_back();
    continued = continuations && !line.empty() && line.back() == '\\';
    if (continued) line.back() = ' ';
    text += line;
    text += ' ';
    if (!continued) finish();
  }
  finish();
  return statements;
}

// A number written out in full: std::from_chars reads it the same in every locale and takes no hex.
// A leading '+' (which from_chars refuses) is allowed, as strtod allows it and writers use it.
std::optional<double> parse_real(const std::string& token) {
  const char* begin = token.data();
  const char* const end = begin + token.size();
  if (begin != end && *begin == '+' && ++begin != end && *begin == '-') return std::nullopt;
  double value = 0;
  const auto [stop, error] = std::from_chars(begin, end, value);
  if (error != std::errc() || stop != end) return std::nullopt;
  return value;
}

// A finite number, or an error naming the item: NaN, infinities and values beyond double's range
// (1e400) are refused even where the loader would not use them.
template <typename... Item>
double finite_real(const std::string& token, const Place& place, const Item&... item) {
  const std::optional<double> value = parse_real(token);
  if (!value || !std::isfinite(*value)) fail(place, ": ", item..., " '", token, "' is not a finite number");
  return *value;
}

// An integer written as one: "1.7", "1e3", "nan" and "1e308" are refused, not converted (a
// float-to-integer conversion of NaN or of a value out of range is undefined behaviour).
template <typename... Item>
long long integer(const std::string& token, const Place& place, const Item&... item) {
  long long value = 0;
  const char* const end = token.data() + token.size();
  const auto [stop, error] = std::from_chars(token.data(), end, value);
  if (error == std::errc::result_out_of_range && stop == end)
    fail(place, ": ", item..., " '", token, "' is out of range");
  if (error != std::errc() || stop != end) fail(place, ": ", item..., " '", token, "' is not an integer");
  return value;
}

double orient(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
  const Eigen::Vector2d ab = b - a, ac = c - a;
  return ab.x() * ac.y() - ab.y() * ac.x();
}

// Whether closed segments ab and cd share a point.
bool segments_meet(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                   const Eigen::Vector2d& d) {
  const double d1 = orient(c, d, a), d2 = orient(c, d, b), d3 = orient(a, b, c), d4 = orient(a, b, d);
  if (((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0))) return true;
  // A point on the line of the other segment, within that segment's box.
  const auto on = [](const Eigen::Vector2d& p, const Eigen::Vector2d& q, const Eigen::Vector2d& r) {
    return std::min(p.x(), q.x()) <= r.x() && r.x() <= std::max(p.x(), q.x()) && std::min(p.y(), q.y()) <= r.y() &&
           r.y() <= std::max(p.y(), q.y());
  };
  return (d1 == 0 && on(c, d, a)) || (d2 == 0 && on(c, d, b)) || (d3 == 0 && on(a, b, c)) || (d4 == 0 && on(a, b, d));
}

// Cuts a polygon (corner indices into `vertices`) into triangles of its own winding, appended to
// `triangles`. A triangle stays as it is; a larger polygon is cut by ear clipping in the plane of its
// Newell normal, so concave polygons come out as triangles that do not overlap (a fan from one corner
// overlaps itself around a reflex corner). A polygon that is not flat is cut as its projection on that
// plane, which must be simple. Returns what is wrong with the polygon, or an empty string: a vertex
// used twice, no area (relative to its longest edge, as the tet loader's volume test), or edges that
// cross or touch in that plane (no set of triangles covers it once).
std::string add_polygon(const std::vector<Vec3>& vertices, const std::vector<Index>& polygon,
                        std::vector<std::array<Index, 3>>& triangles) {
  const std::size_t n = polygon.size();
  std::vector<Index> sorted = polygon;
  std::sort(sorted.begin(), sorted.end());
  if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) return "uses one vertex twice";
  // Newell's normal (twice the area vector) about the first corner: the coordinates may be far from
  // the origin (1 km) while the polygon is small.
  const Vec3& origin = vertices[static_cast<std::size_t>(polygon[0])];
  Vec3 normal = Vec3::Zero();
  double longest = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3 a = vertices[static_cast<std::size_t>(polygon[i])] - origin;
    const Vec3 b = vertices[static_cast<std::size_t>(polygon[(i + 1) % n])] - origin;
    normal += a.cross(b);
    longest = std::max(longest, (b - a).norm());
  }
  if (!std::isfinite(longest) || !normal.allFinite()) return "is too large for double precision";
  if (!(normal.norm() > 1e-12 * longest * longest)) return "has no area";
  if (n == 3) {
    triangles.push_back({polygon[0], polygon[1], polygon[2]});
    return "";
  }
  // In-plane coordinates: (u, v, normal) is right-handed, so the polygon turns anticlockwise in them.
  const Vec3 w = normal.normalized(), u = w.unitOrthogonal(), v = w.cross(u);
  std::vector<Eigen::Vector2d> p(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3 q = vertices[static_cast<std::size_t>(polygon[i])] - origin;
    p[i] = Eigen::Vector2d(q.dot(u), q.dot(v));
  }
  // Simple: neighbouring edges meet only at their shared corner (not folding back along each other),
  // others not at all.
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = i + 1; j < n; ++j) {
      const std::size_t i1 = (i + 1) % n, j1 = (j + 1) % n;
      if (j == i1 || j1 == i) {
        const std::size_t shared = j == i1 ? j : i, a = j == i1 ? i : i1, b = j == i1 ? j1 : j;
        if (orient(p[a], p[shared], p[b]) == 0 && (p[a] - p[shared]).dot(p[b] - p[shared]) > 0)
          return "folds back along itself";
      } else if (segments_meet(p[i], p[i1], p[j], p[j1])) {
        return "crosses or touches itself";
      }
    }
  // Ear clipping: cut off a convex corner whose triangle holds no other corner, even on its edges.
  // A simple polygon always has one (Meisters' two-ears theorem), and cutting it leaves a simple
  // polygon. Of the ears, the fattest (area over longest edge squared) goes first, so that a corner
  // nearly on an edge is not left for a sliver; an ear must pass the area test above.
  const auto fatness = [&](std::size_t a, std::size_t b, std::size_t c) {
    const double longest_edge =
        std::max({(p[b] - p[a]).squaredNorm(), (p[c] - p[b]).squaredNorm(), (p[a] - p[c]).squaredNorm()});
    return orient(p[a], p[b], p[c]) / longest_edge;
  };
  std::vector<std::size_t> ring(n);
  for (std::size_t i = 0; i < n; ++i) ring[i] = i;
  while (ring.size() > 3) {
    const std::size_t m = ring.size();
    double best = 1e-12;
    std::size_t cut = m;
    for (std::size_t k = 0; k < m; ++k) {
      const std::size_t a = ring[(k + m - 1) % m], b = ring[k], c = ring[(k + 1) % m];
      const double f = fatness(a, b, c);
      if (!(f > best)) continue;
      const auto inside = [&](std::size_t o) {
        return o != a && o != b && o != c && orient(p[a], p[b], p[o]) >= 0 && orient(p[b], p[c], p[o]) >= 0 &&
               orient(p[c], p[a], p[o]) >= 0;
      };
      if (std::any_of(ring.begin(), ring.end(), inside)) continue;
      best = f;
      cut = k;
    }
    // Only corners nearly on an edge (relative to 1e-12) or rounding get here.
    if (cut == m) return "cannot be cut into triangles with area";
    triangles.push_back({polygon[ring[(cut + m - 1) % m]], polygon[ring[cut]], polygon[ring[(cut + 1) % m]]});
    ring.erase(ring.begin() + static_cast<std::ptrdiff_t>(cut));
  }
  if (!(fatness(ring[0], ring[1], ring[2]) > 1e-12)) return "cannot be cut into triangles with area";
  triangles.push_back({polygon[ring[0]], polygon[ring[1]], polygon[ring[2]]});
  return "";
}

// The vertices the triangles use, in their order in `vertices`: a vertex no triangle uses would be a
// particle without mass.
TriangleMesh used_vertices(const std::vector<Vec3>& vertices, std::vector<std::array<Index, 3>> triangles) {
  std::vector<bool> used(vertices.size(), false);
  for (const auto& t : triangles)
    for (Index v : t) used[static_cast<std::size_t>(v)] = true;
  std::vector<Index> renumbered(vertices.size(), -1);
  Index count = 0;
  for (std::size_t i = 0; i < vertices.size(); ++i)
    if (used[i]) renumbered[i] = count++;
  TriangleMesh out;
  out.vertices.resize(3, count);
  for (std::size_t i = 0; i < vertices.size(); ++i)
    if (used[i]) out.vertices.col(renumbered[i]) = vertices[i];
  for (auto& t : triangles)
    for (Index& v : t) v = renumbered[static_cast<std::size_t>(v)];
  out.triangles = std::move(triangles);
  return out;
}

// OBJ is read here, not through assimp: Debian's assimp is built with float ai_real, which rounds
// coordinates (by up to 3e-5 m at 1 km), and its OBJ reader skips a vertex line with two coordinates,
// so that every later index points at the next vertex. This reader keeps the file's doubles and its
// vertex numbering, and names every line it cannot take.
TriangleMesh load_obj(const std::string& path) {
  const Place file{"mesh file", path};
  const std::vector<Statement> statements = read_statements(file, true);
  // Statements that carry nothing for a triangle mesh: texture and normal data (counted, as faces
  // refer to them), grouping, materials, lines, points and the settings of free-form geometry.
  static const std::set<std::string> ignored{
      "vt",   "vn",    "vp",       "o",        "g",          "s",         "mg",     "usemtl", "mtllib", "l",    "p",
      "lod",  "bevel", "c_interp", "d_interp", "shadow_obj", "trace_obj", "maplib", "usemap", "cstype", "deg",  "bmat",
      "step", "parm",  "trim",     "hole",     "scrv",       "sp",        "end",    "con",    "ctech",  "stech"};
  struct Face {
    std::size_t line, number;
    std::vector<Index> vertices;
  };
  // A reference forward (OBJ allows positive indices to vertices defined later), checked at the end.
  struct Forward {
    std::size_t line, face;
    int kind;
    long long index;
  };
  static const char* const kinds[] = {"vertex", "texture coordinate", "normal"};
  std::vector<Vec3> positions;
  std::array<long long, 3> counts{0, 0, 0};  // vertices, texture coordinates, normals so far
  std::vector<Face> faces;
  std::vector<Forward> forward;
  for (const Statement& s : statements) {
    const Place at{file.kind, path, s.line};
    const std::string& key = s.fields[0];
    const std::size_t values = s.fields.size() - 1;
    if (key == "v") {
      const std::size_t number = positions.size() + 1;  // OBJ counts from 1
      // x y z, then an optional w or r g b that a triangle mesh does not use.
      if (values < 3 || values > 7)
        fail(at, ": vertex ", number, " has ", values, values == 1 ? " value" : " values", ", expected x y z");
      Vec3 x;
      for (int k = 0; k < 3; ++k)
        x[k] = finite_real(s.fields[static_cast<std::size_t>(k) + 1], at, "vertex ", number, " ", "xyz"[k]);
      for (std::size_t k = 4; k <= values; ++k) finite_real(s.fields[k], at, "vertex ", number, " value ", k);
      positions.push_back(x);
      ++counts[0];
    } else if (key == "vt" || key == "vn") {
      ++counts[key == "vt" ? 1 : 2];
    } else if (key == "f") {
      Face face{s.line, faces.size() + 1, {}};
      if (values < 3)
        fail(at, ": face ", face.number, " has ", values, values == 1 ? " corner" : " corners", ", expected 3 or more");
      for (std::size_t c = 1; c <= values; ++c) {
        // v, v/vt, v//vn or v/vt/vn
        const std::string& corner = s.fields[c];
        std::array<std::string, 3> parts;
        std::size_t part = 0;
        for (char ch : corner) {
          if (ch != '/') parts[part] += ch;
          else if (++part == 3) break;
        }
        if (part == 3 || parts[0].empty())
          fail(at, ": face ", face.number, " corner '", corner, "' is not v, v/vt, v//vn or v/vt/vn");
        for (int kind = 0; kind < 3; ++kind) {
          const std::string& text = parts[static_cast<std::size_t>(kind)];
          if (text.empty()) continue;
          const long long index = integer(text, at, "face ", face.number, " ", kinds[kind], " index");
          const long long count = counts[static_cast<std::size_t>(kind)];
          // Negative indices count back from the last one defined.
          if (index == 0 || (index < 0 && index < -count))
            fail(at, ": face ", face.number, " refers to ", kinds[kind], " ", index, ", which does not exist (", count,
                 " so far)");
          if (index > count) forward.push_back({s.line, face.number, kind, index});
          if (kind == 0) face.vertices.push_back(index < 0 ? count + index : index - 1);
        }
      }
      faces.push_back(std::move(face));
    } else if (key == "curv" || key == "curv2" || key == "surf") {
      fail(at, ": free-form geometry ('", key, "') is not supported; export it as polygons");
    } else if (ignored.count(key) == 0) {
      fail(at, ": unknown statement '", key, "'");
    }
  }
  for (const Forward& f : forward)
    if (f.index > counts[static_cast<std::size_t>(f.kind)])
      fail(Place{file.kind, path, f.line}, ": face ", f.face, " refers to ", kinds[f.kind], " ", f.index,
           ", which does not exist (", counts[static_cast<std::size_t>(f.kind)], " in the file)");
  std::vector<std::array<Index, 3>> triangles;
  for (const Face& face : faces) {
    const std::string problem = add_polygon(positions, face.vertices, triangles);
    if (!problem.empty()) fail(Place{file.kind, path, face.line}, ": face ", face.number, " ", problem);
  }
  if (triangles.empty()) fail(file, ": contains no triangles");
  return used_vertices(positions, std::move(triangles));
}

// PLY is read here too: assimp 5.2 loops forever on a header that ends inside a comment line (the
// fuzzer's find), and rounds double properties to float.
enum class PlyType { kInt8, kUInt8, kInt16, kUInt16, kInt32, kUInt32, kFloat32, kFloat64 };

std::optional<PlyType> ply_type(const std::string& name) {
  static const std::map<std::string, PlyType> types{
      {"char", PlyType::kInt8},      {"int8", PlyType::kInt8},       {"uchar", PlyType::kUInt8},
      {"uint8", PlyType::kUInt8},    {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUInt16},  {"uint16", PlyType::kUInt16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},    {"uint", PlyType::kUInt32},     {"uint32", PlyType::kUInt32},
      {"float", PlyType::kFloat32},  {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  const auto found = types.find(name);
  return found == types.end() ? std::nullopt : std::optional<PlyType>(found->second);
}

bool is_integer(PlyType t) { return t != PlyType::kFloat32 && t != PlyType::kFloat64; }

struct PlyProperty {
  std::string name;
  PlyType type;
  std::optional<PlyType> list_count;  // set for a list: the type of its length
};

struct PlyElement {
  std::string name;
  long long count;
  std::vector<PlyProperty> properties;
};

// The body of a PLY file, value by value, in ASCII or binary of either byte order.
class PlyBody {
 public:
  PlyBody(const Place& file, const std::string& bytes, std::size_t offset, std::size_t line, std::string format)
      : m_file(file), m_bytes(bytes), m_at(offset), m_line(line), m_format(std::move(format)) {}

  // The next value, as a double (every PLY type converts exactly); an integer type in ASCII must be
  // written as an integer within its range.
  template <typename... Item>
  double next(PlyType type, const Item&... item) {
    if (m_format == "ascii") {
      const std::string token = next_token(item...);
      const Place at{m_file.kind, m_file.path, m_token_line};
      if (!is_integer(type)) {
        const std::optional<double> value = parse_real(token);
        if (!value) fail(at, ": ", item..., " '", token, "' is not a number");
        return *value;
      }
      const long long value = integer(token, at, item...);
      static const std::map<PlyType, std::pair<long long, long long>> ranges{
          {PlyType::kInt8, {-128, 127}},
          {PlyType::kUInt8, {0, 255}},
          {PlyType::kInt16, {-32768, 32767}},
          {PlyType::kUInt16, {0, 65535}},
          {PlyType::kInt32, {-2147483648LL, 2147483647LL}},
          {PlyType::kUInt32, {0, 4294967295LL}}};
      const auto [low, high] = ranges.at(type);
      if (value < low || value > high) fail(at, ": ", item..., " '", token, "' is out of its type's range");
      return static_cast<double>(value);
    }
    static const std::map<PlyType, std::size_t> sizes{
        {PlyType::kInt8, 1},  {PlyType::kUInt8, 1},  {PlyType::kInt16, 2},   {PlyType::kUInt16, 2},
        {PlyType::kInt32, 4}, {PlyType::kUInt32, 4}, {PlyType::kFloat32, 4}, {PlyType::kFloat64, 8}};
    const std::size_t size = sizes.at(type);
    if (m_bytes.size() - m_at < size) fail(m_file, ": ", item..., " is past the end of the file");
    unsigned char raw[8];
    std::memcpy(raw, m_bytes.data() + m_at, size);
    m_at += size;
    const std::uint16_t probe = 1;
    const bool host_little = *reinterpret_cast<const unsigned char*>(&probe) == 1;
    if (host_little != (m_format == "binary_little_endian")) std::reverse(raw, raw + size);
    switch (type) {
      case PlyType::kInt8: return static_cast<double>(static_cast<std::int8_t>(raw[0]));
      case PlyType::kUInt8: return raw[0];
      case PlyType::kInt16: return decode<std::int16_t>(raw);
      case PlyType::kUInt16: return decode<std::uint16_t>(raw);
      case PlyType::kInt32: return decode<std::int32_t>(raw);
      case PlyType::kUInt32: return decode<std::uint32_t>(raw);
      case PlyType::kFloat32: return decode<float>(raw);
      default: return decode<double>(raw);
    }
  }

  // Nothing may follow the last element but blanks (ASCII); a binary body ends with it.
  void expect_end() {
    if (m_format == "ascii") {
      skip_blanks();
      if (m_at < m_bytes.size()) fail(Place{m_file.kind, m_file.path, m_line}, ": data after the last element");
    } else if (m_at < m_bytes.size()) {
      fail(m_file, ": ", m_bytes.size() - m_at, " bytes after the last element");
    }
  }

  // The line of the last ASCII value read, 0 in binary.
  std::size_t line() const { return m_format == "ascii" ? m_token_line : 0; }

 private:
  template <typename T>
  static double decode(const unsigned char* raw) {
    T value;
    std::memcpy(&value, raw, sizeof(T));
    return static_cast<double>(value);
  }
  void skip_blanks() {
    while (m_at < m_bytes.size() && (is_space(m_bytes[m_at]) || m_bytes[m_at] == '\n')) {
      if (m_bytes[m_at] == '\n') ++m_line;
      ++m_at;
    }
  }
  template <typename... Item>
  std::string next_token(const Item&... item) {
    skip_blanks();
    if (m_at == m_bytes.size()) fail(m_file, ": ", item..., " is past the end of the file");
    const std::size_t start = m_at;
    while (m_at < m_bytes.size() && !is_space(m_bytes[m_at]) && m_bytes[m_at] != '\n') ++m_at;
    m_token_line = m_line;
    return m_bytes.substr(start, m_at - start);
  }

  const Place& m_file;
  const std::string& m_bytes;
  std::size_t m_at, m_line, m_token_line = 0;
  std::string m_format;
};

TriangleMesh load_ply(const std::string& path) {
  const Place file{"mesh file", path};
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(file, ": cannot be opened");
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  // The header: lines up to "end_header".
  std::vector<PlyElement> elements;
  std::string format;
  std::size_t at = 0, line = 0;
  for (bool ended = false; !ended;) {
    if (at >= bytes.size()) fail(file, ": the header has no end_header line");
    const std::size_t end = std::min(bytes.find('\n', at), bytes.size());
    std::istringstream text(bytes.substr(at, end - at));
    at = std::min(end + 1, bytes.size());
    const Place here{file.kind, path, ++line};
    std::vector<std::string> f;
    for (std::string field; text >> field;) f.push_back(field);
    if (line == 1) {
      if (f.size() != 1 || f[0] != "ply") fail(here, ": not a PLY file (the first line is not 'ply')");
    } else if (f.empty() || f[0] == "comment" || f[0] == "obj_info") {
    } else if (f[0] == "format") {
      if (f.size() != 3 || (f[1] != "ascii" && f[1] != "binary_little_endian" && f[1] != "binary_big_endian") ||
          f[2] != "1.0")
        fail(here, ": unknown format (expected ascii, binary_little_endian or binary_big_endian 1.0)");
      format = f[1];
    } else if (f[0] == "element") {
      if (f.size() != 3) fail(here, ": an element line is 'element <name> <count>'");
      const long long count = integer(f[2], here, "element ", f[1], " count");
      if (count < 0) fail(here, ": element ", f[1], " count ", count, " is negative");
      elements.push_back({f[1], count, {}});
    } else if (f[0] == "property") {
      if (elements.empty()) fail(here, ": a property before any element");
      const bool list = f.size() == 5 && f[1] == "list";
      if (f.size() != 3 && !list) fail(here, ": a property line is 'property <type> <name>' or 'property list ...'");
      const std::optional<PlyType> type = ply_type(f[f.size() - 2]);
      const std::optional<PlyType> count = list ? ply_type(f[2]) : std::nullopt;
      if (!type || (list && !count)) fail(here, ": unknown property type");
      if (list && !is_integer(*count)) fail(here, ": a list's length must have an integer type");
      elements.back().properties.push_back({f.back(), *type, count});
    } else if (f[0] == "end_header") {
      ended = true;
    } else {
      fail(here, ": unknown header line '", f[0], "'");
    }
  }
  if (format.empty()) fail(file, ": the header has no format line");
  PlyBody body(file, bytes, at, line + 1, format);
  std::vector<Vec3> vertices;
  struct Face {
    std::size_t line;
    long long number;
    std::vector<Index> vertices;
  };
  std::vector<Face> faces;
  for (const PlyElement& element : elements) {
    const bool is_vertex = element.name == "vertex", is_face = element.name == "face";
    std::array<int, 3> xyz{-1, -1, -1};
    int corners = -1;
    for (std::size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& property = element.properties[p];
      for (int k = 0; k < 3; ++k)
        if (is_vertex && property.name == std::string(1, "xyz"[k]) && !property.list_count)
          xyz[k] = static_cast<int>(p);
      if (is_face && (property.name == "vertex_indices" || property.name == "vertex_index") && property.list_count) {
        if (!is_integer(property.type)) fail(file, ": face ", property.name, " must have an integer type");
        corners = static_cast<int>(p);
      }
    }
    if (is_vertex && (xyz[0] < 0 || xyz[1] < 0 || xyz[2] < 0)) fail(file, ": vertex has no x, y and z properties");
    if (is_face && corners < 0) fail(file, ": face has no vertex_indices list");
    for (long long row = 0; row < element.count; ++row) {
      Vec3 x = Vec3::Zero();
      Face face{0, row, {}};
      for (std::size_t p = 0; p < element.properties.size(); ++p) {
        const PlyProperty& property = element.properties[p];
        if (!property.list_count) {
          const double value = body.next(property.type, element.name, " ", row, " ", property.name);
          for (int k = 0; k < 3; ++k)
            if (xyz[k] == static_cast<int>(p)) {
              if (!std::isfinite(value))
                fail(Place{file.kind, path, body.line()}, ": vertex ", row, " ", property.name, " is not finite");
              x[k] = value;
            }
          continue;
        }
        const double length = body.next(*property.list_count, element.name, " ", row, " ", property.name, " length");
        if (length < 0)
          fail(Place{file.kind, path, body.line()}, ": ", element.name, " ", row, " has a negative list length");
        face.line = body.line();
        for (double i = 0; i < length; ++i) {
          const double value = body.next(property.type, element.name, " ", row, " ", property.name);
          if (static_cast<int>(p) == corners) face.vertices.push_back(static_cast<Index>(value));
        }
      }
      if (is_vertex) vertices.push_back(x);
      if (is_face) faces.push_back(std::move(face));
    }
  }
  body.expect_end();
  std::vector<std::array<Index, 3>> triangles;
  for (const Face& face : faces) {
    const Place where{file.kind, path, face.line};
    if (face.vertices.size() < 3)
      fail(where, ": face ", face.number, " has ", face.vertices.size(), " corners, expected 3 or more");
    for (Index v : face.vertices)
      if (v < 0 || v >= static_cast<Index>(vertices.size()))
        fail(where, ": face ", face.number, " refers to vertex ", v, ", which does not exist (", vertices.size(),
             " vertices)");
    const std::string problem = add_polygon(vertices, face.vertices, triangles);
    if (!problem.empty()) fail(where, ": face ", face.number, " ", problem);
  }
  if (triangles.empty()) fail(file, ": contains no triangles");
  return used_vertices(vertices, std::move(triangles));
}

// The binary glTF container (a 12-byte header, then chunks of an 8-byte header and 4-byte aligned
// data) must add up to the file's size before assimp reads it: assimp 5.2 allocates what a length field
// says, gigabytes for a 100-byte file.
void check_glb(const Place& file) {
  std::ifstream in(file.path, std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  const auto word = [&](std::size_t at) {
    std::uint32_t w = 0;
    for (std::size_t k = 0; k < 4; ++k)
      w |= static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at + k])) << (8 * k);
    return w;
  };
  if (bytes.size() < 12 || bytes.compare(0, 4, "glTF") != 0) fail(file, ": not a binary glTF file (no 'glTF' header)");
  if (word(4) != 2) fail(file, ": glTF version ", word(4), ", expected 2");
  if (word(8) != bytes.size()) fail(file, ": the header says ", word(8), " bytes, the file has ", bytes.size());
  for (std::size_t at = 12; at < bytes.size();) {
    if (bytes.size() - at < 8) fail(file, ": a chunk header at byte ", at, " runs past the end");
    const std::uint32_t length = word(at);
    if (length % 4 != 0 || length > bytes.size() - at - 8)
      fail(file, ": the chunk at byte ", at, " says ", length, " bytes (", bytes.size() - at - 8,
           " remain; chunks are 4-byte aligned)");
    at += 8 + length;
  }
}

// Every other format through assimp, whose positions are ai_real (float in Debian's build; binary STL
// and glTF store float anyway, ASCII STL's digits beyond float are lost).
TriangleMesh load_with_assimp(const std::string& path) {
  const Place file{"mesh file", path};
  Assimp::Importer importer;
  // Simulation needs connectivity: drop normals, texture coordinates and colours first so that vertices
  // that share a position are joined (STL and flat-shaded files repeat them per face).
  importer.SetPropertyInteger(AI_CONFIG_PP_RVC_FLAGS, aiComponent_NORMALS | aiComponent_TANGENTS_AND_BITANGENTS |
                                                          aiComponent_TEXCOORDS | aiComponent_COLORS);
  // Not aiProcess_Triangulate, which cuts some concave polygons into overlapping triangles (an
  // L-shaped hexagon gets an inverted one), nor aiProcess_FindDegenerates, which drops faces without a
  // word: polygons are cut and degenerate faces named below, as for OBJ.
  const aiScene* scene = nullptr;
  try {
    scene = importer.ReadFile(path, aiProcess_ValidateDataStructure | aiProcess_RemoveComponent |
                                        aiProcess_JoinIdenticalVertices | aiProcess_SortByPType);
  } catch (const std::exception& e) {
    fail(file, ": ", e.what());
  }
  if (!scene || !scene->mRootNode) fail(file, ": ", importer.GetErrorString());
  std::vector<Vec3> vertices;
  std::vector<std::array<Index, 3>> triangles;
  std::vector<Index> polygon;
  // Depth first, children in order, without recursion (a file may nest nodes deeply).
  std::vector<std::pair<const aiNode*, aiMatrix4x4>> stack{{scene->mRootNode, aiMatrix4x4()}};
  while (!stack.empty()) {
    const auto [node, parent] = stack.back();
    stack.pop_back();
    const aiMatrix4x4 transform = parent * node->mTransformation;
    for (unsigned m = 0; m < node->mNumMeshes; ++m) {
      if (node->mMeshes[m] >= scene->mNumMeshes)
        fail(file, ": node '", node->mName.C_Str(), "' refers to a missing mesh");
      const aiMesh* mesh = scene->mMeshes[node->mMeshes[m]];
      const auto base = static_cast<Index>(vertices.size());
      for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
        const aiVector3D p = transform * mesh->mVertices[v];
        vertices.emplace_back(p.x, p.y, p.z);
        if (!all_finite(vertices.back())) fail(file, ": mesh ", node->mMeshes[m], " vertex ", v, " is not finite");
      }
      for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
        const aiFace& face = mesh->mFaces[f];
        if (face.mNumIndices < 3) continue;  // points and lines, which these formats may hold beside faces
        polygon.clear();
        for (unsigned k = 0; k < face.mNumIndices; ++k) {
          if (face.mIndices[k] >= mesh->mNumVertices)
            fail(file, ": mesh ", node->mMeshes[m], " face ", f, " refers to vertex ", face.mIndices[k], " of ",
                 mesh->mNumVertices);
          polygon.push_back(base + face.mIndices[k]);
        }
        const std::string problem = add_polygon(vertices, polygon, triangles);
        if (!problem.empty()) fail(file, ": mesh ", node->mMeshes[m], " face ", f, " ", problem);
      }
    }
    for (unsigned c = node->mNumChildren; c-- > 0;) stack.emplace_back(node->mChildren[c], transform);
  }
  if (triangles.empty()) fail(file, ": contains no triangles");
  return used_vertices(vertices, std::move(triangles));
}

}  // namespace

TriangleMesh load_triangle_mesh(const std::string& path) {
  if (!std::filesystem::exists(path)) fail("mesh file '", path, "': no such file");
  std::string extension = std::filesystem::path(path).extension().string();
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (extension == ".obj") return load_obj(path);
  if (extension == ".ply") return load_ply(path);
  if (extension == ".glb") check_glb(Place{"mesh file", path});
  return load_with_assimp(path);
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

TetMesh load_tet_mesh(const std::string& stem) {
  const std::string node_path = stem + ".node", ele_path = stem + ".ele";
  const Place node_file{"tet mesh file", node_path}, ele_file{"tet mesh file", ele_path};
  const std::vector<Statement> nodes = read_statements(node_file, false);
  if (nodes.empty()) fail(node_file, ": empty");
  const std::vector<Statement> eles = read_statements(ele_file, false);
  if (eles.empty()) fail(ele_file, ": empty");

  // .node: "<nodes> 3 [<attributes> [<boundary markers 0 or 1>]]", then one line per node:
  // "<number> <x> <y> <z> <attributes...> [<boundary marker>]".
  Place at{node_file.kind, node_path, nodes[0].line};
  const std::vector<std::string>& header = nodes[0].fields;
  if (header.size() < 2 || header.size() > 4)
    fail(at, ": header has ", header.size(), " fields, expected <nodes> 3 [<attributes> [<boundary markers>]]");
  const long long count = integer(header[0], at, "node count");
  if (integer(header[1], at, "dimension") != 3) fail(at, ": header must declare 3 dimensions, not ", header[1]);
  const long long attributes = header.size() > 2 ? integer(header[2], at, "attribute count") : 0;
  const long long markers = header.size() > 3 ? integer(header[3], at, "boundary marker count") : 0;
  if (count < 1) fail(at, ": header declares ", count, " nodes");
  if (attributes < 0) fail(at, ": header declares ", attributes, " attributes");
  if (markers != 0 && markers != 1) fail(at, ": header declares ", markers, " boundary markers, expected 0 or 1");
  if (nodes.size() - 1 != static_cast<std::size_t>(count))
    fail(node_file, ": header says ", count, " nodes, found ", nodes.size() - 1);
  TetMesh out;
  out.vertices.resize(3, static_cast<Index>(count));
  // TetGen numbers from 0 or 1; the first node decides, every later node and tet follows in order.
  long long first = 0;
  for (long long i = 0; i < count; ++i) {
    const std::vector<std::string>& row = nodes[static_cast<std::size_t>(i) + 1].fields;
    at.line = nodes[static_cast<std::size_t>(i) + 1].line;
    const long long number = integer(row[0], at, "node number");
    if (i == 0 && number != 0 && number != 1) fail(at, ": the first node is numbered ", number, ", expected 0 or 1");
    if (i == 0) first = number;
    if (number != first + i)
      fail(at, ": node numbered ", number, " where ", first + i, " was expected (nodes are listed in order, from ",
           first, " as the first)");
    if (static_cast<long long>(row.size()) - 4 - markers != attributes)
      fail(at, ": node ", number, " has ", row.size(), " fields, expected its number, x, y, z, ", attributes,
           " attributes and ", markers, " boundary markers");
    for (int k = 0; k < 3; ++k)
      out.vertices(k, static_cast<Index>(i)) =
          finite_real(row[static_cast<std::size_t>(k) + 1], at, "node ", number, " ", "xyz"[k]);
    for (long long a = 0; a < attributes; ++a)
      finite_real(row[static_cast<std::size_t>(a) + 4], at, "node ", number, " attribute ", a + 1);
    if (markers == 1) integer(row.back(), at, "node ", number, " boundary marker");
  }

  // .ele: "<tets> 4 [<attributes>]", then "<number> <node> <node> <node> <node> <attributes...>".
  Place ele_at{ele_file.kind, ele_path, eles[0].line};
  const std::vector<std::string>& ele_header = eles[0].fields;
  if (ele_header.size() < 2 || ele_header.size() > 3)
    fail(ele_at, ": header has ", ele_header.size(), " fields, expected <tets> 4 [<attributes>]");
  const long long tets = integer(ele_header[0], ele_at, "tet count");
  if (integer(ele_header[1], ele_at, "nodes per tet") != 4)
    fail(ele_at, ": only 4-node tets are supported, the header says ", ele_header[1]);
  const long long tet_attributes = ele_header.size() > 2 ? integer(ele_header[2], ele_at, "attribute count") : 0;
  if (tets < 1) fail(ele_at, ": header declares ", tets, " tets");
  if (tet_attributes < 0) fail(ele_at, ": header declares ", tet_attributes, " attributes");
  if (eles.size() - 1 != static_cast<std::size_t>(tets))
    fail(ele_file, ": header says ", tets, " tets, found ", eles.size() - 1);
  for (long long t = 0; t < tets; ++t) {
    const std::vector<std::string>& row = eles[static_cast<std::size_t>(t) + 1].fields;
    ele_at.line = eles[static_cast<std::size_t>(t) + 1].line;
    const long long number = integer(row[0], ele_at, "tet number");
    if (number != first + t)
      fail(ele_at, ": tet numbered ", number, " where ", first + t, " was expected (tets are listed in order, from ",
           first, " as the nodes)");
    if (static_cast<long long>(row.size()) - 5 != tet_attributes)
      fail(ele_at, ": tet ", t, " has ", row.size(), " fields, expected its number, 4 nodes and ", tet_attributes,
           " attributes");
    std::array<Index, 4> tet;
    for (std::size_t k = 0; k < 4; ++k) {
      const long long node = integer(row[k + 1], ele_at, "tet ", t, " node");
      if (node < first || node >= first + count)
        fail(ele_at, ": tet ", t, " refers to node ", node, ", which does not exist (nodes ", first, " to ",
             first + count - 1, ")");
      tet[k] = static_cast<Index>(node - first);
    }
    for (long long a = 0; a < tet_attributes; ++a)
      finite_real(row[static_cast<std::size_t>(a) + 5], ele_at, "tet ", t, " attribute ", a + 1);
    Mat3 edges;
    edges << out.vertices.col(tet[1]) - out.vertices.col(tet[0]), out.vertices.col(tet[2]) - out.vertices.col(tet[0]),
        out.vertices.col(tet[3]) - out.vertices.col(tet[0]);
    const double volume = edges.determinant() / 6.0;
    const double scale = edges.colwise().norm().maxCoeff();
    if (!std::isfinite(volume) || !std::isfinite(scale))
      fail(ele_at, ": tet ", t, " is too large for double precision");
    if (!(std::abs(volume) > 1e-12 * scale * scale * scale))
      fail(ele_at, ": tet ", t, " is degenerate (volume ", volume, ")");
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
