// Soft bindings (Sifakis et al. 2007, section 3): force mapping, masses, synchronisation and drift.
#include "sinew/system.hpp"
#include "test_forces_local.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <array>

namespace sinew {
namespace {

const SystemSettings kNoGravity{Vec3::Zero(), true};

enum class TargetKind { free, segment_point, rigid_point };

// A soft particle spring-bound to a target in free fall must fall at g: it gets m_s a_target from the
// mapping and no gravity of its own (twice g would stretch the spring by ~ m g / k).
TEST(SoftBinding, FallsAtGNotTwiceG) {
  for (TargetKind kind : {TargetKind::free, TargetKind::segment_point, TargetKind::rigid_point}) {
    System s;
    Index target = -1;
    const Vec3 start(0.3, 2.0, -0.1);
    if (kind == TargetKind::free) {
      target = s.add_particle(start, Vec3::Zero(), 0.7);
    } else if (kind == TargetKind::segment_point) {
      const Index a = s.add_particle(start - Vec3(0.5, 0, 0), Vec3::Zero(), 1.0);
      const Index b = s.add_particle(start + Vec3(1.0, 0, 0), Vec3::Zero(), 3.0);
      target = s.add_particle(start, Vec3::Zero(), 0.0);
      const std::array<Index, 2> parents{a, b};
      const std::array<double, 2> w{2.0 / 3.0, 1.0 / 3.0};
      s.bind_linear(target, parents, w);
    } else {
      RigidBodySettings rb;
      rb.x = start + Vec3(0, 0.2, 0.4);
      rb.q = test::random_rotation();
      rb.inertia = Vec3(0.3, 0.4, 0.5);
      const Index body = s.add_rigid_body(rb);
      target = s.add_particle(start, Vec3::Zero(), 0.0);
      s.bind_rigid_here(target, body);
    }
    const Index soft = s.add_particle(start, Vec3::Zero(), 0.0);
    s.add_soft_binding({soft, target, SoftCoupling::spring, 1e4, 1.0, 0.0});
    const double dt = 1.0 / 60;
    double stretch = 0.0;
    for (int i = 0; i < 60; ++i) {
      s.step(dt);
      stretch = std::max(stretch, s.binding_springs().max_stretch(s.particles().x));
    }
    const Vec3 expected = start + 0.5 * s.settings().gravity;  // t = 1 s
    EXPECT_NEAR((s.particles().x.col(soft) - expected).norm(), 0.0, 1e-10) << "target kind " << static_cast<int>(kind);
    EXPECT_NEAR((s.particles().x.col(target) - expected).norm(), 0.0, 1e-10);
    // Round-off only: in free fall step 1's extrapolated guess is exact, so CG stops at once and the
    // rounding of each step's guess is carried into the next (about 1e-14 m per step here).
    EXPECT_LT(stretch, 1e-11) << "target kind " << static_cast<int>(kind);
    EXPECT_GT(s.particles().mass[soft], 0.0);
  }
}

TEST(SoftBinding, MassIsTheTargetsEffectiveMass) {
  System s(kNoGravity);
  const Index a = s.add_particle(Vec3::Zero(), Vec3::Zero(), 1.0);
  const Index b = s.add_particle(Vec3::UnitX(), Vec3::Zero(), 4.0);
  const Index t = s.add_particle(Vec3(0.25, 0, 0), Vec3::Zero(), 0.0);
  const std::array<Index, 2> parents{a, b};
  const std::array<double, 2> w{0.75, 0.25};
  s.bind_linear(t, parents, w);
  const Index soft = s.add_particle(Vec3(0.25, 0, 0), Vec3::Zero(), 0.0);
  s.add_soft_binding({soft, t, SoftCoupling::spring, 1e3, 1.0, 0.0});
  s.finalize();
  const double m_e = 1.0 / (0.75 * 0.75 / 1.0 + 0.25 * 0.25 / 4.0);  // eq. 4
  EXPECT_NEAR(s.particles().mass[soft], m_e, 1e-14);
  // Critical damping from the reduced effective mass of the two ends, mu = m_e / 2.
  EXPECT_NEAR(s.binding_springs().damping(0), 2.0 * std::sqrt(1e3 * m_e / 2), 1e-10);
}

// Mapping elastic forces makes the soft particle follow its target without lag (section 3): on an
// undamped oscillating target the binding spring never stretches.
TEST(SoftBinding, InheritsElasticAccelerationWithoutLag) {
  System s(kNoGravity);
  const Index t = s.add_particle(Vec3(1, 0, 0), Vec3(0, 0.5, 0), 2.0);
  s.add_force(std::make_unique<test::AnchorSprings>(std::vector<Index>{t}, Vectors3::Zero(3, 1), 50.0, 0.0));
  const Index soft = s.add_particle(Vec3(1, 0, 0), Vec3(0, 0.5, 0), 0.0);
  s.add_soft_binding({soft, t, SoftCoupling::spring, 10.0, 1.0, 0.0});
  double stretch = 0.0;
  for (int i = 0; i < 500; ++i) {
    s.step(1e-2);
    stretch = std::max(stretch, s.binding_springs().max_stretch(s.particles().x));
  }
  EXPECT_LT(stretch, 1e-12);
  EXPECT_GT(s.particles().x.col(t).norm(), 0.1);  // it did move
}

// Section 3.1: drift given to a synchronized soft particle in the collision phase moves its target
// by the same amount and adds the momentum m_e dv, shared by the parents as w_i m_e / m_i.
TEST(SoftBinding, SynchronizedDriftIsPushedToParents) {
  for (bool rigid : {false, true}) {
    System s(kNoGravity);
    Index t;
    if (!rigid) {
      const Index a = s.add_particle(Vec3::Zero(), Vec3::Zero(), 1.0);
      const Index b = s.add_particle(Vec3::UnitX(), Vec3::Zero(), 3.0);
      t = s.add_particle(Vec3(0.4, 0, 0), Vec3::Zero(), 0.0);
      const std::array<Index, 2> parents{a, b};
      const std::array<double, 2> w{0.6, 0.4};
      s.bind_linear(t, parents, w);
    } else {
      RigidBodySettings rb;
      rb.mass = 2.0;
      rb.inertia = Vec3(0.2, 0.3, 0.4);
      rb.q = test::random_rotation();
      const Index body = s.add_rigid_body(rb);
      t = s.add_particle(Vec3(0.3, 0.2, 0.1), Vec3::Zero(), 0.0);
      s.bind_rigid_here(t, body);
    }
    const Index soft = s.add_particle(s.particles().x.col(t), Vec3::Zero(), 0.0);
    s.add_soft_binding({soft, t, SoftCoupling::synchronized, 0.0, 0.0, 0.0});
    const Vec3 dx(1e-6, -2e-6, 0.5e-6), dv(0.01, 0.02, -0.03);
    s.add_collision_source(make_collision_source("drift", [&](CollisionContext& c) {
      c.x->col(soft) += dx;
      c.v->col(soft) += dv;
    }));
    s.finalize();
    const Vec3 before = s.particles().x.col(t);
    const double m_e = s.effective_mass_along(t, dv.normalized());
    s.step(0.01);
    const Vec3 moved = s.particles().x.col(t) - before;
    const Vec3 target_v = s.particles().v.col(t);
    const std::string label = rigid ? "rigid" : "linear";
    // The impulse m_e dv is the momentum added, exactly.
    EXPECT_NEAR((s.linear_momentum() - m_e * dv).norm(), 0.0, 1e-14) << label;
    if (!rigid) {
      // dx_i = w_i (m_e/m_i) dx moves the embedded point by sum_i w_i^2 m_e/m_i dx = dx.
      EXPECT_NEAR((moved - dx).norm(), 0.0, 1e-15) << label;
      EXPECT_NEAR((target_v - dv).norm(), 0.0, 1e-15) << label;
    } else {
      // A rigid frame answers through its anisotropic impulse matrix: along the drift it moves by the
      // drift (to first order in the rotation), across it by whatever K couples in.
      EXPECT_NEAR(dx.normalized().dot(moved), dx.norm(), 1e-10) << label;
      EXPECT_NEAR(dv.normalized().dot(target_v), dv.norm(), 1e-6 * dv.norm()) << label;
    }
    EXPECT_EQ(s.particles().x.col(soft), s.particles().x.col(t));  // re-synchronized
  }
}

TEST(SoftBinding, KinematicTargetNeedsAnExplicitMass) {
  System s;
  const Index t = s.add_kinematic_particle(Vec3::Zero());
  const Index soft = s.add_particle(Vec3::Zero(), Vec3::Zero(), 0.0);
  s.add_soft_binding({soft, t, SoftCoupling::spring, 1e3, 1.0, 0.0});
  try {
    s.finalize();
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("soft binding 0"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace sinew
