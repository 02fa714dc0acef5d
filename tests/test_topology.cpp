// Topology changes between steps: particles, bindings, soft bindings, binding springs, forces and
// elements added and removed while running (System's "topology changes" API).
#include "sinew/builders.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/system.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <array>
#include <string>
#include <utility>
#include <vector>

namespace sinew {
namespace {

ClothGridSettings cloth_settings() {
  ClothGridSettings c = test::square_cloth(6, 0.5, Vec3(-0.25, 1.0, 0.0));
  c.mass = 0.36;
  c.stretch_stiffness = 80.0;
  c.stretch_damping = 0.05;
  c.bending_stiffness = 1e-3;
  return c;
}

// The model both systems of the next test are built with, before any step: a cloth, an embedded point
// with a binding spring to a kinematic anchor, a soft-bound particle on a node, and a spring to be
// removed. (Built by one function, so "from scratch" means the same calls.)
struct Model {
  ClothGrid cloth;
  Index anchor = -1, embedded = -1, soft = -1, spare_spring = -1;
};
Model build(System& s) {
  Model m;
  m.cloth = add_cloth_grid(s, cloth_settings());
  m.anchor = s.add_kinematic_particle(Vec3(0.0, 1.2, 0.0));
  const std::array<Index, 3> parents{m.cloth.node(2, 0), m.cloth.node(3, 0), m.cloth.node(3, 1)};
  const std::array<double, 3> weights{0.2, 0.5, 0.3};
  m.embedded = s.add_embedded_point(parents, weights);
  s.add_binding_spring({m.embedded, m.anchor, 2e3, 1.0});
  m.soft = s.add_particle(s.particles().x.col(m.cloth.node(5, 5)), Vec3::Zero(), 0.0);
  s.add_soft_binding({m.soft, m.cloth.node(5, 5), SoftCoupling::spring, 1e3, 1.0, 0.0});
  m.spare_spring = s.add_binding_spring({m.cloth.node(0, 5), m.anchor, 50.0, 0.5});
  return m;
}

// The change: two cloth nodes (one a node of the soft binding's target row, one on the edge) and the
// soft particle removed, a spring removed, a new particle tied to the cloth by a new spring.
Index change(System& s, const Model& m, const Vec3& x_new, const Vec3& v_new) {
  const std::array<Index, 3> gone{m.cloth.node(1, 4), m.cloth.node(4, 2), m.soft};
  s.remove_particles(gone);
  s.remove_binding_spring(m.spare_spring);
  const Index added = s.add_particle(x_new, v_new, 0.02);
  s.add_binding_spring({added, m.cloth.node(0, 0), 500.0, 1.0});
  return added;
}

// A system changed while running takes the same next step, bit for bit, as one built from scratch in
// the changed state: the same model and changes, the positions and velocities copied, no step before.
TEST(Topology, ChangedSystemStepsAsOneBuiltFromScratch) {
  System a;
  const Model ma = build(a);
  for (int k = 0; k < 12; ++k) a.step(1.0 / 240);
  const Vectors3 x = a.particles().x, v = a.particles().v;
  const Vec3 x_new(0.3, 0.9, 0.1), v_new(0.0, 0.5, -0.2);
  change(a, ma, x_new, v_new);
  a.step(1.0 / 240);

  System b;
  const Model mb = build(b);
  b.particles().x = x;
  b.particles().v = v;
  change(b, mb, x_new, v_new);
  b.step(1.0 / 240);
  EXPECT_EQ(a.state_hash(), b.state_hash());
  // And the change did something: the same run without it differs.
  System c;
  build(c);
  c.particles().x = x;
  c.particles().v = v;
  c.step(1.0 / 240);
  EXPECT_NE(a.state_hash(), c.state_hash());
}

double total_mass(const System& s) {
  double m = 0.0;
  for (Index i = 0; i < s.particles().size(); ++i)
    if (s.particles().kind[i] == ParticleKind::free) m += s.particles().mass[i];
  return m;
}

// Without gravity nothing outside acts: removing particles takes exactly their mass and momentum out
// (for a hard-bound point, what its parents carried for it), adding one puts its own in, and the
// steps in between keep the momentum to the solver's tolerance.
TEST(Topology, AddingAndRemovingParticlesKeepsMassAndMomentum) {
  System s({Vec3::Zero()});
  const ClothGrid cloth = add_cloth_grid(s, cloth_settings());
  const std::array<Index, 2> parents{cloth.node(2, 2), cloth.node(3, 2)};
  const std::array<double, 2> weights{0.25, 0.75};
  const Index point = s.add_embedded_point(parents, weights);
  for (Index i = 0; i < s.particles().size(); ++i) s.particles().v.col(i) = Vec3(0.1 * (i % 3), -0.2, 0.05 * (i % 5));
  s.clamp_bound_rows();
  s.step_settings().cg_tolerance = 1e-13;
  s.finalize();
  (void)point;
  for (int k = 0; k < 10; ++k) s.step(1.0 / 240);
  const double m0 = total_mass(s);
  const Vec3 p0 = s.linear_momentum();

  // The embedded point is massless here; give a removed node's share and check the parents' loss too.
  const std::array<Index, 2> gone{cloth.node(0, 3), cloth.node(5, 5)};
  double m_gone = 0.0;
  Vec3 p_gone = Vec3::Zero();
  for (Index i : gone) {
    m_gone += s.particles().mass[i];
    p_gone += s.particles().mass[i] * s.particles().v.col(i);
  }
  s.remove_particles(gone);
  const Vec3 v_new(1.0, 2.0, -0.5);
  const Index added = s.add_particle(Vec3(0.0, 1.3, 0.0), v_new, 0.05);
  s.add_binding_spring({added, cloth.node(3, 0), 300.0, 1.0});
  s.finalize();
  EXPECT_NEAR(total_mass(s), m0 - m_gone + 0.05, 1e-15);
  EXPECT_NEAR((s.linear_momentum() - (p0 - p_gone + 0.05 * v_new)).norm(), 0.0, 1e-15);
  const Vec3 p1 = s.linear_momentum();
  for (int k = 0; k < 40; ++k) s.step(1.0 / 240);
  EXPECT_NEAR((s.linear_momentum() - p1).norm(), 0.0, 1e-11);
  EXPECT_EQ(s.particles().kind[gone[0]], ParticleKind::removed);
  EXPECT_EQ(s.particles().mass[gone[0]], 0.0);
}

// A hard-bound point with mass leaves with what its parents carried for it: m_bar v_e of momentum.
TEST(Topology, RemovingAHardBoundPointTakesItsShareFromTheParents) {
  System s({Vec3::Zero()});
  const Index a = s.add_particle(Vec3::Zero(), Vec3(1, 0, 0), 1.0);
  const Index b = s.add_particle(Vec3::UnitX(), Vec3(0, 2, 0), 3.0);
  const Index e = s.add_particle(Vec3(0.4, 0, 0), Vec3::Zero(), 0.5);
  const std::array<Index, 2> parents{a, b};
  const std::array<double, 2> weights{0.6, 0.4};
  s.bind_linear(e, parents, weights);
  s.finalize();
  const Vec3 p0 = s.linear_momentum();
  const Vec3 v_e = s.particles().v.col(e);
  const std::array<Index, 1> gone{e};
  s.remove_particles(gone);
  s.finalize();
  EXPECT_NEAR((s.linear_momentum() - (p0 - 0.5 * v_e)).norm(), 0.0, 1e-15);
  EXPECT_NEAR(s.particles().mass[a] + s.particles().mass[b], 4.0, 1e-15);
}

// With the bound points' mass merged into the body (the core's default), unbinding one mid-run gives
// the body back its own mass and re-merges the rest: linear and angular momentum are unchanged by the
// change, and the freed point keeps its velocity.
TEST(Topology, UnbindingFromABodyWithMergedMassKeepsMomentum) {
  System s({Vec3::Zero()});
  RigidBodySettings rb;
  rb.mass = 2.0;
  rb.inertia = Vec3(0.1, 0.2, 0.3);
  rb.v = Vec3(0.3, -0.1, 0.2);
  rb.w = Vec3(1.0, 2.0, -0.5);
  const Index body = s.add_rigid_body(rb);
  const Index p = s.add_particle(Vec3(0.3, 0.1, 0.0), Vec3::Zero(), 0.4);
  const Index q = s.add_particle(Vec3(-0.2, 0.0, 0.25), Vec3::Zero(), 0.7);
  s.bind_rigid_here(p, body);
  s.bind_rigid_here(q, body);
  s.clamp_bound_rows();
  s.finalize();
  EXPECT_NEAR(s.rigid_bodies().mass[body], 3.1, 1e-15);
  for (int k = 0; k < 10; ++k) s.step(1.0 / 240);
  const Vec3 p0 = s.linear_momentum(), l0 = s.angular_momentum();
  const Vec3 v_p = s.particles().v.col(p);
  s.unbind(p);
  s.finalize();
  EXPECT_NEAR(s.rigid_bodies().mass[body], 2.7, 1e-14);
  EXPECT_NEAR((s.particles().v.col(p) - v_p).norm(), 0.0, 1e-14);
  EXPECT_NEAR((s.linear_momentum() - p0).norm(), 0.0, 1e-13);
  EXPECT_NEAR((s.angular_momentum() - l0).norm(), 0.0, 1e-13);
  for (int k = 0; k < 10; ++k) s.step(1.0 / 240);
  EXPECT_NEAR((s.linear_momentum() - p0).norm(), 0.0, 1e-12);
}

// A body's mass changed between steps (a rigid solver's body made kinematic, then dynamic with a new
// mass): the merged masses come out first, so the body ends with the new mass plus what is bound to it;
// kinematic, it holds its twist whatever pulls on it; bad values name the body and change nothing.
TEST(Topology, ARigidBodysMassChangesBetweenSteps) {
  System s;
  RigidBodySettings rb;
  rb.mass = 2.0;
  rb.inertia = Vec3(0.1, 0.2, 0.3);
  const Index body = s.add_rigid_body(rb);
  const Index p = s.add_particle(Vec3(0.3, 0.1, 0.0), Vec3::Zero(), 0.4);
  s.bind_rigid_here(p, body);
  s.step(1.0 / 240);
  EXPECT_NEAR(s.rigid_bodies().mass[body], 2.4, 1e-15);
  s.rigid_bodies().v.col(body) = Vec3(0.5, 0.0, 0.0);
  s.set_rigid_body_mass(body, true);
  for (int k = 0; k < 10; ++k) s.step(1.0 / 240);
  EXPECT_EQ(s.rigid_bodies().v.col(body), Vec3(0.5, 0.0, 0.0)) << "prescribed: gravity does not move it";
  s.set_rigid_body_mass(body, false, 3.0, Vec3(0.2, 0.2, 0.3));
  s.finalize();
  EXPECT_NEAR(s.rigid_bodies().mass[body], 3.4, 1e-15);
  const Vec3 v0 = s.rigid_bodies().v.col(body);
  s.step(1.0 / 240);
  EXPECT_NEAR(s.rigid_bodies().v(1, body) - v0.y(), -9.81 / 240, 1e-12) << "falls at g again";
  for (const auto& [mass, inertia] : {std::pair{-1.0, Vec3(1, 1, 1)}, std::pair{1.0, Vec3(1, 1, 3)}}) {
    try {
      s.set_rigid_body_mass(body, false, mass, inertia);
      ADD_FAILURE() << "accepted mass " << mass << ", inertia " << inertia.transpose();
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("rigid body 0"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(s.set_rigid_body_mass(1, true), Error);
  EXPECT_NEAR(s.rigid_bodies().mass[body], 3.4, 1e-15);
}

TEST(Topology, ForcesAndElementsComeAndGo) {
  System s;
  const ClothGrid cloth = add_cloth_grid(s, cloth_settings());
  s.step(1.0 / 240);
  const auto count = s.forces().size();
  // Cutting: the elements around a node go, the node stays (now free of the cloth).
  const std::array<Index, 1> cut{cloth.node(2, 2)};
  const auto* springs = dynamic_cast<const EdgeSprings*>(s.forces()[0].get());
  ASSERT_NE(springs, nullptr);
  const auto edges = springs->edges().size();
  std::size_t at_node = 0;
  for (const auto& e : springs->edges()) at_node += (e[0] == cut[0] || e[1] == cut[0]) ? 1 : 0;
  ASSERT_GE(at_node, 4u);
  s.remove_elements_touching(cut);
  EXPECT_EQ(springs->edges().size(), edges - at_node);
  for (const auto& e : springs->edges()) EXPECT_TRUE(e[0] != cut[0] && e[1] != cut[0]);
  EXPECT_EQ(s.particles().kind[cloth.node(2, 2)], ParticleKind::free);
  s.step(1.0 / 240);
  // A force added while running joins the next step; removed, it leaves it.
  std::vector<EdgeSprings::Edge> extra{{cloth.node(0, 0), cloth.node(5, 5)}};
  auto& added = s.add_force(std::make_unique<EdgeSprings>(extra, s.particles().x));
  EXPECT_EQ(s.forces().size(), count + 1);
  s.step(1.0 / 240);
  s.remove_force(added);
  EXPECT_EQ(s.forces().size(), count);
  s.step(1.0 / 240);
  EXPECT_TRUE(s.particles().x.allFinite());
}

TEST(Topology, BadRemovalsAreNamedAndChangeNothing) {
  System s;
  const ClothGrid cloth = add_cloth_grid(s, cloth_settings());
  const std::array<Index, 2> parents{cloth.node(0, 0), cloth.node(1, 0)};
  const std::array<double, 2> weights{0.5, 0.5};
  const Index point = s.add_embedded_point(parents, weights);
  s.step(1.0 / 240);
  const std::uint64_t before = s.state_hash();
  const auto edges = dynamic_cast<const EdgeSprings&>(*s.forces()[0]).edges().size();
  auto expect_error = [&](auto&& call, const std::string& needle) {
    try {
      call();
      FAIL() << "expected an error: " << needle;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  const std::array<Index, 1> parent{cloth.node(0, 0)};
  expect_error([&] { s.remove_particles(parent); }, "parent of hard-bound particle " + std::to_string(point));
  const std::array<Index, 1> missing{12345};
  expect_error([&] { s.remove_particles(missing); }, "particle 12345 does not exist");
  expect_error([&] { s.remove_binding_spring(7); }, "binding spring 7 does not exist");
  // The failed calls changed nothing: the same state, the same elements, the parent still free.
  EXPECT_EQ(s.state_hash(), before);
  EXPECT_EQ(s.particles().kind[cloth.node(0, 0)], ParticleKind::free);
  EXPECT_EQ(dynamic_cast<const EdgeSprings&>(*s.forces()[0]).edges().size(), edges);
  const std::array<Index, 1> p{point};
  s.remove_particles(p);
  expect_error([&] { s.remove_particles(p); }, "was removed already");
  s.step(1.0 / 240);
  EXPECT_TRUE(s.particles().x.allFinite());
}

// Between a change and the next set-up the system answers from what it knows: the momentum counts a
// particle just added with its own mass, a spring may be moved onto it (damped at the set-up), and
// effective masses, which the set-up computes, are refused by name rather than read stale.
TEST(Topology, QueriesBetweenAChangeAndTheNextStepAreSafe) {
  System s({Vec3::Zero()});
  const ClothGrid cloth = add_cloth_grid(s, cloth_settings());
  const Index anchor = s.add_kinematic_particle(Vec3(0, 1.5, 0));
  const Index spring = s.add_binding_spring({cloth.node(0, 0), anchor, 100.0, 1.0});
  s.step(1.0 / 240);
  const Vec3 p0 = s.linear_momentum();
  const Index added = s.add_particle(Vec3(0, 1.2, 0), Vec3(1, 0, 0), 0.5);
  EXPECT_NEAR((s.linear_momentum() - (p0 + Vec3(0.5, 0, 0))).norm(), 0.0, 1e-15);
  s.set_binding_spring_ends(spring, added, anchor);
  try {
    s.effective_mass(added);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("finalize"), std::string::npos) << e.what();
  }
  s.step(1.0 / 240);
  EXPECT_NEAR(s.effective_mass(added), 0.5, 1e-15);
  EXPECT_GT(s.binding_spring_force(spring).norm(), 0.0);
}

}  // namespace
}  // namespace sinew
