// Element forces: every derivative against central finite differences, damping structure,
// invariances, closed-form cases and degenerate inputs.
#include "sinew/builders.hpp"
#include "sinew/forces/centroid_springs.hpp"
#include "sinew/forces/corotated_tets.hpp"
#include "sinew/forces/dihedral_bending.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/forces/elastic_rods.hpp"
#include "sinew/forces/meshfree_corotated.hpp"
#include "sinew/forces/triangle_membrane.hpp"
#include "sinew/parallel.hpp"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <numbers>
#include <random>
#include <string>
#include <vector>

namespace sinew {
namespace {

using Edge = EdgeSprings::Edge;
using Triangle = TriangleMembrane::Triangle;
using Hinge = DihedralBending::Hinge;
using Tet = CorotatedTets::Tet;
using MatrixXd = Eigen::MatrixXd;

// ---------------------------------------------------------------------------------------------
// Small meshes.

/// nx x ny vertices in the z = 0 plane with spacing h, vertex (i, j) at column j * nx + i.
Vectors3 grid_positions(Index nx, Index ny, double h) {
  Vectors3 x(3, nx * ny);
  for (Index j = 0; j < ny; ++j) {
    for (Index i = 0; i < nx; ++i) {
      x.col(j * nx + i) = Vec3(h * static_cast<double>(i), h * static_cast<double>(j), 0.0);
    }
  }
  return x;
}

/// Two counter-clockwise (normal +z) triangles per cell.
std::vector<Triangle> grid_triangles(Index nx, Index ny) {
  std::vector<Triangle> triangles;
  for (Index j = 0; j + 1 < ny; ++j) {
    for (Index i = 0; i + 1 < nx; ++i) {
      const Index v00 = j * nx + i;
      const Index v10 = v00 + 1;
      const Index v01 = v00 + nx;
      const Index v11 = v01 + 1;
      triangles.push_back({v00, v10, v11});
      triangles.push_back({v00, v11, v01});
    }
  }
  return triangles;
}

std::vector<Edge> edges_of(const std::vector<Triangle>& triangles) {
  std::vector<Edge> edges;
  for (const Triangle& t : triangles) {
    for (std::size_t a = 0; a < 3; ++a) {
      edges.push_back({std::min(t[a], t[(a + 1) % 3]), std::max(t[a], t[(a + 1) % 3])});
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  return edges;
}

/// Unit cube (vertex index = x + 2y + 4z bits) split into 6 positively oriented tets around the
/// diagonal 0-7.
void cube_block(Vectors3& x, std::vector<Tet>& tets) {
  x.resize(3, 8);
  for (Index i = 0; i < 8; ++i) {
    x.col(i) = Vec3(static_cast<double>(i & 1), static_cast<double>((i >> 1) & 1), static_cast<double>((i >> 2) & 1));
  }
  const Index axes[6][3] = {{1, 2, 4}, {1, 4, 2}, {2, 1, 4}, {2, 4, 1}, {4, 1, 2}, {4, 2, 1}};
  tets.clear();
  for (const auto& p : axes) {
    Tet t = {0, p[0], p[0] + p[1], 7};
    Mat3 dm;
    for (int c = 0; c < 3; ++c) dm.col(c) = x.col(t[static_cast<std::size_t>(c) + 1]) - x.col(t[0]);
    if (dm.determinant() < 0.0) std::swap(t[1], t[2]);
    tets.push_back(t);
  }
}

Vectors3 single_tet_positions() {
  Vectors3 x(3, 4);
  x << 0.0, 1.0, 0.0, 0.0,  //
      0.0, 0.0, 1.0, 0.0,   //
      0.0, 0.0, 0.0, 1.0;
  return x;
}

// ---------------------------------------------------------------------------------------------
// Generic checks on any Force.

Eigen::Map<const VectorXd> flat(const Vectors3& m) { return {m.data(), m.size()}; }

double relative_error(const Vectors3& a, const Vectors3& b) {
  return (flat(a) - flat(b)).norm() / std::max(flat(b).norm(), 1e-300);
}

Vectors3 random_like(const Vectors3& x, double amplitude, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  Vectors3 r(3, x.cols());
  for (Index i = 0; i < r.size(); ++i) r.data()[i] = u(rng);
  return r;
}

Vectors3 elastic_forces(const Force& force, const Vectors3& x) {
  Vectors3 f = Vectors3::Zero(3, x.cols());
  force.add_elastic_forces(x, f);
  return f;
}

Vectors3 damping_forces(const Force& force, const Vectors3& v) {
  Vectors3 f = Vectors3::Zero(3, v.cols());
  force.add_damping_forces(v, f);
  return f;
}

Vectors3 differentials(const Force& force, const Vectors3& dx) {
  Vectors3 df = Vectors3::Zero(3, dx.cols());
  force.add_elastic_differentials(dx, df);
  return df;
}

/// Central differences of the energy, eps = 1e-6 of the mesh size: truncation O(eps^2) ~ 1e-12 and
/// round-off ~ 1e-16 |Psi| / eps both far below the 1e-6 tolerance.
void expect_force_is_negative_energy_gradient(const Force& force, const Vectors3& x, double size) {
  const double eps = 1e-6 * size;
  const Vectors3 f = elastic_forces(force, x);
  Vectors3 minus_gradient(3, x.cols());
  for (Index k = 0; k < x.size(); ++k) {
    Vectors3 xp = x;
    Vectors3 xm = x;
    xp.data()[k] += eps;
    xm.data()[k] -= eps;
    minus_gradient.data()[k] = -(force.potential_energy(xp) - force.potential_energy(xm)) / (2.0 * eps);
  }
  ASSERT_GT(flat(f).norm(), 0.0);
  EXPECT_LT(relative_error(f, minus_gradient), 1e-6);
}

void expect_differential_matches_finite_differences(Force& force, const Vectors3& x, double size, std::mt19937& rng) {
  force.update_position_state(x);
  const double eps = 1e-6 * size;
  for (int trial = 0; trial < 3; ++trial) {
    const Vectors3 dx = random_like(x, 1.0, rng);
    const Vectors3 df = differentials(force, dx);
    const Vectors3 fd = (elastic_forces(force, x + eps * dx) - elastic_forces(force, x - eps * dx)) / (2.0 * eps);
    ASSERT_GT(flat(fd).norm(), 0.0);
    EXPECT_LT(relative_error(df, fd), 1e-6) << "trial " << trial;
  }
}

void expect_damping_linear_symmetric_nsd(Force& force, const Vectors3& x, std::mt19937& rng) {
  ASSERT_TRUE(force.has_damping());
  force.update_position_state(x);
  for (int trial = 0; trial < 5; ++trial) {
    const Vectors3 u = random_like(x, 1.0, rng);
    const Vectors3 v = random_like(x, 1.0, rng);
    const Vectors3 du = damping_forces(force, u);
    const Vectors3 dv = damping_forces(force, v);
    const double scale = flat(u).norm() * flat(dv).norm() + flat(v).norm() * flat(du).norm();
    ASSERT_GT(scale, 0.0);
    EXPECT_LT(relative_error(damping_forces(force, 2.0 * u - 3.0 * v), 2.0 * du - 3.0 * dv), 1e-12);
    EXPECT_NEAR(flat(u).dot(flat(dv)), flat(v).dot(flat(du)), 1e-12 * scale);
    EXPECT_LE(flat(v).dot(flat(dv)), 1e-12 * scale);
    EXPECT_LE(flat(u).dot(flat(du)), 1e-12 * scale);
  }
}

void expect_rigid_motion_invariance(const Force& force, const Vectors3& x) {
  const Vectors3 f = elastic_forces(force, x);
  const double f_scale = flat(f).norm();
  ASSERT_GT(f_scale, 0.0);
  EXPECT_LT(f.rowwise().sum().norm(), 1e-12 * f_scale);
  Vec3 torque = Vec3::Zero();
  double torque_scale = 0.0;
  for (Index i = 0; i < x.cols(); ++i) {
    torque += Vec3(x.col(i)).cross(Vec3(f.col(i)));
    torque_scale += x.col(i).norm() * f.col(i).norm();
  }
  EXPECT_LT(torque.norm(), 1e-12 * torque_scale);

  const Mat3 q = Eigen::AngleAxisd(0.9, Vec3(1.0, -2.0, 0.5).normalized()).toRotationMatrix();
  const Vectors3 moved = (q * x).colwise() + Vec3(0.3, -1.2, 2.0);
  const double energy = force.potential_energy(x);
  ASSERT_GT(energy, 0.0);
  EXPECT_NEAR(force.potential_energy(moved), energy, 1e-10 * energy);
  EXPECT_LT(relative_error(elastic_forces(force, moved), q * f), 1e-9);
}

void expect_at_rest(const Force& force, const Vectors3& rest, double force_scale) {
  EXPECT_NEAR(force.potential_energy(rest), 0.0, 1e-20 * force_scale);
  EXPECT_LT(flat(elastic_forces(force, rest)).lpNorm<Eigen::Infinity>(), 1e-10 * force_scale);
}

/// -d f / d x at the cached state, densely, by probing with unit vectors.
MatrixXd dense_stiffness(const Force& force, Index n) {
  MatrixXd k(3 * n, 3 * n);
  for (Index j = 0; j < 3 * n; ++j) {
    Vectors3 e = Vectors3::Zero(3, n);
    e.data()[j] = 1.0;
    k.col(j) = -flat(differentials(force, e));
  }
  return 0.5 * (k + k.transpose());
}

/// 2 / sqrt(lambda_max(M^-1 K)) over the rows with finite positive mass, K at rest.
double exact_stable_dt(Force& force, const Vectors3& rest, const VectorXd& m) {
  force.update_position_state(rest);
  const MatrixXd k = dense_stiffness(force, rest.cols());
  std::vector<Index> dofs;
  for (Index i = 0; i < rest.cols(); ++i) {
    if (m[i] > 0.0 && std::isfinite(m[i])) {
      for (Index c = 0; c < 3; ++c) dofs.push_back(3 * i + c);
    }
  }
  const auto d = static_cast<Index>(dofs.size());
  MatrixXd a(d, d);
  for (Index r = 0; r < d; ++r) {
    for (Index c = 0; c < d; ++c) {
      a(r, c) = k(dofs[static_cast<std::size_t>(r)], dofs[static_cast<std::size_t>(c)]) /
                std::sqrt(m[dofs[static_cast<std::size_t>(r)] / 3] * m[dofs[static_cast<std::size_t>(c)] / 3]);
    }
  }
  const double lambda_max = Eigen::SelfAdjointEigenSolver<MatrixXd>(a, Eigen::EigenvaluesOnly).eigenvalues().maxCoeff();
  return 2.0 / std::sqrt(lambda_max);
}

void expect_stable_dt_conservative_within_10x(Force& force, const Vectors3& rest, const VectorXd& m) {
  const double exact = exact_stable_dt(force, rest, m);
  const double estimate = force.stable_dt(m);
  EXPECT_LE(estimate, exact * (1.0 + 1e-12));
  EXPECT_GE(estimate, 0.1 * exact);
}

// ---------------------------------------------------------------------------------------------
// Scenes: a 4x4 cloth patch (9 cells, 18 triangles) and a 6-tet cube, deformed at random.

constexpr double kSpacing = 0.25;

struct Cloth {
  Vectors3 rest;
  std::vector<Triangle> triangles;
  /// n x n vertices.
  explicit Cloth(Index n = 4) : rest(grid_positions(n, n, kSpacing)), triangles(grid_triangles(n, n)) {}

  /// In-plane stretch and shear plus 3D noise of 20% of the spacing: large but not degenerate.
  Vectors3 deformed(std::mt19937& rng) const {
    Mat3 a;
    a << 1.3, 0.2, 0.0, -0.1, 0.8, 0.0, 0.1, 0.3, 1.0;
    return a * rest + random_like(rest, 0.2 * kSpacing, rng);
  }
};

struct Block {
  Vectors3 rest;
  std::vector<Tet> tets;
  Block() { cube_block(rest, tets); }
  /// k x k x k unit cubes sharing their vertices, six tets each (cube_block's split, 6 k^3 tets).
  explicit Block(Index k) {
    Vectors3 cube;
    std::vector<Tet> cube_tets;
    cube_block(cube, cube_tets);
    const Index side = k + 1;
    rest.resize(3, side * side * side);
    for (Index z = 0; z < side; ++z)
      for (Index y = 0; y < side; ++y)
        for (Index x = 0; x < side; ++x) rest.col((z * side + y) * side + x) = Vec3(double(x), double(y), double(z));
    for (Index z = 0; z < k; ++z)
      for (Index y = 0; y < k; ++y)
        for (Index x = 0; x < k; ++x)
          for (const Tet& local : cube_tets) {
            Tet t;
            for (std::size_t a = 0; a < 4; ++a)
              t[a] = ((z + ((local[a] >> 2) & 1)) * side + y + ((local[a] >> 1) & 1)) * side + x + (local[a] & 1);
            tets.push_back(t);
          }
  }

  Vectors3 deformed(std::mt19937& rng) const {
    Mat3 a;
    a << 1.2, 0.3, -0.1, 0.1, 0.7, 0.2, -0.2, 0.1, 1.1;
    return a * rest + random_like(rest, 0.08, rng);
  }
};

EdgeSprings make_springs(const Cloth& cloth) {
  return EdgeSprings(edges_of(cloth.triangles), cloth.rest, {.stiffness = 200.0, .damping = 0.7});
}
TriangleMembrane make_membrane(const Cloth& cloth) {
  return TriangleMembrane(cloth.triangles, cloth.rest, {.mu = 300.0, .lambda = 150.0, .beta = 0.01});
}
/// Implicit (definite Gauss-Newton differential) as the scenes with implicit elasticity use it.
DihedralBending make_implicit_bending(const Cloth& cloth) {
  return DihedralBending(DihedralBending::hinges_from_triangles(cloth.triangles), cloth.rest,
                         {.stiffness = 0.02, .damping = 0.003, .implicit = true});
}
DihedralBending make_bending(const Cloth& cloth) {
  return DihedralBending(DihedralBending::hinges_from_triangles(cloth.triangles), cloth.rest,
                         {.stiffness = 0.02, .damping = 0.003});
}
CorotatedTets make_tets(const Block& block) {
  return CorotatedTets(block.tets, block.rest, {.young_modulus = 1e4, .poisson_ratio = 0.35, .beta = 0.02});
}

/// Bending needs out-of-plane folds to be non-trivial.
Vectors3 folded(const Cloth& cloth, std::mt19937& rng) {
  Vectors3 x = cloth.deformed(rng);
  for (Index i = 0; i < x.cols(); ++i) x(2, i) += 0.3 * std::sin(3.0 * x(0, i)) * std::cos(2.0 * x(1, i));
  return x;
}

/// At the cached state, the implicit products less the damping (b = 1: K+) are symmetric and
/// negative semi-definite, probed with random pairs shaped like `like`.
void expect_definite_part_symmetric_nsd(const Force& force, const Vectors3& like, std::mt19937& rng) {
  auto definite = [&](const Vectors3& v) {
    Vectors3 f = Vectors3::Zero(3, like.cols());
    force.add_implicit_products(v, 1.0, f);
    return Vectors3(f - damping_forces(force, v));
  };
  for (int trial = 0; trial < 20; ++trial) {
    const Vectors3 u = random_like(like, 1.0, rng), v = random_like(like, 1.0, rng);
    const Vectors3 ku = definite(u), kv = definite(v);
    const double scale = flat(u).norm() * flat(kv).norm();
    EXPECT_NEAR(flat(u).dot(flat(kv)), flat(v).dot(flat(ku)), 1e-12 * scale) << force.name();
    EXPECT_LE(flat(u).dot(flat(ku)), 1e-12 * scale) << force.name();
  }
}

// ---------------------------------------------------------------------------------------------
// The checks every force passes, one parameterised suite over force factories. A new force is
// tested by writing a factory (a small perturbed configuration, and a large one for the threaded
// element loops) and adding one line to kForceFactories.

/// A force on a configuration, and what the generic checks need to know about it.
struct ForceCase {
  std::unique_ptr<Force> force;
  Vectors3 rest;             ///< a configuration where force and energy vanish
  Vectors3 x;                ///< a perturbed one, far from degenerate
  VectorXd m;                ///< particle masses for the stable step (inf: kinematic)
  double size = 1.0;         ///< element size: the finite-difference step is 1e-6 of it
  double force_scale = 1.0;  ///< typical force magnitude (tolerance of the rest check)
};

/// small: a few elements (dense probes are cheap); else at least kMinChunkedElements elements,
/// so that the element loops split into chunks and run on two threads.
using ForceFactory = ForceCase (*)(bool small, std::mt19937& rng);

VectorXd masses(Index n, double m, std::initializer_list<Index> pinned) {
  VectorXd out = VectorXd::Constant(n, m);
  for (Index i : pinned) out[i] = kInfinity;
  return out;
}

ForceCase edge_springs_case(bool small, std::mt19937& rng) {
  const Cloth cloth(small ? 4 : 40);
  return {std::make_unique<EdgeSprings>(make_springs(cloth)),
          cloth.rest,
          cloth.deformed(rng),
          masses(cloth.rest.cols(), 0.01, {0}),
          kSpacing,
          200.0 * kSpacing};
}

ForceCase triangle_membrane_case(bool small, std::mt19937& rng) {
  const Cloth cloth(small ? 4 : 40);
  auto membrane = std::make_unique<TriangleMembrane>(make_membrane(cloth));
  // Area-lumped masses with density 0.2 kg/m^2, two corners pinned.
  VectorXd m = VectorXd::Zero(cloth.rest.cols());
  for (std::size_t e = 0; e < cloth.triangles.size(); ++e)
    for (Index i : cloth.triangles[e]) m[i] += 0.2 * membrane->rest_areas()[e] / 3.0;
  m[0] = m[3] = kInfinity;
  return {std::move(membrane), cloth.rest, cloth.deformed(rng), m, kSpacing, 300.0 * kSpacing};
}

ForceCase dihedral_bending_case(bool small, std::mt19937& rng) {
  const Cloth cloth(small ? 4 : 40);
  return {std::make_unique<DihedralBending>(make_implicit_bending(cloth)), cloth.rest, folded(cloth, rng),
          masses(cloth.rest.cols(), 0.2 * kSpacing * kSpacing, {0}),       kSpacing,   0.02 / kSpacing};
}

ForceCase corotated_tets_case(bool small, std::mt19937& rng) {
  const Block block = small ? Block() : Block(8);
  auto tets = std::make_unique<CorotatedTets>(make_tets(block));
  VectorXd m = VectorXd::Zero(block.rest.cols());
  for (std::size_t e = 0; e < block.tets.size(); ++e)
    for (Index i : block.tets[e]) m[i] += 1000.0 * tets->rest_volumes()[e] / 4.0;
  m[0] = kInfinity;
  return {std::move(tets), block.rest, block.deformed(rng), m, 1.0, 1e4};
}

// Particles at random in a box, each tied to the centroid of the next 1 to 5 (stencils of 2 to 6
// nodes, wrapping around).
ForceCase centroid_springs_case(bool small, std::mt19937& rng) {
  const Index n = small ? 12 : 2400;
  const Vectors3 rest = random_like(Vectors3::Zero(3, n), 1.0, rng);
  Stencils stencils;
  for (Index p = 0; p < n; ++p) {
    std::vector<Index> nodes{p};
    for (Index j = 1; j <= 1 + p % 5; ++j) nodes.push_back((p + j) % n);
    stencils.push_back(nodes);
  }
  Mat3 a;
  a << 1.2, 0.2, 0.0, -0.1, 0.8, 0.1, 0.1, 0.3, 1.1;
  const Vectors3 x = a * rest + random_like(rest, 0.1, rng);
  return {
      std::make_unique<CentroidSprings>(stencils, rest, CentroidSpringsSettings{.stiffness = 200.0, .damping = 0.7}),
      rest,
      x,
      masses(n, 0.01, {0}),
      0.5,
      200.0};
}

// Material particles on a jittered n x n x n lattice of unit spacing (support 2.5), volume 1 each;
// deformed by a turn of 40 degrees, a 5% stretch and noise. With the hourglass penalty, damping and
// the implicit option on, every term is checked.
ForceCase meshfree_corotated_case(bool small, std::mt19937& rng) {
  const int n = small ? 4 : 10;
  Vectors3 rest(3, n * n * n);
  for (int k = 0, c = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i, ++c) rest.col(c) = Vec3(i, j, k);
  rest += random_like(rest, 0.15, rng);
  std::vector<Index> particles(static_cast<std::size_t>(rest.cols()));
  for (Index i = 0; i < rest.cols(); ++i) particles[static_cast<std::size_t>(i)] = i;
  MeshfreeCorotatedSettings settings{.support_radius = 2.5,
                                     .young_modulus = 1e4,
                                     .poisson_ratio = 0.3,
                                     .beta = 0.01,
                                     .hourglass = 0.1,
                                     .implicit = true};
  auto force =
      std::make_unique<MeshfreeCorotated>(particles, rest, std::vector<double>(particles.size(), 1.0), settings);
  const Mat3 turn = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const Mat3 stretch = Vec3(1.05, 0.98, 1.0).asDiagonal();
  const Vectors3 x = (turn * stretch * rest) + random_like(rest, 0.05, rng);
  return {std::move(force), rest, x, masses(rest.cols(), 1000.0, {0}), 1.0, 1e4};
}

// Curved fibers (each edge turned from the last by up to 0.6 rad) of 5 particles (small) or 12,
// one straight; deformed by a turn, a stretch and noise.
ForceCase elastic_rods_case(bool small, std::mt19937& rng) {
  const int fibers = small ? 3 : 220, per = small ? 5 : 12;
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Vectors3 rest(3, fibers * per);
  std::vector<std::vector<Index>> lines;
  for (int k = 0; k < fibers; ++k) {
    Vec3 at(u(rng), u(rng), u(rng)), direction = Vec3(u(rng), u(rng), u(rng)).normalized();
    std::vector<Index> line;
    for (int i = 0; i < per; ++i) {
      const Index p = k * per + i;
      rest.col(p) = at;
      line.push_back(p);
      if (k > 0) direction = (direction + 0.6 * Vec3(u(rng), u(rng), u(rng))).normalized();
      at += 0.1 * direction;
    }
    lines.push_back(line);
  }
  auto force = std::make_unique<ElasticRods>(
      lines, rest,
      ElasticRodsSettings{.stretch_stiffness = 50.0, .bending_stiffness = 0.02, .beta = 0.01, .implicit = true});
  const Mat3 turn = Eigen::AngleAxisd(0.5, Vec3(0.3, -1, 0.2).normalized()).toRotationMatrix();
  const Vectors3 x = turn * Vec3(1.04, 0.97, 1.0).asDiagonal() * rest + random_like(rest, 0.01, rng);
  return {std::move(force), rest, x, masses(rest.cols(), 0.01, {0}), 0.1, 5.0};
}

struct NamedFactory {
  const char* name;
  ForceFactory make;
};

void PrintTo(const NamedFactory& factory, std::ostream* os) { *os << factory.name; }

const NamedFactory kForceFactories[] = {
    {"EdgeSprings", edge_springs_case},         {"TriangleMembrane", triangle_membrane_case},
    {"DihedralBending", dihedral_bending_case}, {"CorotatedTets", corotated_tets_case},
    {"CentroidSprings", centroid_springs_case}, {"MeshfreeCorotated", meshfree_corotated_case},
    {"ElasticRods", elastic_rods_case},
};

class EveryForce : public ::testing::TestWithParam<NamedFactory> {
 protected:
  std::mt19937 rng{17};
  ForceCase small() {
    ForceCase c = GetParam().make(true, rng);
    c.force->validate(c.rest.cols());
    c.force->set_implicit(c.force->has_definite_differentials());
    return c;
  }
};

/// The factor of K+ the implicit solves would use: 0 without a definite differential.
double implicit_b(const Force& force) { return force.has_definite_differentials() ? 0.25 : 0.0; }

Vectors3 implicit_products(const Force& force, const Vectors3& v, double b) {
  Vectors3 f = Vectors3::Zero(3, v.cols());
  force.add_implicit_products(v, b, f);
  return f;
}

TEST_P(EveryForce, ForceIsNegativeEnergyGradient) {
  ForceCase c = small();
  expect_force_is_negative_energy_gradient(*c.force, c.x, c.size);
}

TEST_P(EveryForce, DifferentialMatchesFiniteDifferences) {
  ForceCase c = small();
  expect_differential_matches_finite_differences(*c.force, c.x, c.size, rng);
}

// The exact differential is the negative Hessian of the energy, so symmetric (not definite).
TEST_P(EveryForce, DifferentialIsSymmetric) {
  ForceCase c = small();
  c.force->update_position_state(c.x);
  for (int trial = 0; trial < 5; ++trial) {
    const Vectors3 u = random_like(c.x, 1.0, rng), v = random_like(c.x, 1.0, rng);
    const Vectors3 ku = differentials(*c.force, u), kv = differentials(*c.force, v);
    const double scale = flat(u).norm() * flat(kv).norm() + flat(v).norm() * flat(ku).norm();
    ASSERT_GT(scale, 0.0);
    EXPECT_NEAR(flat(u).dot(flat(kv)), flat(v).dot(flat(ku)), 1e-12 * scale);
  }
}

TEST_P(EveryForce, DampingIsLinearSymmetricNegativeSemiDefinite) {
  ForceCase c = small();
  if (!c.force->has_damping()) GTEST_SKIP() << "no damping";
  expect_damping_linear_symmetric_nsd(*c.force, c.x, rng);
}

// The implicit products are D v + b K+ v with K+ symmetric negative semi-definite.
TEST_P(EveryForce, ImplicitProductsAreDampingPlusDefiniteDifferential) {
  ForceCase c = small();
  c.force->update_position_state(c.x);
  if (c.force->has_definite_differentials()) expect_definite_part_symmetric_nsd(*c.force, c.x, rng);
  const Vectors3 v = random_like(c.x, 1.0, rng);
  EXPECT_TRUE(implicit_products(*c.force, v, 0.0) == damping_forces(*c.force, v)) << "b = 0: the damping alone";
}

// What a force offers the preconditioners is the matrix its implicit products apply: the scalar
// diagonal is a third of each probed diagonal block's trace, the 3x3 blocks are the probed blocks,
// the pair blocks with the diagonal blocks assemble the products exactly, and the single pair
// blocks are the visited ones in their order. At b = 0 (damping alone) and at the step's b.
TEST_P(EveryForce, ImplicitBlocksAreTheProbedProducts) {
  ForceCase c = small();
  const ImplicitBlocks* offered = c.force->implicit_blocks();
  if (!offered) GTEST_SKIP() << "no implicit blocks offered";
  c.force->update_position_state(c.x);
  const Index n = c.x.cols();
  for (const double b : {0.0, implicit_b(*c.force)}) {
    MatrixXd dense(3 * n, 3 * n);
    for (Index j = 0; j < 3 * n; ++j) {
      Vectors3 e = Vectors3::Zero(3, n);
      e.data()[j] = 1.0;
      dense.col(j) = flat(implicit_products(*c.force, e, b));
    }
    const double scale = 1.0 + dense.norm();
    VectorXd diag = VectorXd::Zero(n);
    offered->add_diagonal(b, diag);
    for (Index i = 0; i < n; ++i)
      EXPECT_NEAR(diag[i], -dense.block(3 * i, 3 * i, 3, 3).trace() / 3.0, 1e-12 * scale)
          << "b " << b << ", particle " << i;
    ImplicitBlocks::Blocks blocks = ImplicitBlocks::Blocks::Zero(9, n);
    if (!offered->add_diagonal_blocks(b, blocks)) {
      EXPECT_TRUE(blocks.isZero()) << "declined, yet added";
      continue;
    }
    for (Index i = 0; i < n; ++i)
      EXPECT_LT((Eigen::Map<const Mat3>(blocks.col(i).data()) + dense.block(3 * i, 3 * i, 3, 3)).norm(), 1e-12 * scale)
          << "particle " << i;
    struct Assembled final : PairBlockSink {
      MatrixXd m;
      std::vector<Mat3> sequence;
      void add(Index i, Index j, const Mat3& block) override {
        m.block<3, 3>(3 * i, 3 * j) += block;
        m.block<3, 3>(3 * j, 3 * i) += block.transpose();
        sequence.push_back(block);
      }
    } assembled;
    assembled.m.setZero(3 * n, 3 * n);
    if (!offered->visit_pair_blocks(b, assembled)) continue;
    for (Index i = 0; i < n; ++i) assembled.m.block<3, 3>(3 * i, 3 * i) -= Eigen::Map<const Mat3>(blocks.col(i).data());
    EXPECT_LT((assembled.m - dense).norm(), 1e-12 * scale) << "b " << b;
    const Index count = offered->pair_block_count();
    if (count == 0) continue;
    ASSERT_EQ(count, static_cast<Index>(assembled.sequence.size()));
    for (Index k = 0; k < count; ++k)
      EXPECT_TRUE(offered->pair_block(k, b) == assembled.sequence[static_cast<std::size_t>(k)])
          << "b " << b << ", block " << k;
  }
}

TEST_P(EveryForce, ForcesBalanceAndEnergyIsRigidInvariant) {
  ForceCase c = small();
  expect_rigid_motion_invariance(*c.force, c.x);
}

TEST_P(EveryForce, ZeroForceAndEnergyAtRest) {
  ForceCase c = small();
  expect_at_rest(*c.force, c.rest, c.force_scale);
}

// The estimate is at most the exact limit 2 / sqrt(lambda_max(M^-1 K)) at rest, and not uselessly
// small (within 10x).
TEST_P(EveryForce, StableDtIsConservative) {
  ForceCase c = small();
  expect_stable_dt_conservative_within_10x(*c.force, c.rest, c.m);
}

// Above kMinChunkedElements elements the element loops split into chunks and run in parallel: every
// result must have the same bits on one thread and on two.
TEST_P(EveryForce, SameBitsOnOneAndTwoThreads) {
  ForceCase c = GetParam().make(false, rng);
  Force& force = *c.force;
  force.validate(c.rest.cols());
  force.set_implicit(force.has_definite_differentials());
  const Vectors3 v = random_like(c.x, 1.0, rng);
  const Index n = c.x.cols();
  auto evaluate = [&](int threads) {
    set_thread_count(threads);
    force.update_position_state(c.x);
    std::vector<Vectors3> out{elastic_forces(force, c.x), differentials(force, v), damping_forces(force, v),
                              implicit_products(force, v, implicit_b(force))};
    std::vector<double> scalars{force.potential_energy(c.x), force.stable_dt(c.m)};
    if (const ImplicitBlocks* offered = force.implicit_blocks()) {
      VectorXd diag = VectorXd::Zero(n);
      offered->add_diagonal(implicit_b(force), diag);
      scalars.insert(scalars.end(), diag.begin(), diag.end());
      ImplicitBlocks::Blocks blocks = ImplicitBlocks::Blocks::Zero(9, n);
      offered->add_diagonal_blocks(implicit_b(force), blocks);
      scalars.insert(scalars.end(), blocks.reshaped().begin(), blocks.reshaped().end());
    }
    set_thread_count(1);
    return std::make_pair(out, scalars);
  };
  const auto one = evaluate(1), two = evaluate(2);
  for (std::size_t k = 0; k < one.first.size(); ++k) EXPECT_TRUE(one.first[k] == two.first[k]) << "result " << k;
  EXPECT_TRUE(one.second == two.second);
  EXPECT_GT(flat(one.first[0]).norm(), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Forces, EveryForce, ::testing::ValuesIn(kForceFactories),
                         [](const ::testing::TestParamInfo<NamedFactory>& param) {
                           return std::string(param.param.name);
                         });

// ---------------------------------------------------------------------------------------------
// EdgeSprings

// The implicit products are D v + b K+ v: with every edge stretched K+ is the exact differential
// (checked against damping + differential); compressed, K+ drops the transverse term and stays
// symmetric negative semi-definite while the exact differential is not; the Jacobi diagonal is the
// probed third of the trace.
TEST(EdgeSprings, ImplicitProductsAreDampingPlusDefiniteDifferential) {
  std::mt19937 rng(11);
  const Cloth cloth;
  EdgeSprings springs = make_springs(cloth);
  const Index n = cloth.rest.cols();
  auto implicit = [&](const Vectors3& v, double b) {
    Vectors3 f = Vectors3::Zero(3, n);
    springs.add_implicit_products(v, b, f);
    return f;
  };
  ASSERT_TRUE(springs.has_definite_differentials());
  springs.update_position_state(1.1 * cloth.rest);  // every edge stretched by 10%
  for (int trial = 0; trial < 3; ++trial) {
    const Vectors3 v = random_like(cloth.rest, 1.0, rng);
    EXPECT_LT(relative_error(implicit(v, 0.25), damping_forces(springs, v) + 0.25 * differentials(springs, v)), 1e-13);
  }
  springs.update_position_state(0.8 * cloth.rest);  // every edge compressed
  expect_definite_part_symmetric_nsd(springs, cloth.rest, rng);
  // Out of the (flat) cloth's plane every edge moves transversally, where the exact differential of
  // a compressed spring pushes outwards (buckling).
  Vectors3 out_of_plane = Vectors3::Zero(3, n);
  out_of_plane.row(2) = random_like(cloth.rest, 1.0, rng).row(2);
  EXPECT_GT(flat(out_of_plane).dot(flat(differentials(springs, out_of_plane))), 0.0);  // what the clamp is for
  EXPECT_LE(flat(out_of_plane).dot(flat(implicit(out_of_plane, 1.0) - damping_forces(springs, out_of_plane))), 0.0);
  VectorXd diag = VectorXd::Zero(n);
  springs.update_position_state(1.1 * cloth.rest);
  springs.add_diagonal(0.25, diag);
  for (Index i = 0; i < n; ++i) {
    double trace = 0.0;
    for (Index c = 0; c < 3; ++c) {
      Vectors3 e = Vectors3::Zero(3, n);
      e(c, i) = 1.0;
      trace += implicit(e, 0.25)(c, i);
    }
    EXPECT_NEAR(diag[i], -trace / 3.0, 1e-12 * diag.maxCoeff()) << "particle " << i;
  }
}

// The block-Jacobi preconditioner's 3x3 blocks are the products' diagonal blocks (probed), stretched
// and compressed (where the transverse term is clamped).
TEST(EdgeSprings, DiagonalBlocksMatchProbedProducts) {
  std::mt19937 rng(12);
  const Cloth cloth;
  EdgeSprings springs = make_springs(cloth);
  const Index n = cloth.rest.cols();
  for (const Vectors3& x : {Vectors3(cloth.deformed(rng)), Vectors3(1.1 * cloth.rest), Vectors3(0.8 * cloth.rest)}) {
    springs.update_position_state(x);
    Eigen::Matrix<double, 9, Eigen::Dynamic> blocks = Eigen::Matrix<double, 9, Eigen::Dynamic>::Zero(9, n);
    ASSERT_TRUE(springs.add_diagonal_blocks(0.25, blocks));
    for (Index i = 0; i < n; ++i) {
      Mat3 probed;
      for (Index c = 0; c < 3; ++c) {
        Vectors3 e = Vectors3::Zero(3, n), f = Vectors3::Zero(3, n);
        e(c, i) = 1.0;
        springs.add_implicit_products(e, 0.25, f);
        probed.col(c) = -f.col(i);
      }
      const Mat3 block = Eigen::Map<const Mat3>(blocks.col(i).data());
      EXPECT_LT((block - probed).norm(), 1e-12 * (1.0 + probed.norm())) << "particle " << i;
      EXPECT_LT((block - block.transpose()).norm(), 1e-12 * (1.0 + probed.norm())) << "particle " << i;
    }
  }
}

// A mesh above the parallel threshold takes the chunked, vectorised product: it must equal the
// per-edge formula and give the same bits on 1 and 2 threads.
TEST(EdgeSprings, ChunkedProductsMatchPerEdgeSumsOnAnyThreadCount) {
  const int nx = 40;
  Vectors3 rest(3, nx * nx);
  std::vector<EdgeSprings::Edge> edges;
  for (int j = 0; j < nx; ++j)
    for (int i = 0; i < nx; ++i) {
      const Index a = j * nx + i;
      rest.col(a) = Vec3(0.05 * i, -0.05 * j, 0.0);
      if (i + 1 < nx) edges.push_back({a, a + 1});
      if (j + 1 < nx) edges.push_back({a, a + nx});
      if (i + 1 < nx && j + 1 < nx)
        edges.push_back((i + j) % 2 ? EdgeSprings::Edge{a, a + nx + 1} : EdgeSprings::Edge{a + 1, a + nx});
    }
  ASSERT_GE(static_cast<Index>(edges.size()), parallel::kMinChunkedElements);
  EdgeSprings springs(edges, rest, {.stiffness = 200.0, .damping = 0.05});
  std::mt19937 rng(13);
  Vectors3 x = 1.05 * rest + random_like(rest, 0.01, rng);
  springs.update_position_state(x);
  const Vectors3 v = random_like(rest, 1.0, rng);
  const double b = 1e-3, bk = b * 200.0;
  Vectors3 expected = Vectors3::Zero(3, rest.cols());
  for (std::size_t e = 0; e < edges.size(); ++e) {
    const auto [i, j] = edges[e];
    const Vec3 diff = x.col(j) - x.col(i);
    const Vec3 d = diff / diff.norm();
    const double t = std::max(0.0, 1.0 - (rest.col(j) - rest.col(i)).norm() / diff.norm());
    const Vec3 dv = v.col(j) - v.col(i);
    const Vec3 f = (0.05 + bk) * d.dot(dv) * d + bk * t * (dv - d.dot(dv) * d);
    expected.col(i) += f;
    expected.col(j) -= f;
  }
  auto product = [&](int threads) {
    set_thread_count(threads);
    Vectors3 f = Vectors3::Zero(3, rest.cols());
    springs.add_implicit_products(v, b, f);
    set_thread_count(1);
    return f;
  };
  const Vectors3 one = product(1), two = product(2);
  EXPECT_LT(relative_error(one, expected), 1e-14);
  EXPECT_TRUE(one == two);
}

// ChunkedScatter: elements in grid order (each chunk's nodes a band) add straight into f, even chunks
// then odd; the same elements shuffled (chunks spanning every node) fall back to per-chunk buffers.
// Either way every node gets its terms to round-off, with the same bits on one and two threads.
// Runs `scatter` through `chunks` on one and two threads into f = 0.5 everywhere: integer terms make
// the sums exact in any order, so both must equal `expected` bit for bit.
template <typename Scatter>
void expect_exact_on_one_and_two_threads(const ChunkedScatter& chunks, Scatter&& scatter, Index nodes,
                                         const Vectors3& expected) {
  auto run = [&](int threads) {
    set_thread_count(threads);
    Vectors3 f = Vectors3::Constant(3, nodes, 0.5);
    chunks.run(f, scatter);
    set_thread_count(1);
    return f;
  };
  const Vectors3 one = run(1), two = run(2);
  EXPECT_TRUE(one == expected) << "integer terms: exact in any order";
  EXPECT_TRUE(one == two);
}

TEST(ChunkedScatter, DirectAndBufferedChunksGiveEachNodeItsTermsOnAnyThreadCount) {
  const Index side = 60, nodes = side * side;
  std::vector<std::array<Index, 2>> grid;
  for (Index j = 0; j < side; ++j)
    for (Index i = 0; i + 1 < side; ++i) {
      grid.push_back({j * side + i, j * side + i + 1});
      if (j + 1 < side) grid.push_back({j * side + i, (j + 1) * side + i});
    }
  std::vector<std::array<Index, 2>> shuffled = grid;
  std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(31));
  ASSERT_GE(static_cast<Index>(grid.size()), parallel::kMinChunkedElements);
  for (const auto* elements : {&grid, &shuffled}) {
    const ChunkedScatter chunks(*elements, nodes);
    ASSERT_GE(chunks.chunks().size(), 4u);  // two or more chunks per half
    EXPECT_EQ(chunks.direct(), elements == &grid);
    // Element e adds (e + 1) (1, 2, 3) to its first node and subtracts it from its second.
    auto scatter = [&](const ChunkedScatter::Chunk& chunk, double* out) {
      for (Index e = chunk.begin; e < chunk.end; ++e) {
        const auto& [a, b] = (*elements)[static_cast<std::size_t>(e)];
        for (Index c = 0; c < 3; ++c) {
          out[3 * a + c] += static_cast<double>((e + 1) * (c + 1));
          out[3 * b + c] -= static_cast<double>((e + 1) * (c + 1));
        }
      }
    };
    Vectors3 expected = Vectors3::Constant(3, nodes, 0.5);
    for (std::size_t e = 0; e < elements->size(); ++e)
      for (Index c = 0; c < 3; ++c) {
        expected(c, (*elements)[e][0]) += static_cast<double>((e + 1) * (c + 1));
        expected(c, (*elements)[e][1]) -= static_cast<double>((e + 1) * (c + 1));
      }
    expect_exact_on_one_and_two_threads(chunks, scatter, nodes, expected);
  }
}

// ChunkedScatter over elements of varying size (Stencils, CSR): 2 to 5 nodes each, in grid order
// (direct) and shuffled (buffered). The chunks split the elements as they split fixed-size ones of
// the same count, and every node gets its terms with the same bits on one and two threads.
TEST(ChunkedScatter, VariableStencilsGiveEachNodeItsTermsOnAnyThreadCount) {
  const Index side = 80, nodes = side * side;
  std::vector<std::vector<Index>> grid;
  for (Index j = 0; j < side; ++j)
    for (Index i = 0; i + 1 < side; ++i) {
      const Index a = j * side + i;
      std::vector<Index> element{a, a + 1};
      for (Index extra = 0; extra < static_cast<Index>(grid.size() % 4) && a + side + extra < nodes; ++extra)
        element.push_back(a + side + extra);
      grid.push_back(element);
    }
  std::vector<std::vector<Index>> shuffled = grid;
  std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937(32));
  ASSERT_GE(static_cast<Index>(grid.size()), parallel::kMinChunkedElements);
  for (const auto* elements : {&grid, &shuffled}) {
    Stencils stencils;
    for (const auto& element : *elements) stencils.push_back(element);
    ASSERT_EQ(stencils.size(), static_cast<Index>(elements->size()));
    const ChunkedScatter chunks(stencils, nodes);
    const ChunkedScatter fixed(std::vector<std::array<Index, 2>>(elements->size()), nodes);
    ASSERT_EQ(chunks.chunks().size(), fixed.chunks().size());
    for (std::size_t c = 0; c < fixed.chunks().size(); ++c) {
      EXPECT_EQ(chunks.chunks()[c].begin, fixed.chunks()[c].begin);
      EXPECT_EQ(chunks.chunks()[c].end, fixed.chunks()[c].end);
    }
    ASSERT_GE(chunks.chunks().size(), 4u);
    EXPECT_EQ(chunks.direct(), elements == &grid);
    // Element e adds (e + 1) (a + 1) (1, 2, 3) to its a-th node.
    auto term = [](Index e, Index a, Index c) { return static_cast<double>((e + 1) * (a + 1) * (c + 1)); };
    auto scatter = [&](const ChunkedScatter::Chunk& chunk, double* out) {
      for (Index e = chunk.begin; e < chunk.end; ++e) {
        const std::span<const Index> element = stencils[e];
        for (std::size_t a = 0; a < element.size(); ++a)
          for (Index c = 0; c < 3; ++c) out[3 * element[a] + c] += term(e, static_cast<Index>(a), c);
      }
    };
    Vectors3 expected = Vectors3::Constant(3, nodes, 0.5);
    for (std::size_t e = 0; e < elements->size(); ++e)
      for (std::size_t a = 0; a < (*elements)[e].size(); ++a)
        for (Index c = 0; c < 3; ++c)
          expected(c, (*elements)[e][a]) += term(static_cast<Index>(e), static_cast<Index>(a), c);
    expect_exact_on_one_and_two_threads(chunks, scatter, nodes, expected);
  }
}

TEST(EdgeSprings, DampingDoesNotResistRigidRotation) {
  std::mt19937 rng(6);
  const Cloth cloth;
  EdgeSprings springs = make_springs(cloth);
  const Vectors3 x = cloth.deformed(rng);
  springs.update_position_state(x);
  const Vec3 w(0.3, -1.0, 2.0);
  Vectors3 v(3, x.cols());
  for (Index i = 0; i < x.cols(); ++i) v.col(i) = w.cross(Vec3(x.col(i))) + Vec3(1.0, 2.0, 3.0);
  EXPECT_LT(flat(damping_forces(springs, v)).norm(), 1e-12 * flat(v).norm());
}

TEST(EdgeSprings, StableDtIsConservativeForAChain) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> mass(0.5, 2.0);
  const Index n = 6;
  Vectors3 rest(3, n);
  VectorXd m(n);
  std::vector<Edge> edges;
  for (Index i = 0; i < n; ++i) {
    rest.col(i) = Vec3(0.1 * static_cast<double>(i), 0.02 * static_cast<double>(i % 2), 0.0);
    m[i] = mass(rng);
    if (i > 0) edges.push_back({i - 1, i});
  }
  m[0] = kInfinity;  // pinned end: skipped by the estimate, eliminated from the exact problem
  EdgeSprings springs(edges, rest, {.stiffness = 150.0, .damping = 0.0});
  expect_stable_dt_conservative_within_10x(springs, rest, m);
  // The Gershgorin bound itself: 2 / sqrt(max_i 2 sum_k / m_i).
  double omega_sq = 0.0;
  for (Index i = 1; i < n; ++i) omega_sq = std::max(omega_sq, 2.0 * 150.0 * (i + 1 < n ? 2.0 : 1.0) / m[i]);
  EXPECT_DOUBLE_EQ(springs.stable_dt(m), 2.0 / std::sqrt(omega_sq));
}

// ---------------------------------------------------------------------------------------------
// TriangleMembrane

TEST(TriangleMembrane, DampingAtRestIsBetaTimesStiffness) {
  const Cloth cloth;
  TriangleMembrane membrane = make_membrane(cloth);
  membrane.update_position_state(cloth.rest);
  const MatrixXd k = dense_stiffness(membrane, cloth.rest.cols());
  MatrixXd d(k.rows(), k.cols());
  for (Index j = 0; j < k.cols(); ++j) {
    Vectors3 e = Vectors3::Zero(3, cloth.rest.cols());
    e.data()[j] = 1.0;
    d.col(j) = flat(damping_forces(membrane, e));
  }
  EXPECT_LT((d + membrane.settings().beta * k).norm(), 1e-12 * d.norm());
}

TEST(TriangleMembrane, ZeroForceAndEnergyAtRest) {
  const Cloth cloth;
  expect_at_rest(make_membrane(cloth), cloth.rest, 300.0 * kSpacing);
  // Also for a rest shape that is not planar and not axis-aligned.
  const Mat3 q = Eigen::AngleAxisd(0.4, Vec3(1.0, 1.0, 0.0).normalized()).toRotationMatrix();
  Vectors3 curved = q * cloth.rest;
  for (Index i = 0; i < curved.cols(); ++i) curved(2, i) += 0.2 * curved(0, i) * curved(0, i);
  expect_at_rest(TriangleMembrane(cloth.triangles, curved, {.mu = 300.0, .lambda = 150.0}), curved, 300.0 * kSpacing);
}

TEST(TriangleMembrane, UniformStretchEnergyMatchesClosedForm) {
  // Stretching a unit-area sheet by s along x: E = diag((s^2 - 1) / 2, 0).
  const Cloth cloth;
  const TriangleMembrane membrane(cloth.triangles, cloth.rest, {.mu = 300.0, .lambda = 150.0});
  const double s = 1.3;
  Vectors3 x = cloth.rest;
  x.row(0) *= s;
  const double e = 0.5 * (s * s - 1.0);
  const double area = 9.0 * kSpacing * kSpacing;
  const double expected = area * (300.0 * e * e + 0.5 * 150.0 * e * e);
  EXPECT_NEAR(membrane.potential_energy(x), expected, 1e-12 * expected);
}

// ---------------------------------------------------------------------------------------------
// DihedralBending

// Implicit bending: the products are D v + b K+ v with K+ = -2 k_b w g g^T (Gauss-Newton). Where
// every hinge is at its rest angle (here the rest sheet turned rigidly) that is the exact
// differential; bent, K+ stays symmetric negative semi-definite while the exact differential need
// not; the diagonal blocks are the probed products' blocks.
TEST(DihedralBending, ImplicitProductsAreDampingPlusGaussNewtonDifferential) {
  std::mt19937 rng(21);
  const Cloth cloth;
  DihedralBending bending(DihedralBending::hinges_from_triangles(cloth.triangles), cloth.rest,
                          {.stiffness = 0.02, .damping = 0.003, .implicit = true});
  ASSERT_TRUE(bending.has_definite_differentials());
  EXPECT_FALSE(make_bending(cloth).has_definite_differentials());  // explicit unless asked
  const Index n = cloth.rest.cols();
  bending.set_implicit(true);
  auto implicit = [&](const Vectors3& v, double b) {
    Vectors3 f = Vectors3::Zero(3, n);
    bending.add_implicit_products(v, b, f);
    return f;
  };
  const Mat3 turn = Eigen::AngleAxisd(0.7, Vec3(1, 2, -1).normalized()).toRotationMatrix();
  bending.update_position_state(turn * cloth.rest);
  for (int trial = 0; trial < 3; ++trial) {
    const Vectors3 v = random_like(cloth.rest, 1.0, rng);
    EXPECT_LT(relative_error(implicit(v, 0.25), damping_forces(bending, v) + 0.25 * differentials(bending, v)), 1e-12);
  }
  bending.update_position_state(folded(cloth, rng));
  expect_definite_part_symmetric_nsd(bending, cloth.rest, rng);
  Eigen::Matrix<double, 9, Eigen::Dynamic> blocks = Eigen::Matrix<double, 9, Eigen::Dynamic>::Zero(9, n);
  ASSERT_TRUE(bending.add_diagonal_blocks(0.25, blocks));
  for (Index i = 0; i < n; ++i) {
    Mat3 probed;
    for (Index c = 0; c < 3; ++c) {
      Vectors3 e = Vectors3::Zero(3, n);
      e(c, i) = 1.0;
      probed.col(c) = -implicit(e, 0.25).col(i);
    }
    EXPECT_LT((Eigen::Map<const Mat3>(blocks.col(i).data()) - probed).norm(), 1e-12 * (1.0 + probed.norm()))
        << "particle " << i;
  }
}

TEST(DihedralBending, HingesFromTrianglesFindsEachInteriorEdgeOnce) {
  const Cloth cloth;
  const std::vector<Hinge> hinges = DihedralBending::hinges_from_triangles(cloth.triangles);
  // 3x3 cells: 33 edges, 12 on the boundary.
  ASSERT_EQ(hinges.size(), 21u);
  for (std::size_t h = 0; h < hinges.size(); ++h) {
    const Hinge& v = hinges[h];
    // Sorted by edge key, and (x0, x1, x2) is a triangle in its own winding.
    if (h > 0) {
      const Hinge& u = hinges[h - 1];
      EXPECT_LT(std::make_pair(std::min(u[0], u[1]), std::max(u[0], u[1])),
                std::make_pair(std::min(v[0], v[1]), std::max(v[0], v[1])));
    }
    const bool found = std::any_of(cloth.triangles.begin(), cloth.triangles.end(), [&](const Triangle& t) {
      for (std::size_t a = 0; a < 3; ++a) {
        if (t[a] == v[0] && t[(a + 1) % 3] == v[1] && t[(a + 2) % 3] == v[2]) return true;
      }
      return false;
    });
    EXPECT_TRUE(found) << "hinge " << h;
  }
  // Flat and consistently wound: every rest angle is zero.
  const DihedralBending bending(hinges, cloth.rest);
  for (double theta0 : bending.rest_angles()) EXPECT_EQ(theta0, 0.0);
}

/// A single hinge: edge x0 = 0, x1 = e_x; x2 at +y (triangle 1 normal +z), x3 at -y.
struct SingleHinge {
  Vectors3 rest;
  SingleHinge() {
    rest.resize(3, 4);
    rest << 0.0, 1.0, 0.3, 0.6,  //
        0.0, 0.0, 1.0, -0.8,     //
        0.0, 0.0, 0.0, 0.0;
  }
  /// x3's wing rotated by a about the edge direction x1 - x0 (right-handed).
  Vectors3 folded_by(double a) const {
    Vectors3 x = rest;
    x.col(3) = Eigen::AngleAxisd(a, Vec3::UnitX()) * Vec3(rest.col(3));
    return x;
  }
};

// The force kernel evaluates two hinges per SSE2 register and the last odd one alone; every lane
// must give a hinge the bits of the one-hinge evaluation. Seven disjoint hinges (no node shared, so
// each node's force is one hinge's term, with no order of summation involved), each against a force
// holding only that hinge, at random folds and rest shapes.
TEST(DihedralBending, PairedKernelGivesEachHingeTheBitsOfOneHingeAlone) {
  std::mt19937 rng(31);
  const int count = 7;
  const SingleHinge single;
  Vectors3 rest(3, 4 * count), x(3, 4 * count);
  std::vector<DihedralBending::Hinge> hinges;
  for (int k = 0; k < count; ++k) {
    const Vectors3 r = single.folded_by(0.2 * k) + random_like(single.rest, 0.05, rng);
    rest.middleCols(4 * k, 4) = r;
    x.middleCols(4 * k, 4) = single.folded_by(0.3 - 0.25 * k) + random_like(single.rest, 0.1, rng);
    hinges.push_back({4 * k, 4 * k + 1, 4 * k + 2, 4 * k + 3});
  }
  const DihedralBendingSettings settings{.stiffness = 0.02, .damping = 0.003};
  DihedralBending all(hinges, rest, settings);
  Vectors3 f = Vectors3::Zero(3, 4 * count);
  all.add_elastic_forces(x, f);
  for (int k = 0; k < count; ++k) {
    DihedralBending one({{0, 1, 2, 3}}, rest.middleCols(4 * k, 4), settings);
    Vectors3 f_one = Vectors3::Zero(3, 4);
    one.add_elastic_forces(x.middleCols(4 * k, 4), f_one);
    EXPECT_TRUE(f.middleCols(4 * k, 4) == f_one) << "hinge " << k;
    EXPECT_GT(f_one.norm(), 0.0);
  }
}

// The force's angle: within 7.1 degrees of the rest angle it comes from a series rather than atan2.
// Read back from the force on x3, f_3 = -2 k_b w delta g_3 with g_3 = -|e| n2 / |n2|^2, it must be
// the fold angle to round-off on both sides of that threshold, near flat, and far from rest (on a
// flat and on a curved rest shape, so the angle is measured from theta0).
TEST(DihedralBending, ForceAngleIsTheFoldAngleToRoundOff) {
  const SingleHinge hinge;
  const double k_b = 0.05;
  for (const double rest_angle : {0.0, 0.7}) {
    const Vectors3 rest = hinge.folded_by(rest_angle);
    const DihedralBending bending({{0, 1, 2, 3}}, rest, {.stiffness = k_b});
    const double w = bending.weights()[0];
    for (double d : {-3.0, -0.5, -0.13, -0.124, -0.02, -1e-6, 1e-12, 1e-5, 0.05, 0.1239, 0.1241, 0.2, 1.0, 2.9}) {
      const Vectors3 x = hinge.folded_by(rest_angle + d);
      Vectors3 f = Vectors3::Zero(3, 4);
      bending.add_elastic_forces(x, f);
      const Vec3 e = x.col(1) - x.col(0), n2 = (x.col(3) - x.col(0)).cross(e);
      const double delta = f.col(3).dot(n2) / (2.0 * k_b * w * e.norm());
      EXPECT_NEAR(delta, d, 1e-14 * std::abs(d) + 1e-16) << "rest " << rest_angle << ", delta " << d;
    }
  }
}

TEST(DihedralBending, FoldedFlatHingeHasAngleAndClosedFormEnergy) {
  const SingleHinge hinge;
  const double k_b = 0.05;
  const DihedralBending bending({{0, 1, 2, 3}}, hinge.rest, {.stiffness = k_b});
  // Rest areas 0.5 and 0.4, |e0| = 1.
  ASSERT_DOUBLE_EQ(bending.weights()[0], 3.0 / 0.9);
  // Near flat and near fully folded included: atan2 keeps full relative precision there.
  for (double a : {-3.1, -2.0, -0.3, -1e-7, 1e-9, 1e-4, 0.5, 1.5, 2.5, 3.14159}) {
    const Vectors3 x = hinge.folded_by(a);
    const double theta = DihedralBending::dihedral_angle(x.col(0), x.col(1), x.col(2), x.col(3));
    EXPECT_NEAR(theta, a, 1e-14 * std::max(1.0, std::abs(a))) << "a = " << a;
    EXPECT_NEAR(theta / a, 1.0, 1e-9) << "a = " << a;
    EXPECT_NEAR(bending.potential_energy(x), k_b * (3.0 / 0.9) * a * a, 1e-13 * std::max(a * a, 1e-30)) << "a = " << a;
  }
  // Documented sign: positive when x3 lies on the side of triangle 1 opposite to its normal (+z).
  EXPECT_LT(hinge.folded_by(0.5)(2, 3), 0.0);
}

TEST(DihedralBending, CurvedRestShapeIsAtRest) {
  const SingleHinge hinge;
  const Vectors3 rest = hinge.folded_by(0.7);
  const DihedralBending bending({{0, 1, 2, 3}}, rest, {.stiffness = 0.05});
  EXPECT_NEAR(bending.rest_angles()[0], 0.7, 1e-14);
  expect_at_rest(bending, rest, 0.05);
  // Folding further by b costs k w b^2 relative to the curved rest angle.
  const Vectors3 x = hinge.folded_by(0.7 + 0.2);
  EXPECT_NEAR(bending.potential_energy(x), 0.05 * (3.0 / 0.9) * 0.04, 1e-14);

  // A cylinder patch: every hinge curved at rest.
  const Cloth cloth;
  Vectors3 cylinder(3, cloth.rest.cols());
  for (Index i = 0; i < cylinder.cols(); ++i) {
    const double phi = cloth.rest(0, i) / 0.5;
    cylinder.col(i) = Vec3(0.5 * std::sin(phi), cloth.rest(1, i), 0.5 * (1.0 - std::cos(phi)));
  }
  const DihedralBending curved(DihedralBending::hinges_from_triangles(cloth.triangles), cylinder, {.stiffness = 0.02});
  // The sheet curves toward its normal (+z), so by the sign convention every angle is <= 0; the
  // hinges across the cylinder's rulings carry the 0.5 rad chord angle, the others are flat.
  EXPECT_NEAR(*std::min_element(curved.rest_angles().begin(), curved.rest_angles().end()), -0.5, 1e-12);
  EXPECT_LE(*std::max_element(curved.rest_angles().begin(), curved.rest_angles().end()), 1e-12);
  expect_at_rest(curved, cylinder, 0.02 / kSpacing);
}

TEST(DihedralBending, RestAngleNearFullFoldDoesNotJump) {
  // With theta0 = 3.1, folding 0.1 further crosses theta = pi; the wrapped difference keeps the
  // energy k w 0.1^2 instead of jumping to k w (2 pi - 0.1)^2.
  const SingleHinge hinge;
  const DihedralBending bending({{0, 1, 2, 3}}, hinge.folded_by(3.1), {.stiffness = 0.05});
  EXPECT_NEAR(bending.potential_energy(hinge.folded_by(3.2)), 0.05 * (3.0 / 0.9) * 0.01, 1e-13);
}

// ---------------------------------------------------------------------------------------------
// CorotatedTets

/// The single tet with x3 pushed through the face (x0, x1, x2).
Vectors3 inverted_tet() {
  Vectors3 x = single_tet_positions();
  x.col(3) = Vec3(0.2, 0.3, -0.4);
  return x;
}

TEST(CorotatedTets, DifferentialMatchesFiniteDifferencesWhenInverted) {
  std::mt19937 rng(33);
  CorotatedTets tets({{0, 1, 2, 3}}, single_tet_positions(), {.young_modulus = 1e4, .poisson_ratio = 0.3});
  const Vectors3 x = inverted_tet();
  tets.update_position_state(x);
  expect_force_is_negative_energy_gradient(tets, x, 1.0);
  expect_differential_matches_finite_differences(tets, x, 1.0, rng);
}

// Each tet keeps the SVD of the F it last saw and reuses it for the same F: forces and energy read
// through that cache are the bits a fresh force gives, whatever positions the state was taken at,
// and so is a rigid translation (the same F from other positions).
TEST(CorotatedTets, CachedDecompositionGivesTheBitsOfAFreshOne) {
  std::mt19937 rng(35);
  const Block block(2);
  CorotatedTets cached = make_tets(block);
  const Vectors3 x = block.deformed(rng), y = block.deformed(rng);
  const Vectors3 moved = x.colwise() + Vec3(0.25, -0.5, 1.0);
  for (const Vectors3* state : {&y, &x}) {
    cached.update_position_state(*state);
    for (const Vectors3* at : {&x, &y, &moved}) {
      const CorotatedTets fresh = make_tets(block);
      const Vectors3 f = elastic_forces(cached, *at), g = elastic_forces(fresh, *at);
      EXPECT_EQ(0, std::memcmp(f.data(), g.data(), sizeof(double) * std::size_t(f.size())));
      const double e = cached.potential_energy(*at), e_fresh = fresh.potential_energy(*at);
      EXPECT_EQ(0, std::memcmp(&e, &e_fresh, sizeof e));
    }
  }
}

// CorotatedTetsSettings::implicit: K+ (the warped stiffness, R held fixed) is offered only when asked,
// symmetric and negative semi-definite at any state, and where the stress vanishes (rest, or rest
// turned rigidly) it is the exact differential.
TEST(CorotatedTets, WarpedStiffnessIsSymmetricDefiniteAndExactWhereTheStressVanishes) {
  std::mt19937 rng(36);
  const Block block(2);
  CorotatedTetsSettings settings{.young_modulus = 1e4, .poisson_ratio = 0.35, .beta = 0.0};
  EXPECT_FALSE(CorotatedTets(block.tets, block.rest, settings).has_definite_differentials());
  settings.implicit = true;
  CorotatedTets tets(block.tets, block.rest, settings);
  EXPECT_TRUE(tets.has_definite_differentials());
  const auto k_plus = [&](const Vectors3& v) {
    Vectors3 f = Vectors3::Zero(3, v.cols());
    tets.add_implicit_products(v, 1.0, f);
    return f;
  };
  const Mat3 R = Eigen::AngleAxisd(1.1, Vec3(0.3, -1.0, 0.6).normalized()).toRotationMatrix();
  const Vectors3 turned = (R * block.rest).colwise() + Vec3(0.4, 2.0, -1.0);
  for (const Vectors3* at : {&block.rest, &turned}) {
    tets.update_position_state(*at);
    for (int trial = 0; trial < 3; ++trial) {
      const Vectors3 dx = random_like(*at, 1.0, rng);
      EXPECT_LT(relative_error(k_plus(dx), differentials(tets, dx)), 1e-12);
    }
  }
  const Vectors3 x = block.deformed(rng);
  tets.update_position_state(x);
  for (int trial = 0; trial < 5; ++trial) {
    const Vectors3 u = random_like(x, 1.0, rng), v = random_like(x, 1.0, rng);
    const double uKv = flat(u).dot(flat(k_plus(v))), vKu = flat(v).dot(flat(k_plus(u)));
    EXPECT_NEAR(uKv, vKu, 1e-12 * std::abs(uKv));
    EXPECT_LE(flat(v).dot(flat(k_plus(v))), 0.0);
  }
  // With damping, D v + b K+ v is the same operator at beta + b.
  CorotatedTetsSettings damped = settings;
  damped.beta = 0.25;
  CorotatedTets with_damping(block.tets, block.rest, damped);
  with_damping.update_position_state(x);
  const Vectors3 v = random_like(x, 1.0, rng);
  Vectors3 f = Vectors3::Zero(3, v.cols());
  with_damping.add_implicit_products(v, 0.5, f);
  EXPECT_LT(relative_error(f, 0.75 * k_plus(v)), 1e-13);
}

// A block hanging from its top face in gravity: stepped implicitly at one 1/60 s step a frame
// (StepSettings::automatic picks it), it comes to the rest state the explicit step reaches at its
// stable substeps, and its energy never grows on the way.
TEST(CorotatedTets, ImplicitTetsReachTheExplicitRestStateAtOneStepAFrame) {
  const auto hang = [](bool implicit, int* substeps) {
    const Block block(3);
    System s;
    VolumeMaterial material;
    material.density = 1000.0;
    material.young_modulus = 2e5;
    material.damping = 0.02;
    material.implicit = implicit;
    const Vectors3 x0 = 0.1 * block.rest;
    const std::vector<Index> particles = add_volume(s, x0, block.tets, material);
    for (Index k = 0; k < x0.cols(); ++k)
      if (x0(2, k) > 0.3 - 1e-12) {
        const Index pin = s.add_kinematic_particle(x0.col(k));
        const std::array<Index, 1> parent{pin};
        const std::array<double, 1> one{1.0};
        s.bind_linear(particles[static_cast<std::size_t>(k)], parent, one);
      }
    s.set_gravity(Vec3(0.0, 0.0, -9.81));
    double first = 0.0, gain = -kInfinity;
    *substeps = 0;
    for (int frame = 0; frame < 240; ++frame) {
      *substeps += s.advance(1.0 / 60.0).substeps;
      const double e = s.kinetic_energy() + s.potential_energy();
      if (frame == 0) first = e;
      gain = std::max(gain, e - first);
    }
    EXPECT_LT(gain, 1e-9 * std::abs(first));
    return Vectors3(s.particles().x.leftCols(x0.cols()));
  };
  int explicit_substeps = 0, implicit_substeps = 0;
  const Vectors3 reference = hang(false, &explicit_substeps), implicit = hang(true, &implicit_substeps);
  EXPECT_LE(implicit_substeps, 240 * 2);
  EXPECT_GT(explicit_substeps, 4 * implicit_substeps);
  const double sag = 0.3 - reference.row(2).minCoeff();
  EXPECT_GT(sag, 0.001);
  EXPECT_LT((flat(implicit) - flat(reference)).cwiseAbs().maxCoeff(), 1e-3 * sag);
  std::printf("substeps over 4 s: %d explicit, %d implicit\n", explicit_substeps, implicit_substeps);
}

TEST(CorotatedTets, InvertedTetForcePushesTowardUninversion) {
  CorotatedTets tets({{0, 1, 2, 3}}, single_tet_positions(), {.young_modulus = 1e4, .poisson_ratio = 0.3});
  Vectors3 x = inverted_tet();
  const auto volume = [](const Vectors3& p) {
    return (p.col(1) - p.col(0)).cross(p.col(2) - p.col(0)).dot(p.col(3) - p.col(0)) / 6.0;
  };
  ASSERT_LT(volume(x), 0.0);
  const Vectors3 f = elastic_forces(tets, x);
  ASSERT_TRUE(f.allFinite());
  EXPECT_GT(f(2, 3), 0.0);  // x3 is pushed back up through the face
  const double h = 1e-3 / flat(f).norm();
  EXPECT_LT(tets.potential_energy(x + h * f), tets.potential_energy(x));
  // Gradient descent along the force un-inverts the tet and comes to rest at the rest shape.
  for (int it = 0; it < 20000 && tets.potential_energy(x) > 1e-16; ++it) x += 2e-5 * elastic_forces(tets, x);
  EXPECT_GT(volume(x), 0.0);
  EXPECT_NEAR(volume(x), 1.0 / 6.0, 1e-6);
}

TEST(CorotatedTets, ZeroForceAndEnergyAtRest) {
  const Block block;
  const CorotatedTets tets = make_tets(block);
  expect_at_rest(tets, block.rest, 1e4);
  // A rigidly rotated copy is also at rest: the corotated energy ignores rotation exactly.
  const Mat3 q = Eigen::AngleAxisd(2.5, Vec3(0.2, -1.0, 0.4).normalized()).toRotationMatrix();
  expect_at_rest(tets, q * block.rest, 1e4);
}

TEST(CorotatedTets, UniformScaleEnergyMatchesClosedForm) {
  const Block block;
  const CorotatedTets tets = make_tets(block);
  const double s = 1.1;
  // F = s I on the whole unit cube (volume 1): sigma_i = s.
  const double strain = s - 1.0;
  const double expected = tets.mu() * 3.0 * strain * strain + 0.5 * tets.lambda() * 9.0 * strain * strain;
  EXPECT_NEAR(tets.potential_energy(s * block.rest), expected, 1e-10 * expected);
}

// ---------------------------------------------------------------------------------------------
// Bad input: every case throws sinew::Error whose message names the item.

struct BadInputCase {
  std::string label;
  std::function<void()> build;
  std::string expected;  ///< substring of what()
};

void PrintTo(const BadInputCase& c, std::ostream* os) { *os << c.label; }

class BadInput : public ::testing::TestWithParam<BadInputCase> {};

TEST_P(BadInput, ThrowsErrorNamingTheItem) {
  const BadInputCase& c = GetParam();
  try {
    c.build();
    FAIL() << "no sinew::Error thrown";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(c.expected), std::string::npos) << "message: " << e.what();
  }
}

Vectors3 three_points() {
  Vectors3 x(3, 3);
  x << 0.0, 1.0, 0.0,  //
      0.0, 0.0, 1.0,   //
      0.0, 0.0, 0.0;
  return x;
}

/// The unit tet's vertices and a fifth point x4, for a second tet on the face (x1, x2, x3).
Vectors3 five_points(const Vec3& x4) {
  Vectors3 x(3, 5);
  x.leftCols(4) = single_tet_positions();
  x.col(4) = x4;
  return x;
}

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One line per bad input: the table reads as one.
// clang-format off
const BadInputCase kBadInputs[] = {
    {"springs_nan_stiffness", [] { EdgeSprings({{0, 1}}, three_points(), {.stiffness = kNaN}); },
     "edge springs: stiffness is nan"},
    {"springs_negative_stiffness", [] { EdgeSprings({{0, 1}}, three_points(), {.stiffness = -1.0}); },
     "edge springs: stiffness is negative"},
    {"springs_inf_damping", [] { EdgeSprings({{0, 1}}, three_points(), {.damping = kInfinity}); },
     "edge springs: damping is inf"},
    {"springs_index_out_of_range", [] { EdgeSprings({{0, 1}, {1, 7}}, three_points()); },
     "edge 1: vertex index 7 out of range [0, 3)"},
    {"springs_repeated_index", [] { EdgeSprings({{0, 1}, {2, 2}}, three_points()); },
     "edge 1: vertex index 2 is repeated"},
    {"springs_zero_length",
     [] {
       Vectors3 x = three_points();
       x.col(2) = x.col(1);
       EdgeSprings({{0, 1}, {1, 2}}, x);
     },
     "edge 1 has zero rest length"},
    {"springs_non_finite_rest",
     [] {
       Vectors3 x = three_points();
       x(1, 2) = kNaN;
       EdgeSprings({{0, 1}, {1, 2}}, x);
     },
     "edge 1: rest position of vertex 2 is not finite"},
    {"springs_validate_out_of_range", [] { EdgeSprings({{0, 1}, {1, 2}}, three_points()).validate(2); },
     "edge 1: vertex index 2 out of range [0, 2)"},
    {"springs_stable_dt_short_masses",
     [] { (void)EdgeSprings({{0, 1}, {1, 2}}, three_points()).stable_dt(VectorXd::Ones(2)); },
     "edge springs: stable_dt got 2 masses"},
    {"membrane_nan_mu", [] { TriangleMembrane({{0, 1, 2}}, three_points(), {.mu = kNaN}); },
     "triangle membrane: mu is nan"},
    {"membrane_negative_beta", [] { TriangleMembrane({{0, 1, 2}}, three_points(), {.beta = -0.1}); },
     "triangle membrane: beta is negative"},
    {"membrane_lambda_below_minus_mu",
     [] { TriangleMembrane({{0, 1, 2}}, three_points(), {.mu = 1.0, .lambda = -2.0}); },
     "triangle membrane: lambda -2"},
    {"membrane_index_out_of_range", [] { TriangleMembrane({{0, 1, 900}}, three_points()); },
     "triangle 0: vertex index 900 out of range [0, 3)"},
    {"membrane_negative_index", [] { TriangleMembrane({{0, 1, 2}, {-1, 1, 2}}, three_points()); },
     "triangle 1: vertex index -1 out of range"},
    {"membrane_repeated_index", [] { TriangleMembrane({{0, 1, 2}, {2, 1, 2}}, three_points()); },
     "triangle 1: vertex index 2 is repeated"},
    {"membrane_zero_area",
     [] {
       Vectors3 x(3, 4);
       x.leftCols(3) = three_points();
       x.col(3) = Vec3(2.0, 0.0, 0.0);  // collinear with x0, x1
       TriangleMembrane({{0, 1, 2}, {0, 1, 3}}, x);
     },
     "triangle 1 is degenerate (area 0)"},
    {"bending_nan_stiffness", [] { DihedralBending({{0, 1, 2, 3}}, SingleHinge().rest, {.stiffness = kNaN}); },
     "dihedral bending: stiffness is nan"},
    {"bending_negative_damping", [] { DihedralBending({{0, 1, 2, 3}}, SingleHinge().rest, {.damping = -1.0}); },
     "dihedral bending: damping is negative"},
    {"bending_repeated_index", [] { DihedralBending({{0, 1, 2, 3}, {0, 1, 2, 2}}, SingleHinge().rest); },
     "hinge 1: vertex index 2 is repeated"},
    {"bending_index_out_of_range", [] { DihedralBending({{0, 1, 2, 4}}, SingleHinge().rest); },
     "hinge 0: vertex index 4 out of range [0, 4)"},
    {"bending_degenerate_wing",
     [] {
       Vectors3 x = SingleHinge().rest;
       x.col(3) = Vec3(3.0, 0.0, 0.0);  // on the hinge line
       DihedralBending({{0, 1, 2, 3}}, x);
     },
     "hinge 0: triangle (0, 1, 3) is degenerate"},
    {"bending_zero_edge",
     [] {
       Vectors3 x = SingleHinge().rest;
       x.col(1) = x.col(0);
       DihedralBending({{0, 1, 2, 3}}, x);
     },
     "hinge 0: shared edge (0, 1) has zero rest length"},
    {"bending_non_manifold_edge",
     [] { (void)DihedralBending::hinges_from_triangles({{0, 1, 2}, {1, 0, 3}, {0, 1, 4}}); },
     "edge (0, 1) is shared by 3 triangles"},
    {"bending_triangle_with_repeated_index",
     [] { (void)DihedralBending::hinges_from_triangles({{0, 1, 2}, {1, 1, 3}}); },
     "triangle 1: vertex index 1 is repeated"},
    {"tets_inverted_rest",
     [] { CorotatedTets({{0, 1, 2, 3}, {1, 3, 2, 4}}, five_points(Vec3(1.0, 1.0, 1.0))); },
     "tet 1 is inverted (volume -"},
    {"tets_flat_rest",
     [] { CorotatedTets({{0, 1, 2, 3}, {1, 3, 2, 4}}, five_points(Vec3(0.5, 0.0, 0.5))); },
     "tet 1 is degenerate (volume"},
    {"tets_index_out_of_range", [] { CorotatedTets({{0, 1, 2, 3}, {1, 3, 2, 5}}, five_points(Vec3::Ones())); },
     "tet 1: vertex index 5 out of range [0, 5)"},
    {"tets_repeated_index", [] { CorotatedTets({{0, 1, 2, 3}, {1, 3, 3, 4}}, five_points(Vec3::Ones())); },
     "tet 1: vertex index 3 is repeated"},
    {"tets_negative_young", [] { CorotatedTets({{0, 1, 2, 3}}, single_tet_positions(), {.young_modulus = -5.0}); },
     "corotated tets: young_modulus is negative"},
    {"tets_zero_young", [] { CorotatedTets({{0, 1, 2, 3}}, single_tet_positions(), {.young_modulus = 0.0}); },
     "corotated tets: young_modulus is 0"},
    {"tets_nan_poisson", [] { CorotatedTets({{0, 1, 2, 3}}, single_tet_positions(), {.poisson_ratio = kNaN}); },
     "corotated tets: poisson_ratio is nan"},
    {"tets_incompressible_poisson",
     [] { CorotatedTets({{0, 1, 2, 3}}, single_tet_positions(), {.poisson_ratio = 0.5}); },
     "corotated tets: poisson_ratio 0.5 is outside (-1, 0.5)"},
    {"tets_nan_beta", [] { CorotatedTets({{0, 1, 2, 3}}, single_tet_positions(), {.beta = kNaN}); },
     "corotated tets: beta is nan"},
};
// clang-format on

INSTANTIATE_TEST_SUITE_P(AllForces, BadInput, ::testing::ValuesIn(kBadInputs),
                         [](const ::testing::TestParamInfo<BadInputCase>& case_info) { return case_info.param.label; });

}  // namespace
}  // namespace sinew
