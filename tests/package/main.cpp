// Outside project: a Bullet world with a falling box and one particle hard-bound to it, and a mesh
// written and read back through sinew::mesh and made into a Bullet convex hull.
#include <sinew/bullet/coupling.hpp>
#include <sinew/bullet/shapes.hpp>
#include <sinew/mesh/mesh_io.hpp>

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
    sinew::mesh::TriangleMesh tet;
    tet.vertices.resize(3, 4);
    tet.vertices << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
    tet.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    sinew::mesh::save_triangle_meshes("tet.obj", {tet}, {"tet"});
    const sinew::mesh::TriangleMesh loaded = sinew::mesh::load_triangle_mesh("tet.obj");
    const sinew::bullet::MeshShape hull = sinew::bullet::convex_hull_shape(loaded.vertices);
    if (loaded.triangles.size() != 4 || hull.shape == nullptr) {
      std::printf("mesh round trip failed\n");
      return 1;
    }
  }
  {
    sinew::bullet::Coupling coupling(&world);
    const auto p = coupling.system().add_particle({0.1, 0.9, 0}, {0, 0, 0}, 0.0);
    coupling.bind_here(p, &box);
    for (int i = 0; i < 60; ++i) world.stepSimulation(1.0 / 60, 4, 1.0 / 240);
    const btVector3 expected = box.getCenterOfMassTransform() * btVector3(0.1, -0.1, 0);
    const double error = (btVector3(coupling.system().particles().x(0, p), coupling.system().particles().x(1, p),
                                    coupling.system().particles().x(2, p)) -
                          expected)
                             .length();
    std::printf("bound point error %g m\n", error);
    status = error < 1e-9 ? 0 : 1;
  }
  world.removeRigidBody(&box);
  return status;
}
