// Cutting by duplicated, partially filled tets (Sifakis et al. 2007, section 4, figure 11; the
// virtual node algorithm for planes through the whole body): pieces, fills and node copies counted,
// volume kept, pieces sharing no node, and a cut body coming apart under gravity as free fall says.
#include "sinew/cutting.hpp"
#include "sinew/forces/corotated_tets.hpp"
#include "sinew/system.hpp"

#include "cloth.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <numeric>

namespace sinew {
namespace {

void kuhn_block(int nx, int ny, int nz, double h, Vectors3& v, std::vector<std::array<Index, 4>>& tets) {
  scenes::kuhn_block(Vec3::Zero(), nx, ny, nz, h, v, tets);
}

double volume(const Vectors3& x, const std::array<Index, 4>& t) {
  Mat3 e;
  e << x.col(t[1]) - x.col(t[0]), x.col(t[2]) - x.col(t[0]), x.col(t[3]) - x.col(t[0]);
  return e.determinant() / 6.0;
}

// Pieces of the copies' node graph (union-find over shared nodes).
Index components(const CutTets& cut) {
  std::vector<Index> parent(static_cast<std::size_t>(cut.vertices.cols()));
  std::iota(parent.begin(), parent.end(), Index{0});
  std::function<Index(Index)> root = [&](Index i) {
    return parent[static_cast<std::size_t>(i)] == i
               ? i
               : parent[static_cast<std::size_t>(i)] = root(parent[static_cast<std::size_t>(i)]);
  };
  for (const auto& t : cut.tets)
    for (int k = 1; k < 4; ++k) parent[static_cast<std::size_t>(root(t[static_cast<std::size_t>(k)]))] = root(t[0]);
  Index count = 0;
  for (Index i = 0; i < cut.vertices.cols(); ++i) count += root(i) == i;
  return count;
}

TEST(Cutting, APlaneOnTheMeshFacesSplitsNodesAndNoTet) {
  Vectors3 v;
  std::vector<std::array<Index, 4>> tets;
  kuhn_block(2, 1, 1, 0.1, v, tets);
  const CutPlane plane{Vec3(0.1, 0, 0), Vec3::UnitX()};
  const CutTets cut = cut_by_planes(v, tets, {}, std::span<const CutPlane>(&plane, 1));
  EXPECT_EQ(cut.pieces(), 2);
  EXPECT_EQ(cut.tets.size(), tets.size());
  for (const double f : cut.fill) EXPECT_EQ(f, 1.0);
  EXPECT_EQ(cut.vertices.cols(), v.cols() + 4);  // the four nodes on the plane, once per side
  EXPECT_EQ(components(cut), 2);
}

TEST(Cutting, APlaneThroughTheTetsCopiesThemPartlyFilledAndKeepsTheVolume) {
  Vectors3 v;
  std::vector<std::array<Index, 4>> tets;
  kuhn_block(2, 2, 2, 0.1, v, tets);
  // Into four sticks along y, through the middle of the cells.
  const CutPlane planes[2] = {{Vec3(0.05, 0, 0), Vec3::UnitX()}, {Vec3(0, 0, 0.13), Vec3(0, 0, 2.0)}};
  const CutTets cut = cut_by_planes(v, tets, {}, planes);
  ASSERT_EQ(cut.pieces(), 4);
  EXPECT_EQ(components(cut), 4) << "each piece holds together and shares no node with another";
  EXPECT_GT(cut.tets.size(), tets.size());
  std::vector<double> piece_volume(4, 0.0), per_tet(tets.size(), 0.0);
  for (std::size_t c = 0; c < cut.tets.size(); ++c) {
    EXPECT_GT(cut.fill[c], 0.0);
    EXPECT_LE(cut.fill[c], 1.0);
    const double part = cut.fill[c] * volume(cut.vertices, cut.tets[c]);
    piece_volume[static_cast<std::size_t>(cut.piece[c])] += part;
    per_tet[static_cast<std::size_t>(cut.source_tet[c])] += cut.fill[c];
    for (const Index node : cut.tets[c])
      EXPECT_EQ(cut.vertices.col(node), v.col(cut.source_vertex[static_cast<std::size_t>(node)]));
  }
  for (const double f : per_tet) EXPECT_NEAR(f, 1.0, 1e-12);  // every tet's material, no more, no less
  double total = 0.0;
  for (Index p = 0; p < 4; ++p) {
    const std::uint32_t code = cut.cell[static_cast<std::size_t>(p)];
    const double wx = (code & 1u) ? 0.15 : 0.05, wz = (code & 2u) ? 0.07 : 0.13;
    EXPECT_NEAR(piece_volume[static_cast<std::size_t>(p)], wx * 0.2 * wz, 1e-12 * wx * 0.2 * wz) << "piece " << p;
    total += piece_volume[static_cast<std::size_t>(p)];
  }
  EXPECT_NEAR(total, 0.008, 1e-15 * 8);
  // A rest point is found in a copy of its own piece, at its own place.
  const Vec3 X(0.02, 0.11, 0.17);
  std::array<double, 4> w{};
  const Index p = cut.piece_of(X);
  const Index c = cut.locate(p, X, w);
  ASSERT_GE(c, 0);
  EXPECT_EQ(cut.piece[static_cast<std::size_t>(c)], p);
  Vec3 back = Vec3::Zero();
  for (int k = 0; k < 4; ++k)
    back += w[static_cast<std::size_t>(k)] *
            cut.vertices.col(cut.tets[static_cast<std::size_t>(c)][static_cast<std::size_t>(k)]);
  EXPECT_LT((back - X).norm(), 1e-15);
  EXPECT_GE(*std::min_element(w.begin(), w.end()), -1e-12);
  const CutPlane flat{Vec3::Zero(), Vec3::Zero()};
  EXPECT_THROW(cut_by_planes(v, tets, {}, std::span<const CutPlane>(&flat, 1)), Error);
}

// A block cut into two sticks, the one pinned by its top nodes: the other falls away as a free body
// does (its centre of mass 0.5 g t^2 down, whatever its elasticity does inside), the mass is the
// block's, and the pinned one stays.
TEST(Cutting, ACutPieceFallsAwayAsAFreeBody) {
  Vectors3 v;
  std::vector<std::array<Index, 4>> tets;
  kuhn_block(2, 1, 1, 0.1, v, tets);
  const CutPlane plane{Vec3(0.13, 0, 0), Vec3::UnitX()};
  const CutTets cut = cut_by_planes(v, tets, {}, std::span<const CutPlane>(&plane, 1));
  constexpr double density = 500.0;
  System s;
  std::vector<double> mass(static_cast<std::size_t>(cut.vertices.cols()), 0.0);
  for (std::size_t c = 0; c < cut.tets.size(); ++c)
    for (const Index node : cut.tets[c])
      mass[static_cast<std::size_t>(node)] += density * cut.fill[c] * volume(cut.vertices, cut.tets[c]) / 4.0;
  for (Index i = 0; i < cut.vertices.cols(); ++i) s.add_particle(cut.vertices.col(i), Vec3::Zero(), mass[i]);
  CorotatedTetsSettings settings{.young_modulus = 2e4, .poisson_ratio = 0.3, .beta = 0.0};  // explicit: no solve
  settings.volume_fraction = cut.fill;
  s.add_force(std::make_unique<CorotatedTets>(cut.tets, cut.vertices, settings));
  const Index left = cut.piece_of(Vec3(0.01, 0.05, 0.05));
  std::vector<Index> free_nodes;
  for (std::size_t c = 0; c < cut.tets.size(); ++c)
    for (const Index node : cut.tets[c]) {
      if (cut.piece[c] != left) {
        free_nodes.push_back(node);
        continue;
      }
      if (cut.vertices(2, node) > 0.1 - 1e-12 && s.hard_bindings().is_bound(node) == false) {
        const Index pin = s.add_kinematic_particle(cut.vertices.col(node));
        const std::array<Index, 1> parent{pin};
        const std::array<double, 1> one{1.0};
        s.bind_linear(node, parent, one);
        s.finalize();
      }
    }
  std::sort(free_nodes.begin(), free_nodes.end());
  free_nodes.erase(std::unique(free_nodes.begin(), free_nodes.end()), free_nodes.end());
  s.set_gravity(Vec3(0, 0, -9.81));
  s.finalize();
  double total = 0.0;
  for (const double m : mass) total += m;
  EXPECT_NEAR(total, density * 0.2 * 0.1 * 0.1, 1e-12);
  const auto centre = [&] {
    Vec3 c = Vec3::Zero();
    double m = 0.0;
    for (const Index i : free_nodes) {
      c += mass[static_cast<std::size_t>(i)] * s.particles().x.col(i);
      m += mass[static_cast<std::size_t>(i)];
    }
    return Vec3(c / m);
  };
  const Vec3 c0 = centre();
  const double t = 0.5;
  for (int frame = 0; frame < 30; ++frame) s.advance(1.0 / 60.0);
  EXPECT_NEAR(c0.z() - centre().z(), 0.5 * 9.81 * t * t, 1e-9);
  EXPECT_LT((centre() - c0).head<2>().norm(), 1e-12);
  EXPECT_LT(s.max_hard_binding_drift(), 1e-15);
}

}  // namespace
}  // namespace sinew
