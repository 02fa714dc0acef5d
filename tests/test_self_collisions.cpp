// Contact between deformable surfaces (SelfCollisions), judged by the independent FCL checker
// (intersections.hpp): a cloth dropped onto another lying on the ground stays on it, with no
// triangle pair intersecting at the end of any tick (and falls through without the source); two
// cloths flying into each other keep their total linear momentum to round-off; runs repeat bit for
// bit; bad settings are named.
#include "cloth.hpp"
#include "intersections.hpp"
#include "sinew/self_collisions.hpp"
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>

namespace sinew {
namespace {

constexpr double kThickness = 0.005;

// A ground plane y = 0 holding particles at kThickness above it, with no friction.
std::unique_ptr<CollisionSource> ground() {
  return make_collision_source("ground", [](CollisionContext& c) {
    for (Index i = 0; i < c.particles->size(); ++i) {
      if (!is_dynamic(c.particles->kind[i]) || (*c.x)(1, i) >= kThickness) continue;
      (*c.x)(1, i) = kThickness;
      (*c.v)(1, i) = std::max(0.0, (*c.v)(1, i));
      c.add_constraint(CollisionConstraint::point(i, Vec3::UnitY(), 0.0));
    }
  });
}

// Two 12 x 12 cloths of 0.5 m: `lower` lying at rest, `upper` above it, shifted by a third of a cell
// along x and z so that no node sits on a node, moving at `velocity`.
struct TwoCloths {
  System system;
  scenes::ClothGrid lower, upper;
  std::vector<std::array<Index, 3>> triangles;
  TwoCloths(double lower_y, double upper_y, const Vec3& velocity, bool gravity) {
    if (!gravity) system.set_gravity(Vec3::Zero());
    scenes::ClothGridSettings c;
    c.nx = c.ny = 12;
    c.width = c.height = 0.5;
    c.mass = 0.1;
    c.down = Vec3::UnitZ();
    c.origin = Vec3(-0.25, lower_y, -0.25);
    lower = scenes::add_cloth_grid(system, c);
    c.origin = Vec3(-0.25 + 0.5 / 33, upper_y, -0.25 + 0.5 / 33);
    upper = scenes::add_cloth_grid(system, c);
    for (const Index i : upper.nodes) system.particles().v.col(i) = velocity;
    triangles = lower.triangles;
    triangles.insert(triangles.end(), upper.triangles.begin(), upper.triangles.end());
  }
};

// The upper cloth falls 0.1 m onto the lower one lying on the ground: with the self-contact source
// it comes to rest on it, never crossing (no intersecting pair at any tick's end over half a second,
// every upper node over the lower cloth's middle above it); without it, it falls through.
TEST(SelfCollisions, AClothDroppedOnAnotherStaysOnIt) {
  for (const bool contact : {true, false}) {
    TwoCloths s(kThickness, 0.1, Vec3::Zero(), true);
    if (contact) {
      SelfCollisionSettings settings;
      settings.thickness = kThickness;
      s.system.add_collision_source(std::make_unique<SelfCollisions>(settings));
    }
    s.system.add_collision_source(ground());
    intersections::SurfaceIntersections checker(s.triangles, s.system.particles().x);
    std::size_t worst = 0;
    double lowest = kInfinity;
    for (int tick = 0; tick < 120; ++tick) {
      s.system.advance(1.0 / 240);
      worst = std::max(worst, checker.count(s.system.particles().x));
      // The upper nodes over the lower cloth (not those overhanging its edge, which drape down).
      for (const Index i : s.upper.nodes) {
        const Vec3 x = s.system.particles().x.col(i);
        if (std::max(std::abs(x.x()), std::abs(x.z())) < 0.2) lowest = std::min(lowest, x.y());
      }
    }
    if (contact) {
      EXPECT_EQ(worst, 0u) << "intersecting triangle pairs at a tick's end";
      // The lower cloth is held at the thickness above the ground; the upper stays above it (measured
      // nearest: 2.3 mm above, the ground pushing the lower cloth back up after the contact pass).
      EXPECT_GT(lowest, kThickness + 0.1 * kThickness) << "an upper node went down to the lower cloth";
    } else {
      EXPECT_GT(worst, 0u) << "without the source the cloths must cross: the test tests nothing";
    }
  }
}

// No gravity, no ground: the upper cloth flies at 2 m/s into the lower one, at rest. The impulses and
// the pushes apart act on both sides of each pair with weights summing to zero, so the total linear
// momentum is unchanged to round-off at every tick, and no pair intersects.
TEST(SelfCollisions, TwoClothsFlyingIntoEachOtherKeepTheirMomentum) {
  TwoCloths s(0.0, 0.02, Vec3(0, -2, 0), false);
  SelfCollisionSettings settings;
  settings.thickness = kThickness;
  auto source = std::make_unique<SelfCollisions>(settings);
  const SelfCollisions& contact = *source;
  s.system.add_collision_source(std::move(source));
  intersections::SurfaceIntersections checker(s.triangles, s.system.particles().x);
  s.system.finalize();
  const Vec3 p0 = s.system.linear_momentum();
  int touched = 0;
  for (int tick = 0; tick < 60; ++tick) {
    s.system.advance(1.0 / 240);
    touched += contact.contacts() > 0;
    EXPECT_LT((s.system.linear_momentum() - p0).norm(), 1e-12 * p0.norm()) << "tick " << tick;
    EXPECT_EQ(checker.count(s.system.particles().x), 0u) << "tick " << tick;
  }
  EXPECT_GT(touched, 0) << "the cloths never met";
}

// One cloth against itself: a 16 x 16 cloth of 0.5 m dropped edge first from 0.3 m, slightly tilted,
// collapses onto the ground and folds over itself. With the source no pair of its triangles (apart
// from neighbours) intersects at any tick's end; without it, the folds pass through each other.
TEST(SelfCollisions, AClothCollapsingOnTheGroundFoldsWithoutCrossingItself) {
  for (const bool contact : {true, false}) {
    System system;
    scenes::ClothGridSettings c;
    c.nx = c.ny = 16;
    c.width = c.height = 0.5;
    c.mass = 0.1;
    c.origin = Vec3(-0.25, 0.55, 0.0);
    c.down = Vec3(0.0, -1.0, 0.15).normalized();
    const scenes::ClothGrid cloth = scenes::add_cloth_grid(system, c);
    if (contact) {
      SelfCollisionSettings settings;
      settings.thickness = kThickness;
      system.add_collision_source(std::make_unique<SelfCollisions>(settings));
    }
    system.add_collision_source(ground());
    intersections::SurfaceIntersections checker(cloth.triangles, system.particles().x);
    std::size_t worst = 0;
    for (int tick = 0; tick < 240; ++tick) {
      system.advance(1.0 / 240);
      worst = std::max(worst, checker.count(system.particles().x));
    }
    if (contact) {
      EXPECT_EQ(worst, 0u) << "the cloth crossed itself";
    } else {
      EXPECT_GT(worst, 0u) << "without the source the folds must cross: the test tests nothing";
    }
  }
}

TEST(SelfCollisions, RunsRepeatBitForBit) {
  std::uint64_t hashes[2];
  for (auto& hash : hashes) {
    TwoCloths s(kThickness, 0.1, Vec3::Zero(), true);
    s.system.add_collision_source(std::make_unique<SelfCollisions>());
    s.system.add_collision_source(ground());
    for (int tick = 0; tick < 60; ++tick) s.system.advance(1.0 / 240);
    hash = s.system.state_hash();
  }
  EXPECT_EQ(hashes[0], hashes[1]);
}

TEST(SelfCollisions, BadSettingsAreNamed) {
  const auto error = [](const SelfCollisionSettings& s) {
    try {
      SelfCollisions source(s);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  SelfCollisionSettings s;
  s.thickness = -1.0;
  EXPECT_NE(error(s).find("thickness"), std::string::npos);
  s = {};
  s.friction = std::nan("");
  EXPECT_NE(error(s).find("friction"), std::string::npos);
  s = {};
  s.passes = 0;
  EXPECT_NE(error(s).find("passes"), std::string::npos);
}

}  // namespace
}  // namespace sinew
