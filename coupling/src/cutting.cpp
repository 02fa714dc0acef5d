#include "sinew/cutting.hpp"

#include "sinew/embedding.hpp"

#include <algorithm>
#include <cmath>
#include <map>

namespace sinew {

namespace {

using Part = std::array<Vec3, 4>;

// A tet's part in a cell below this share of its volume is left out (a plane through a face or a
// vertex leaves such slivers of round-off).
constexpr double kSliver = 1e-9;

double part_volume(const Part& t) { return std::abs((t[1] - t[0]).cross(t[2] - t[0]).dot(t[3] - t[0])) / 6.0; }

// The triangular prism with ends (p0, p1, p2) and (q0, q1, q2), p_i joined to q_i, as three tets.
void add_prism(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& q0, const Vec3& q1, const Vec3& q2,
               std::vector<Part>& out) {
  out.push_back({p0, p1, p2, q0});
  out.push_back({p1, p2, q0, q1});
  out.push_back({p2, q0, q1, q2});
}

// Splits tet t by the plane phi(x) = n.(x - p) = 0 into tets in front (phi > 0) and behind.
void split(const Part& t, const CutPlane& plane, std::vector<Part>& front, std::vector<Part>& back) {
  std::array<double, 4> phi{};
  std::vector<int> in, out;
  for (int k = 0; k < 4; ++k) {
    phi[static_cast<std::size_t>(k)] = plane.normal.dot(t[static_cast<std::size_t>(k)] - plane.point);
    (phi[static_cast<std::size_t>(k)] > 0.0 ? in : out).push_back(k);
  }
  if (out.empty()) return front.push_back(t);
  if (in.empty()) return back.push_back(t);
  const auto cut = [&](int a, int b) {  // where edge (a, b) meets the plane
    const double s =
        phi[static_cast<std::size_t>(a)] / (phi[static_cast<std::size_t>(a)] - phi[static_cast<std::size_t>(b)]);
    return Vec3(t[static_cast<std::size_t>(a)] + s * (t[static_cast<std::size_t>(b)] - t[static_cast<std::size_t>(a)]));
  };
  const auto at = [&](int k) { return t[static_cast<std::size_t>(k)]; };
  if (in.size() == 1 || out.size() == 1) {
    // One vertex alone on its side: a corner tet there, a prism on the other.
    const bool lone_in = in.size() == 1;
    const int a = lone_in ? in[0] : out[0];
    const std::vector<int>& rest = lone_in ? out : in;
    const Vec3 ab = cut(a, rest[0]), ac = cut(a, rest[1]), ad = cut(a, rest[2]);
    std::vector<Part>& corner = lone_in ? front : back;
    std::vector<Part>& prism = lone_in ? back : front;
    corner.push_back({at(a), ab, ac, ad});
    add_prism(at(rest[0]), at(rest[1]), at(rest[2]), ab, ac, ad, prism);
    return;
  }
  // Two on each side: a prism on each.
  const int a = in[0], b = in[1], c = out[0], d = out[1];
  const Vec3 ac = cut(a, c), ad = cut(a, d), bc = cut(b, c), bd = cut(b, d);
  add_prism(at(a), ac, ad, at(b), bc, bd, front);
  add_prism(at(c), ac, bc, at(d), ad, bd, back);
}

std::uint32_t cell_of(std::span<const CutPlane> planes, const Vec3& X) {
  std::uint32_t code = 0;
  for (std::size_t p = 0; p < planes.size(); ++p)
    if (planes[p].normal.dot(X - planes[p].point) > 0.0) code |= 1u << p;
  return code;
}

}  // namespace

CutTets cut_by_planes(const Vectors3& vertices, const std::vector<std::array<Index, 4>>& tets,
                      const std::vector<double>& fill, std::span<const CutPlane> planes) {
  if (planes.size() > 32) fail("cut_by_planes: ", planes.size(), " planes (at most 32)");
  for (std::size_t p = 0; p < planes.size(); ++p)
    if (!all_finite(planes[p].point) || !all_finite(planes[p].normal) || !(planes[p].normal.norm() > 0.0))
      fail("cut_by_planes: plane ", p, " has a point or normal that is not finite, or a zero normal");
  if (!fill.empty() && fill.size() != tets.size())
    fail("cut_by_planes: ", fill.size(), " fills for ", tets.size(), " tets");
  CutTets out;
  out.planes.assign(planes.begin(), planes.end());
  std::map<std::uint32_t, Index> piece_of_cell;
  std::map<std::pair<Index, Index>, Index> copy_of;  // (input vertex, piece) -> vertex copy
  std::vector<Vec3> copies;
  for (std::size_t t = 0; t < tets.size(); ++t) {
    const auto& v = tets[t];
    for (const Index i : v)
      if (i < 0 || i >= vertices.cols())
        fail("cut_by_planes: tet ", t, " has vertex ", i, ", which does not exist (there are ", vertices.cols(), ")");
    // The tet clipped by each plane in turn: its parts in each cell, and their volumes.
    std::vector<std::pair<std::uint32_t, std::vector<Part>>> cells{
        {0u, {Part{vertices.col(v[0]), vertices.col(v[1]), vertices.col(v[2]), vertices.col(v[3])}}}};
    for (std::size_t p = 0; p < planes.size(); ++p) {
      std::vector<std::pair<std::uint32_t, std::vector<Part>>> next;
      for (const auto& [code, parts] : cells) {
        std::vector<Part> front, back;
        for (const Part& part : parts) split(part, planes[p], front, back);
        if (!back.empty()) next.push_back({code, std::move(back)});
        if (!front.empty()) next.push_back({code | (1u << p), std::move(front)});
      }
      cells = std::move(next);
    }
    const double whole = part_volume({vertices.col(v[0]), vertices.col(v[1]), vertices.col(v[2]), vertices.col(v[3])});
    std::vector<std::pair<std::uint32_t, double>> count;
    for (const auto& [code, parts] : cells) {
      double sum = 0.0;
      for (const Part& part : parts) sum += part_volume(part);
      if (sum > kSliver * whole) count.push_back({code, sum / whole});
    }
    std::sort(count.begin(), count.end());
    for (const auto& [code, share] : count) {
      const auto [found, fresh] = piece_of_cell.try_emplace(code, static_cast<Index>(out.cell.size()));
      if (fresh) out.cell.push_back(code);
      const Index piece = found->second;
      std::array<Index, 4> copy{};
      for (int k = 0; k < 4; ++k) {
        const Index source = v[static_cast<std::size_t>(k)];
        const auto [node, added] = copy_of.try_emplace({source, piece}, static_cast<Index>(copies.size()));
        if (added) {
          copies.push_back(vertices.col(source));
          out.source_vertex.push_back(source);
        }
        copy[static_cast<std::size_t>(k)] = node->second;
      }
      out.tets.push_back(copy);
      out.fill.push_back((fill.empty() ? 1.0 : fill[t]) * std::min(share, 1.0));
      out.piece.push_back(piece);
      out.source_tet.push_back(static_cast<Index>(t));
    }
  }
  out.vertices.resize(3, static_cast<Index>(copies.size()));
  for (std::size_t k = 0; k < copies.size(); ++k) out.vertices.col(static_cast<Index>(k)) = copies[k];
  return out;
}

Index CutTets::piece_of(const Vec3& X) const {
  const std::uint32_t code = cell_of(planes, X);
  const auto it = std::find(cell.begin(), cell.end(), code);
  return it == cell.end() ? -1 : static_cast<Index>(it - cell.begin());
}

Index CutTets::locate(Index p, const Vec3& X, std::array<double, 4>& weights) const {
  Index best = -1;
  double best_low = -kInfinity;
  for (std::size_t t = 0; t < tets.size(); ++t) {
    if (piece[t] != p) continue;
    const auto& v = tets[t];
    const std::array<double, 4> w =
        tet_weights(vertices.col(v[0]), vertices.col(v[1]), vertices.col(v[2]), vertices.col(v[3]), X);
    const double low = *std::min_element(w.begin(), w.end());
    if (low > best_low) {
      best_low = low;
      best = static_cast<Index>(t);
      weights = w;
    }
  }
  return best;
}

}  // namespace sinew
