// Elastic fibers (ElasticRods: Liu et al. 2012, section 4.1, as discrete rods parameterised by EA and
// EI). The generic checks (finite-difference gradient and differential, symmetry, zero net force and
// torque, rigid invariance, zero force at a curved rest shape, stable step) run in test_forces'
// EveryForce suite; here the fiber alone against beam theory, its independence of the resolution,
// and a curved hinge swept through straight.
#include "sinew/fibers.hpp"
#include "sinew/forces/elastic_rods.hpp"
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
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

// A block of material particles (n x n x length on a lattice of spacing s from the origin, z along
// the length; volume s^3, 1000 kg/m^3) with the meshfree matrix, in a system without gravity.
struct Block {
  System system{SystemSettings{.gravity = Vec3::Zero()}};
  MeshfreeCorotated* matrix = nullptr;
  double s = 0.006, h = 0.015, E = 1e6;
  int n = 6, length = 6;
  explicit Block(int count = 6, int along = 0) : n(count), length(along > 0 ? along : count) {
    std::vector<Index> particles;
    for (int k = 0; k < length; ++k)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
          particles.push_back(system.add_particle(Vec3(i * s, j * s, k * s), Vec3::Zero(), 1000.0 * s * s * s));
    matrix = &system.add_force(std::make_unique<MeshfreeCorotated>(
        particles, system.particles().x, std::vector<double>(particles.size(), s * s * s),
        MeshfreeCorotatedSettings{.support_radius = h, .young_modulus = E, .poisson_ratio = 0.3, .hourglass = 0.1}));
  }
  // Four fibers along z at (x, y) in {1.5, 3.5} s, drawn from 3 s below the block (beyond h of it:
  // outside the material) to its top.
  std::vector<Vectors3> axial_fibers() const {
    std::vector<Vectors3> lines;
    for (const double x : {1.5, 3.5})
      for (const double y : {1.5, 3.5}) {
        Vectors3 line(3, length + 3);
        for (int k = 0; k < length + 3; ++k) line.col(k) = s * Vec3(x, y, double(k) - 3.0);
        lines.push_back(line);
      }
    return lines;
  }
  // The stiffness against a pull along `axis`: the layer at 0 along it clamped, a force F spread over
  // the far layer, F / (the far layer's mean displacement), from the assembled differential of the
  // matrix and the fibers (structure particles through their weights, W^T K W). With `load` another
  // axis the far layer is pushed across instead: the stiffness of a cantilever's tip.
  double stiffness(int axis, const EmbeddedFibers* fibers, int load = -1) {
    if (load < 0) load = axis;
    const int far_layer = (axis == 2 ? length : n) - 1;
    const Vectors3& x = system.particles().x;
    matrix->update_position_state(x);
    if (fibers && fibers->force) fibers->force->update_position_state(x);
    const std::vector<Index>& mp = matrix->particles();
    std::vector<Index> dof;
    std::vector<char> far(static_cast<std::size_t>(x.cols()), 0);
    for (const Index i : mp) {
      if (x(axis, i) < 0.5 * s) continue;
      for (int a = 0; a < 3; ++a) dof.push_back(3 * i + a);
      far[static_cast<std::size_t>(i)] = x(axis, i) > (far_layer - 0.5) * s;
    }
    const Index m = static_cast<Index>(dof.size());
    Eigen::MatrixXd K(m, m);
    Vectors3 dx = Vectors3::Zero(3, x.cols()), df(3, x.cols());
    for (Index c = 0; c < m; ++c) {
      dx.setZero();
      dx.data()[dof[static_cast<std::size_t>(c)]] = 1.0;
      df.setZero();
      if (fibers && fibers->force) {
        std::size_t sp = 0;
        for (const auto& fiber : fibers->fibers)
          for (const Index p : fiber) {
            Vec3 d = Vec3::Zero();
            for (std::size_t a = 0; a < fibers->parents[sp].size(); ++a)
              d += fibers->weights[sp][a] * dx.col(fibers->parents[sp][a]);
            dx.col(p) = d;
            ++sp;
          }
        Vectors3 dfs = Vectors3::Zero(3, x.cols());
        fibers->force->add_elastic_differentials(dx, dfs);
        sp = 0;
        for (const auto& fiber : fibers->fibers)
          for (const Index p : fiber) {
            for (std::size_t a = 0; a < fibers->parents[sp].size(); ++a)
              df.col(fibers->parents[sp][a]) += fibers->weights[sp][a] * dfs.col(p);
            ++sp;
          }
      }
      matrix->add_elastic_differentials(dx, df);
      for (Index r = 0; r < m; ++r) K(r, c) = -df.data()[dof[static_cast<std::size_t>(r)]];
    }
    Eigen::VectorXd b = Eigen::VectorXd::Zero(m);
    int count = 0;
    for (Index r = 0; r < m; ++r)
      count += (dof[static_cast<std::size_t>(r)] % 3 == load &&
                far[static_cast<std::size_t>(dof[static_cast<std::size_t>(r)] / 3)])
                   ? 1
                   : 0;
    for (Index r = 0; r < m; ++r)
      if (dof[static_cast<std::size_t>(r)] % 3 == load &&
          far[static_cast<std::size_t>(dof[static_cast<std::size_t>(r)] / 3)])
        b[r] = 1.0 / count;
    const Eigen::VectorXd u = K.ldlt().solve(b);
    double mean = 0.0;
    for (Index r = 0; r < m; ++r) mean += b[r] * u[r];  // sum of (1/count) u over the far layer
    return 1.0 / mean;
  }
};

// Fibers drawn partly outside the material lose those points; the structure particles sit at their
// embedded rest places, so at rest the fibers store nothing (round-off) and pull nothing: 300 steps
// without gravity move no particle by 1e-12 m.
TEST(EmbeddedFibers, AtRestTheyStoreNothingAndMoveNothing) {
  Block block;
  const EmbeddedFibers fibers = embed_fibers(block.system, *block.matrix, block.h, block.axial_fibers(),
                                             {.stretch_stiffness = 1e3, .bending_stiffness = 1e-3, .lambda = 0.5});
  ASSERT_NE(fibers.force, nullptr);
  EXPECT_EQ(fibers.fibers.size(), 4u);
  EXPECT_EQ(fibers.dropped, 4);  // the point 3 s below the block on each; 2 s below is within h
  for (std::size_t sp = 0; sp < fibers.weights.size(); ++sp) {
    double sum = 0.0;
    for (const double w : fibers.weights[sp]) sum += w;
    EXPECT_NEAR(sum, 1.0, 1e-15);
  }
  const Vectors3 x0 = block.system.particles().x;
  EXPECT_LT(fibers.force->potential_energy(x0), 1e-20);
  block.system.step_settings().automatic = false;
  for (int n = 0; n < 300; ++n) block.system.step(1e-5);
  EXPECT_LT((block.system.particles().x - x0).cwiseAbs().maxCoeff(), 1e-12);
}

// The paper's claim (figure 6): drawing fibers makes a block anisotropic. Four axial fibers (lambda
// 0.5, EA three times the block's own E A) in a 6 x 6 x 6 block: every particle is within h of a
// fiber, so the matrix keeps half its stiffness everywhere, and across the fibers (which have no
// bending stiffness here) the block is 1 - lambda as stiff, to 10%; along them it is at least 1.5
// times the plain block (1.55: the matrix passes load into the fibers through its shear, so tripling
// EA from E A raised it from 1.17 only), and at least 1.7 times as stiff as across (2.9). Fibers of
// no stiffness leave the cube isotropic to 5% (lambda then softens the matrix alike both ways).
TEST(EmbeddedFibers, AxialFibersMakeTheBlockStifferAlongThem) {
  Block plain;
  const double along0 = plain.stiffness(2, nullptr), across0 = plain.stiffness(0, nullptr);
  EXPECT_NEAR(along0 / across0, 1.0, 1e-9);  // the cube's symmetry
  const double EA = plain.E * std::pow(plain.n * plain.s, 2);
  Block fibred;
  const EmbeddedFibers fibers = embed_fibers(fibred.system, *fibred.matrix, fibred.h, fibred.axial_fibers(),
                                             {.stretch_stiffness = 3.0 * EA, .bending_stiffness = 0.0, .lambda = 0.5});
  const double along = fibred.stiffness(2, &fibers), across = fibred.stiffness(0, &fibers);
  Block soft;
  const EmbeddedFibers none = embed_fibers(soft.system, *soft.matrix, soft.h, soft.axial_fibers(),
                                           {.stretch_stiffness = 0.0, .bending_stiffness = 0.0, .lambda = 0.5});
  const double along_soft = soft.stiffness(2, &none), across_soft = soft.stiffness(0, &none);
  std::printf("along / plain %.3f, across / plain %.3f, ratio %.3f; no-stiffness fibers: ratio %.3f\n", along / along0,
              across / across0, along / across, along_soft / across_soft);
  EXPECT_GE(along / along0, 1.5);
  EXPECT_NEAR(across / across0, 0.5, 0.05);
  EXPECT_GE(along / across, 1.7);
  EXPECT_NEAR(along_soft / across_soft, 1.0, 0.05);
}

// The paper's material-editing claims (fibers notes, acceptance checks 8 and 9), on a 6 x 6 x 12 bar:
// four axial fibers (lambda 0.5, EA 6 times the bar's own E A) make it at least twice as stiff along
// them as the plain bar and at most 1.2 times across; one thin fiber on the neutral axis (a volume
// fraction of 0.1: it takes little of the matrix around it; as stiff as one of the four, lambda EA,
// and the bending stiffness of a rod of radius r = s / 2, EA r^2 / 4) raises the axial stiffness at least twice and the
// cantilever's bending stiffness at most 1.3 times: easy to bend, hard to stretch. (The matrix hands
// the end loads to the fibers over about h at each end and through its own shear, so the gain grows
// with the bar's length and with the matrix it keeps.)
TEST(EmbeddedFibers, FibersStiffenAlongThemAndNotAcrossOrInBending) {
  Block plain(6, 12);
  const double along0 = plain.stiffness(2, nullptr), across0 = plain.stiffness(0, nullptr),
               bend0 = plain.stiffness(2, nullptr, 0);
  const double EA = 6.0 * plain.E * std::pow(plain.n * plain.s, 2);
  Block axial(6, 12);
  const EmbeddedFibers four = embed_fibers(axial.system, *axial.matrix, axial.h, axial.axial_fibers(),
                                           {.stretch_stiffness = EA, .bending_stiffness = 0.0, .lambda = 0.5});
  const double along = axial.stiffness(2, &four), across = axial.stiffness(0, &four);
  Block neutral(6, 12);
  Vectors3 axis(3, neutral.length + 3);
  for (int k = 0; k < neutral.length + 3; ++k) axis.col(k) = neutral.s * Vec3(2.5, 2.5, double(k) - 3.0);
  const double r = 0.5 * neutral.s;
  const double lambda = 0.1, EA1 = 0.5 * EA / lambda;  // as stiff as one of the four (lambda times)
  const EmbeddedFibers one =
      embed_fibers(neutral.system, *neutral.matrix, neutral.h, {axis},
                   {.stretch_stiffness = EA1, .bending_stiffness = EA1 * r * r / 4, .lambda = lambda});
  const double along1 = neutral.stiffness(2, &one), bend1 = neutral.stiffness(2, &one, 0);
  std::printf("four axial: along %.3f, across %.3f of the plain bar; one on the axis: along %.3f, bending %.3f\n",
              along / along0, across / across0, along1 / along0, bend1 / bend0);
  EXPECT_GE(along / along0, 2.0);
  EXPECT_LE(across / across0, 1.2);
  EXPECT_GE(along1 / along0, 2.0);
  EXPECT_LE(bend1 / bend0, 1.3);
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

// The work a step linearised at its start misses (turn_work_rate): a stretched edge of tension
// T = EA (l - lbar) / lbar spun at w misses T l w^2 / 2 per squared step, an unstretched one nothing; a
// hinge bent from its rest turning adds |dE/dpsi| (w_e^2 + w_f^2) / 2, dE/dpsi = 2 EI (psi - psibar) / Lbar;
// and every turning edge, stressed or not, is stretched by moving along tangents (turn_stretch_rate).
// Explicit rods, which the step does not linearise, miss nothing.
TEST(ElasticRods, ItsTurnWorkRateFollowsTensionMomentAndSpin) {
  const double EA = 40.0, EI = 2e-3, w = 5.0;
  Vectors3 rest(3, 3);
  rest << 0, 0.1, 0.2, 0, 0, 0, 0, 0, 0;
  const ElasticRods rods({{0, 1, 2}}, rest, {.stretch_stiffness = EA, .bending_stiffness = EI, .implicit = true});
  const ElasticRods explicit_rods({{0, 1, 2}}, rest, {.stretch_stiffness = EA, .bending_stiffness = EI});
  const auto spun = [&](const Vectors3& x) {
    Vectors3 v(3, 3);
    for (Index i = 0; i < 3; ++i) v.col(i) = Vec3(0, 0, w).cross(Vec3(x.col(i)));
    return v;
  };
  EXPECT_NEAR(rods.turn_work_rate(rest, spun(rest)), 0.0, 1e-15);
  // Moved along tangents, each edge stores EA l^2 w^4 dt^4 / (8 lbar) (turn_stretch_rate), at rest
  // length and stretched by 10%.
  EXPECT_NEAR(rods.turn_stretch_rate(rest, spun(rest)), 2 * EA * 0.1 * 0.1 * std::pow(w, 4) / (8 * 0.1), 1e-12 * EA);
  EXPECT_EQ(rods.turn_stretch_rate(rest, Vectors3::Zero(3, 3)), 0.0);
  Vectors3 stretched = 1.1 * rest;
  const double stretch = 2 * EA * 0.11 * 0.11 * std::pow(w, 4) / (8 * 0.1);
  EXPECT_NEAR(rods.turn_stretch_rate(stretched, spun(stretched)), stretch, 1e-12 * stretch);
  const double T = EA * 0.1;
  const double turn = 2 * 0.5 * T * 0.11 * w * w;
  EXPECT_NEAR(rods.turn_work_rate(stretched, spun(stretched)), turn, 1e-12 * turn);
  // Explicit rods are not linearised: nothing missed.
  EXPECT_EQ(explicit_rods.turn_work_rate(stretched, spun(stretched)), 0.0);
  EXPECT_EQ(explicit_rods.turn_stretch_rate(stretched, spun(stretched)), 0.0);
  // Bent by 90 degrees at the middle, lengths kept: psi = 2 tan(45 deg) = 2, both edges turning at w.
  Vectors3 bent(3, 3);
  bent << 0, 0.1, 0.1, 0, 0, 0.1, 0, 0, 0;
  const double moment = 2 * EI * 2.0 / 0.2;
  EXPECT_NEAR(rods.turn_work_rate(bent, spun(bent)), 0.5 * moment * 2 * w * w, 1e-12 * moment * w * w);
}

// Breaking (figure 10): a bent, stretched fiber split at an edge loses exactly that edge's stretching
// term and the bending terms of the two hinges that use it (the energy drops by them to round-off);
// the other terms keep their rest data, nothing moves and the forces still sum to zero. A fiber pulled
// past a strain breaks there, into pieces whose ends carry no bending.
TEST(ElasticRods, ABreakRemovesExactlyItsTerms) {
  const Index n = 8;
  Vectors3 rest(3, n), x(3, n);
  for (Index i = 0; i < n; ++i) {
    rest.col(i) = Vec3(0.05 * i, 0.01 * std::sin(0.7 * i), 0);
    x.col(i) = Vec3(0.052 * i, 0.02 * std::sin(0.9 * i), 0.003 * i * i);
  }
  std::vector<Index> line;
  for (Index i = 0; i < n; ++i) line.push_back(i);
  ElasticRods rods({line}, rest, {.stretch_stiffness = 100.0, .bending_stiffness = 1e-2});
  const double before = rods.potential_energy(x);
  // The removed terms, from a rod made of them alone: edge 3 (particles 3, 4) and hinges 3 and 4.
  const ElasticRods edge({{3, 4}}, rest, {.stretch_stiffness = 100.0, .bending_stiffness = 0.0});
  const ElasticRods hinges({{2, 3, 4}, {3, 4, 5}}, rest, {.stretch_stiffness = 0.0, .bending_stiffness = 1e-2});
  const double removed = edge.potential_energy(x) + hinges.potential_energy(x);
  rods.break_fiber(0, 3);
  ASSERT_EQ(rods.fibers().size(), 2u);
  EXPECT_EQ(rods.fibers()[0], (std::vector<Index>{0, 1, 2, 3}));
  EXPECT_EQ(rods.fibers()[1], (std::vector<Index>{4, 5, 6, 7}));
  EXPECT_NEAR(rods.potential_energy(x), before - removed, 1e-14 * before);
  EXPECT_GT(removed, 0.0);
  Vectors3 f = Vectors3::Zero(3, n);
  rods.add_elastic_forces(x, f);
  EXPECT_LT(f.rowwise().sum().norm(), 1e-12 * f.cwiseAbs().maxCoeff());
  // Pulled past 10% at its sixth edge only: one break, there.
  Vectors3 pulled = rest;
  for (Index i = 6; i < n; ++i) pulled(0, i) += 0.01;
  ElasticRods whole({line}, rest, {.stretch_stiffness = 100.0, .bending_stiffness = 1e-2});
  EXPECT_EQ(whole.break_stretched(pulled, 0.1), 1u);
  ASSERT_EQ(whole.fibers().size(), 2u);
  EXPECT_EQ(whole.fibers()[1], (std::vector<Index>{6, 7}));
  EXPECT_EQ(whole.break_stretched(pulled, 0.1), 0u);
}

}  // namespace
}  // namespace sinew

namespace sinew {
namespace {

double distance_to_polyline(const Vec3& p, const Vectors3& line) {
  double best = kInfinity;
  for (Index i = 0; i + 1 < line.cols(); ++i) {
    const Vec3 a = line.col(i), d = line.col(i + 1) - a;
    const double t = std::clamp((p - a).dot(d) / d.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (a + t * d - p).norm());
  }
  return best;
}

// Drawing (section 5, P20): a known 3D curve projected to the front view (x, y) and the side view
// (z, y), each stroke sampled differently and drawn top down, is rebuilt at the spacing s: every
// rebuilt point lies on the curve and every point of the curve near the rebuilt polyline, within s/2
// (Hausdorff), with segments s long to 2%.
TEST(FiberDrawing, TwoOrthogonalStrokesRebuildTheCurve) {
  const auto curve = [](double y) { return Vec3(0.05 * std::sin(12.0 * y), y, 0.03 * std::cos(20.0 * y)); };
  Eigen::Matrix2Xd front(2, 40), side(2, 57);
  for (Index i = 0; i < front.cols(); ++i) {
    const Vec3 p = curve(0.3 * (1.0 - double(i) / 39.0));
    front.col(i) = Eigen::Vector2d(p.x(), p.y());
  }
  for (Index i = 0; i < side.cols(); ++i) {
    const Vec3 p = curve(0.3 * (1.0 - double(i) / 56.0));
    side.col(i) = Eigen::Vector2d(p.z(), p.y());
  }
  const double s = 0.006;
  const Vectors3 fiber = fiber_from_strokes(front, side, s);
  Vectors3 truth(3, 3001);
  for (Index i = 0; i < truth.cols(); ++i) truth.col(i) = curve(0.3 * (1.0 - double(i) / 3000.0));
  double hausdorff = 0.0;
  for (Index i = 0; i < fiber.cols(); ++i) hausdorff = std::max(hausdorff, distance_to_polyline(fiber.col(i), truth));
  for (Index i = 0; i < truth.cols(); ++i) hausdorff = std::max(hausdorff, distance_to_polyline(truth.col(i), fiber));
  EXPECT_LT(hausdorff, 0.5 * s);
  EXPECT_GT(fiber(1, 0), fiber(1, fiber.cols() - 1)) << "drawn top down";
  for (Index i = 0; i + 1 < fiber.cols(); ++i) EXPECT_NEAR((fiber.col(i + 1) - fiber.col(i)).norm(), s, 0.02 * s) << i;
  // A stroke that turns back along the shared axis, and strokes that share no height, are named.
  Eigen::Matrix2Xd back = front;
  back(1, 20) = back(1, 10);
  try {
    fiber_from_strokes(back, side, s);
    ADD_FAILURE() << "accepted a stroke turning back";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("front stroke turns back along y at its point"), std::string::npos)
        << e.what();
  }
  Eigen::Matrix2Xd high = side;
  high.row(1).array() += 1.0;
  EXPECT_THROW(fiber_from_strokes(front, high, s), Error);
}

// The plain file: fibers and their points, comments and blank lines skipped; a malformed line, a
// point before any fiber, a one-point fiber and a missing file are named; write_fibers' files read
// back to the bit.
TEST(FiberDrawing, FiberFilesReadBackAndBadOnesAreNamed) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "sinew_fiber_files";
  std::filesystem::create_directories(dir);
  const auto write = [&](const char* name, const char* text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  const std::vector<Vectors3> fibers =
      read_fibers(write("good.txt", "# two fibers\nfiber\n0 0 0\n0 1 0  # up\n\nfiber\n1 0 0\n1 0 1\n1 0 2\n"));
  ASSERT_EQ(fibers.size(), 2u);
  EXPECT_EQ(fibers[1].cols(), 3);
  EXPECT_EQ(Vec3(fibers[0].col(1)), Vec3(0, 1, 0));
  const auto says = [&](const std::string& path, const std::string& text) {
    try {
      read_fibers(path);
      ADD_FAILURE() << "accepted " << path;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  says(write("bad.txt", "fiber\n0 0 0\n0 zero 0\n"), "line 3: expected 'fiber' or three finite numbers");
  says(write("early.txt", "0 0 0\nfiber\n"), "line 1: a point before the first 'fiber'");
  says(write("short.txt", "fiber\n0 0 0\nfiber\n0 0 0\n1 1 1\n"), "the fiber started on line 1 has 1 points");
  says((dir / "missing.txt").string(), "cannot read");
  // What sinew-view's drawing panel saves reads back to the bit; a bad fiber is named, not written.
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Vectors3> drawn{Vectors3(3, 5), Vectors3(3, 2)};
  for (Vectors3& fiber : drawn)
    for (Index i = 0; i < fiber.cols(); ++i) fiber.col(i) = Vec3(u(rng), u(rng), u(rng)) / 3.0;
  const std::string saved = (dir / "saved.txt").string();
  write_fibers(saved, drawn);
  const std::vector<Vectors3> back = read_fibers(saved);
  ASSERT_EQ(back.size(), drawn.size());
  for (std::size_t f = 0; f < drawn.size(); ++f) EXPECT_TRUE(back[f] == drawn[f]) << "fiber " << f;
  try {
    write_fibers((dir / "one.txt").string(), {Vectors3::Zero(3, 1)});
    ADD_FAILURE() << "wrote a one-point fiber";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("fiber 0 has 1 points"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

// A fibered bar (3 x 3 x 16 particles 1 cm apart, E = 100 kPa, one axial fiber of EA = 50 N) spun at
// 12 rad/s about a short axis without gravity, advanced 2 s at one 1/60 s step a frame by the automatic
// scheme, which treats its implicit matrix and fiber implicitly. Unstressed at first, it has no stress
// to turn, but moving its particles along tangents instead of arcs stretches it by (w dt)^2 / 2 a step
// (Force::turn_stretch_rate): the scheme's substeps bound that. Returns the largest rise of kinetic plus
// elastic energy over its start, and the substeps taken.
double spun_bar_energy_rise(double turn_work_per_implicit_step, int& substeps) {
  System system{SystemSettings{.gravity = Vec3::Zero()}};
  const double s = 0.01, h = 2.5 * s;
  std::vector<Index> particles;
  for (int k = 0; k < 16; ++k)
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i)
        particles.push_back(system.add_particle(Vec3(i * s, j * s, k * s), Vec3::Zero(), 1000.0 * s * s * s));
  MeshfreeCorotated& matrix = system.add_force(std::make_unique<MeshfreeCorotated>(
      particles, system.particles().x, std::vector<double>(particles.size(), s * s * s),
      MeshfreeCorotatedSettings{
          .support_radius = h, .young_modulus = 1e5, .poisson_ratio = 0.3, .hourglass = 0.1, .implicit = true}));
  Vectors3 axis(3, 16);
  for (int k = 0; k < 16; ++k) axis.col(k) = Vec3(s, s, k * s);
  embed_fibers(system, matrix, h, {axis},
               {.stretch_stiffness = 50.0, .bending_stiffness = 1e-3, .lambda = 0.5, .implicit = true});
  const Vec3 centre(s, s, 7.5 * s);
  for (const Index i : particles)
    system.particles().v.col(i) = Vec3(12.0, 0.0, 0.0).cross(Vec3(system.particles().x.col(i) - centre));
  system.step_settings().turn_work_per_implicit_step = turn_work_per_implicit_step;
  system.finalize();
  const double start = system.kinetic_energy() + system.potential_energy();
  double largest = start;
  substeps = 0;
  for (int frame = 0; frame < 120; ++frame) {
    substeps += system.advance(1.0 / 60.0).substeps;
    largest = std::max(largest, system.kinetic_energy() + system.potential_energy());
  }
  return largest / start - 1.0;
}

// Bounded (the default fraction), the bar's energy rises by 0.07% at most (3 substeps a frame);
// unbounded (a fraction so large that every frame is one step) it rises by 26% in the first frame.
TEST(EmbeddedFibers, ASpunBarKeepsItsEnergyAtOneStepAFrame) {
  int bounded_substeps = 0, unbounded_substeps = 0;
  EXPECT_LT(spun_bar_energy_rise(StepSettings{}.turn_work_per_implicit_step, bounded_substeps), 5e-3);
  EXPECT_GT(spun_bar_energy_rise(1e30, unbounded_substeps), 0.1);
  EXPECT_EQ(unbounded_substeps, 120);
  EXPECT_GT(bounded_substeps, unbounded_substeps);
}

}  // namespace
}  // namespace sinew
