#include "bullet_scenes.hpp"

namespace sinew::scenes {
namespace {

// Three rigid plates with cloth sheets hard-bound between them, held by two rigid bodies that Bullet
// constrains to the world, swinging under gravity.
class Plates final : public BulletScene {
 public:
  Plates() : BulletScene(btVector3(0, -9.81, 0)) {
    const double width = 0.6, gap = 0.35, thick = 0.02, plate_mass = 0.4;
    btCollisionShape* plate = m_world.keep(
        std::make_unique<btBoxShape>(btVector3(btScalar(width / 2), btScalar(thick / 2), btScalar(width / 2))));
    btCollisionShape* holder = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.04, 0.04, 0.04)));
    const double top = 2.0;
    std::vector<btRigidBody*> plates;
    for (int i = 0; i < 3; ++i) {
      btRigidBody* p = m_world.add_body(plate, plate_mass, at(btVector3(0, btScalar(top - gap * (i + 1)), 0)));
      p->setActivationState(DISABLE_DEACTIVATION);
      p->setLinearVelocity(btVector3(btScalar(0.6 * (i + 1)), 0, 0));  // start the swing
      plates.push_back(p);
    }
    // The two holders hang from the world on point-to-point constraints.
    std::vector<btRigidBody*> holders;
    for (int side : {-1, 1}) {
      btRigidBody* h = m_world.add_body(holder, 0.3, at(btVector3(btScalar(side * width / 2), btScalar(top), 0)));
      h->setActivationState(DISABLE_DEACTIVATION);
      m_world.add_constraint(std::make_unique<btPoint2PointConstraint>(*h, btVector3(0, 0.04, 0)));
      holders.push_back(h);
    }
    // Sheets: holders -> plate 0 -> plate 1 -> plate 2, top and bottom rows hard-bound.
    for (int s = 0; s < 3; ++s) {
      ClothGridSettings c;
      c.nx = 13;
      c.ny = 8;
      c.width = width;
      c.height = gap - thick - (s == 0 ? 0.04 : 0.0);
      c.mass = 0.1;
      const double y_top = s == 0 ? top - 0.04 : top - gap * s - thick / 2;
      c.origin = Vec3(-width / 2, y_top, 0.0);
      const ClothGrid sheet = add_cloth_grid(system(), c);
      add_surface("sheet" + std::to_string(s), sheet.triangles);
      for (int i = 0; i < c.nx; ++i) {
        btRigidBody* above = s == 0 ? holders[i < c.nx / 2 ? 0 : 1] : plates[static_cast<std::size_t>(s - 1)];
        if (s == 0 && i == c.nx / 2) continue;  // the middle of the top edge hangs free between the holders
        coupling().bind_here(sheet.node(i, 0), above);
        coupling().bind_here(sheet.node(i, c.ny - 1), plates[static_cast<std::size_t>(s)]);
      }
    }
  }
};

SINEW_REGISTER_SCENE(bullet_scene<Plates>({.name = "plates",
                                           .description = "figure 14: three rigid plates joined by hard-bound cloth "
                                                          "sheets, hung from two Bullet point constraints, swinging",
                                           .gallery_frame = 150}));

}  // namespace
}  // namespace sinew::scenes
