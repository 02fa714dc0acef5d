// Sub-element plasticity (Sifakis et al. 2007, section 4, figure 9): a target yields to its soft
// particle until the binding spring is L_y long, is re-embedded where the material is, never leaves
// the material, and the re-embedding keeps mass, momentum and angular momentum while the energy drops
// by exactly what the spring stored past L_y.
#include "sinew/builders.hpp"
#include "sinew/plasticity.hpp"
#include "sinew/system.hpp"

#include "cloth.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace sinew {
namespace {

constexpr double kHalf = 0.1;        // the block is [-kHalf, kHalf]^3
constexpr double kSpacing = 0.05;    // lattice cells
constexpr double kYield = 0.01;      // L_y
constexpr double kStiffness = 50.0;  // binding springs

// A free block in zero gravity with targets on its top face (a 3 x 3 grid) and a soft particle on a
// binding spring at each.
struct Block {
  System system;
  scenes::ClosedSurface surface;
  EmbeddedVolume volume;
  std::unique_ptr<PlasticSurface> plastic;
  std::vector<Index> targets, soft;

  explicit Block(double inset = 0.05) : system(settings()) {
    surface = scenes::box_surface(Vec3::Constant(-kHalf), Vec3::Constant(kHalf), 2);
    VolumeMaterial material;
    material.density = 500.0;
    material.young_modulus = 1e4;
    volume = add_embedded_volume(system, surface.vertices, surface.triangles, kSpacing, material);
    plastic = std::make_unique<PlasticSurface>(volume.embedding.vertices, volume.embedding.tets, volume.lattice,
                                               surface.vertices, surface.triangles, kYield);
    for (int i = -1; i <= 1; ++i)
      for (int k = -1; k <= 1; ++k) {
        const Vec3 X(i * inset, kHalf, k * inset);
        const Index t = plastic->add_target(system, X);
        const Index s = system.add_particle(X, Vec3::Zero(), 0.0);
        SoftBindingSettings binding;
        binding.particle = s;
        binding.target = t;
        binding.stiffness = kStiffness;
        system.add_soft_binding(binding);
        plastic->track(s, t);
        targets.push_back(t);
        soft.push_back(s);
      }
    system.finalize();
  }

  static SystemSettings settings() {
    SystemSettings s;
    s.gravity = Vec3::Zero();
    return s;
  }
  Vec3 x(Index i) const { return system.particles().x.col(i); }
};

TEST(Plasticity, AYieldingSpringComesBackToTheYieldLengthAndTheTargetMovesInMaterialSpace) {
  Block block;
  const Index t = block.targets[4], s = block.soft[4];  // the centre of the top face
  const Vec3 X0 = block.plastic->material_point(t);
  block.system.particles().x.col(s) += Vec3(0.0, -0.03, 0.0);
  const YieldStats stats = block.plastic->yield(block.system);
  EXPECT_EQ(stats.moved, 1);
  EXPECT_EQ(stats.stopped, 0);
  EXPECT_NEAR((block.x(s) - block.x(t)).norm(), kYield, 1e-15);
  // The block is at rest and undeformed: material space is world space; the target went 2 cm down.
  EXPECT_LT((block.plastic->material_point(t) - (X0 + Vec3(0.0, -0.02, 0.0))).norm(), 1e-15);
  EXPECT_LT(block.system.max_hard_binding_drift(), 1e-16);
  // The other springs were not stretched: their targets stay.
  EXPECT_EQ(block.plastic->yield(block.system).moved, 0);
}

TEST(Plasticity, OnATurnedAndStretchedBlockTheMoveIsMappedBackThroughTheDeformation) {
  Block block;
  // x = c + R A X: every lattice node, and the bound rows with them.
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1.0, 2.0, -0.5).normalized()).toRotationMatrix();
  Mat3 A = Mat3::Identity();
  A(1, 1) = 0.8;
  A(0, 2) = 0.15;
  const Vec3 c(0.3, -1.0, 2.0);
  const Mat3 F = R * A;
  for (const Index i : block.volume.lattice) block.system.particles().x.col(i) = c + F * block.x(i);
  block.system.clamp_bound_rows();
  const Index t = block.targets[0], s = block.soft[0];
  const Vec3 X0 = block.plastic->material_point(t);
  ASSERT_LT((block.x(t) - (c + F * X0)).norm(), 1e-14);
  // Pulled 5 cm into the block along its turned "down": the target crosses cells (a walk of tets).
  const Vec3 world_down = -(R * Vec3::UnitY());
  block.system.particles().x.col(s) = block.x(t) + 0.05 * world_down;
  const YieldStats stats = block.plastic->yield(block.system);
  ASSERT_EQ(stats.moved, 1);
  EXPECT_NEAR((block.x(s) - block.x(t)).norm(), kYield, 1e-14);
  const Vec3 expected = X0 + F.inverse() * (0.04 * world_down);
  EXPECT_LT((block.plastic->material_point(t) - expected).norm(), 1e-14);
  EXPECT_NEAR(stats.largest_move, (expected - X0).norm(), 1e-14);
}

TEST(Plasticity, ATargetNeverLeavesTheMaterial) {
  Block block(0.09);  // targets 1 cm inside the top face's edges
  // Pulled straight out of the top face: no step along the move stays in the material.
  const Index t = block.targets[4], s = block.soft[4];
  const Vec3 X0 = block.plastic->material_point(t);
  block.system.particles().x.col(s) += Vec3(0.0, 0.03, 0.0);
  YieldStats stats = block.plastic->yield(block.system);
  EXPECT_EQ(stats.moved, 0);
  EXPECT_EQ(block.plastic->material_point(t), X0);
  // Down and out through the side x = kHalf: the target stops on that side, inside the material.
  const Index t2 = block.targets[7], s2 = block.soft[7];  // at (0.09, 0.1, 0)
  block.system.particles().x.col(s2) += Vec3(0.04, -0.03, 0.0);
  stats = block.plastic->yield(block.system);
  ASSERT_EQ(stats.moved, 1);  // the first target still has no step inside: it stays
  EXPECT_EQ(stats.stopped, 1);
  const Vec3 X = block.plastic->material_point(t2);
  EXPECT_LE(X.x(), kHalf);
  EXPECT_GT(X.x(), kHalf - 1e-9);
  EXPECT_LT(X.y(), kHalf);
  EXPECT_GT((block.x(s2) - block.x(t2)).norm(), kYield);  // stopped short: the spring stays longer
}

TEST(Plasticity, ReEmbeddingKeepsMassMomentumAndAngularMomentumAndDropsTheSpringsEnergy) {
  Block block;
  // Everything moving: a spin and a drift on the lattice, the soft particles with their own motion.
  for (const Index i : block.volume.lattice)
    block.system.particles().v.col(i) = Vec3(0.2, -0.1, 0.3) + Vec3(0.0, 1.5, 0.4).cross(block.x(i));
  block.system.clamp_bound_rows();
  for (std::size_t k = 0; k < block.soft.size(); ++k) {
    block.system.particles().x.col(block.soft[k]) += Vec3(0.003 * k, -0.02 - 0.003 * k, 0.005);
    block.system.particles().v.col(block.soft[k]) = Vec3(0.1, 0.05 * k, -0.2);
  }
  double mass = 0.0;
  for (Index i = 0; i < block.system.particles().size(); ++i) mass += block.system.particles().mass[i];
  const Vec3 P = block.system.linear_momentum(true), L = block.system.angular_momentum(true);
  const double kinetic = block.system.kinetic_energy(true), potential = block.system.potential_energy();
  double stored_past_yield = 0.0;
  for (std::size_t k = 0; k < block.soft.size(); ++k) {
    const double length = (block.x(block.soft[k]) - block.x(block.targets[k])).norm();
    if (length > kYield) stored_past_yield += 0.5 * kStiffness * (length * length - kYield * kYield);
  }
  const YieldStats stats = block.plastic->yield(block.system);
  EXPECT_EQ(stats.moved, 9);
  EXPECT_EQ(stats.stopped, 0);
  double mass_after = 0.0;
  for (Index i = 0; i < block.system.particles().size(); ++i) mass_after += block.system.particles().mass[i];
  EXPECT_EQ(mass_after, mass);
  EXPECT_EQ(block.system.linear_momentum(true), P);
  EXPECT_EQ(block.system.angular_momentum(true), L);
  EXPECT_EQ(block.system.kinetic_energy(true), kinetic);
  EXPECT_NEAR(potential - block.system.potential_energy(), stored_past_yield, 1e-14 * stored_past_yield);
  EXPECT_GT(stored_past_yield, 0.0);
  // And stepping on after it: the next set-up keeps the soft particles' masses.
  block.system.step(1e-3);
  double mass_stepped = 0.0;
  for (Index i = 0; i < block.system.particles().size(); ++i) mass_stepped += block.system.particles().mass[i];
  EXPECT_EQ(mass_stepped, mass);
}

TEST(Plasticity, BadInputIsNamedAndChangesNothing) {
  Block block;
  EXPECT_THROW(
      {
        try {
          PlasticSurface(block.volume.embedding.vertices, block.volume.embedding.tets, block.volume.lattice,
                         block.surface.vertices, block.surface.triangles, std::nan(""));
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find("yield length"), std::string::npos) << e.what();
          throw;
        }
      },
      Error);
  EXPECT_THROW(block.plastic->add_target(block.system, Vec3(5.0, 0.0, 0.0)), Error);
  EXPECT_THROW(block.plastic->track(block.soft[0], block.soft[1]), Error);
  // System::reembed: a point with mass, a free particle, weights that do not sum to one.
  const Index lattice0 = block.volume.lattice[0], lattice1 = block.volume.lattice[1];
  const Index parents[2] = {lattice0, lattice1};
  const double half[2] = {0.5, 0.5}, bad[2] = {0.5, 0.6};
  try {
    block.system.reembed(lattice0, parents, half);
    ADD_FAILURE() << "re-embedded a lattice node with mass";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("particle " + std::to_string(lattice0)), std::string::npos) << e.what();
  }
  EXPECT_THROW(block.system.reembed(block.soft[0], parents, half), Error);  // soft-bound, not embedded
  const Vec3 before = block.x(block.targets[0]);
  EXPECT_THROW(block.system.reembed(block.targets[0], parents, bad), Error);
  EXPECT_EQ(block.x(block.targets[0]), before);
  block.system.reembed(block.targets[0], parents, half);
  EXPECT_EQ(block.x(block.targets[0]), 0.5 * (block.x(lattice0) + block.x(lattice1)));
}

}  // namespace
}  // namespace sinew
