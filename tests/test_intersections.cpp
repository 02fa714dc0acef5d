// The FCL intersection checker (intersections.hpp) the contact tests judge surfaces by: checked on
// cases whose answer is known by construction, its tree against FCL's triangle test on every pair,
// and its refit against a checker built afresh.
#include "intersections.hpp"

#include "cloth.hpp"
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace sinew {
namespace {

using intersections::intersecting_pairs_brute_force;
using intersections::SurfaceIntersections;

// Two squares of two triangles each: A in the plane z = 0 over [-1, 1]^2, split along y = x
// (triangle 0 below it, 1 above); B in the plane x = 0 over y in [-0.5, 0.7], z in [-1, 1], split
// along its diagonal, which meets z = 0 at y = 0.1 (triangle 2 on the side of larger y there, 3 on
// the other). They cross along x = z = 0, y in [-0.5, 0.7]: triangle 0 (y < 0 on that line) meets 3;
// triangle 1 meets 3 for 0 < y < 0.1 and 2 beyond. Three pairs; 0 and 2 never meet.
struct CrossedSquares {
  Vectors3 x{3, 8};
  std::vector<std::array<Index, 3>> triangles{{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {4, 6, 7}};
  CrossedSquares() {
    x.col(0) = Vec3(-1, -1, 0);
    x.col(1) = Vec3(1, -1, 0);
    x.col(2) = Vec3(1, 1, 0);
    x.col(3) = Vec3(-1, 1, 0);
    x.col(4) = Vec3(0, -0.5, -1);
    x.col(5) = Vec3(0, 0.7, -1);
    x.col(6) = Vec3(0, 0.7, 1);
    x.col(7) = Vec3(0, -0.5, 1);
  }
};

TEST(Intersections, TwoCrossedSquaresGiveTheThreePairsThatMeet) {
  CrossedSquares s;
  SurfaceIntersections checker(s.triangles, s.x);
  const std::vector<std::pair<Index, Index>> expected{{0, 3}, {1, 2}, {1, 3}};
  EXPECT_EQ(checker.pairs(s.x), expected);
  EXPECT_EQ(intersecting_pairs_brute_force(s.triangles, s.x), expected);
  // B moved 1 cm past A's edge: nothing meets (the refit follows the positions).
  for (Index i = 4; i < 8; ++i) s.x(0, i) = 1.01;
  EXPECT_EQ(checker.count(s.x), 0u);
  EXPECT_TRUE(intersecting_pairs_brute_force(s.triangles, s.x).empty());
}

// Neighbours share an edge or a corner by construction: a flat cloth, and one crumpled smoothly (no
// fold through itself), have no intersecting pair.
TEST(Intersections, AFlatOrGentlyWavedClothHasNone) {
  System system;
  scenes::ClothGridSettings c;
  c.nx = c.ny = 16;
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(system, c);
  Vectors3 x = system.particles().x;
  SurfaceIntersections checker(cloth.triangles, x);
  EXPECT_EQ(checker.count(x), 0u);
  for (Index i = 0; i < x.cols(); ++i) x(2, i) = 0.1 * std::sin(3.0 * x(0, i)) * std::cos(2.0 * x(1, i));
  EXPECT_EQ(checker.count(x), 0u);
  EXPECT_TRUE(intersecting_pairs_brute_force(cloth.triangles, x).empty());
}

// A cloth folded through itself: its lower half turned by 150 degrees about a line along x at y = -0.05
// and lifted 0.1 m, so that it comes back over the upper half and passes down through it (crossing
// z = 0 0.2 m from the fold). The tree finds exactly the pairs FCL's test finds on every pair, a
// checker refitted to the fold agrees with one built on it, and unfolding clears them.
TEST(Intersections, AClothFoldedThroughItselfMatchesTheBruteForceCount) {
  System system;
  scenes::ClothGridSettings c;
  c.nx = c.ny = 12;
  c.width = c.height = 1.0;
  c.origin = Vec3(-0.5, 0.5, 0.0);
  const scenes::ClothGrid cloth = scenes::add_cloth_grid(system, c);
  const Vectors3 flat = system.particles().x;
  SurfaceIntersections refitted(cloth.triangles, flat);
  Vectors3 folded = flat;
  const double a = 150.0 * 3.14159265358979323846 / 180.0, y0 = -0.05;
  for (Index i = 0; i < folded.cols(); ++i) {
    const double y = flat(1, i) - y0;
    if (y >= 0.0) continue;
    folded(1, i) = y0 + std::cos(a) * y;
    folded(2, i) = std::sin(a) * y + 0.1;
  }
  const auto brute = intersecting_pairs_brute_force(cloth.triangles, folded);
  EXPECT_GT(brute.size(), 10u) << "the fold must pass through the cloth";
  EXPECT_EQ(refitted.pairs(folded), brute);
  SurfaceIntersections fresh(cloth.triangles, folded);
  EXPECT_EQ(fresh.pairs(folded), brute);
  EXPECT_EQ(refitted.count(flat), 0u);
}

TEST(Intersections, ATriangleNamingAMissingPointIsRefused) {
  CrossedSquares s;
  s.triangles.push_back({0, 1, 8});
  try {
    SurfaceIntersections checker(s.triangles, s.x);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 8"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace sinew
