// Bullet 3.24's two cloth-to-rigid couplings on the benchmark curtain: the scene is the spec's, each
// peer behaves as its model says (including its documented defects), and the curtain's shared geometry.
#include "bullet_peers.hpp"
#include "curtain_bench.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>

namespace sinew::bench {
namespace {

constexpr double kFrame = 1.0 / 60.0;
constexpr int kSteps = 4;

CurtainSpec curtain(int n) {
  CurtainSpec spec;
  spec.n = n;
  return spec;
}

// ---- the curtain's geometry ---------------------------------------------------------------------

TEST(CurtainBench, BoundNodesOnePerRingAtTheNearestNode) {
  const CurtainSpec spec = curtain(20);
  const auto bound = bound_nodes(spec);
  ASSERT_EQ(bound.size(), 10u);
  const double dx = spec.size / (spec.n - 1);
  std::set<int> nodes;
  for (std::size_t k = 0; k < bound.size(); ++k) {
    const auto [i, ring] = bound[k];
    EXPECT_EQ(ring, static_cast<int>(k)) << "each ring has exactly one node";
    nodes.insert(i);
    // The nearest top-row node is within half a spacing of the ring's centre.
    EXPECT_LE(std::abs(node_rest_position(spec, i, 0).x() - ring_rest_centre(spec, ring).x()), 0.5 * dx + 1e-12)
        << "ring " << ring;
  }
  EXPECT_EQ(nodes.size(), 10u) << "no node is bound twice";
  EXPECT_EQ(bound.front().first, 0);
  EXPECT_EQ(bound.back().first, spec.n - 1);
}

TEST(CurtainBench, BindAllBindsEveryTopNodeAndUsesEveryRing) {
  for (int n : {10, 20, 37, 40}) {
    CurtainSpec spec = curtain(n);
    spec.bind_all = true;
    const auto bound = bound_nodes(spec);
    ASSERT_EQ(static_cast<int>(bound.size()), n);
    std::set<int> rings;
    for (int i = 0; i < n; ++i) {
      EXPECT_EQ(bound[static_cast<std::size_t>(i)].first, i);
      const int ring = bound[static_cast<std::size_t>(i)].second;
      EXPECT_EQ(ring, static_cast<int>(std::lround(i * (spec.rings - 1.0) / (n - 1)))) << "n " << n << " node " << i;
      rings.insert(ring);
    }
    EXPECT_EQ(static_cast<int>(rings.size()), spec.rings) << "n " << n << ": every ring carries a node";
  }
}

TEST(CurtainBench, BadSpecsAreNamed) {
  CurtainSpec spec = curtain(8);
  spec.rings = 9;
  EXPECT_THROW(bound_nodes(spec), Error);
  spec = curtain(8);
  spec.rings = 4;
  spec.ring_mass = 0.0;
  try {
    validate(spec);
    FAIL() << "a massless ring was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("ring_mass"), std::string::npos) << e.what();
  }
}

// ---- both peers build the spec's scene ----------------------------------------------------------

// Positions start exactly at the spec's rest positions in the interface's numbering (the patch's own
// numbering and mirroring are hidden), every binding starts satisfied, and the masses add up: momentum
// along the rod is (cloth + rings) times the initial slide.
TEST(BulletPeers, StartFromTheSpecsState) {
  for (int n : {10, 11}) {
    const CurtainSpec spec = curtain(n);
    const double total_mass = spec.cloth_mass + spec.rings * spec.ring_mass;
    std::unique_ptr<CurtainRun> runs[] = {make_classic_curtain(spec), make_deformable_curtain(spec)};
    for (const auto& r : runs) {
      const Vectors3 x = r->nodes();
      ASSERT_EQ(x.cols(), n * n);
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
          EXPECT_EQ(x.col(j * n + i), node_rest_position(spec, i, j)) << r->system() << " node " << i << ", " << j;
      const AttachmentError e = r->attachment();
      EXPECT_EQ(e.bound_node, 0.0) << r->system();
      EXPECT_EQ(e.ring_joint, 0.0) << r->system();
      EXPECT_NEAR(r->momentum_along_rod(), total_mass * spec.initial_velocity.x(), 1e-14) << r->system();
      EXPECT_TRUE(r->healthy());
      EXPECT_EQ(r->mismatch().find("odd n") != std::string::npos, n % 2 == 1) << r->system() << ": " << r->mismatch();
    }
  }
}

// ---- classic ------------------------------------------------------------------------------------

// Every exchange in the classic step is an equal and opposite pair: a link moves its two nodes by
// mass-weighted amounts, an anchor moves its node by J/m and gives the ring -J, and v = (x - q)/h turns
// those moves into momentum one for one (kDP = 0). The slider has no row along the rod and gravity is
// along -y, so momentum along x changes only by rounding: 1e-12 kg m/s is about 2000 ulps of the 0.2 kg m/s total.
TEST(BulletClassic, CurtainHangsWithMillimetreAnchorDriftAndConservesMomentumAlongTheRod) {
  const CurtainSpec spec = curtain(20);
  auto classic = make_classic_curtain(spec);
  const double p0 = classic->momentum_along_rod();
  double worst_drift = 0.0, worst_momentum = 0.0;
  for (int f = 0; f < 60; ++f) {
    classic->advance(kFrame, kSteps);
    ASSERT_TRUE(classic->healthy()) << "frame " << f + 1;
    const AttachmentError e = classic->attachment();
    EXPECT_EQ(e.bound_node_before_overwrite, e.bound_node) << "the classic world overwrites nothing";
    worst_drift = std::max(worst_drift, e.bound_node);
    worst_momentum = std::max(worst_momentum, std::abs(classic->momentum_along_rod() - p0));
  }
  const AttachmentError e = classic->attachment();
  // The anchor is a projection swept before the links, which then pull the node off again: a real,
  // positive residual every step, millimetres at this resolution.
  EXPECT_GT(e.bound_node, 0.0);
  EXPECT_LT(worst_drift, 0.05);
  EXPECT_LT(e.ring_joint, 1e-3);
  EXPECT_LT(worst_momentum, 1e-12);
  std::cout << "classic 20x20: bound node " << e.bound_node << " m (max " << worst_drift << " m), ring joint "
            << e.ring_joint << " m, momentum change " << worst_momentum << " kg m/s, energy " << classic->energy()
            << " J\n";
}

// ---- deformable ---------------------------------------------------------------------------------

// Implicit + projection, the path Bullet's implicit demos use: the run stays healthy, the anchored
// nodes sit exactly on their pivots after each step (Bullet writes them there), and the error that
// overwrite hides, measured inside applyTransforms, is small but not zero: the anchor is a velocity
// constraint solved by 10 PGS sweeps, so a node's end-of-step position misses its pivot by the residual
// velocity times h (micrometres; 0.1 mm would mean the anchor impulses no longer hold the node).
TEST(BulletDeformable, ImplicitProjectedCurtainHasItsAnchorsOverwritten) {
  CurtainSpec spec = curtain(20);
  spec.stretch_stiffness = 200.0;
  auto deformable = make_deformable_curtain(spec);
  double worst_before = 0.0;
  for (int f = 0; f < 60; ++f) {
    deformable->advance(kFrame, kSteps);
    ASSERT_TRUE(deformable->healthy()) << "frame " << f + 1;
    const AttachmentError e = deformable->attachment();
    EXPECT_EQ(e.bound_node, 0.0) << "frame " << f + 1 << ": anchored nodes are overwritten onto their pivots";
    worst_before = std::max(worst_before, e.bound_node_before_overwrite);
  }
  const AttachmentError e = deformable->attachment();
  EXPECT_GT(e.bound_node_before_overwrite, 0.0);
  EXPECT_LT(worst_before, 1e-4);
  std::cout << "deformable 20x20 k=200: before overwrite " << e.bound_node_before_overwrite << " m (max "
            << worst_before << " m), ring joint " << e.ring_joint << " m, momentum " << deformable->momentum_along_rod()
            << " kg m/s, energy " << deformable->energy() << " J\n";
}

// Known defect of the peer, asserted so that a Bullet that fixes it shows up here: with setImplicit(true)
// and without setUseProjection(true), btDeformableBodySolver builds no KKT preconditioner on the implicit
// path, the conjugate-residual solve sees a zero preconditioned residual and returns dv = 0, and every
// force, gravity included, is dropped without an error. Started at rest, the sheet does not fall. The
// same sheet with projection on is the control: it sags under its own weight, its bottom row moving by
// about a centimetre in the same half second.
TEST(BulletDeformable, KnownDefectImplicitWithoutProjectionDropsEveryForce) {
  CurtainSpec spec = curtain(20);
  spec.initial_velocity = Vec3::Zero();
  DeformableSettings broken;
  broken.implicit = true;
  broken.use_projection = false;
  auto bottom_row_motion = [&](const DeformableSettings& settings) {
    auto r = make_deformable_curtain(spec, settings);
    const Vectors3 x0 = r->nodes();
    for (int f = 0; f < 30; ++f) r->advance(kFrame, kSteps);
    EXPECT_TRUE(r->healthy());
    // The bottom row (j = n - 1) is the last n columns.
    return (r->nodes().rightCols(spec.n) - x0.rightCols(spec.n)).colwise().norm().maxCoeff();
  };
  const double dropped = bottom_row_motion(broken);
  EXPECT_LT(dropped, 1e-3) << "the forces are no longer dropped: Bullet fixed the implicit path without projection";
  const double control = bottom_row_motion(DeformableSettings{});
  EXPECT_GT(control, 5e-3) << "with projection the sheet sags";
  std::cout << "deformable without projection: bottom row moved " << dropped << " m (with projection " << control
            << " m)\n";
}

}  // namespace
}  // namespace sinew::bench
