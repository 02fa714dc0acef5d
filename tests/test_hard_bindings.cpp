// Hard bindings: W, W^T, masses, effective masses and impulses (Sifakis et al. 2007, sections 2, 5).
#include "sinew/embedding.hpp"
#include "sinew/hard_bindings.hpp"
#include "sinew/system.hpp"
#include "test_util.hpp"

#include <gtest/gtest.h>

#include <array>
#include <string>
#include <vector>

namespace sinew {
namespace {

using test::random_rotation;
using test::random_vec3;
using test::uniform;

// A system with free parents and three dynamic rigid bodies, and bound points of every kind:
// segment, triangle, tet, point cloud (k = 6) and rigid frame; one T-junction chain on top, and
// massless points embedded among free particles and one body's frame points (mixed bindings, as a
// fiber's structure particle where its matrix is bound to a body).
struct BoundScene {
  System system{SystemSettings{Vec3::Zero(), true}};
  std::vector<Index> bound;

  BoundScene() {
    const int parents = 16;
    for (int i = 0; i < parents; ++i) system.add_particle(random_vec3(), random_vec3(), uniform(0.5, 2.0));
    for (int b = 0; b < 3; ++b) {
      RigidBodySettings s;
      s.x = random_vec3();
      s.q = random_rotation();
      s.v = random_vec3();
      s.w = random_vec3(3.0);
      s.mass = uniform(1.0, 3.0);
      s.inertia = Vec3(0.2, 0.3, 0.4);
      system.add_rigid_body(s);
    }
    Vectors3 cloud = system.particles().x.leftCols(parents);
    auto add_bound = [&](double mass) {
      const Index p = system.add_particle(random_vec3(), Vec3::Zero(), mass);
      bound.push_back(p);
      return p;
    };
    for (int rep = 0; rep < 3; ++rep) {
      const std::array<Index, 2> seg{0 + rep, 5 + rep};
      const std::array<double, 2> ws{0.3, 0.7};
      system.bind_linear(add_bound(0.1), seg, ws);
      const std::array<Index, 3> tri{1 + rep, 6 + rep, 11 + rep};
      const std::array<double, 3> wt{0.2, 0.5, 0.3};
      system.bind_linear(add_bound(0.2), tri, wt);
      const std::array<Index, 4> tet{2 + rep, 7 + rep, 12 + rep, 15 - rep};
      const std::array<double, 4> wtet{0.1, 0.2, 0.3, 0.4};
      system.bind_linear(add_bound(0.3), tet, wtet);
      const PointCloudEmbedding e = point_cloud_weights(cloud, random_vec3(0.5), 6);
      system.bind_linear(add_bound(0.05), e.parents, e.weights);
      for (int b = 0; b < 3; ++b) system.bind_rigid(add_bound(0.25), b, random_vec3(0.5));
    }
    // T-junction: a point on the segment between a bound point and a free particle.
    const std::array<Index, 2> chain{bound[0], 3};
    const std::array<double, 2> wc{0.5, 0.5};
    system.bind_linear(add_bound(0.15), chain, wc);
    // bound[4 + 7 r + b]: the frame point of repetition r on body b.
    for (int b = 0; b < 3; ++b) {
      const std::array<Index, 4> mixed{bound[4 + b], bound[11 + b], Index(2 + b), Index(9 + b)};
      const std::array<double, 4> wm{0.2, 0.15, 0.4, 0.25};
      system.bind_linear(add_bound(0.0), mixed, wm);
    }
    system.clamp_bound_rows();
  }
};

TEST(HardBindings, DistributionIsTheTransposeOfInterpolation) {
  BoundScene scene;
  System& s = scene.system;
  s.finalize();
  const HardBindings& hard = s.hard_bindings();
  const Index n = s.particles().size();
  for (int trial = 0; trial < 5; ++trial) {
    Vectors3 v = Vectors3::Random(3, n);
    Vectors6 twist = Vectors6::Random(6, s.rigid_bodies().size());
    for (Index p : scene.bound) v.col(p).setZero();
    Vectors3 wv = v;
    hard.clamp_velocities(wv, twist);

    Vectors3 u = Vectors3::Zero(3, n);
    for (Index p : scene.bound) u.col(p) = random_vec3();
    double lhs = 0.0;  // u . (W v) over bound rows
    for (Index p : scene.bound) lhs += u.col(p).dot(wv.col(p));
    Vectors6 wrench = Vectors6::Zero(6, s.rigid_bodies().size());
    Vectors3 wtu = u;
    hard.distribute(wtu, wrench);
    for (Index p : scene.bound) EXPECT_EQ(wtu.col(p).norm(), 0.0) << "W^T must clear bound rows";
    const double rhs = wtu.cwiseProduct(v).sum() + wrench.cwiseProduct(twist).sum();
    EXPECT_NEAR(lhs, rhs, 1e-12 * (std::abs(lhs) + 1.0));
  }
}

TEST(HardBindings, ChainsAreFlattenedSoParentsAreNeverBound) {
  BoundScene scene;
  System& s = scene.system;
  s.finalize();
  const HardBindings& hard = s.hard_bindings();
  EXPECT_EQ(hard.mixed().size(), 3);
  for (Index k = 0; k < hard.linear_count(); ++k) {
    double sum = 0.0;
    for (Index p : hard.linear_parents(k)) EXPECT_FALSE(hard.is_bound(p)) << "binding " << k;
    for (double w : hard.linear_weights(k)) sum += w;
    EXPECT_NEAR(sum, 1.0, 1e-14);
  }
  // The T-junction point is the midpoint of (segment point 0.3 x0 + 0.7 x5) and x3.
  const Index t = scene.bound[scene.bound.size() - 4];
  const Vectors3& x = s.particles().x;
  const Vec3 expected = 0.5 * (0.3 * x.col(0) + 0.7 * x.col(5)) + 0.5 * x.col(3);
  EXPECT_NEAR((x.col(t) - expected).norm(), 0.0, 1e-14);
}

TEST(HardBindings, PointOnRigidPointsBecomesRigidBinding) {
  System s(SystemSettings{Vec3::Zero(), false});
  RigidBodySettings rb;
  rb.q = random_rotation();
  const Index body = s.add_rigid_body(rb);
  const Index a = s.add_particle(Vec3(1, 0, 0), Vec3::Zero(), 0.0);
  const Index b = s.add_particle(Vec3(0, 1, 0), Vec3::Zero(), 0.0);
  const Index c = s.add_particle(Vec3::Zero(), Vec3::Zero(), 0.0);
  s.bind_rigid_here(a, body);
  s.bind_rigid_here(b, body);
  const std::array<Index, 2> parents{a, b};
  const std::array<double, 2> w{0.25, 0.75};
  s.bind_linear(c, parents, w);
  s.finalize();
  EXPECT_EQ(s.hard_bindings().rigid_count(), 3);
  EXPECT_NEAR((s.particles().x.col(c) - Vec3(0.25, 0.75, 0)).norm(), 0.0, 1e-14);
}

// A massless point embedded among free particles and a spinning body's frame points (a mixed
// binding) stays exactly where W puts it while the body turns and the particles fall, also in a
// System moved after set-up; unbinding its frame points turns it back into a point-cloud embedding,
// and a mixed point with mass of its own is refused by name.
TEST(HardBindings, MixedPointsFollowTheirFrameAndParticles) {
  System s(SystemSettings{Vec3(0, -9.81, 0), true});
  RigidBodySettings rb;
  rb.mass = 1.0;
  rb.inertia = Vec3(0.1, 0.2, 0.3);
  rb.v = Vec3(0.3, 0.0, 0.0);
  rb.w = Vec3(0.5, 1.0, 2.0);
  const Index body = s.add_rigid_body(rb);
  const Index a = s.add_particle(Vec3(0.2, 0.0, 0.0), Vec3::Zero(), 0.1);
  const Index b = s.add_particle(Vec3(0.0, 0.2, 0.0), Vec3::Zero(), 0.1);
  const Index c = s.add_particle(Vec3(0.3, 0.3, 0.0), Vec3::Zero(), 0.1);
  const Index d = s.add_particle(Vec3(0.3, 0.0, 0.3), Vec3::Zero(), 0.1);
  s.bind_rigid_here(a, body);
  s.bind_rigid_here(b, body);
  const Index m = s.add_particle(Vec3::Zero(), Vec3::Zero(), 0.0);
  const std::array<Index, 4> parents{a, c, b, d};
  const std::array<double, 4> w{0.3, 0.2, 0.25, 0.25};
  s.bind_linear(m, parents, w);
  s.finalize();
  ASSERT_EQ(s.hard_bindings().mixed().size(), 1);
  System moved = std::move(s);
  for (int n = 0; n < 50; ++n) {
    moved.step(1e-3);
    const Vectors3& x = moved.particles().x;
    const Vec3 expected = 0.3 * x.col(a) + 0.2 * x.col(c) + 0.25 * x.col(b) + 0.25 * x.col(d);
    ASSERT_LT((x.col(m) - expected).norm(), 1e-14) << "step " << n;
    ASSERT_LT(moved.max_hard_binding_drift(), 1e-14) << "step " << n;
  }
  moved.unbind(a);
  moved.finalize();
  EXPECT_EQ(moved.hard_bindings().mixed().size(), 1);  // b is still on the frame
  moved.unbind(b);
  moved.finalize();
  EXPECT_EQ(moved.hard_bindings().mixed().size(), 0);
  EXPECT_GE(moved.hard_bindings().linear_binding_of(m), 0);

  System heavy;
  const Index body2 = heavy.add_rigid_body(rb);
  const Index e = heavy.add_particle(Vec3(0.2, 0.0, 0.0), Vec3::Zero(), 0.1);
  const Index f = heavy.add_particle(Vec3(0.0, 0.2, 0.0), Vec3::Zero(), 0.1);
  heavy.bind_rigid_here(e, body2);
  const Index g = heavy.add_particle(Vec3::Zero(), Vec3::Zero(), 0.5);
  const std::array<Index, 2> pg{e, f};
  const std::array<double, 2> wg{0.5, 0.5};
  heavy.bind_linear(g, pg, wg);
  try {
    heavy.finalize();
    ADD_FAILURE() << "a mixed point with mass was accepted";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("particle " + std::to_string(g) + " has mass"), std::string::npos) << message;
  }
}

TEST(HardBindings, CycleIsRejected) {
  System s;
  const Index a = s.add_particle(Vec3::Zero(), Vec3::Zero(), 1.0);
  const Index b = s.add_particle(Vec3::UnitX(), Vec3::Zero(), 1.0);
  const Index c = s.add_particle(Vec3::UnitY(), Vec3::Zero(), 1.0);
  const std::array<Index, 2> pa{b, c}, pb{a, c};
  const std::array<double, 2> w{0.5, 0.5};
  s.bind_linear(a, pa, w);
  s.bind_linear(b, pb, w);
  EXPECT_THROW(s.finalize(), Error);
}

TEST(HardBindings, MassRedistributionConservesMassAndMomentum) {
  BoundScene scene;
  System& s = scene.system;
  // Before set-up every point carries its own mass and moves with W (bound rows are clamped).
  const Vectors3 x = s.particles().x, v = s.particles().v;
  const VectorXd m_bar = s.input_mass();
  double mass_before = m_bar.sum();
  Vec3 p_before = Vectors3(v * m_bar.asDiagonal()).rowwise().sum();
  Vec3 l_rigid_before = Vec3::Zero();  // rigid bodies with the points fixed in their frames
  const RigidBodyParticles& bodies = s.rigid_bodies();
  for (Index b = 0; b < bodies.size(); ++b) {
    mass_before += bodies.mass[b];
    p_before += bodies.mass[b] * bodies.v.col(b);
    l_rigid_before += bodies.mass[b] * Vec3(bodies.x.col(b)).cross(Vec3(bodies.v.col(b))) + bodies.angular_momentum(b);
  }
  s.finalize();
  const HardBindings& hard = s.hard_bindings();
  for (Index k = 0; k < hard.rigid_count(); ++k) {
    const Index p = hard.rigid_particle(k);
    l_rigid_before += m_bar[p] * Vec3(x.col(p)).cross(Vec3(v.col(p)));
  }
  double mass_after = s.particles().mass.sum();  // bound rows hold 0
  Vec3 l_rigid_after = Vec3::Zero();
  for (Index b = 0; b < bodies.size(); ++b) {
    mass_after += bodies.mass[b];
    l_rigid_after += bodies.mass[b] * Vec3(bodies.x.col(b)).cross(Vec3(bodies.v.col(b))) + bodies.angular_momentum(b);
  }
  EXPECT_NEAR(mass_after, mass_before, 1e-12 * mass_before);
  // P = m_bar^T W v = (W^T m_bar)^T v: lumping conserves linear momentum exactly.
  EXPECT_NEAR((s.linear_momentum() - p_before).norm(), 0.0, 1e-12 * p_before.norm());
  // Points merged into rigid bodies (parallel-axis theorem) keep angular momentum too. (Lumping onto
  // particles does not: x_e x v_e is not sum_i w_i x_i x v_i, a property of lumped masses.)
  EXPECT_NEAR((l_rigid_after - l_rigid_before).norm(), 0.0, 1e-12 * l_rigid_before.norm());
  EXPECT_LT(s.max_hard_binding_drift(), 1e-14);
}

TEST(HardBindings, ImpulseChangesBoundVelocityByImpulseOverEffectiveMass) {
  BoundScene scene;
  System& s = scene.system;
  s.finalize();
  for (Index p : scene.bound) {
    const Vec3 j = random_vec3();
    const Vec3 before = s.particles().v.col(p);
    s.apply_impulse(p, j);
    const Vec3 dv = s.particles().v.col(p) - before;
    const MixedBindings& mixed = s.hard_bindings().mixed();
    bool on_frame = s.hard_bindings().on_rigid_frame(p);
    for (Index k = 0; k < mixed.size(); ++k) on_frame = on_frame || mixed.particle(k) == p;
    if (!on_frame) {
      // eq. 4: a linear bound point's velocity changes by j / m_e exactly.
      EXPECT_NEAR((dv - j / s.effective_mass(p)).norm(), 0.0, 1e-12 * dv.norm()) << "particle " << p;
    } else {
      // A rigid frame responds through its impulse matrix K: along j the effective mass is
      // 1 / (j^ K j^), and the isotropic bound m_e = 1/lambda_max(K) bounds the response (a mixed
      // point: sum_F w_i^2 / m_i plus w_B^2 K, the same way).
      const Vec3 n = j.normalized();
      EXPECT_NEAR(n.dot(dv), j.norm() / s.effective_mass_along(p, n), 1e-12 * dv.norm()) << "particle " << p;
      EXPECT_LE(dv.norm(), j.norm() / s.effective_mass(p) * (1 + 1e-12));
    }
  }
}

TEST(RigidBinding, VelocityIsTheDerivativeOfPositionAndWrenchIsRxF) {
  RigidBodyParticles bodies;
  RigidBodySettings rb;
  rb.x = random_vec3();
  rb.q = random_rotation();
  add_rigid_body(bodies, rb);
  HardBindings hard;
  const Vec3 r0 = random_vec3();
  hard.add_rigid(0, 0, r0);
  hard.flatten(1, 1);
  const Vec3 v = random_vec3(), w = random_vec3();
  auto position = [&](double eps) {
    RigidBodyParticles moved = bodies;
    moved.x.col(0) += eps * v;
    moved.q[0] = rotation_from_vector(eps * w) * moved.q[0];
    hard.update_rigid_offsets(moved);
    Vectors3 x = Vectors3::Zero(3, 1);
    hard.clamp_positions(x, moved.x);
    return Vec3(x.col(0));
  };
  const double eps = 1e-6;
  const Vec3 fd = (position(eps) - position(-eps)) / (2 * eps);
  hard.update_rigid_offsets(bodies);
  Vectors3 ve = Vectors3::Zero(3, 1);
  Vectors6 twist(6, 1);
  twist << v, w;
  hard.clamp_velocities(ve, twist);  // W(q) (v_c, w)
  EXPECT_NEAR((fd - ve.col(0)).norm(), 0.0, 1e-8 * fd.norm());

  Vectors3 f(3, 1);
  f.col(0) = random_vec3();
  Vectors6 wrench = Vectors6::Zero(6, 1);
  hard.distribute(f, wrench);
  const Vec3 r = bodies.q[0] * r0;
  const Vec3 force = wrench.col(0).head<3>(), torque = wrench.col(0).tail<3>();
  EXPECT_NEAR((torque - r.cross(force)).norm(), 0.0, 1e-14 * torque.norm() + 1e-15);
}

TEST(Embedding, PointCloudWeightsArePartitionOfUnityWithLinearPrecision) {
  Vectors3 cloud = Vectors3::Random(3, 40);
  for (int trial = 0; trial < 10; ++trial) {
    const Vec3 p = random_vec3(0.5);
    const PointCloudEmbedding e = point_cloud_weights(cloud, p, 8);
    double sum = 0.0;
    Vec3 reproduced = Vec3::Zero();
    for (std::size_t i = 0; i < e.parents.size(); ++i) {
      sum += e.weights[i];
      reproduced += e.weights[i] * cloud.col(e.parents[i]);
    }
    EXPECT_NEAR(sum, 1.0, 1e-14);
    EXPECT_NEAR((reproduced - p).norm(), 0.0, 1e-12);
  }
}

TEST(Embedding, BarycentricWeightsReproduceThePoint) {
  const Vec3 a = random_vec3(), b = random_vec3(), c = random_vec3(), d = random_vec3();
  const Vec3 p = 0.1 * a + 0.2 * b + 0.3 * c + 0.4 * d;
  const auto w = tet_weights(a, b, c, d, p);
  EXPECT_NEAR((w[0] * a + w[1] * b + w[2] * c + w[3] * d - p).norm(), 0.0, 1e-13);
  const Vec3 q = 0.2 * a + 0.3 * b + 0.5 * c;
  const auto wt = triangle_weights(a, b, c, q);
  EXPECT_NEAR((wt[0] * a + wt[1] * b + wt[2] * c - q).norm(), 0.0, 1e-13);
  EXPECT_THROW(tet_weights(a, b, c, 0.5 * (a + b), p), Error);
}

}  // namespace
}  // namespace sinew
