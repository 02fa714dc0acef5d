// Volumes from closed surfaces (Sifakis et al. 2007, section 2): the inside test, the BCC lattice and
// its fills against the volume the surface encloses, the embedding's weights, and an embedded ball
// simulated in sinew's step.
#include "sinew/builders.hpp"
#include "sinew/collision.hpp"
#include "sinew/forces/corotated_tets.hpp"
#include "sinew/lattice.hpp"

#include "cloth.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>

namespace sinew {
namespace {

using Surface = scenes::ClosedSurface;

Surface icosphere(int levels, double radius, const Vec3& centre = Vec3::Zero()) {
  return scenes::sphere_surface(levels, radius, centre);
}

// The closed surface of the box [lo, hi], two triangles a face.
Surface box_surface(const Vec3& lo, const Vec3& hi) {
  Surface s;
  s.vertices.resize(3, 8);
  for (int k = 0; k < 8; ++k)
    s.vertices.col(k) = Vec3(k & 1 ? hi.x() : lo.x(), k & 2 ? hi.y() : lo.y(), k & 4 ? hi.z() : lo.z());
  s.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return s;
}

double inscribed_radius(const Surface& s) {
  double r = kInfinity;
  for (const auto& t : s.triangles) {
    const Vec3 a = s.vertices.col(t[0]), b = s.vertices.col(t[1]), c = s.vertices.col(t[2]);
    r = std::min(r, std::abs((b - a).cross(c - a).normalized().dot(a)));
  }
  return r;
}

double tet_volume(const Vectors3& x, const std::array<Index, 4>& t) {
  return (x.col(t[1]) - x.col(t[0])).cross(x.col(t[2]) - x.col(t[0])).dot(x.col(t[3]) - x.col(t[0])) / 6.0;
}

TEST(SurfaceInside, AgreesWithTheSphereItApproximatesEvenOnRaysThroughItsVertices) {
  const Surface s = icosphere(3, 0.5);
  const SurfaceInside inside(s.vertices, s.triangles);
  const double r_in = inscribed_radius(s);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-0.7, 0.7);
  int checked = 0;
  auto check = [&](const Vec3& p) {
    const double r = p.norm();
    if (r < r_in * 0.999) {
      EXPECT_TRUE(inside.inside(p)) << p.transpose();
      ++checked;
    } else if (r > 0.5 * 1.001) {
      EXPECT_FALSE(inside.inside(p)) << p.transpose();
      ++checked;
    }
  };
  for (int k = 0; k < 20000; ++k) check(Vec3(u(rng), u(rng), u(rng)));
  // Rays along +x through every vertex and every edge's midpoint (y, z exactly theirs).
  for (Index v = 0; v < s.vertices.cols(); ++v)
    for (double x : {-0.6, -0.2, 0.0, 0.2, 0.6}) check(Vec3(x, s.vertices(1, v), s.vertices(2, v)));
  for (const auto& t : s.triangles)
    for (int e = 0; e < 3; ++e) {
      const Vec3 m = 0.5 * (s.vertices.col(t[e]) + s.vertices.col(t[(e + 1) % 3]));
      for (double x : {-0.6, -0.1, 0.1, 0.6}) check(Vec3(x, m.y(), m.z()));
    }
  EXPECT_GT(checked, 10000);
  // The divergence theorem's volume lies between the inscribed and circumscribed balls'.
  EXPECT_GT(inside.enclosed_volume(), 4.0 / 3.0 * M_PI * std::pow(r_in, 3));
  EXPECT_LT(inside.enclosed_volume(), 4.0 / 3.0 * M_PI * std::pow(0.5, 3));
}

TEST(SurfaceInside, ABoxSeenAlongItsFacesAndEdges) {
  const Surface s = box_surface(Vec3(0, 0, 0), Vec3(1, 2, 3));
  const SurfaceInside inside(s.vertices, s.triangles);
  EXPECT_DOUBLE_EQ(inside.enclosed_volume(), 6.0);
  // Rays along the faces' diagonals and through the corners' (y, z): each decided as a slightly
  // moved ray would be, never counted twice or missed by both triangles of an edge.
  for (double y : {0.0, 0.5, 1.0, 2.0 / 3.0, 2.0})
    for (double z : {0.0, 0.75, 1.5, 3.0}) {
      const bool strictly = y > 0.0 && y < 2.0 && z > 0.0 && z < 3.0;
      EXPECT_FALSE(inside.inside(Vec3(-0.5, y, z))) << y << " " << z;
      EXPECT_FALSE(inside.inside(Vec3(1.5, y, z))) << y << " " << z;
      if (strictly) {
        EXPECT_TRUE(inside.inside(Vec3(0.5, y, z))) << y << " " << z;
      }
    }
  // Inside as the perturbed point (y + eps, z + eps^2) is: on the lower faces y = 0 or z = 0 it
  // moves in, on the upper ones out.
  EXPECT_TRUE(inside.inside(Vec3(0.5, 0.0, 1.0)));
  EXPECT_FALSE(inside.inside(Vec3(0.5, 2.0, 1.0)));
}

TEST(SurfaceInside, RefusesWhatIsNotAClosedSurfaceByName) {
  const auto message = [](const Surface& s) {
    try {
      SurfaceInside inside(s.vertices, s.triangles);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  Surface open = box_surface(Vec3::Zero(), Vec3::Ones());
  open.triangles.pop_back();  // a hole: the edges of the missing triangle are used once
  EXPECT_NE(message(open).find("is used by 1 triangle(s)"), std::string::npos) << message(open);
  Surface fin = box_surface(Vec3::Zero(), Vec3::Ones());
  fin.triangles.push_back({0, 1, 7});  // edge (0, 1) in three triangles
  EXPECT_NE(message(fin).find("edge (0, 1) is used by 3"), std::string::npos) << message(fin);
  Surface nan = box_surface(Vec3::Zero(), Vec3::Ones());
  nan.vertices(1, 5) = std::nan("");
  EXPECT_NE(message(nan).find("vertex 5 is not finite"), std::string::npos) << message(nan);
  Surface bad = box_surface(Vec3::Zero(), Vec3::Ones());
  bad.triangles[3][1] = 8;
  EXPECT_NE(message(bad).find("triangle 3 refers to vertex 8"), std::string::npos) << message(bad);
  EXPECT_NE(message(Surface{}).find("no triangles"), std::string::npos);
}

TEST(BccLattice, MaterialVolumeConvergesToTheEnclosedVolume) {
  const Surface s = icosphere(4, 0.5, Vec3(0.013, -0.021, 0.007));
  const double enclosed = SurfaceInside(s.vertices, s.triangles).enclosed_volume();
  double last_error = kInfinity;
  for (double spacing : {0.2, 0.1, 0.05}) {
    const EmbeddedLattice lattice = bcc_lattice(s.vertices, s.triangles, spacing);
    double material = 0.0, whole = 0.0;
    for (std::size_t t = 0; t < lattice.tets.size(); ++t) {
      const double v = tet_volume(lattice.vertices, lattice.tets[t]);
      EXPECT_NEAR(v, spacing * spacing * spacing / 12.0, 1e-12) << "tet " << t;  // congruent, positive
      EXPECT_GT(lattice.fill[t], 0.0);
      EXPECT_LE(lattice.fill[t], 1.0);
      material += lattice.fill[t] * v;
      whole += v;
    }
    const double error = std::abs(material - enclosed) / enclosed;
    EXPECT_LT(error, last_error) << "spacing " << spacing;
    EXPECT_GT(whole, enclosed);  // the kept tets cover the material
    last_error = error;
  }
  EXPECT_LT(last_error, 0.005);
}

TEST(BccLattice, EverySurfaceVertexSitsAtItsWeightsInTheTetThatHoldsIt) {
  const Surface s = icosphere(3, 0.3);
  const EmbeddedLattice lattice = bcc_lattice(s.vertices, s.triangles, 0.07);
  ASSERT_EQ(lattice.host.size(), static_cast<std::size_t>(s.vertices.cols()));
  for (Index v = 0; v < s.vertices.cols(); ++v) {
    const auto& t = lattice.tets[static_cast<std::size_t>(lattice.host[static_cast<std::size_t>(v)])];
    const auto& w = lattice.weights[static_cast<std::size_t>(v)];
    Vec3 x = Vec3::Zero();
    double sum = 0.0;
    for (int k = 0; k < 4; ++k) {
      EXPECT_GE(w[static_cast<std::size_t>(k)], -1e-12) << "vertex " << v;
      x += w[static_cast<std::size_t>(k)] * lattice.vertices.col(t[static_cast<std::size_t>(k)]);
      sum += w[static_cast<std::size_t>(k)];
    }
    EXPECT_NEAR(sum, 1.0, 1e-14);
    EXPECT_LT((x - s.vertices.col(v)).norm(), 1e-14) << "vertex " << v;
  }
}

TEST(BccLattice, RefusesABadSpacingByName) {
  const Surface s = icosphere(1, 0.5);
  for (double spacing : {0.0, -0.1, std::nan(""), kInfinity, 1e-5}) {
    try {
      bcc_lattice(s.vertices, s.triangles, spacing);
      ADD_FAILURE() << "accepted spacing " << spacing;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("spacing"), std::string::npos) << e.what();
    }
  }
}

// A tet holding a part f of material: energy and forces are f times the whole tet's, at any
// deformation; fractions outside (0, 1] or of the wrong count are refused by name.
TEST(CorotatedTetsFraction, ScalesEnergyAndForcesByTheMaterialItHolds) {
  Vectors3 rest(3, 5);
  rest << 0, 1, 0, 0, 1, 0, 0, 1, 0, 1, 0, 0, 0, 1, 1;
  const std::vector<CorotatedTets::Tet> tets = {{0, 1, 2, 3}, {1, 2, 3, 4}};
  CorotatedTetsSettings whole, part;
  part.volume_fraction = {0.25, 0.6};
  for (const auto& t : tets) ASSERT_GT(tet_volume(rest, t), 0.0);
  Vectors3 x = rest;
  x.col(4) += Vec3(0.2, -0.1, 0.3);
  x.col(0) += Vec3(-0.05, 0.02, 0.0);
  // Each tet alone, whole, against the two with their fractions.
  double energy = 0.0;
  Vectors3 f = Vectors3::Zero(3, 5);
  for (std::size_t e = 0; e < tets.size(); ++e) {
    CorotatedTets one({tets[e]}, rest, whole);
    one.update_position_state(x);
    energy += part.volume_fraction[e] * one.potential_energy(x);
    Vectors3 fe = Vectors3::Zero(3, 5);
    one.add_elastic_forces(x, fe);
    f += part.volume_fraction[e] * fe;
  }
  CorotatedTets both(tets, rest, part);
  both.update_position_state(x);
  Vectors3 f_both = Vectors3::Zero(3, 5);
  both.add_elastic_forces(x, f_both);
  EXPECT_GT(energy, 0.0);
  EXPECT_NEAR(both.potential_energy(x), energy, 1e-12 * energy);
  EXPECT_LT((f_both - f).norm(), 1e-12 * f.norm());
  for (const std::vector<double>& bad : {std::vector<double>{0.0, 1.0}, std::vector<double>{0.5, 1.5},
                                         std::vector<double>{0.5, std::nan("")}, std::vector<double>{0.5}}) {
    CorotatedTetsSettings s;
    s.volume_fraction = bad;
    try {
      CorotatedTets t(tets, rest, s);
      ADD_FAILURE() << "accepted a bad volume_fraction";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("volume_fraction"), std::string::npos) << e.what();
    }
  }
}

// A ball of material embedded in its lattice: the system's mass is the material's, and in a step
// the surface follows the lattice exactly while momentum goes as gravity says.
TEST(EmbeddedVolume, CarriesTheMaterialsMassAndTheSurfaceFollowsTheLattice) {
  const Surface s = icosphere(3, 0.2, Vec3(0, 1, 0));
  System system;
  system.set_gravity(Vec3(0, -9.81, 0));
  VolumeMaterial material;
  material.density = 500.0;
  material.young_modulus = 2e4;
  const EmbeddedVolume ball = add_embedded_volume(system, s.vertices, s.triangles, 0.05, material);
  system.finalize();
  const double enclosed = SurfaceInside(s.vertices, s.triangles).enclosed_volume();
  double mass = 0.0;
  for (Index p : ball.lattice) mass += system.particles().mass[p];
  EXPECT_NEAR(mass, material.density * enclosed, 0.01 * material.density * enclosed);
  // Set spinning and moving; the elastic forces are internal, so momentum changes by m g t alone.
  for (Index p : ball.lattice) {
    const Vec3 r = system.particles().x.col(p) - Vec3(0, 1, 0);
    system.particles().v.col(p) = Vec3(0.3, 0.0, -0.2) + Vec3(0.0, 4.0, 1.0).cross(r);
  }
  const Vec3 p0 = system.linear_momentum();
  const double dt = 1.0 / 240.0;
  for (int k = 0; k < 60; ++k) system.advance(dt);
  const Vec3 expected = p0 + mass * Vec3(0, -9.81, 0) * 60 * dt;
  EXPECT_LT((system.linear_momentum() - expected).norm(), 1e-9 * mass);
  for (std::size_t v = 0; v < ball.surface.size(); ++v) {
    const auto& t = ball.embedding.tets[static_cast<std::size_t>(ball.embedding.host[v])];
    Vec3 x = Vec3::Zero();
    for (int k = 0; k < 4; ++k)
      x += ball.embedding.weights[v][static_cast<std::size_t>(k)] *
           system.particles().x.col(ball.lattice[static_cast<std::size_t>(t[static_cast<std::size_t>(k)])]);
    EXPECT_LT((system.particles().x.col(ball.surface[v]) - x).norm(), 1e-12) << "surface vertex " << v;
  }
}

}  // namespace
}  // namespace sinew
