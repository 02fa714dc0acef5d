// Joint rows between rigid-body particles (JointRow) and applied forces on them: what a rigid solver's
// bilateral joints and force accumulators become inside the Newmark step.
#include "sinew/system.hpp"

#include <gtest/gtest.h>

namespace sinew {
namespace {

Vec6 twist_row(const Vec3& linear, const Vec3& angular) { return (Vec6() << linear, angular).finished(); }

// A slider along x for body b: no linear velocity along y or z, no rotation about y or z.
std::vector<JointRow> slider_along_x(Index b) {
  std::vector<JointRow> rows;
  for (int axis : {1, 2}) {
    const Vec3 n = Vec3::Unit(axis);
    rows.push_back({b, twist_row(n, Vec3::Zero())});
    rows.push_back({b, twist_row(Vec3::Zero(), n)});
  }
  return rows;
}

RigidBodySettings body(double mass, const Vec3& x = Vec3::Zero()) {
  RigidBodySettings s;
  s.mass = mass;
  s.inertia = Vec3(0.3, 0.2, 0.1);
  s.x = x;
  return s;
}

// A body on a slider along x under gravity, pulled by an applied force with components on every axis
// and a torque about every axis: the rows take the y and z parts (the slider's reaction), so the body
// slides with a = F_x / m and turns about x with dw = tau_x / I_x t, exactly (a constant force: the
// Newmark step integrates it without error), while gravity does nothing.
TEST(JointRows, ASliderLetsTheBodyMoveOnlyAlongAndAboutItsAxis) {
  System s;
  const Index b = s.add_rigid_body(body(2.0));
  s.rigid_bodies().force.col(b) = Vec3(3.0, 5.0, -7.0);
  s.rigid_bodies().torque.col(b) = Vec3(0.6, -0.2, 0.4);
  s.set_joint_rows(slider_along_x(b));
  s.step_settings().cg_tolerance = 1e-14;
  const double dt = 0.01;
  const int steps = 100;
  for (int i = 0; i < steps; ++i) s.step(dt);
  const double t = dt * steps;
  const auto& bodies = s.rigid_bodies();
  EXPECT_NEAR(bodies.v(0, b), 3.0 / 2.0 * t, 1e-12);
  EXPECT_NEAR(bodies.x(0, b), 0.5 * 3.0 / 2.0 * t * t, 1e-12);
  EXPECT_NEAR(bodies.v.col(b).tail<2>().norm(), 0.0, 1e-12);
  EXPECT_NEAR(bodies.x.col(b).tail<2>().norm(), 0.0, 1e-12);
  EXPECT_NEAR(bodies.w(0, b), 0.6 / 0.3 * t, 1e-12);
  EXPECT_NEAR(bodies.w.col(b).tail<2>().norm(), 0.0, 1e-12);
}

// Two bodies whose x velocities a row ties together (a prismatic coupling): a force on one only moves
// both with a = F / (m_a + m_b), and the row's reaction conserves their total momentum.
TEST(JointRows, ARowBetweenTwoBodiesSharesTheForceByMass) {
  SystemSettings settings;
  settings.gravity.setZero();
  System s(settings);
  const Index a = s.add_rigid_body(body(1.0));
  const Index c = s.add_rigid_body(body(3.0, Vec3(1, 0, 0)));
  s.rigid_bodies().force.col(a) = Vec3(4.0, 0, 0);
  s.set_joint_rows({{a, twist_row(Vec3::UnitX(), Vec3::Zero()), c, twist_row(-Vec3::UnitX(), Vec3::Zero())}});
  s.step_settings().cg_tolerance = 1e-14;
  for (int i = 0; i < 50; ++i) s.step(0.02);
  EXPECT_NEAR(s.rigid_bodies().v(0, a), 4.0 / 4.0 * 1.0, 1e-12);
  EXPECT_NEAR(s.rigid_bodies().v(0, c), 4.0 / 4.0 * 1.0, 1e-12);
}

// A row to a kinematic body moving at 0.5 m/s along x: the dynamic body keeps that velocity too (its
// row's target comes from the prescribed twist), against an applied force.
TEST(JointRows, ARowToAKinematicBodyCarriesTheDynamicOne) {
  SystemSettings settings;
  settings.gravity.setZero();
  System s(settings);
  RigidBodySettings driver = body(1.0, Vec3(0, 1, 0));
  driver.kinematic = true;
  driver.v = Vec3(0.5, 0, 0);
  const Index k = s.add_rigid_body(driver);
  const Index b = s.add_rigid_body(body(1.0));
  s.rigid_bodies().force.col(b) = Vec3(-2.0, 0, 0);
  s.set_joint_rows({{b, twist_row(Vec3::UnitX(), Vec3::Zero()), k, twist_row(-Vec3::UnitX(), Vec3::Zero())}});
  for (int i = 0; i < 20; ++i) s.step(0.05);
  EXPECT_NEAR(s.rigid_bodies().v(0, b), 0.5, 1e-12);
  EXPECT_NEAR(s.rigid_bodies().x(0, b), 0.5, 1e-12);
}

// Redundant rows (the same slider given twice, as two joints on one axis would) drop out by rank.
TEST(JointRows, RedundantRowsAreHarmless) {
  System s;
  const Index b = s.add_rigid_body(body(2.0));
  auto rows = slider_along_x(b);
  const auto twice = slider_along_x(b);
  rows.insert(rows.end(), twice.begin(), twice.end());
  s.rigid_bodies().force.col(b) = Vec3(1.0, 1.0, 1.0);
  s.set_joint_rows(rows);
  for (int i = 0; i < 10; ++i) s.step(0.01);
  EXPECT_TRUE(s.rigid_bodies().v.col(b).allFinite());
  EXPECT_NEAR(s.rigid_bodies().v.col(b).tail<2>().norm(), 0.0, 1e-12);
}

// Without rows, an applied force and torque move a free body as F t / m and change L by tau t.
TEST(AppliedForces, MoveAFreeBodyByImpulse) {
  SystemSettings settings;
  settings.gravity.setZero();
  System s(settings);
  const Index b = s.add_rigid_body(body(2.0));
  s.rigid_bodies().force.col(b) = Vec3(1.0, -2.0, 0.5);
  s.rigid_bodies().torque.col(b) = Vec3(0.0, 0.0, 0.05);
  s.step_settings().cg_tolerance = 1e-14;
  for (int i = 0; i < 10; ++i) s.step(0.1);
  EXPECT_LT((s.rigid_bodies().v.col(b) - Vec3(1.0, -2.0, 0.5) / 2.0).norm(), 1e-12);
  EXPECT_LT((s.rigid_bodies().angular_momentum(b) - Vec3(0, 0, 0.05)).norm(), 1e-12);
}

TEST(JointRows, BadRowsAndForcesAreNamed) {
  System s;
  const Index b = s.add_rigid_body(body(1.0));
  auto message = [&](std::vector<JointRow> rows) {
    try {
      s.set_joint_rows(std::move(rows));
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const Vec6 x = twist_row(Vec3::UnitX(), Vec3::Zero());
  EXPECT_NE(message({{3, x}}).find("body_a = 3 is not a rigid body"), std::string::npos);
  EXPECT_NE(message({{b, x, 5, x}}).find("body_b = 5"), std::string::npos);
  EXPECT_NE(message({{b, x, b, x}}).find("both ends are rigid body 0"), std::string::npos);
  EXPECT_NE(message({{b, Vec6::Zero()}}).find("the Jacobian is zero"), std::string::npos);
  EXPECT_NE(message({{b, x, -1, Vec6::Zero(), std::nan("")}}).find("not finite"), std::string::npos);
  s.rigid_bodies().force.col(b) = Vec3(0, std::nan(""), 0);
  try {
    s.step(0.01);
    ADD_FAILURE() << "a NaN force was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("rigid body 0: applied force"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace sinew
