#include "bullet_scenes.hpp"

namespace sinew::scenes {
namespace {

// A 40 x 40 cloth bound by its top row to a box that spins and tumbles in the air (no gravity, nothing
// else): a passive scene, so its energy only falls. The box's spin swings the cloth round with a
// centripetal load, and its explicit bending needs twelve substeps per 1/240 s tick; System::advance
// chooses implicit elasticity instead (sinew-demo spinning-box --fixed-scheme runs it explicitly).
class SpinningBox final : public BulletScene {
 public:
  SpinningBox() : BulletScene(btVector3(0, 0, 0)) {
    btCollisionShape* shape = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.6, 0.05, 0.05)));
    btRigidBody* box = m_world.add_body(shape, 1.0, at(btVector3(0, 2, 0)));
    box->setAngularVelocity(btVector3(0, 10, 3));
    box->setActivationState(DISABLE_DEACTIVATION);
    ClothGridSettings c;
    c.nx = c.ny = 40;
    c.width = c.height = 1.2;
    c.mass = 0.3;
    c.origin = Vec3(-0.6, 1.95, 0.0);
    const ClothGrid cloth = add_cloth_grid(system(), c);
    add_surface("cloth", cloth.triangles);
    for (int i = 0; i < c.nx; ++i) coupling().bind_here(cloth.node(i, 0), box);
  }
};

SINEW_REGISTER_SCENE(bullet_scene<SpinningBox>(
    {.name = "spinning-box",
     .description = "a 40 x 40 cloth bound by its top row to a box spinning in the air: the scheme sinew chooses "
                    "(--fixed-scheme: as set)"}));

}  // namespace
}  // namespace sinew::scenes
