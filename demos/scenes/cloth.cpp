#include "cloth.hpp"

namespace sinew::scenes {

HangingCloth add_hanging_cloth(System& system, const HangingClothSettings& s) {
  HangingCloth scene;
  scene.cloth = add_cloth_grid(system, s.cloth);
  const ClothGridSettings& c = s.cloth;
  // The rod: a slender rigid body along the top edge, a little above it.
  RigidBodySettings rod;
  rod.x = c.origin + 0.5 * c.width * c.across - 0.02 * c.down;
  rod.q = Quat::FromTwoVectors(Vec3::UnitX(), c.across);
  rod.mass = s.rod_mass;
  const double length = c.width * 1.1, radius = 0.01;
  const double axial = 0.5 * s.rod_mass * radius * radius;
  const double transverse = s.rod_mass * (3 * radius * radius + length * length) / 12.0;
  rod.inertia = Vec3(axial, transverse, transverse);
  scene.rod = system.add_rigid_body(rod);
  const Vec3 normal = c.across.cross(c.down).normalized();
  for (int i = 0; i < c.nx; ++i) {
    const Index node = scene.cloth.node(i, 0);
    // A point of the rod directly above the node, tied to the node by a binding spring.
    const Index point = system.add_particle(system.particles().x.col(node), Vec3::Zero(), 0.0);
    system.bind_rigid_here(point, scene.rod);
    system.add_binding_spring({node, point, s.binding_stiffness, 1.0});
    scene.rod_points.push_back(point);
  }
  for (int end = 0; end < 2; ++end) {
    const Vec3 at = rod.x + (end == 0 ? -0.5 : 0.5) * length * c.across;
    const Index anchor = system.add_kinematic_particle(at);
    const Index point = system.add_particle(at, Vec3::Zero(), 0.0);
    system.bind_rigid_here(point, scene.rod);
    system.add_binding_spring({point, anchor, 100.0 * s.binding_stiffness, 1.0});
  }
  for (Index node : scene.cloth.nodes) system.particles().v.col(node) = s.initial_speed * normal;
  return scene;
}

}  // namespace sinew::scenes
