// Bullet's hello world — a ground plane and a falling sphere — plus the lines that add sinew: a cloth
// tied at its centre to the sphere, falling with it and draping over it on the ground. Everything
// marked "sinew" is what an existing Bullet program adds; the rest is plain Bullet.
#include <btBulletDynamicsCommon.h>

#include <sinew/builders.hpp>         // sinew
#include <sinew/bullet/coupling.hpp>  // sinew

#include <cmath>
#include <cstdio>

int main() {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher(&configuration);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world(&dispatcher, &broadphase, &solver, &configuration);
  world.setGravity(btVector3(0, -9.81, 0));

  btStaticPlaneShape ground_shape(btVector3(0, 1, 0), 0);
  btRigidBody ground(0, nullptr, &ground_shape);
  world.addRigidBody(&ground);
  btSphereShape ball(0.3);
  btVector3 inertia;
  ball.calculateLocalInertia(1, inertia);
  btDefaultMotionState start(btTransform(btQuaternion::getIdentity(), btVector3(0, 2, 0)));
  btRigidBody sphere(btRigidBody::btRigidBodyConstructionInfo(1, &start, &ball, inertia));
  world.addRigidBody(&sphere);

  int status = 0;
  {
    sinew::bullet::Coupling coupling(&world);  // sinew: attach to the world
    sinew::ClothGridSettings grid;             // sinew: 1.2 m, 15 x 15 nodes, 0.2 kg
    grid.nx = grid.ny = 15;
    grid.width = grid.height = 1.2;
    grid.mass = 0.2;
    grid.origin = {-0.6, 2.31, -0.6};
    grid.down = {0, 0, 1};
    const sinew::ClothGrid cloth = sinew::add_cloth_grid(coupling.system(), grid);  // sinew
    coupling.attach(cloth.node(7, 7), &sphere, {0, 0.3, 0}, 1e4);                   // sinew: tie its centre to the top

    for (int frame = 1; frame <= 180; ++frame) {
      world.stepSimulation(1.0 / 60, 4, 1.0 / 240);
      const auto& x = coupling.system().particles().x;  // sinew: read the cloth
      if (frame % 30 == 0)
        std::printf("t %.1f s  sphere y %.3f m  cloth lowest y %.3f m\n", frame / 60.0,
                    double(sphere.getCenterOfMassPosition().y()), x.row(1).minCoeff());
      if (!x.allFinite()) status = 1;
    }
  }
  world.removeRigidBody(&sphere);
  world.removeRigidBody(&ground);
  return status;
}
