// Rigid bodies joined by binding springs (figure 13's point joints): chains of rods hung from a
// kinematic point, released horizontal, at one step per frame. Checked against what cannot fail: the
// visible energy (kinetic + gravity) of a passive chain never rises above its start, a joint's
// stretch is what its tension over k allows, and the trajectory converges to a fine-step reference.
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <tuple>
#include <vector>

namespace sinew {
namespace {

constexpr double kLength = 0.1;  // each rod [m]
constexpr double kG = 9.81;

struct ChainSettings {
  int links = 1;
  double stiffness = 1e9;
  double inertia = 8.7e-5;  // of the light rods [kg m^2]; the heavy ones have ratio times it
  double mass_ratio = 1.0;  // odd links are this much heavier than even ones (0.1 kg)
  double dt = 1.0 / 60;
};

struct ChainRun {
  double worst_gain = -kInfinity;  // max over the steps of E_visible - E_visible(0) [J]
  double worst_gap = 0.0;          // largest joint stretch [m]
  double energy_scale = 0.0;       // sum of m g L over the links [J]
  double gap_allowance = 0.0;      // 1 mm, or what the chain's weight stretches the softest joint by
  bool converged = true;
  std::vector<double> angles;  // of the first rod, per step
};

double link_mass(int i, const ChainSettings& c) { return i % 2 == 0 ? 0.1 : 0.1 * c.mass_ratio; }

ChainRun run_chain(const ChainSettings& c, int steps) {
  System s;
  // A spring of stiffness k turns a velocity error e into a force of about k dt e; the tolerance
  // keeps that well below the lightest link's weight (never looser than the default).
  s.step_settings().cg_tolerance = std::clamp(1e-2 * 0.1 * kG / (c.stiffness * c.dt), 1e-13, 1e-9);
  std::vector<Index> bodies;
  Index previous = s.add_kinematic_particle(Vec3::Zero());
  ChainRun run;
  double total_weight = 0.0;
  for (int i = 0; i < c.links; ++i) {
    RigidBodySettings rod;
    rod.mass = link_mass(i, c);
    const double I = i % 2 == 0 ? c.inertia : c.inertia * c.mass_ratio;
    rod.inertia = Vec3(0.5 * I, I, I);
    rod.x = Vec3((i + 0.5) * kLength, 0, 0);
    const Index b = s.add_rigid_body(rod);
    bodies.push_back(b);
    const Index start = s.add_particle(Vec3(i * kLength, 0, 0), Vec3::Zero(), 0.0);
    s.bind_rigid(start, b, Vec3(-0.5 * kLength, 0, 0));
    s.add_binding_spring({previous, start, c.stiffness, 1.0});
    previous = s.add_particle(Vec3((i + 1) * kLength, 0, 0), Vec3::Zero(), 0.0);
    s.bind_rigid(previous, b, Vec3(0.5 * kLength, 0, 0));
    run.energy_scale += rod.mass * kG * kLength * (i + 1);
    total_weight += rod.mass * kG;
  }
  // The first joint carries the whole chain: statically its weight, swinging a few times that.
  run.gap_allowance = std::max(1e-3, 5.0 * total_weight / c.stiffness);
  auto visible_energy = [&] {
    const RigidBodyParticles& B = s.rigid_bodies();
    double e = 0.0;
    for (Index b : bodies)
      e += 0.5 * B.mass[b] * B.v.col(b).squaredNorm() + 0.5 * B.w.col(b).dot(B.angular_momentum(b)) +
           B.mass[b] * kG * B.x(1, b);
    return e;
  };
  const double start_energy = visible_energy();
  for (int i = 0; i < steps; ++i) {
    const StepStats stats = s.step(c.dt);
    run.converged = run.converged && stats.cg_converged;
    run.worst_gain = std::max(run.worst_gain, visible_energy() - start_energy);
    run.worst_gap = std::max(run.worst_gap, s.binding_springs().max_stretch(s.particles().x));
    const Vec3 x = s.rigid_bodies().x.col(bodies[0]);
    run.angles.push_back(std::atan2(-x.y(), x.x()));
  }
  return run;
}

std::string describe(const ChainSettings& c) {
  return std::to_string(c.links) + " links, k " + std::to_string(c.stiffness) + ", I " + std::to_string(c.inertia) +
         ", mass ratio " + std::to_string(c.mass_ratio) + ", dt " + std::to_string(c.dt);
}

void expect_holds(const ChainSettings& c, const ChainRun& run) {
  // A trace is allowed (the largest seen: 4e-5 of m g L, a double pendulum of 1e-6 kg m^2 rods on
  // 1e6 N/m at 1/60 s, whose source is not pinned down); anything of the order of the motion is a gain.
  EXPECT_LE(run.worst_gain, 1e-4 * run.energy_scale) << describe(c);
  EXPECT_LE(run.worst_gap, run.gap_allowance) << describe(c);
}

// k x inertia x mass ratio x dt on a double pendulum (the two rods of the given mass ratio), one second.
class PointJointSweep : public ::testing::TestWithParam<std::tuple<double, double, double, double>> {};

TEST_P(PointJointSweep, StaysBoundedWithoutGainingEnergy) {
  const auto [k, inertia, ratio, dt] = GetParam();
  const ChainSettings c{2, k, inertia, ratio, dt};
  expect_holds(c, run_chain(c, static_cast<int>(std::lround(1.0 / dt))));
}

INSTANTIATE_TEST_SUITE_P(KInertiaMassRatioStep, PointJointSweep,
                         ::testing::Combine(::testing::Values(1e3, 1e6, 1e9, 1e12), ::testing::Values(1e-6, 1e-3, 1.0),
                                            ::testing::Values(1.0, 1000.0), ::testing::Values(1.0 / 60, 1.0 / 240)));

// The chain: 20 capsule-like rods, released horizontal, one 1/60 s step per frame for a second.
class TwentyLinkChain : public ::testing::TestWithParam<std::tuple<double, double>> {};

TEST_P(TwentyLinkChain, StaysBoundedWithoutGainingEnergy) {
  const auto [k, ratio] = GetParam();
  const ChainSettings c{20, k, 8.7e-5, ratio, 1.0 / 60};
  expect_holds(c, run_chain(c, 60));
}

INSTANTIATE_TEST_SUITE_P(StiffnessAndMassRatio, TwentyLinkChain,
                         ::testing::Combine(::testing::Values(1e3, 1e9, 1e12), ::testing::Values(1.0, 1000.0)));

// A stiff pendulum (a 0.1 kg rod on 1e9 N/m, which used to gain 1e244 times its energy in 600 steps)
// against a converged reference: the rod's angle after half a second at 1/60, 1/120 and 1/240 s
// steps, against 1/3840 s; the error falls with the step.
TEST(PointJoint, StiffPendulumConvergesToAFineStepReference) {
  auto angle_at = [](double dt) {
    const ChainSettings c{1, 1e9, 8.7e-5, 1.0, dt};
    const ChainRun run = run_chain(c, static_cast<int>(std::lround(0.5 / dt)));
    return run.angles.back();
  };
  const double reference = angle_at(1.0 / 3840);
  double last = kInfinity;
  for (double dt : {1.0 / 60, 1.0 / 120, 1.0 / 240}) {
    const double error = std::abs(angle_at(dt) - reference);
    EXPECT_LT(error, 0.75 * last) << "dt " << dt;
    last = error;
  }
  EXPECT_LT(last, 0.05) << "rad at 1/240 s";
}

}  // namespace
}  // namespace sinew
