// Contact between deformable surfaces (SelfCollisions), judged by the independent FCL checker
// (intersections.hpp): a cloth dropped onto another lying on the ground stays on it, with no
// triangle pair intersecting at the end of any tick (and falls through without the source); two
// cloths flying into each other keep their total linear momentum to round-off; runs repeat bit for
// bit; bad settings are named.
#include "cloth.hpp"
#include "intersections.hpp"
#include "sinew/ccd.hpp"
#include "sinew/self_collisions.hpp"
#include "sinew/system.hpp"

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <random>
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

// Too fast for proximity: the upper cloth flies at 20 m/s into the lower one, 8.3 cm a tick against
// a 2 cm gap and a 5 mm thickness, so it is past the lower cloth before any pair is ever closer than
// the thickness. The continuous test catches the pairs on their paths and the impact zones keep the
// upper cloth on its side of the lower one (its centre above the lower cloth's plane at every tick's
// end; the pair turns as one, the impact being off-centre), with no pair
// intersecting and linear momentum kept to round-off; without it, the cloth passes through.
TEST(SelfCollisions, AClothTooFastForTheThicknessDoesNotPassThroughAnother) {
  for (const bool continuous : {true, false}) {
    TwoCloths s(0.0, 0.02, Vec3(0, -20, 0), false);
    SelfCollisionSettings settings;
    settings.thickness = kThickness;
    settings.continuous = continuous;
    auto source = std::make_unique<SelfCollisions>(settings);
    const SelfCollisions& contact = *source;
    s.system.add_collision_source(std::move(source));
    intersections::SurfaceIntersections checker(s.triangles, s.system.particles().x);
    s.system.finalize();
    const Vec3 p0 = s.system.linear_momentum();
    const auto centre = [&](const scenes::ClothGrid& cloth) {
      Vec3 sum = Vec3::Zero();
      for (const Index i : cloth.nodes) sum += s.system.particles().x.col(i);
      return Vec3(sum / double(cloth.nodes.size()));
    };
    // The lower cloth's plane normal (the least direction of its nodes' spread), kept on the side of
    // the last tick's (the pair turns: the impact was off-centre).
    Vec3 normal = Vec3::UnitY();
    const auto lower_normal = [&] {
      const Vec3 c = centre(s.lower);
      Mat3 spread = Mat3::Zero();
      for (const Index i : s.lower.nodes) {
        const Vec3 r = s.system.particles().x.col(i) - c;
        spread += r * r.transpose();
      }
      Vec3 n = Eigen::SelfAdjointEigenSolver<Mat3>(spread).eigenvectors().col(0);
      return n.dot(normal) < 0.0 ? Vec3(-n) : n;
    };
    bool crossed = false;
    for (int tick = 0; tick < 30; ++tick) {
      s.system.advance(1.0 / 240);
      normal = lower_normal();
      crossed = crossed || (centre(s.upper) - centre(s.lower)).dot(normal) < 0.0;
      if (!continuous) continue;
      EXPECT_EQ(checker.count(s.system.particles().x), 0u) << "tick " << tick;
      EXPECT_LT((s.system.linear_momentum() - p0).norm(), 1e-12 * p0.norm()) << "tick " << tick;
    }
    if (continuous) {
      EXPECT_FALSE(crossed) << "the upper cloth passed the lower one";
      EXPECT_GT(contact.totals().zone_points, 0) << "no impact zone: the test does not reach the continuous test";
      EXPECT_EQ(contact.totals().unresolved, 0);
      std::printf("crossings %lld, points in zones %lld, contacts %lld over %lld steps\n", contact.totals().crossings,
                  contact.totals().zone_points, contact.totals().contacts, contact.totals().steps);
    } else {
      EXPECT_TRUE(crossed) << "without the continuous test the cloth must pass: the test tests nothing";
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

// The continuous tests against brute force: 4000 random moving vertex-triangle and edge-edge pairs,
// their paths sampled at 20000 times. Where the sampled coplanarity function changes sign with the
// crossing point well inside both elements (a certain crossing), the test must find it; where the
// test reports a touch, the sampled distance must come within a small margin of zero somewhere.
TEST(ContinuousTests, FindEveryCrossingABruteForceSamplingFindsAndNoFarMiss) {
  std::mt19937 random(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const auto point = [&] { return Vec3(unit(random), unit(random), unit(random)); };
  constexpr int kSamples = 20000;
  constexpr double kEta = 1e-6;
  int certain = 0, reported = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const bool edges = trial % 2 == 1;
    std::array<Vec3, 4> x0, x1;
    for (std::size_t k = 0; k < 4; ++k) {
      x0[k] = point();
      x1[k] = x0[k] + point();
    }
    const auto at = [&](double t) {
      std::array<Vec3, 4> x;
      for (std::size_t k = 0; k < 4; ++k) x[k] = (1.0 - t) * x0[k] + t * x1[k];
      return x;
    };
    // Coplanarity (the triple product) and the distance at a time.
    const auto f = [&](const std::array<Vec3, 4>& x) { return (x[1] - x[0]).cross(x[2] - x[0]).dot(x[3] - x[0]); };
    const auto distance = [&](const std::array<Vec3, 4>& x) {
      if (edges) {
        double a, b;
        ccd::closest_on_segments(x[0], x[1], x[2], x[3], a, b);
        return ((1.0 - a) * x[0] + a * x[1] - ((1.0 - b) * x[2] + b * x[3])).norm();
      }
      const auto w = ccd::closest_on_triangle(x[3], x[0], x[1], x[2]);
      return (x[3] - (w[0] * x[0] + w[1] * x[1] + w[2] * x[2])).norm();
    };
    // Well inside: the closest points at least 1e-3 from every element's boundary (parameters).
    const auto well_inside = [&](const std::array<Vec3, 4>& x) {
      if (edges) {
        double a, b;
        ccd::closest_on_segments(x[0], x[1], x[2], x[3], a, b);
        return std::min({a, 1.0 - a, b, 1.0 - b}) > 1e-3;
      }
      const auto w = ccd::closest_on_triangle(x[3], x[0], x[1], x[2]);
      return std::min({w[0], w[1], w[2]}) > 1e-3;
    };
    bool crossing = false;
    double nearest = kInfinity;
    double f_prev = f(at(0.0));
    for (int k = 1; k <= kSamples; ++k) {
      const double t = double(k) / kSamples;
      const auto x = at(t);
      const double f_now = f(x);
      nearest = std::min(nearest, distance(x));
      if ((f_prev < 0.0) != (f_now < 0.0)) {
        // Linear interpolation of the sign change, judged there.
        const double tc = t - (1.0 / kSamples) * f_now / (f_now - f_prev);
        const auto xc = at(tc);
        if (distance(xc) < 1e-4 && well_inside(xc)) crossing = true;
      }
      f_prev = f_now;
    }
    const std::optional<double> hit =
        edges ? ccd::edge_edge(x0[0], x0[1], x0[2], x0[3], x1[0], x1[1], x1[2], x1[3], kEta)
              : ccd::vertex_triangle(x0[3], x0[0], x0[1], x0[2], x1[3], x1[0], x1[1], x1[2], kEta);
    certain += crossing;
    reported += hit.has_value();
    if (crossing) {
      EXPECT_TRUE(hit.has_value()) << (edges ? "edges" : "vertex-triangle") << ", trial " << trial;
    }
    // A reported touch: the sampled path comes within the sampling's reach of contact.
    if (hit) {
      EXPECT_LT(nearest, 2e-3) << (edges ? "edges" : "vertex-triangle") << ", trial " << trial;
    }
  }
  EXPECT_GT(certain, 200) << "too few crossings among the random pairs to judge the tests";
  std::printf("%d certain crossings, %d reported\n", certain, reported);
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
