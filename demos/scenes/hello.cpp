#include "bullet_scenes.hpp"

namespace sinew::scenes {
namespace {

// The Bullet hello-world (a ground plane and a falling sphere) with a cloth bound to the sphere.
class Hello final : public BulletScene {
 public:
  Hello() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, at(btVector3(0, 0, 0)))->setFriction(0.8);
    btCollisionShape* ball = m_world.keep(std::make_unique<btSphereShape>(0.3));
    btRigidBody* sphere = m_world.add_body(ball, 1.0, at(btVector3(0, 2.0, 0)));
    sphere->setActivationState(DISABLE_DEACTIVATION);
    // The same cloth as the plain program demos/hello.cpp adds.
    ClothGridSettings c;
    c.nx = c.ny = 15;
    c.width = c.height = 1.2;
    c.mass = 0.2;
    c.origin = Vec3(-0.6, 2.31, -0.6);
    c.across = Vec3::UnitX();
    c.down = Vec3::UnitZ();
    const ClothGrid cloth = add_cloth_grid(system(), c);
    add_surface("cloth", cloth.triangles);
    coupling().attach(cloth.node(7, 7), sphere, Vec3(0, 0.3, 0), 1e4);
  }
};

SINEW_REGISTER_SCENE(bullet_scene<Hello>(
    {.name = "hello",
     .description = "Bullet's hello world (a sphere falling on a ground plane) with a cloth bound to the sphere",
     .gallery_frame = 90}));

}  // namespace
}  // namespace sinew::scenes
