// Elastic fibers (ElasticRods: Liu et al. 2012, section 4.1, as discrete rods parameterised by EA and
// EI). The generic checks (finite-difference gradient and differential, symmetry, zero net force and
// torque, rigid invariance, zero force at a curved rest shape, stable step) run in test_forces'
// EveryForce suite; here the fiber alone against beam theory, its independence of the resolution,
// and a curved hinge swept through straight.
#include "sinew/forces/elastic_rods.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <vector>

namespace sinew {
namespace {

// A straight fiber of n particles along x, spacing s = L / (n - 1.5), x_i = (i - 1/2) s: particles 0
// and 1 are clamped. The hinge at x_1 bends over the half-edges around it, so the beam it models is
// clamped at the clamped edge's middle, x = 0, and the free span is L. Returns the static
// displacement under per-particle loads (one Newton step from rest on the assembled differential:
// the loads are small enough to stay linear).
Vectors3 solve_clamped(const ElasticRods& rods_in, const Vectors3& rest, const Vectors3& load) {
  ElasticRods rods = rods_in;
  rods.update_position_state(rest);
  const Index n = rest.cols(), m = 3 * (n - 2);
  Eigen::MatrixXd K(m, m);
  Vectors3 dx = Vectors3::Zero(3, n), df(3, n);
  for (Index c = 0; c < m; ++c) {
    dx.data()[6 + c] = 1.0;
    df.setZero();
    rods.add_elastic_differentials(dx, df);
    dx.data()[6 + c] = 0.0;
    for (Index r = 0; r < m; ++r) K(r, c) = -df.data()[6 + r];
  }
  const Eigen::VectorXd b = Eigen::Map<const Eigen::VectorXd>(load.data() + 6, m);
  const Eigen::VectorXd u = K.ldlt().solve(b);
  Vectors3 displacement = Vectors3::Zero(3, n);
  Eigen::Map<Eigen::VectorXd>(displacement.data() + 6, m) = u;
  return displacement;
}

Vectors3 straight(Index n, double L) {
  const double s = L / (double(n) - 1.5);
  Vectors3 x = Vectors3::Zero(3, n);
  for (Index i = 0; i < n; ++i) x(0, i) = (double(i) - 0.5) * s;
  return x;
}

std::vector<std::vector<Index>> one_fiber(Index n) {
  std::vector<Index> line;
  for (Index i = 0; i < n; ++i) line.push_back(i);
  return {line};
}

// A clamped cantilever under its own weight q per length bends its tip by q L^4 / (8 EI), and pulled
// by F at its tip lengthens by F L / EA (L the stretching span): within 2% and 1% with 30 particles,
// whatever the number of particles (EA and EI are the material's, not per segment): 60 particles
// give the same deflection to 1%.
TEST(ElasticRods, ACantileverBendsAndStretchesAsBeamTheorySays) {
  const double L = 0.3, EA = 200.0, EI = 2e-3, q = 0.5, F = 0.2;
  double deflections[2], elongations[2], spans[2];
  int run = 0;
  for (const Index n : {Index(30), Index(60)}) {
    const Vectors3 rest = straight(n, L);
    const ElasticRods rods(one_fiber(n), rest, {.stretch_stiffness = EA, .bending_stiffness = EI});
    const double s = L / (double(n) - 1.5);
    Vectors3 weight = Vectors3::Zero(3, n);
    for (Index i = 2; i < n; ++i) weight(1, i) = -q * s * (i == n - 1 ? 0.5 : 1.0);
    weight(1, 1) = 0.0;
    deflections[run] = -solve_clamped(rods, rest, weight)(1, n - 1);
    Vectors3 pull = Vectors3::Zero(3, n);
    pull(0, n - 1) = F;
    elongations[run] = solve_clamped(rods, rest, pull)(0, n - 1);
    spans[run] = L - 0.5 * s;  // the stretching edges run from the clamped x_1 to the tip
    ++run;
  }
  const double beam = q * std::pow(L, 4) / (8.0 * EI), axial = F * spans[0] / EA;
  std::printf("tip deflection %.6g and %.6g against %.6g; elongation %.6g and %.6g against %.6g\n", deflections[0],
              deflections[1], beam, elongations[0], elongations[1], axial);
  EXPECT_NEAR(deflections[0], beam, 0.02 * beam);
  EXPECT_NEAR(elongations[0], axial, 0.01 * axial);
  EXPECT_NEAR(deflections[1], deflections[0], 0.01 * deflections[0]);
  EXPECT_NEAR(elongations[1], F * spans[1] / EA, 0.01 * F * spans[1] / EA);
}

// A hinge whose rest shape turns by 0.4 rad, its last particle swept through the straight line and
// beyond: energy and forces stay finite and bounded (the cone at straight gives no force there, the
// direction of the turn being undefined), the energy is EI (psi - psibar)^2 / Lbar, smallest at the
// rest turn on either side.
TEST(ElasticRods, ACurvedHingeSweptThroughStraightStaysFinite) {
  const double angle = 0.4, EI = 1e-3;
  Vectors3 rest(3, 3);
  rest.col(0) = Vec3(-0.1, 0, 0);
  rest.col(1) = Vec3::Zero();
  rest.col(2) = 0.1 * Vec3(std::cos(angle), std::sin(angle), 0);
  const ElasticRods rods(one_fiber(3), rest, {.stretch_stiffness = 10.0, .bending_stiffness = EI});
  const double psibar = 2.0 * std::tan(angle / 2.0);
  double largest = 0.0;
  for (int k = -100; k <= 100; ++k) {
    const double turn = 0.8 * k / 100.0;  // -0.8 .. 0.8 rad, through 0
    Vectors3 x = rest;
    x.col(2) = 0.1 * Vec3(std::cos(turn), std::sin(turn), 0);
    Vectors3 f = Vectors3::Zero(3, 3);
    rods.add_elastic_forces(x, f);
    ASSERT_TRUE(f.allFinite()) << turn;
    largest = std::max(largest, f.cwiseAbs().maxCoeff());
    const double psi = 2.0 * std::tan(std::abs(turn) / 2.0);
    EXPECT_NEAR(rods.potential_energy(x), EI * (psi - psibar) * (psi - psibar) / 0.2, 1e-12) << turn;
  }
  EXPECT_LT(largest, 10.0 * EI * psibar / (0.2 * 0.1));
}

}  // namespace
}  // namespace sinew
