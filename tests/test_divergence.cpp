// Divergence is stopped early, named, and leaves the state of the failed step's start; stable
// active scenes (dragged, falling, torqued, spinning) run through untouched. Public API only.
#include "sinew/builders.hpp"
#include "sinew/force.hpp"
#include "sinew/system.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <limits>
#include <string>

namespace sinew {
namespace {

using test::error_of;

// Everything a step may change, to compare the state after a failed step with its start.
struct Snapshot {
  Vectors3 x, v, body_x, body_v, body_w;
  std::vector<Quat> q;
  explicit Snapshot(const System& s)
      : x(s.particles().x),
        v(s.particles().v),
        body_x(s.rigid_bodies().x),
        body_v(s.rigid_bodies().v),
        body_w(s.rigid_bodies().w),
        q(s.rigid_bodies().q) {}
  bool operator==(const Snapshot& o) const {
    bool same = x == o.x && v == o.v && body_x == o.body_x && body_v == o.body_v && body_w == o.body_w;
    for (std::size_t b = 0; b < q.size(); ++b) same = same && q[b].coeffs() == o.q[b].coeffs();
    return same;
  }
  bool finite() const { return x.allFinite() && v.allFinite() && body_x.allFinite() && body_w.allFinite(); }
};

// Steps with a fixed dt (System::step: no substepping) until one throws, at most `limit` steps.
struct Outcome {
  int failed_step = -1;  // the index of the step that threw, -1 if none did
  std::string message;
  bool start_state_kept = false;  // the state after the throw is the one before that step
  bool finite = false;
};
Outcome step_until_error(System& s, double dt, int limit) {
  Outcome out;
  for (int i = 0; i < limit; ++i) {
    const Snapshot before(s);
    try {
      s.step(dt);
    } catch (const Error& e) {
      out.failed_step = i;
      out.message = e.what();
      const Snapshot after(s);
      out.start_state_kept = after == before;
      out.finite = after.finite();
      return out;
    }
  }
  return out;
}

// The particle index named as "particle N" in a message, or -1.
Index named_particle(const std::string& message) {
  const auto at = message.find("particle ");
  return at == std::string::npos ? -1 : std::atol(message.c_str() + at + 9);
}

// A 10x10 cloth of 0.5 m, its top corners on a fixed (kinematic) body, with edge springs of
// stiffness k and no damping (so no linear solve: every elastic force explicit).
struct PinnedCloth {
  System s;
  ClothGrid grid;
  explicit PinnedCloth(double k, double damping = 0.0) {
    ClothGridSettings c;
    c.nx = c.ny = 10;
    c.width = c.height = 0.5;
    c.origin = Vec3(0, 1, 0);
    c.stretch_stiffness = k;
    c.stretch_damping = damping;
    grid = add_cloth_grid(s, c);
    RigidBodySettings fixed;
    fixed.kinematic = true;
    fixed.x = Vec3(0.25, 1, 0);
    const Index body = s.add_rigid_body(fixed);
    s.bind_rigid_here(grid.node(0, 0), body);
    s.bind_rigid_here(grid.node(9, 0), body);
  }
  bool is_free_node(Index p) const {
    for (Index n : grid.nodes)
      if (n == p) return p != grid.node(0, 0) && p != grid.node(9, 0);
    return false;
  }
};

void expect_named_stop(const Outcome& out, int within, const std::string& item, const std::string& force) {
  ASSERT_GE(out.failed_step, 0) << "no error";
  EXPECT_LE(out.failed_step, within) << out.message;
  EXPECT_NE(out.message.find("diverged"), std::string::npos) << out.message;
  EXPECT_NE(out.message.find(item), std::string::npos) << out.message;
  EXPECT_NE(out.message.find(force), std::string::npos) << out.message;
  EXPECT_TRUE(out.start_state_kept) << "the failed step must leave the state of its start";
  EXPECT_TRUE(out.finite);
}

// Above its stable step the explicit cloth's stiffest mode grows about fifteenfold a step; it used to
// run until it overflowed (step 56), with garbage states from about step 3 on.
TEST(Divergence, AnExplicitClothAboveItsStableStepStopsWithinAFewSteps) {
  PinnedCloth cloth(200.0);
  const double dt = 3.0 * cloth.s.stable_dt();
  const Outcome out = step_until_error(cloth.s, dt, 200);
  expect_named_stop(out, 10, "particle ", "largest force on it: 'edge springs'");
  EXPECT_TRUE(cloth.is_free_node(named_particle(out.message))) << out.message;
  // The caller can go on at a stable step from the kept state.
  for (int i = 0; i < 50; ++i) cloth.s.step(0.5 * cloth.s.stable_dt());
  EXPECT_TRUE(cloth.s.particles().v.allFinite());
}

// Springs 500 times too stiff for a 1/240 s tick (with damping, so the step solves with CG): it used to
// stop at step 21 with an error about dihedral bending's implicit products, which had nothing to do
// with it.
TEST(Divergence, TooStiffExplicitSpringsStopNamingTheSprings) {
  PinnedCloth cloth(1e5, 0.05);
  ASSERT_LT(cloth.s.stable_dt(), 0.1 / 240);
  const Outcome out = step_until_error(cloth.s, 1.0 / 240, 200);
  expect_named_stop(out, 10, "particle ", "largest force on it: 'edge springs'");
  EXPECT_TRUE(cloth.is_free_node(named_particle(out.message))) << out.message;
}

// A light body on a lever, tied to a fixed point by a stiff binding spring evaluated at the end of the
// step in step 4 (BindingSpringStep4::explicit_end_of_step, unstable for stiff springs by section 3.3):
// it spins up by a factor of about ten every ten steps. It used to overflow only at step 1356.
TEST(Divergence, ARigidBodySpunUnstablyStopsNamingTheBody) {
  System s(SystemSettings{Vec3::Zero(), true});
  s.step_settings().binding_springs_in_step4 = BindingSpringStep4::explicit_end_of_step;
  s.step_settings().settle_stiff_binding_springs = false;  // it damps this instability; the check is what is tested
  RigidBodySettings ring;
  ring.mass = 0.05;
  ring.inertia = {8e-5, 4e-5, 4e-5};
  const Index body = s.add_rigid_body(ring);
  const Vec3 lever(0, -0.04, 0);
  const Index end = s.add_particle(lever, Vec3::Zero(), 0.0);
  s.bind_rigid(end, body, lever);
  const Index anchor = s.add_kinematic_particle(lever + Vec3(0.01, 0, 0));  // 50 J in the spring
  s.add_binding_spring({anchor, end, 1e6, 1.0});
  const Outcome out = step_until_error(s, 1.0 / 60, 2000);
  expect_named_stop(out, 20, "rigid body " + std::to_string(body), "largest force on it: the binding springs");
}

// A force whose coefficient turns NaN mid-run (set where nothing validates it): the step stops at once,
// as before, and now names the force as well as the particle.
class Wind final : public Force {
 public:
  explicit Wind(std::vector<Index> particles) : m_particles(std::move(particles)) {}
  double strength = 0.1;  // [N] on each particle, along +z
  std::string_view name() const override { return "wind"; }
  void validate(Index particle_count) const override {
    for (Index p : m_particles)
      if (p < 0 || p >= particle_count) fail("wind: particle ", p, " does not exist");
  }
  void update_position_state(const Vectors3&) override {}
  double potential_energy(const Vectors3&) const override { return 0.0; }
  void add_elastic_forces(const Vectors3&, Vectors3& f) const override {
    for (Index p : m_particles) f(2, p) += strength;
  }
  void add_elastic_differentials(const Vectors3&, Vectors3&) const override {}

 private:
  std::vector<Index> m_particles;
};

TEST(Divergence, ANaNCoefficientNamesTheForce) {
  for (const double damping : {0.0, 0.05}) {  // explicit only, and with a CG solve
    PinnedCloth cloth(200.0, damping);
    Wind& wind = cloth.s.add_force(std::make_unique<Wind>(std::vector<Index>{cloth.grid.node(4, 7)}));
    const double dt = 0.5 * cloth.s.stable_dt();
    for (int i = 0; i < 10; ++i) cloth.s.step(dt);
    wind.strength = std::numeric_limits<double>::quiet_NaN();
    const Outcome out = step_until_error(cloth.s, dt, 10);
    EXPECT_EQ(out.failed_step, 0) << out.message;
    EXPECT_NE(out.message.find("particle " + std::to_string(cloth.grid.node(4, 7))), std::string::npos) << out.message;
    EXPECT_NE(out.message.find("force 'wind' gives non-finite forces"), std::string::npos) << out.message;
    EXPECT_TRUE(out.start_state_kept);
    EXPECT_TRUE(out.finite);
  }
}

// The check off (divergence_factor = 0): the unstable cloth runs on as it used to, until it
// overflows. Out of range: refused by name.
TEST(Divergence, TheCheckCanBeTurnedOffAndIsValidated) {
  PinnedCloth cloth(200.0);
  cloth.s.step_settings().divergence_factor = 0.0;
  const Outcome out = step_until_error(cloth.s, 3.0 * cloth.s.stable_dt(), 500);
  ASSERT_GE(out.failed_step, 0);
  EXPECT_GT(out.failed_step, 20) << out.message;
  EXPECT_NE(out.message.find("non-finite"), std::string::npos) << out.message;
  PinnedCloth other(200.0);
  other.s.step_settings().divergence_factor = -1.0;
  EXPECT_NE(error_of([&] { other.s.step(1e-4); }).find("divergence_factor"), std::string::npos);
}

// ---- stable active scenes: their energy grows, the check stays quiet -------------------------------

// A cloth (explicit springs, damped) stepped by advance(), at its stable substeps.
struct ActiveCloth {
  System s;
  ClothGrid grid;
  explicit ActiveCloth(const Vec3& origin, int n = 8, double size = 0.4) {
    ClothGridSettings c;
    c.nx = c.ny = n;
    c.width = c.height = size;
    c.origin = origin;
    grid = add_cloth_grid(s, c);
  }
  double energy() { return s.kinetic_energy() + s.potential_energy(); }
};

// Dragged by one corner, bound to a kinematic particle that accelerates at 60 m/s^2 for a second,
// then reverses at the same rate: the cloth takes about 0.5 (60 m/s)^2 per kg.
TEST(Divergence, ACornerDraggedByAHardAcceleratingKinematicPointDoesNotTrip) {
  ActiveCloth cloth(Vec3(0, 1, 0));
  const Index corner = cloth.grid.node(0, 0);
  const Index hand = cloth.s.add_kinematic_particle(cloth.s.particles().x.col(corner));
  const Index parents[] = {hand};
  const double weights[] = {1.0};
  cloth.s.bind_linear(corner, parents, weights);
  // And a second corner on a stiff binding spring to a second, faster hand.
  const Index other = cloth.grid.node(7, 0);
  const Index hand2 = cloth.s.add_kinematic_particle(cloth.s.particles().x.col(other));
  cloth.s.add_binding_spring({hand2, other, 1e4, 1.0});
  cloth.s.finalize();
  const double e0 = cloth.energy();
  const Vec3 a(60.0, 20.0, 0.0);
  double t = 0.0;
  for (int frame = 0; frame < 120; ++frame) {
    const Vec3 v = (t < 1.0 ? t : 2.0 - t) * a;
    cloth.s.particles().v.col(hand) = v;
    cloth.s.particles().v.col(hand2) = 1.2 * v;
    ASSERT_NO_THROW(cloth.s.advance(1.0 / 60)) << "frame " << frame;
    t += 1.0 / 60;
  }
  EXPECT_GT(cloth.energy(), e0 + 100.0) << "the scene is active: the hands put energy in";
}

// Falling freely for ten seconds: 100 m/s, 490 J per kg, all of it gravity's work.
TEST(Divergence, AClothFallingForTenSecondsDoesNotTrip) {
  ActiveCloth cloth(Vec3(0, 1, 0));
  cloth.s.particles().v.col(cloth.grid.node(3, 3)) = Vec3(0, 0, 2);  // something to flap
  for (int frame = 0; frame < 600; ++frame) ASSERT_NO_THROW(cloth.s.advance(1.0 / 60)) << "frame " << frame;
  EXPECT_GT(cloth.s.particles().v.col(cloth.grid.node(0, 0)).norm(), 90.0);
}

// A body spun up by a large applied torque, 40 N m on 0.02 kg m^2 (2000 rad/s^2), holding a cloth by
// one edge, for half a second: from rest to 1000 rad/s.
TEST(Divergence, ABodySpunUpByALargeTorqueHoldingClothDoesNotTrip) {
  ActiveCloth cloth(Vec3(0.05, 0, 0), 6, 0.2);
  RigidBodySettings hub;
  hub.mass = 2.0;
  hub.inertia = Vec3(0.02, 0.02, 0.02);
  hub.gravity = false;
  const Index body = cloth.s.add_rigid_body(hub);
  for (int i = 0; i < 6; ++i) cloth.s.bind_rigid_here(cloth.grid.node(0, i), body);
  cloth.s.set_gravity(Vec3::Zero());
  cloth.s.finalize();
  const double e0 = cloth.energy();
  for (int frame = 0; frame < 120; ++frame) {
    cloth.s.rigid_bodies().torque.col(body) = Vec3(0, 40.0, 0);
    ASSERT_NO_THROW(cloth.s.advance(1.0 / 240)) << "frame " << frame;
  }
  EXPECT_GT(cloth.s.rigid_bodies().w.col(body).norm(), 500.0);
  EXPECT_GT(cloth.energy(), 100.0 * (e0 + 1.0));
}

// A body given 1000 rad/s, holding a cloth by one edge: the cloth is flung out and wound round.
TEST(Divergence, ABodySpinningAtAThousandRadiansASecondHoldingClothDoesNotTrip) {
  ActiveCloth cloth(Vec3(0.05, 0, 0), 6, 0.2);
  RigidBodySettings hub;
  hub.mass = 2.0;
  hub.inertia = Vec3(0.02, 0.02, 0.02);
  hub.w = Vec3(0, 1000.0, 0);
  const Index body = cloth.s.add_rigid_body(hub);
  for (int i = 0; i < 6; ++i) cloth.s.bind_rigid_here(cloth.grid.node(0, i), body);
  for (int frame = 0; frame < 60; ++frame) ASSERT_NO_THROW(cloth.s.advance(1.0 / 240)) << "frame " << frame;
  EXPECT_GT(cloth.s.rigid_bodies().w.col(body).norm(), 100.0);
}

// A viewer's mouse spring: a cloth hanging at rest is grabbed by a stiff binding spring to a cursor
// a metre away, switched on between steps (5000 J into a 0.5 kg cloth that had about 0.03 J).
TEST(Divergence, AMouseSpringGrabbingARestingClothDoesNotTrip) {
  PinnedCloth cloth(200.0, 0.05);
  const double dt = 0.5 * cloth.s.stable_dt();
  for (int i = 0; i < 2000; ++i) cloth.s.step(dt);
  const Index node = cloth.grid.node(5, 9);
  const Index cursor = cloth.s.add_kinematic_particle(cloth.s.particles().x.col(node) + Vec3(0, 0, 1.0));
  const Index spring = cloth.s.add_binding_spring({cursor, node, 1e4, 1.0});
  cloth.s.set_binding_spring_active(spring, false);
  for (int i = 0; i < 10; ++i) cloth.s.step(dt);
  cloth.s.set_binding_spring_active(spring, true);
  for (int i = 0; i < 2000; ++i) ASSERT_NO_THROW(cloth.s.step(dt)) << "step " << i;
  EXPECT_GT(cloth.s.particles().x(2, node), 0.5) << "the spring pulled the node towards the cursor";
}

}  // namespace
}  // namespace sinew
