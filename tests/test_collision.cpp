// Collision sources (step 3) and their weighted-stencil constraints in step 4.
#include "sinew/builders.hpp"
#include "sinew/system.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <set>

namespace sinew {
namespace {

// A toy collision source, written the way coupling/README.md's recipe says (one class, one
// add_collision_source call): a floor at y = 0 that holds the centroid of every registered surface
// triangle above it. A triangle whose centroid went below is lifted as a whole, its centroid's
// approaching velocity removed, and step 4 receives the three-particle stencil (1/3, 1/3, 1/3) with
// normal +y: the centroid's normal velocity, not each node's, is held at zero.
class CentroidFloor final : public CollisionSource {
 public:
  std::string_view name() const override { return "centroid floor"; }
  void process(CollisionContext& c) override {
    active.clear();
    Vectors3& x = *c.x;
    Vectors3& v = *c.v;
    for (std::size_t t = 0; t < c.geometry->triangles.size(); ++t) {
      const auto& tri = c.geometry->triangles[t];
      const double y = (x(1, tri[0]) + x(1, tri[1]) + x(1, tri[2])) / 3.0;
      if (y >= 0.0) continue;
      const double vy = (v(1, tri[0]) + v(1, tri[1]) + v(1, tri[2])) / 3.0;
      CollisionConstraint constraint;
      constraint.size = 3;
      for (int a = 0; a < 3; ++a) {
        x(1, tri[static_cast<std::size_t>(a)]) -= y;
        if (vy < 0.0) v(1, tri[static_cast<std::size_t>(a)]) -= vy;
        constraint.particles[static_cast<std::size_t>(a)] = tri[static_cast<std::size_t>(a)];
        constraint.weights[static_cast<std::size_t>(a)] = 1.0 / 3.0;
      }
      constraint.normal = Vec3::UnitY();
      c.add_constraint(constraint);
      active.push_back(t);
    }
  }
  std::vector<std::size_t> active;
};

ClothGridSettings flat_cloth() {
  ClothGridSettings c = test::square_cloth(5, 0.4, Vec3(-0.2, 0.01, -0.2));
  c.down = Vec3::UnitZ();
  c.mass = 0.1;
  return c;
}

TEST(CollisionSource, BuildersRegisterTheirSurfacesAndEdges) {
  System s;
  const ClothGrid cloth = add_cloth_grid(s, flat_cloth());
  const CollisionGeometry& g = s.collision_geometry();
  EXPECT_EQ(g.triangles.size(), cloth.triangles.size());
  // A 5 x 5 grid: 4 * 5 edges each way and one diagonal per quad.
  EXPECT_EQ(g.segments.size(), 2u * 4u * 5u + 16u);
  for (const auto& e : g.segments) EXPECT_LT(e[0], e[1]);
  // A volume registers its boundary only: a cube of 5 tets has 12 boundary triangles (2 per face);
  // the central tet's four faces are interior and dropped.
  System v;
  Vectors3 cube(3, 8);
  for (int i = 0; i < 8; ++i) cube.col(i) = Vec3(i & 1, (i >> 1) & 1, (i >> 2) & 1);
  // Corners i = x + 2y + 4z; four corner tets and the central one, each oriented to positive volume.
  std::vector<std::array<Index, 4>> tets{{0, 1, 2, 4}, {1, 2, 3, 7}, {1, 4, 5, 7}, {2, 4, 6, 7}, {1, 2, 4, 7}};
  for (auto& t : tets) {
    Mat3 e;
    e << cube.col(t[1]) - cube.col(t[0]), cube.col(t[2]) - cube.col(t[0]), cube.col(t[3]) - cube.col(t[0]);
    if (e.determinant() < 0) std::swap(t[2], t[3]);
  }
  add_volume(v, cube, tets, VolumeMaterial{});
  EXPECT_EQ(v.collision_geometry().triangles.size(), 12u);
  // Outward: each boundary triangle's normal points away from the cube's centre.
  for (const auto& t : v.collision_geometry().triangles) {
    const Vec3 a = cube.col(t[0]), b = cube.col(t[1]), c = cube.col(t[2]);
    EXPECT_GT((b - a).cross(c - a).dot((a + b + c) / 3.0 - Vec3(0.5, 0.5, 0.5)), 0.0);
  }
}

// The stencil constraints hold in step 4: each held triangle's centroid has zero normal velocity at
// v^{n+1/2} = (v~^n + v^{n+1}) / 2 (to the CG tolerance) while its nodes' own velocities differ, even
// where neighbouring triangles' stencils share nodes (they are projected together, as one group).
// A second source, run after the floor, records v~^n. Nothing acts along the floor: the momentum along
// x and z is kept.
TEST(CollisionSource, WeightedStencilsHoldTheCentroidsNotTheNodes) {
  System s;
  const ClothGrid cloth = add_cloth_grid(s, flat_cloth());
  auto& floor = static_cast<CentroidFloor&>(s.add_collision_source(std::make_unique<CentroidFloor>()));
  Vectors3 v_tilde;
  s.add_collision_source(make_collision_source("record", [&](CollisionContext& c) { v_tilde = *c.v; }));
  for (Index node : cloth.nodes) s.particles().v.col(node) = Vec3(0.3, -1.0, -0.2);
  // A tilt, so nodes within a triangle arrive at different speeds.
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j) s.particles().v(1, cloth.node(i, j)) -= 0.1 * i;
  s.step_settings().cg_tolerance = 1e-12;
  s.finalize();
  const Vec3 p0 = s.linear_momentum();
  std::size_t held = 0, shared = 0;
  for (int k = 0; k < 20; ++k) {
    s.step(1.0 / 240);
    const Vectors3 v_half = 0.5 * (v_tilde + s.particles().v);
    std::set<Index> seen;
    for (std::size_t t : floor.active) {
      const auto& tri = s.collision_geometry().triangles[t];
      EXPECT_NEAR((v_half(1, tri[0]) + v_half(1, tri[1]) + v_half(1, tri[2])) / 3.0, 0.0, 1e-10)
          << "step " << k << ", triangle " << t;
      for (Index i : tri) shared += seen.insert(i).second ? 0 : 1;
      ++held;
    }
  }
  EXPECT_GT(held, 20u);
  EXPECT_GT(shared, 0u) << "no two held triangles shared a node: the groups went untested";
  const Vec3 p = s.linear_momentum();
  EXPECT_NEAR(p.x(), p0.x(), 1e-12);
  EXPECT_NEAR(p.z(), p0.z(), 1e-12);
}

TEST(CollisionSource, SourcesRunInOrderAndBadConstraintsNameTheirSource) {
  System s;
  const Index a = s.add_particle(Vec3::Zero(), Vec3::Zero(), 1.0);
  const Index k = s.add_kinematic_particle(Vec3::UnitX());
  std::vector<std::string> order;
  s.add_collision_source(make_collision_source("first", [&](CollisionContext&) { order.push_back("first"); }));
  s.add_collision_source(make_collision_source("second", [&](CollisionContext&) { order.push_back("second"); }));
  s.step(0.01);
  EXPECT_EQ(order, (std::vector<std::string>{"first", "second"}));
  auto expect_error = [&](CollisionConstraint c, const std::string& needle) {
    System t;
    t.add_particle(Vec3::Zero(), Vec3::Zero(), 1.0);
    t.add_kinematic_particle(Vec3::UnitX());
    t.add_collision_source(
        make_collision_source("bad source", [c](CollisionContext& context) { context.add_constraint(c); }));
    try {
      t.step(0.01);
      FAIL() << "expected an error: " << needle;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("bad source"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_error(CollisionConstraint::point(k, Vec3::UnitY(), 0.0), "not a free or soft-spring particle");
  expect_error(CollisionConstraint::point(a, Vec3(0, 2, 0), 0.0), "not a unit vector");
  CollisionConstraint twice = CollisionConstraint::point(a, Vec3::UnitY(), 0.0);
  twice.size = 2;
  twice.particles[1] = a;
  expect_error(twice, "appears twice");
}

// Impulses on rigid-body particles go through the context: the body's momentum changes by exactly
// what the particle loses, and the step carries it (the body ends the step with it).
TEST(CollisionSource, BodyImpulsesGoThroughTheContext) {
  System s({Vec3::Zero()});
  RigidBodySettings rb;
  rb.mass = 2.0;
  rb.inertia = Vec3(0.1, 0.2, 0.3);
  const Index body = s.add_rigid_body(rb);
  const Index p = s.add_particle(Vec3(0.5, 0.2, 0), Vec3(0, -1, 0), 0.5);
  s.add_collision_source(make_collision_source("stop", [&](CollisionContext& c) {
    const Vec3 dv = -c.v->col(p);
    c.v->col(p) += dv;
    c.apply_body_impulse(body, c.x->col(p), -0.5 * dv);
  }));
  s.finalize();
  const Vec3 p0 = s.linear_momentum(), l0 = s.angular_momentum();
  s.step(0.01);
  EXPECT_NEAR((s.linear_momentum() - p0).norm(), 0.0, 1e-14);
  EXPECT_NEAR((s.angular_momentum() - l0).norm(), 0.0, 1e-3);  // the impulse acts at x^{n+1}, not x^n
  EXPECT_NEAR(s.rigid_bodies().v(1, body), -0.25, 1e-14);
  EXPECT_GT(s.rigid_bodies().w.col(body).norm(), 0.1);  // off-centre: it turns
}

}  // namespace
}  // namespace sinew
