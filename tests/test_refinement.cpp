// Red refinement with T-junctions (Sifakis et al. 2007, section 2.1, figures 4 and 5): which
// midpoints are T-junctions, their flattened bindings, and the gap a quasistatically stretched sheet
// opens at them without the bindings.
#include "sinew/builders.hpp"
#include "sinew/refinement.hpp"
#include "sinew/system.hpp"

#include "cloth.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace sinew {
namespace {

// The unit square in the z = 0 plane, two triangles sharing the diagonal (0, 2).
RefinedTriangles unit_square() {
  Vectors3 v(3, 4);
  v << 0, 1, 1, 0,  //
      0, 0, 1, 1,   //
      0, 0, 0, 0;
  return unrefined(v, {{0, 1, 2}, {0, 2, 3}});
}

double signed_area(const RefinedTriangles& m, const std::array<Index, 3>& t) {
  const Vec3 a = m.vertices.col(t[0]), b = m.vertices.col(t[1]), c = m.vertices.col(t[2]);
  return 0.5 * (b - a).cross(c - a).z();
}

TEST(RedRefinement, ASplitTriangleLeavesATJunctionOnTheEdgeItsNeighbourHasWhole) {
  const RefinedTriangles once = red_refine(unit_square(), std::vector<Index>{0});
  ASSERT_EQ(once.triangles.size(), 5u);
  ASSERT_EQ(once.vertices.cols(), 7);
  double area = 0.0;
  for (std::size_t t = 0; t < once.triangles.size(); ++t) {
    const double a = signed_area(once, once.triangles[t]);
    EXPECT_GT(a, 0.0);  // orientation kept
    EXPECT_NEAR(a, once.level[t] == 1 ? 0.125 : 0.5, 1e-15);
    area += a;
  }
  EXPECT_NEAR(area, 1.0, 1e-15);
  // The diagonal's midpoint is one; the two boundary edges' midpoints are ordinary nodes.
  ASSERT_EQ(once.t_junctions.size(), 1u);
  const auto& t = once.t_junctions[0];
  EXPECT_TRUE((once.vertices.col(t.vertex) - Vec3(0.5, 0.5, 0)).isZero(1e-15));
  EXPECT_EQ(std::min(t.segment[0], t.segment[1]), 0);
  EXPECT_EQ(std::max(t.segment[0], t.segment[1]), 2);
  // Split on both sides, the diagonal has none.
  std::vector<Index> whole;
  for (std::size_t k = 0; k < once.triangles.size(); ++k)
    if (once.level[k] == 0) whole.push_back(static_cast<Index>(k));
  EXPECT_TRUE(red_refine(once, whole).t_junctions.empty());
  try {
    red_refine(once, std::vector<Index>{5});
    ADD_FAILURE() << "refined a triangle that does not exist";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("triangle 5 does not exist"), std::string::npos) << e.what();
  }
}

// Figure 4's recursion: a second split next to the diagonal puts a T-junction on a half of it, bound
// to the half's ends; flattened, it sits at 3/4 x_0 + 1/4 x_2 on the coarse edge, wherever the
// corners go.
TEST(RedRefinement, TJunctionsOnHalvesAreFlattenedToTheCoarseEdge) {
  const RefinedTriangles once = red_refine(unit_square(), std::vector<Index>{0});
  // The corner child at vertex 0, (0, m01, m20), touches half (0, m20) of the diagonal.
  const RefinedTriangles twice = red_refine(once, std::vector<Index>{0});
  ASSERT_EQ(twice.t_junctions.size(), 3u);  // (0.5, 0.5), (0.25, 0.25), and (0.5, 0.25) on the middle child's edge
  System s;
  std::vector<Index> particles;
  for (Index v = 0; v < twice.vertices.cols(); ++v)
    particles.push_back(s.add_particle(twice.vertices.col(v), Vec3::Zero(), 0.1));
  EXPECT_EQ(bind_t_junctions(s, twice, particles), 3);
  s.finalize();
  s.particles().x.col(0) = Vec3(-0.3, 0.2, 0.7);
  s.particles().x.col(2) = Vec3(1.4, 0.9, -0.5);
  s.clamp_bound_rows();
  const Vec3 x0 = s.particles().x.col(0), x2 = s.particles().x.col(2);
  bool quarter = false;
  for (const auto& t : twice.t_junctions)
    if ((twice.vertices.col(t.vertex) - Vec3(0.25, 0.25, 0)).isZero(1e-15)) {
      quarter = true;
      EXPECT_TRUE((s.particles().x.col(t.vertex) - (0.75 * x0 + 0.25 * x2)).isZero(1e-15));
    }
  EXPECT_TRUE(quarter);
  EXPECT_LT(largest_t_junction_gap(twice, s.particles().x), 1e-15);
}

// Clamps: each node at x = 0 or x = length bound to a kinematic particle of its own, those at the
// right end moving along +x at `speed`. Returns the right ones (to stop them).
std::vector<Index> clamp_ends(System& s, const Vectors3& vertices, const std::vector<Index>& particles, double length,
                              double speed) {
  std::vector<Index> right;
  for (Index k = 0; k < vertices.cols(); ++k) {
    const double x = vertices(0, k);
    if (x > 1e-12 && x < length - 1e-12) continue;
    const Index clamp = s.add_kinematic_particle(vertices.col(k), Vec3(x > 0.5 * length ? speed : 0.0, 0, 0));
    const std::array<Index, 1> parent{clamp};
    const std::array<double, 1> one{1.0};
    s.bind_linear(particles[static_cast<std::size_t>(k)], parent, one);
    if (x > 0.5 * length) right.push_back(clamp);
  }
  return right;
}

// Figure 5: a sheet refined twice in its middle, clamped at both ends and stretched quasistatically
// by a third of its length (the clamps keep its ends from narrowing: the strain is not uniform, so a
// straight coarse edge does not stay straight on the fine side). With the T-junctions hard-bound the
// mesh has no gap (round-off); simulated as free nodes they open one of millimetres.
double stretched_gap(bool bind) {
  constexpr double width = 1.0;
  const RefinedTriangles mesh = scenes::refined_strip(9, 5, width, 0.5);
  EXPECT_GT(mesh.t_junctions.size(), 8u);
  SystemSettings settings;
  settings.gravity = Vec3::Zero();
  System s(settings);
  ClothMaterial material;
  material.mass = 0.2;
  material.stretch_stiffness = 0.0;
  material.bending_stiffness = 0.0;
  material.membrane_mu = 200.0;
  material.membrane_lambda = 300.0;
  material.membrane_damping = 0.02;
  const std::vector<Index> particles = add_cloth_mesh(s, mesh.vertices, mesh.triangles, material);
  if (bind) bind_t_junctions(s, mesh, particles);
  // The right ends move out by a third of the width over 2 s, then hold for 1 s.
  const std::vector<Index> right = clamp_ends(s, mesh.vertices, particles, width, width / 3.0 / 2.0);
  for (int frame = 0; frame < 180; ++frame) {
    if (frame == 120)
      for (const Index c : right) s.particles().v.col(c).setZero();
    s.advance(1.0 / 60.0);
  }
  Vectors3 x(3, mesh.vertices.cols());
  for (Index k = 0; k < mesh.vertices.cols(); ++k)
    x.col(k) = s.particles().x.col(particles[static_cast<std::size_t>(k)]);
  EXPECT_NEAR(x.row(0).maxCoeff(), width * 4.0 / 3.0, 1e-9);  // stretched by a third
  EXPECT_TRUE(x.allFinite());
  return largest_t_junction_gap(mesh, x);
}

TEST(RedRefinement, AStretchedSheetHasNoGapWithItsTJunctionsBoundAndOneWithout) {
  const double bound = stretched_gap(true), free = stretched_gap(false);
  RecordProperty("gap_bound", std::to_string(bound));
  RecordProperty("gap_free", std::to_string(free));
  std::printf("largest T-junction gap: %.3g m bound, %.3g m free\n", bound, free);
  EXPECT_LT(bound, 1e-12);
  EXPECT_GT(free, 1e-4);
}

// ---- tets ---------------------------------------------------------------------------------------

double volume_of(const Vectors3& x, const std::array<Index, 4>& t) {
  Mat3 e;
  e << x.col(t[1]) - x.col(t[0]), x.col(t[2]) - x.col(t[0]), x.col(t[3]) - x.col(t[0]);
  return e.determinant() / 6.0;
}

// Two tets sharing the face (1, 2, 3).
RefinedTets two_tets() {
  Vectors3 v(3, 5);
  v << 0, 1, 0, 0, 1,  //
      0, 0, 1, 0, 1,   //
      0, 0, 0, 1, 1;
  return unrefined_tets(v, {{0, 1, 2, 3}, {1, 2, 3, 4}});
}

// A box of nx x ny x nz cubes of edge h (Kuhn tets), unrefined.
RefinedTets cube_block(int nx, int ny, int nz, double h) {
  Vectors3 v;
  std::vector<std::array<Index, 4>> tets;
  scenes::kuhn_block(Vec3::Zero(), nx, ny, nz, h, v, tets);
  return unrefined_tets(v, tets);
}

TEST(RedRefinementOfTets, ASplitTetHasEightChildrenOfAnEighthAndHangingNodesOnItsNeighboursEdges) {
  const RefinedTets mesh = two_tets();
  const RefinedTets once = red_refine(mesh, std::vector<Index>{0});
  ASSERT_EQ(once.tets.size(), 9u);
  ASSERT_EQ(once.vertices.cols(), 11);
  const double parent = volume_of(mesh.vertices, mesh.tets[0]);
  double sum = 0.0;
  for (std::size_t t = 0; t < once.tets.size(); ++t) {
    const double v = volume_of(once.vertices, once.tets[t]);
    EXPECT_GT(v, 0.0);
    if (once.level[t] == 1) {
      EXPECT_NEAR(v, parent / 8.0, 1e-15);
    }
    sum += v;
  }
  EXPECT_NEAR(sum, parent + volume_of(mesh.vertices, mesh.tets[1]), 1e-15);
  // Hanging: the midpoints of the shared face's three edges, each on the whole tet (the last one).
  ASSERT_EQ(once.hanging.size(), 3u);
  for (const auto& node : once.hanging) {
    EXPECT_EQ(node.host, 8);
    for (const Index end : node.segment) EXPECT_TRUE(end >= 1 && end <= 3) << end;
    double zeros = 0.0, halves = 0.0;
    for (const double w : node.weights) {
      zeros += std::abs(w) < 1e-15;
      halves += std::abs(w - 0.5) < 1e-15;
    }
    EXPECT_EQ(zeros, 2.0);
    EXPECT_EQ(halves, 2.0);
  }
  // Refining the neighbour too leaves nothing hanging.
  EXPECT_TRUE(red_refine(once, std::vector<Index>{8}).hanging.empty());
  EXPECT_THROW(red_refine(once, std::vector<Index>{9}), Error);
  EXPECT_THROW(unrefined_tets(mesh.vertices, {{0, 2, 1, 3}}), Error);  // inverted
}

TEST(RedRefinementOfTets, NodesInsideANeighboursFaceAreFlattenedToItsLinearField) {
  // Twice on the first tet's side of the shared face: nodes inside the face (midpoints of segments
  // between its edges' midpoints) hang too, bound through chains to the face's three corners.
  const RefinedTets once = red_refine(two_tets(), std::vector<Index>{0});
  std::vector<Index> at_face;
  for (std::size_t t = 0; t < once.tets.size(); ++t)
    if (once.level[t] == 1) at_face.push_back(static_cast<Index>(t));
  const RefinedTets twice = red_refine(once, at_face);
  std::size_t inside_face = 0;
  for (const auto& node : twice.hanging) {
    int zeros = 0;
    for (const double w : node.weights) zeros += std::abs(w) < 1e-15;
    inside_face += zeros == 1;
  }
  EXPECT_GT(inside_face, 0u);
  System s;
  std::vector<Index> particles;
  for (Index v = 0; v < twice.vertices.cols(); ++v)
    particles.push_back(s.add_particle(twice.vertices.col(v), Vec3::Zero(), 0.1));
  EXPECT_EQ(bind_hanging_nodes(s, twice, particles), static_cast<Index>(twice.hanging.size()));
  s.finalize();
  // The hanging nodes' mass went to their segments' ends (w m_bar): none lost.
  EXPECT_NEAR(s.particles().mass.sum(), 0.1 * double(particles.size()), 1e-14);
  // The whole tet's corners anywhere: every hanging node follows their linear field.
  s.particles().x.col(1) = Vec3(1.3, -0.2, 0.4);
  s.particles().x.col(2) = Vec3(-0.1, 0.8, 0.3);
  s.particles().x.col(3) = Vec3(0.2, 0.1, 1.6);
  s.particles().x.col(4) = Vec3(1.1, 1.2, 0.9);
  s.clamp_bound_rows();
  EXPECT_LT(largest_hanging_gap(twice, s.particles().x), 1e-15);
}

// A block of 4 x 1 x 1 cubes (Kuhn tets), its tets with a centre in the left half refined twice (the
// second time those at the block's middle), clamped at both ends and stretched quasistatically by a
// fifth of its length in zero gravity: with its hanging nodes bound, none leaves the coarse tet it
// lies on (round-off); free, they open a gap.
double stretched_block_gap(bool bind) {
  constexpr double h = 0.1, length = 0.4;
  RefinedTets mesh = cube_block(4, 1, 1, h);
  for (int round = 0; round < 2; ++round) {
    std::vector<Index> chosen;
    for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
      Vec3 c = Vec3::Zero();
      for (const Index v : mesh.tets[t]) c += mesh.vertices.col(v) / 4.0;
      if (c.x() < (round == 0 ? 0.5 : 0.3) * length && c.x() > (round == 0 ? 0.0 : 0.1) * length)
        chosen.push_back(static_cast<Index>(t));
    }
    mesh = red_refine(mesh, chosen);
  }
  EXPECT_GT(mesh.hanging.size(), 20u);
  SystemSettings settings;
  settings.gravity = Vec3::Zero();
  System s(settings);
  VolumeMaterial material;
  material.density = 500.0;
  material.young_modulus = 2e4;
  material.damping = 0.02;
  const std::vector<Index> particles = add_volume(s, mesh.vertices, mesh.tets, material);
  double mass = 0.0;
  for (const Index i : particles) mass += s.input_mass()[i];
  EXPECT_NEAR(mass, material.density * length * h * h, 1e-12);
  if (bind) bind_hanging_nodes(s, mesh, particles);
  const std::vector<Index> right = clamp_ends(s, mesh.vertices, particles, length, length / 5.0 / 2.0);
  double worst = 0.0;
  Vectors3 x(3, mesh.vertices.cols());
  for (int frame = 0; frame < 180; ++frame) {
    if (frame == 120)
      for (const Index c : right) s.particles().v.col(c).setZero();
    s.advance(1.0 / 60.0);
    for (Index k = 0; k < mesh.vertices.cols(); ++k)
      x.col(k) = s.particles().x.col(particles[static_cast<std::size_t>(k)]);
    worst = std::max(worst, largest_hanging_gap(mesh, x));
  }
  EXPECT_NEAR(x.row(0).maxCoeff(), length * 1.2, 1e-9);
  EXPECT_TRUE(x.allFinite());
  return worst;
}

TEST(RedRefinementOfTets, AStretchedBlockHasNoGapWithItsHangingNodesBoundAndOneWithout) {
  const double bound = stretched_block_gap(true), free = stretched_block_gap(false);
  RecordProperty("gap_bound", std::to_string(bound));
  RecordProperty("gap_free", std::to_string(free));
  std::printf("largest hanging-node gap over the stretch: %.3g m bound, %.3g m free\n", bound, free);
  EXPECT_LT(bound, 1e-12);
  EXPECT_GT(free, 1e-5);
}

}  // namespace
}  // namespace sinew
