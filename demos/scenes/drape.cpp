#include "bullet_scenes.hpp"

#include <cmath>
#include <numbers>
#include <string>

namespace sinew::scenes {
namespace {

// A square cloth falls onto a Bullet body turning on a table, folds onto itself and slides off: a
// kinematic box (0.3 m, turning at a quarter turn a second about the vertical) on a static table, the
// 30 x 30 cloth of 0.8 m dropped from 0.3 m above it, with CouplingSettings::self_collisions.
class Drape final : public BulletScene {
 public:
  Drape() : BulletScene(btVector3(0, -9.81, 0), with_self_collisions()) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, at(btVector3(0, 0, 0)))->setFriction(0.8);
    btCollisionShape* table = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.5, 0.2, 0.5)));
    m_world.add_body(table, 0.0, at(btVector3(0, 0.2, 0)));
    btCollisionShape* block = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.15, 0.15, 0.15)));
    m_block = m_world.add_body(block, 0.0, at(btVector3(0, 0.55, 0)));
    m_block->setCollisionFlags(m_block->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    m_block->setActivationState(DISABLE_DEACTIVATION);
    m_block->setFriction(0.5);
    ClothGridSettings c;
    c.nx = c.ny = 30;
    c.width = c.height = 0.8;
    c.mass = 0.2;
    c.stretch_stiffness = 500.0;
    c.origin = Vec3(-0.35, 1.0, -0.45);
    c.down = Vec3(0.0, 0.0, 1.0);
    m_cloth = add_cloth_grid(system(), c);
    add_surface("cloth", m_cloth.triangles);
  }
  void before_frame(double t) override {
    const double angle = 0.5 * std::numbers::pi * t;  // a quarter turn a second
    m_block->getMotionState()->setWorldTransform(
        at(btVector3(0, 0.55, 0), btQuaternion(btVector3(0, 1, 0), btScalar(angle))));
  }
  const ClothGrid& cloth() const { return m_cloth; }

 private:
  btRigidBody* m_block = nullptr;
  ClothGrid m_cloth;
};

// Three cloths dropped onto each other and onto a box: 16 x 16 cloths of 0.6 m, each turned by 30
// degrees from the last, 0.12 m apart, falling onto a 0.4 m box on the ground, with
// CouplingSettings::self_collisions.
class Stack final : public BulletScene {
 public:
  Stack() : BulletScene(btVector3(0, -9.81, 0), with_self_collisions()) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, at(btVector3(0, 0, 0)))->setFriction(0.8);
    btCollisionShape* box = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.2, 0.2, 0.2)));
    m_world.add_body(box, 0.0, at(btVector3(0, 0.2, 0)));
    for (int k = 0; k < 3; ++k) {
      const double angle = k * std::numbers::pi / 6.0;
      const Vec3 across(std::cos(angle), 0.0, std::sin(angle)), down(-std::sin(angle), 0.0, std::cos(angle));
      ClothGridSettings c;
      c.nx = c.ny = 16;
      c.width = c.height = 0.6;
      c.mass = 0.1;
      c.stretch_stiffness = 300.0;
      c.across = across;
      c.down = down;
      c.origin = Vec3(0.0, 0.5 + 0.12 * k, 0.0) - 0.3 * across - 0.3 * down;
      const ClothGrid cloth = add_cloth_grid(system(), c);
      add_surface("cloth " + std::to_string(k + 1), cloth.triangles);
    }
  }
};

SINEW_REGISTER_SCENE(bullet_scene<Drape>(
    {.name = "drape",
     .description = "a cloth falls onto a block turning on a table, folds onto itself and slides off (self contact)",
     .gallery_frame = 90}));
SINEW_REGISTER_SCENE(
    bullet_scene<Stack>({.name = "stack",
                         .description = "three cloths dropped onto each other and onto a box (contact between cloths)",
                         .gallery_frame = 90}));

}  // namespace
}  // namespace sinew::scenes
