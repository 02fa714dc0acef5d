// Outside project: a Bullet world with a falling box and one particle hard-bound to it.
#include <sinew/bullet/coupling.hpp>

#include <btBulletDynamicsCommon.h>

#include <cmath>
#include <cstdio>

int main() {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher(&configuration);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world(&dispatcher, &broadphase, &solver, &configuration);
  world.setGravity(btVector3(0, -9.81, 0));
  btBoxShape shape(btVector3(0.1, 0.1, 0.1));
  btVector3 inertia;
  shape.calculateLocalInertia(1, inertia);
  btDefaultMotionState state(btTransform(btQuaternion::getIdentity(), btVector3(0, 1, 0)));
  btRigidBody box(btRigidBody::btRigidBodyConstructionInfo(1, &state, &shape, inertia));
  world.addRigidBody(&box);
  int status = 1;
  {
    sinew::bullet::Coupling coupling(&world);
    const auto p = coupling.system().add_particle({0.1, 0.9, 0}, {0, 0, 0}, 0.0);
    coupling.bind_here(p, &box);
    for (int i = 0; i < 60; ++i) world.stepSimulation(1.0 / 60, 4, 1.0 / 240);
    const btVector3 expected = box.getCenterOfMassTransform() * btVector3(0.1, -0.1, 0);
    const double error = (btVector3(coupling.system().particles().x(0, p), coupling.system().particles().x(1, p),
                                    coupling.system().particles().x(2, p)) - expected).length();
    std::printf("bound point error %g m\n", error);
    status = error < 1e-9 ? 0 : 1;
  }
  world.removeRigidBody(&box);
  return status;
}
