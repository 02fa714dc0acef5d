// Contacts between rigid bodies held in the Newmark step (JointRow::unilateral): a 1 kg box (a 0.2 m
// cube) on a ground plane, its four bottom corners handed to the step as contact rows before every
// step, as a rigid solver's manifold would be. Checked against what cannot fail: a passive box never
// gains visible energy, an inelastic landing does not bounce, a resting box does not sink, Coulomb's
// law gives the sliding distance v^2 / (2 mu g) and the angle at which a box on a slope starts to slide.
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace sinew {
namespace {

constexpr double kG = 9.81, kHalf = 0.1, kDt = 1.0 / 60;

struct BoxOnGround {
  System s;
  Index box = -1;
  Vec3 normal = Vec3::UnitY();  // of the ground plane, through the origin
  double friction = 0.5;

  // The box's frame turned with the ground (its bottom face on the plane when `lift` is 0), `lift`
  // above it along the normal, moving with `v`.
  BoxOnGround(double slope, double lift, const Vec3& v, double mu) : friction(mu) {
    const Quat tilt(Eigen::AngleAxisd(slope, Vec3::UnitZ()));
    normal = tilt * Vec3::UnitY();
    RigidBodySettings b;
    b.mass = 1.0;
    b.inertia = Vec3::Constant(1.0 * (0.2 * 0.2 + 0.2 * 0.2) / 12.0);
    b.x = (kHalf + lift) * normal;
    b.q = tilt;
    box = s.add_rigid_body(b);
    s.set_gravity(Vec3(0, -kG, 0));
    s.rigid_bodies().v.col(box) = v;
  }
  void set_rows() {
    const RigidBodyParticles& bodies = s.rigid_bodies();
    std::vector<JointRow> rows;
    for (double a : {-kHalf, kHalf})
      for (double c : {-kHalf, kHalf}) {
        const Vec3 lever = bodies.q[box] * Vec3(a, -kHalf, c);
        const Vec3 corner = Vec3(bodies.x.col(box)) + lever;
        JointRow row;
        row.unilateral = true;
        row.body_a = box;
        row.j_a << normal, lever.cross(normal);
        row.gap = normal.dot(corner);
        row.friction = friction;
        row.point = corner;
        rows.push_back(row);
      }
    s.set_joint_rows(rows);
  }
  StepStats step() {
    set_rows();
    return s.step(kDt);
  }
  Vec3 x() const { return s.rigid_bodies().x.col(box); }
  Vec3 v() const { return s.rigid_bodies().v.col(box); }
  double height() const { return normal.dot(x()); }
  double energy() const {
    const RigidBodyParticles& b = s.rigid_bodies();
    const Vec3 w = b.w.col(box);
    return 0.5 * v().squaredNorm() + 0.5 * w.dot(b.world_inertia(box) * w) + kG * x().y();
  }
};

// Dropped from 5 cm: the landing is an inelastic collision (step 3), after which the box rests on its
// face. Without it, step 5's v^{n+1} = 2 v^{n+1/2} - v~^n reflected the approach and the box bounced
// back up at the speed it landed with.
TEST(Contacts, ADroppedBoxLandsWithoutBouncingAndRests) {
  BoxOnGround g(0.0, 0.05, Vec3::Zero(), 0.5);
  const double start = g.energy();
  double gain = -kInfinity, lowest = kInfinity, highest_after = -kInfinity;
  bool landed = false;
  for (int step = 0; step < 120; ++step) {
    g.step();
    gain = std::max(gain, g.energy() - start);
    lowest = std::min(lowest, g.height());
    if (landed) highest_after = std::max(highest_after, g.height());
    landed = landed || g.height() < kHalf + 1e-6;
  }
  ASSERT_TRUE(landed);
  EXPECT_LE(gain, 1e-12);
  EXPECT_GT(lowest, kHalf - 1e-9) << "the contact closes its gap and no more";
  EXPECT_LT(highest_after, kHalf + 1e-6) << "no bounce";
  EXPECT_LT(g.v().norm(), 1e-4);
  EXPECT_LT(g.s.rigid_bodies().w.col(g.box).norm(), 1e-3);
}

// Sliding at 2 m/s with mu = 0.5 on its face: it stops after v^2 / (2 mu g) = 0.408 m, and its
// visible energy only falls. (Sliding friction acts a step late, at the step's end.)
TEST(Contacts, ASlidingBoxStopsWhereCoulombSays) {
  const double v0 = 2.0, mu = 0.5;
  BoxOnGround g(0.0, 0.0, Vec3(v0, 0, 0), mu);
  double previous = g.energy(), rise = 0.0;
  for (int step = 0; step < 60; ++step) {
    g.step();
    rise = std::max(rise, g.energy() - previous);
    previous = g.energy();
  }
  const double expected = v0 * v0 / (2.0 * mu * kG);
  EXPECT_NEAR(g.x().x(), expected, 0.05 * expected);
  EXPECT_LT(g.v().norm(), 1e-3);
  EXPECT_NEAR(g.height(), kHalf, 1e-6);
  EXPECT_LE(rise, 1e-9);
}

// On a 20 degree slope a box sticks when mu > tan 20 = 0.364 (the contacts' sticking rows hold it in
// the step) and slides with a = g (sin 20 - mu cos 20) when mu is below.
TEST(Contacts, ABoxOnASlopeSticksAboveTheFrictionAngleAndSlidesBelowIt) {
  const double slope = 20.0 * 3.14159265358979323846 / 180.0;
  {
    BoxOnGround g(slope, 0.0, Vec3::Zero(), 0.5);
    const Vec3 start = g.x();
    for (int step = 0; step < 60; ++step) g.step();
    EXPECT_LT((g.x() - start).norm(), 1e-6) << "mu 0.5 holds it";
  }
  {
    const double mu = 0.2;
    BoxOnGround g(slope, 0.0, Vec3::Zero(), mu);
    const Vec3 start = g.x();
    for (int step = 0; step < 60; ++step) g.step();
    const double a = kG * (std::sin(slope) - mu * std::cos(slope));
    EXPECT_NEAR((g.x() - start).norm(), 0.5 * a, 0.05 * 0.5 * a) << "mu 0.2 lets it slide for 1 s";
    EXPECT_NEAR(g.height(), kHalf, 1e-6);
  }
}

// Contacts whose targets disagree: the box 7 mm into the ground on two corners and 1.5 mm on the
// other two, pushed out at the rates a rigid solver asks for (0.33 and 0.07 m/s), on rows of rank
// three. Held as four equalities their least-norm twists were 1e7 m/s; the step meets them all at
// once with the least motion that does (Constraints::agree_contact_targets).
TEST(Contacts, ContactTargetsThatDisagreeAreMetTogether) {
  BoxOnGround g(0.0, 0.0, Vec3::Zero(), 0.0);
  g.s.set_gravity(Vec3::Zero());
  // The divergence check's budget (the start's energy and the work it knows of) does not count the
  // contacts' push-out work, and the box starts at rest with none.
  g.s.step_settings().divergence_factor = 0.0;
  const RigidBodyParticles& bodies = g.s.rigid_bodies();
  std::vector<JointRow> rows;
  int k = 0;
  for (double a : {-kHalf, kHalf})
    for (double c : {-kHalf, kHalf}) {
      const Vec3 lever(a, -kHalf, c);
      JointRow row;
      row.unilateral = true;
      row.body_a = g.box;
      row.j_a << Vec3::UnitY(), lever.cross(Vec3::UnitY());
      row.gap = k < 2 ? -0.007 : -0.0015;
      row.target = k < 2 ? 0.33 : 0.07;
      row.point = Vec3(bodies.x.col(g.box)) + lever;
      rows.push_back(row);
      ++k;
    }
  g.s.set_joint_rows(rows);
  g.s.step(kDt);
  const Vec3 w = bodies.w.col(g.box);
  EXPECT_LT(g.v().norm() + kHalf * w.norm(), 1.0);
  for (const JointRow& row : rows) {
    const double speed = row.j_a.head<3>().dot(g.v()) + row.j_a.tail<3>().dot(w);
    EXPECT_GT(speed, row.target - 1e-6) << "each contact is pushed out at least as fast as it asks";
  }
}

}  // namespace
}  // namespace sinew
