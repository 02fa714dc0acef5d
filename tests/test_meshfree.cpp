// The fibers' matrix: corotated meshfree elasticity (MeshfreeCorotated; Liu et al. 2012, section 4.2,
// with the corrections of its notes). The generic force checks (finite differences, symmetry,
// damping, rigid invariance, stable step) run in test_forces' EveryForce suite; here, what is
// particular to a meshfree discretisation: the corrected gradient reproduces affine maps exactly at
// every particle (the patch test), momentum and angular momentum survive long free runs, and a bar
// stretched by an end traction shows the material's Young's modulus and Poisson ratio.
#include "forces/signed_svd.hpp"
#include "sinew/collision.hpp"
#include "sinew/forces/meshfree_corotated.hpp"
#include "sinew/system.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <vector>

namespace sinew {
namespace {

// Particles on an nx x ny x nz lattice of spacing s from the origin, jittered by `jitter` s.
Vectors3 lattice(int nx, int ny, int nz, double s, double jitter, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-jitter * s, jitter * s);
  Vectors3 x(3, nx * ny * nz);
  for (int k = 0, c = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i, ++c) x.col(c) = Vec3(i * s + u(rng), j * s + u(rng), k * s + u(rng));
  return x;
}

std::vector<Index> all(Index n) {
  std::vector<Index> out(static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i) out[static_cast<std::size_t>(i)] = i;
  return out;
}

// Any affine map x = A X + b: every particle's F is A, boundary particles too (the correction makes
// sum_j V_j X_ji g_ij^T = I), so its strain in the rotated frame is exactly the map's stretch. The
// forces are then the divergence of a uniform stress: zero inside, where the stencils are whole.
TEST(MeshfreeCorotated, EveryParticleReproducesAnAffineMap) {
  std::mt19937 rng(7);
  const double s = 0.006;
  const Vectors3 rest = lattice(6, 6, 6, s, 0.2, rng);
  MeshfreeCorotated force(all(rest.cols()), rest, std::vector<double>(static_cast<std::size_t>(rest.cols()), s * s * s),
                          {.support_radius = 2.5 * s, .young_modulus = 1e6, .hourglass = 0.1});
  Mat3 strain;
  strain << 1e-3, 2e-4, -1e-4, 2e-4, -5e-4, 3e-4, -1e-4, 3e-4, 8e-4;
  const Mat3 turn = Eigen::AngleAxisd(1.1, Vec3(-1, 2, 0.5).normalized()).toRotationMatrix();
  const Mat3 A = turn * (Mat3::Identity() + strain);
  const Vectors3 x = (A * rest).colwise() + Vec3(0.3, -0.2, 1.0);
  force.update_position_state(x);
  double worst = 0.0;
  for (std::size_t k = 0; k < force.particles().size(); ++k)
    worst = std::max(worst, (force.deformation_gradient(k) - A).cwiseAbs().maxCoeff());
  EXPECT_LT(worst, 1e-12);
  // The energy is the uniform strain energy of the whole volume, hourglass penalty zero.
  const double mu = force.mu(), lambda = force.lambda();
  const double density = mu * strain.squaredNorm() + 0.5 * lambda * strain.trace() * strain.trace();
  // (corotated: the energy is that of the symmetric stretch sqrt(A^T A) - I, equal to the strain to
  // second order)
  const Eigen::JacobiSVD<Mat3> svd(A);
  const Vec3 sigma = svd.singularValues();
  const double exact =
      mu * (sigma.array() - 1.0).square().sum() + 0.5 * lambda * (sigma.sum() - 3.0) * (sigma.sum() - 3.0);
  const double volume = static_cast<double>(rest.cols()) * s * s * s;
  EXPECT_NEAR(force.potential_energy(x), exact * volume, 1e-9 * exact * volume);
  EXPECT_NEAR(exact, density, 1e-3 * density);
}

// A free body, no gravity: the forces sum to zero and their torque vanishes at any state (round-off),
// so over 0.5 s of explicit steps the total momentum is kept to round-off; the angular momentum
// changes only by the step's own second-order error (the Newmark step's positions and velocities come
// from different half-step velocities): halving dt quarters its change.
TEST(MeshfreeCorotated, AFreeBodyKeepsItsMomentumAndAngularMomentum) {
  const double s = 0.01;
  const auto run = [&](double dt, Vec3& dP, Vec3& dL, double& L) {
    std::mt19937 rng(11);
    const Vectors3 rest = lattice(4, 4, 4, s, 0.2, rng);
    System system(SystemSettings{.gravity = Vec3::Zero()});
    std::normal_distribution<double> g(0.0, 0.05);
    for (Index i = 0; i < rest.cols(); ++i)
      system.add_particle(rest.col(i), Vec3(g(rng), g(rng), g(rng)), 1000.0 * s * s * s);
    auto owned = std::make_unique<MeshfreeCorotated>(
        all(rest.cols()), rest, std::vector<double>(static_cast<std::size_t>(rest.cols()), s * s * s),
        MeshfreeCorotatedSettings{.support_radius = 2.5 * s, .young_modulus = 1e5, .hourglass = 0.1});
    const MeshfreeCorotated& force = *owned;
    system.add_force(std::move(owned));
    system.step_settings().automatic = false;
    system.finalize();
    const Vec3 P0 = system.linear_momentum(), L0 = system.angular_momentum();
    for (int n = 0; n * dt < 0.5; ++n) {
      system.step(dt);
      if (n % 500 == 0) {  // the force alone: no net force or torque at this state
        Vectors3 f = Vectors3::Zero(3, rest.cols());
        force.add_elastic_forces(system.particles().x, f);
        Vec3 torque = Vec3::Zero();
        for (Index i = 0; i < rest.cols(); ++i) torque += Vec3(system.particles().x.col(i)).cross(Vec3(f.col(i)));
        const double scale = f.cwiseAbs().maxCoeff() * 0.04;
        EXPECT_LT(f.rowwise().sum().norm(), 1e-12 * scale * 25.0);
        EXPECT_LT(torque.norm(), 1e-12 * scale);
      }
    }
    dP = system.linear_momentum() - P0;
    dL = system.angular_momentum() - L0;
    L = L0.norm();
    EXPECT_TRUE(system.particles().x.allFinite());
  };
  Vec3 dP1, dL1, dP2, dL2;
  double L = 0.0;
  run(2e-4, dP1, dL1, L);
  run(1e-4, dP2, dL2, L);
  const double p_scale = 1000.0 * s * s * s * 0.05 * 8.0;
  EXPECT_LT(dP1.norm(), 1e-13 * p_scale);
  EXPECT_LT(dP2.norm(), 1e-13 * p_scale);
  std::printf("angular momentum change %.3g at dt 2e-4, %.3g at 1e-4 (of %.3g)\n", dL1.norm(), dL2.norm(), L);
  EXPECT_LT(dL1.norm(), 1e-4 * L);
  EXPECT_NEAR(dL1.norm() / dL2.norm(), 4.0, 0.5);
}

// A 7 x 7 x 12 bar (spacing 6 mm, h = 2.5 s: the paper's short bar), its bottom layer clamped and a
// traction sigma_0 = 1e-4 E on its top layer, solved to equilibrium (the forces' Newton step on the
// assembled differential; linear at this strain). Over the middle third, away from the clamp's
// restraint: axial strain sigma_0 / E_eff and lateral strain -nu_eff times it, against the
// material's E and nu.
TEST(MeshfreeCorotated, AStretchedBarShowsItsYoungsModulusAndPoissonRatio) {
  std::mt19937 rng(3);
  const double s = 0.006, E = 5e7, nu = 0.33;
  const int nx = 7, nz = 12;
  const Vectors3 rest = lattice(nx, nx, nz, s, 0.0, rng);
  const Index n = rest.cols();
  MeshfreeCorotated force(all(n), rest, std::vector<double>(static_cast<std::size_t>(n), s * s * s),
                          {.support_radius = 2.5 * s, .young_modulus = E, .poisson_ratio = nu, .hourglass = 0.1});
  const double sigma0 = 1e-4 * E;
  Vectors3 load = Vectors3::Zero(3, n);
  std::vector<char> fixed(static_cast<std::size_t>(n), 0);
  int top = 0;
  for (Index i = 0; i < n; ++i) top += rest(2, i) > (nz - 1.5) * s ? 1 : 0;
  for (Index i = 0; i < n; ++i) {
    if (rest(2, i) < 0.5 * s) fixed[static_cast<std::size_t>(i)] = 1;
    if (rest(2, i) > (nz - 1.5) * s) load(2, i) = sigma0 * (nx * s) * (nx * s) / top;
  }
  // K by probing the differential at rest, reduced to the free rows; one Newton step from rest.
  force.update_position_state(rest);
  std::vector<Index> dof;
  for (Index i = 0; i < n; ++i)
    if (!fixed[static_cast<std::size_t>(i)])
      for (int a = 0; a < 3; ++a) dof.push_back(3 * i + a);
  const Index m = static_cast<Index>(dof.size());
  Eigen::MatrixXd K(m, m);
  Vectors3 dx = Vectors3::Zero(3, n), df(3, n);
  for (Index c = 0; c < m; ++c) {
    dx.data()[dof[static_cast<std::size_t>(c)]] = 1.0;
    df.setZero();
    force.add_elastic_differentials(dx, df);
    dx.data()[dof[static_cast<std::size_t>(c)]] = 0.0;
    for (Index r = 0; r < m; ++r) K(r, c) = -df.data()[dof[static_cast<std::size_t>(r)]];
  }
  Eigen::VectorXd b(m);
  for (Index r = 0; r < m; ++r) b[r] = load.data()[dof[static_cast<std::size_t>(r)]];
  const Eigen::VectorXd u = K.ldlt().solve(b);
  Vectors3 displacement = Vectors3::Zero(3, n);
  for (Index r = 0; r < m; ++r) displacement.data()[dof[static_cast<std::size_t>(r)]] = u[r];
  // Least-squares slopes of u_z against z and u_x against x over the middle third.
  double szz = 0, sz = 0, suz = 0, szu = 0, cz = 0, sxx = 0, sx = 0, sux = 0, sxu = 0;
  for (Index i = 0; i < n; ++i) {
    const double z = rest(2, i), x = rest(0, i);
    if (z < nz * s / 3.0 || z > 2.0 * nz * s / 3.0) continue;
    ++cz;
    szz += z * z, sz += z, suz += displacement(2, i), szu += z * displacement(2, i);
    sxx += x * x, sx += x, sux += displacement(0, i), sxu += x * displacement(0, i);
  }
  const double axial = (cz * szu - sz * suz) / (cz * szz - sz * sz);
  const double lateral = (cz * sxu - sx * sux) / (cz * sxx - sx * sx);
  const double E_eff = sigma0 / axial, nu_eff = -lateral / axial;
  std::printf("E_eff / E %.4f, nu_eff %.4f (nu %.2f)\n", E_eff / E, nu_eff, nu);
  EXPECT_NEAR(E_eff / E, 1.0, 0.1);
  EXPECT_NEAR(nu_eff, nu, 0.05);
}

// The static tip deflection of an n x n x m cantilever (spacing s, h = 2.5 s; its first layer
// clamped) under its own weight across it, from the assembled stiffness at rest: probed in colours
// (particles of one (i, j) column 11 layers apart share a probe: a column of K reaches 2h = 5 s,
// so no particle is reached from two of them), solved sparse.
double cantilever_tip(int n, int m, double s, double E, double nu, double density, double g) {
  std::mt19937 rng(1);
  const Vectors3 rest = lattice(n, n, m, s, 0.0, rng);
  const Index count = rest.cols();
  MeshfreeCorotated force(all(count), rest, std::vector<double>(static_cast<std::size_t>(count), s * s * s),
                          {.support_radius = 2.5 * s, .young_modulus = E, .poisson_ratio = nu, .hourglass = 0.1});
  force.update_position_state(rest);
  const auto layer = [&](Index p) { return static_cast<int>(p / (n * n)); };
  const auto dof = [&](Index p, int a) { return 3 * (p - n * n) + a; };  // layer 0 clamped
  std::vector<Eigen::Triplet<double>> entries;
  Vectors3 dx = Vectors3::Zero(3, count), df(3, count);
  for (Index column = 0; column < n * n; ++column)
    for (int colour = 0; colour < 11; ++colour)
      for (int a = 0; a < 3; ++a) {
        dx.setZero();
        for (int k = colour; k < m; k += 11)
          if (k > 0) dx(a, k * n * n + column) = 1.0;
        df.setZero();
        force.add_elastic_differentials(dx, df);
        for (Index q = n * n; q < count; ++q) {
          // The probed particle of this column nearest q's layer.
          int k = layer(q) - ((layer(q) - colour) % 11 + 11) % 11;
          if (layer(q) - k > 5) k += 11;
          if (k <= 0 || k >= m) continue;
          for (int b = 0; b < 3; ++b)
            if (df(b, q) != 0.0) entries.emplace_back(dof(q, b), dof(k * n * n + column, a), -df(b, q));
        }
      }
  const Index unknowns = 3 * (count - n * n);
  Eigen::SparseMatrix<double> K(unknowns, unknowns);
  K.setFromTriplets(entries.begin(), entries.end());
  Eigen::VectorXd load = Eigen::VectorXd::Zero(unknowns);
  for (Index p = n * n; p < count; ++p) load[dof(p, 0)] = density * s * s * s * g;
  const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(K);
  const Eigen::VectorXd u = solver.solve(load);
  double tip = 0.0;
  for (Index p = (m - 1) * n * n; p < count; ++p) tip += u[dof(p, 0)];
  return tip / (n * n);
}

// A cantilever under its weight against Timoshenko's beam, delta = q L^4 / (8 EI) + q L^2 / (2 kappa
// G A) (kappa = 5/6; the shear part is 3% here), converging on refinement: a 4 x 4 x 24 bar at the
// paper's spacing (a = 4 s, L = 23.5 s: the free layers' masses reach half a spacing past the last)
// bends 43% too far (its stencils, 2.5 s deep, are cut by the faces of a bar 3 s across: the faces
// are soft), the same bar at two thirds of the spacing (6 x 6 x 35) 15%: within 20%, and less than
// half the coarse error. (Taking the span to the last layer instead, L = (m - 1) s, would read the
// fine bar about 21% too soft: the half spacing of mass past it is part of the beam.)
TEST(MeshfreeCorotated, ACantileverBendsAsTimoshenkosBeam) {
  const double E = 1e6, nu = 0.3, density = 1000.0, g = 9.81, s = 0.006;
  const auto beam = [&](int n, int m, double spacing) {
    const double a = n * spacing, L = (m - 0.5) * spacing, q = density * g * a * a;
    const double I = a * a * a * a / 12.0, G = E / (2.0 * (1.0 + nu));
    return q * std::pow(L, 4) / (8.0 * E * I) + q * L * L / (2.0 * (5.0 / 6.0) * G * a * a);
  };
  const double coarse = cantilever_tip(4, 24, s, E, nu, density, g) / beam(4, 24, s) - 1.0;
  const double fine = cantilever_tip(6, 35, s * 4.0 / 6.0, E, nu, density, g) / beam(6, 35, s * 4.0 / 6.0) - 1.0;
  std::printf("tip deflection against Timoshenko's beam: %+.2f%% at s, %+.2f%% at 2s/3\n", 100.0 * coarse,
              100.0 * fine);
  EXPECT_LT(std::abs(fine), 0.2);
  EXPECT_LT(std::abs(fine), 0.5 * std::abs(coarse));
}

// A stiff solid landing at one 1/60 s step: step 1 moves the bar by v dt with no floor, step 3 puts its
// bottom layer back on the floor, and without StepSettings::spread_collisions nothing else moves: the
// bottom layer is squashed against the one above it by up to v dt (here 2 cm against 1.5 cm layers),
// an elastic energy step 4 hands back as a bounce. A 4 x 8 x 4 bar (E = 200 kPa, 1000 kg/m^3, the
// bars scene's material) dropped at 1.3 m/s onto a floor that stops what crosses it (inelastic, as
// the coupling's collisions are): with the spread, the visible energy (kinetic, gravity, elastic)
// never rises above its start and the bar comes to rest standing on the floor at its own height
// within 2 s (its kinetic energy then 5e-5 of the start's, a rocking that decays 1.3% a step);
// without it, the same landing gains more than a fifth of the start's energy.
TEST(MeshfreeCorotated, ABarLandingAtOneStepAFrameGainsNoEnergy) {
  const double s = 0.015, dt = 1.0 / 60.0;
  struct Run {
    double start = 0.0, largest = 0.0, height = 0.0, lowest = 0.0, kinetic = 0.0;
  };
  const auto run = [&](bool spread) {
    std::mt19937 rng(5);
    Vectors3 rest = lattice(4, 8, 4, s, 0.0, rng);
    rest.row(1).array() += 0.02;
    System system;
    for (Index i = 0; i < rest.cols(); ++i) system.add_particle(rest.col(i), Vec3(0, -1.3, 0), 1000.0 * s * s * s);
    auto owned = std::make_unique<MeshfreeCorotated>(
        all(rest.cols()), rest, std::vector<double>(static_cast<std::size_t>(rest.cols()), s * s * s),
        MeshfreeCorotatedSettings{
            .support_radius = 2.5 * s, .young_modulus = 2e5, .beta = 0.01, .hourglass = 0.1, .implicit = true});
    system.add_force(std::move(owned));
    system.add_collision_source(make_collision_source("floor", [](CollisionContext& c) {
      for (Index i = 0; i < c.x->cols(); ++i) {
        if ((*c.x)(1, i) >= 0.0) continue;
        (*c.x)(1, i) = 0.0;
        (*c.v)(1, i) = std::max((*c.v)(1, i), 0.0);
        c.add_constraint(CollisionConstraint::point(i, Vec3::UnitY(), 0.0));
      }
    }));
    system.step_settings().automatic = false;
    system.step_settings().implicit_elasticity = true;
    system.step_settings().spread_collisions = spread;
    system.finalize();
    Run r;
    r.start = r.largest = system.kinetic_energy() + system.potential_energy();
    for (int n = 0; n < 120; ++n) {
      system.step(dt);
      r.largest = std::max(r.largest, system.kinetic_energy() + system.potential_energy());
    }
    const Vectors3& x = system.particles().x;
    r.lowest = x.row(1).minCoeff();
    r.height = x.row(1).maxCoeff() - r.lowest;
    r.kinetic = system.kinetic_energy();
    return r;
  };
  const Run held = run(true), bare = run(false);
  std::printf("visible energy %.4f J at the start; largest after it %.4f J with the spread, %.4f J without\n",
              held.start, held.largest, bare.largest);
  EXPECT_LE(held.largest, held.start * (1.0 + 1e-6));
  EXPECT_GT(bare.largest, 1.2 * bare.start);  // the defect the spread removes is there to see
  EXPECT_NEAR(held.lowest, 0.0, 1e-9);
  EXPECT_NEAR(held.height, 7 * s, 0.05 * 7 * s);
  EXPECT_LT(held.kinetic, 2e-4 * held.start);  // at rest but for a slow rocking, decaying
}

// The work a step linearised at its start misses (turn_work_rate): none for an unstressed body however
// it spins (to round-off), none for a stressed one at rest, and for a uniform stretch F = diag(1 + e, 1, 1) spun at w
// about z (v = w z x x, so Fdot = [w]x F), 1/2 sum_k V_k (2 mu + lambda) e |w_k|^2 with w_k the axial
// vector of skew(Fdot) (R = I), w (1 + e / 2): an analytic value. The stretch of moving along tangents
// follows the spin alone. Turned as a whole, the block misses the same; explicit, nothing.
TEST(MeshfreeCorotated, ItsTurnWorkRateFollowsStressAndSpin) {
  std::mt19937 rng(7);
  const double s = 0.01, E = 1e5, nu = 0.3, e = 0.05, w = 3.0;
  const Vectors3 X = lattice(4, 4, 4, s, 0.2, rng);
  const std::vector<double> volumes(static_cast<std::size_t>(X.cols()), s * s * s);
  const MeshfreeCorotated matrix(
      all(X.cols()), X, volumes,
      {.support_radius = 2.5 * s, .young_modulus = E, .poisson_ratio = nu, .implicit = true});
  const MeshfreeCorotated explicit_matrix(all(X.cols()), X, volumes,
                                          {.support_radius = 2.5 * s, .young_modulus = E, .poisson_ratio = nu});
  Vectors3 spin(3, X.cols()), stretched = X, stretched_spin(3, X.cols());
  for (Index i = 0; i < X.cols(); ++i) {
    stretched(0, i) *= 1.0 + e;
    spin.col(i) = Vec3(0, 0, w).cross(Vec3(X.col(i)));
    stretched_spin.col(i) = Vec3(0, 0, w).cross(Vec3(stretched.col(i)));
  }
  const double mu = E / (2 * (1 + nu)), lambda = E * nu / ((1 + nu) * (1 - 2 * nu));
  const double expected = 0.5 * double(X.cols()) * s * s * s * (2 * mu + lambda) * e * std::pow(w * (1 + e / 2), 2);
  EXPECT_LT(matrix.turn_work_rate(X, spin), 1e-12 * expected);  // round-off stress at rest
  EXPECT_EQ(matrix.turn_work_rate(stretched, Vectors3::Zero(3, X.cols())), 0.0);
  EXPECT_NEAR(matrix.turn_work_rate(stretched, stretched_spin), expected, 1e-9 * expected);
  // Moved along tangents, the spun block is stretched by (w dt)^2 / 2 across w: V (mu + lambda) / 2 w^4
  // per particle and dt^4 (turn_stretch_rate), whatever its stress.
  const double stretch = 0.5 * double(X.cols()) * s * s * s * (mu + lambda) * std::pow(w, 4);
  EXPECT_NEAR(matrix.turn_stretch_rate(X, spin), stretch, 1e-9 * stretch);
  // The same stretched block turned by Q and spun about Q z: F = Q D, R = Q, the same rates.
  const Mat3 Q = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  Vectors3 turned(3, X.cols()), turned_spin(3, X.cols());
  for (Index i = 0; i < X.cols(); ++i) {
    turned.col(i) = Q * stretched.col(i);
    turned_spin.col(i) = (Q * Vec3(0, 0, w)).cross(Vec3(turned.col(i)));
  }
  EXPECT_NEAR(matrix.turn_work_rate(turned, turned_spin), expected, 1e-9 * expected);
  // An explicit matrix is not linearised: nothing missed.
  EXPECT_EQ(explicit_matrix.turn_work_rate(stretched, stretched_spin), 0.0);
  EXPECT_EQ(explicit_matrix.turn_stretch_rate(X, spin), 0.0);
}

// The matrix's signed SVD from the eigenvectors of F^T F against Eigen's Jacobi SVD (signed_svd), on
// stretched, turned, inverted, nearly singular, singular and repeated-stretch F: U and V proper
// rotations to round-off; sigma in decreasing order with only the last negative (for det F < 0), the
// same sigma and F = U diag(sigma) V^T to 1e-8 relative to |F| (the closed-form eigenvectors of F^T F
// lose digits where two stretches nearly coincide; away from that the error is round-off).
TEST(MeshfreeCorotated, ItsSignedSvdMatchesTheJacobiOne) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const auto rotation = [&] {
    return Mat3(Eigen::AngleAxisd(3.0 * u(rng), Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix());
  };
  std::vector<Mat3> cases;
  for (int n = 0; n < 200; ++n) {
    Vec3 stretch(1.0 + 0.5 * u(rng), 1.0 + 0.5 * u(rng), 1.0 + 0.5 * u(rng));
    if (n % 4 == 1) stretch(2) = -stretch(2);                // inverted
    if (n % 4 == 2) stretch(2) = 1e-7 * u(rng);              // nearly singular
    if (n % 4 == 3) stretch(1) = stretch(0) * (1.0 + 1e-9);  // nearly repeated
    cases.push_back(rotation() * stretch.asDiagonal() * rotation());
  }
  cases.push_back(Mat3::Identity());
  cases.push_back(rotation());
  cases.push_back(Mat3::Zero());
  cases.push_back(Vec3(1.0, 0.0, 0.0) * Vec3(0.3, 0.4, 0.5).transpose());  // rank one
  for (const Mat3& F : cases) {
    const detail::SignedSvd fast = detail::signed_svd_from_eigen(F), jacobi = detail::signed_svd(F);
    const double scale = std::max(F.norm(), 1e-300);
    EXPECT_NEAR(fast.U.determinant(), 1.0, 1e-12);
    EXPECT_NEAR(fast.V.determinant(), 1.0, 1e-12);
    EXPECT_LT((fast.U.transpose() * fast.U - Mat3::Identity()).norm(), 1e-12);
    EXPECT_LT((fast.V.transpose() * fast.V - Mat3::Identity()).norm(), 1e-12);
    EXPECT_GE(fast.sigma(0), fast.sigma(1) - 1e-8 * scale);
    EXPECT_GE(fast.sigma(1), std::abs(fast.sigma(2)) - 1e-8 * scale);
    EXPECT_LT((fast.sigma - jacobi.sigma).norm(), 1e-8 * scale) << F;
    EXPECT_LT((fast.U * fast.sigma.asDiagonal() * fast.V.transpose() - F).norm(), 1e-8 * scale) << F;
  }
}

}  // namespace
}  // namespace sinew
