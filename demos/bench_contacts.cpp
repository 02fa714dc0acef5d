// sinew-bench-contacts: what step 3's collisions against Bullet's objects cost as the world fills
// with bodies. A 40 x 40 cloth (1.2 m) falls flat onto a grid of N static boxes (1, 10 and 100), or
// hangs in the air while the same N boxes stand 50 m away; the program prints, per case, the median
// over runs of the mean time per 1/60 s frame (four 1/240 s ticks) spent in step 3
// (PhaseTimes::process_collisions) and in the whole tick, with the cloth's lowest node at the end (draped
// below the boxes' tops, 0.52 m, between them, or at its start, 0.6 m, in the air). With a
// broadphase the far boxes cost (almost) nothing and the near ones what their contacts cost.
//
//   sinew-bench-contacts [--runs N] [--frames N] [--size N]
#include "machine.hpp"
#include "sinew/builders.hpp"
#include "sinew/bullet/coupling.hpp"

#include <btBulletDynamicsCommon.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <thread>
#include <vector>

namespace {

using namespace sinew;

struct Result {
  double step3_ms = 0.0;  // per frame
  double tick_ms = 0.0;   // per frame
  double lowest = 0.0;    // the cloth's lowest node at the end [m]
};

// N boxes of 4 cm in a square grid spanning the cloth (near) or the same grid moved 50 m off (far).
Result run(int boxes, bool near, int size, int frames) {
  btDefaultCollisionConfiguration configuration;
  btCollisionDispatcher dispatcher(&configuration);
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world(&dispatcher, &broadphase, &solver, &configuration);
  world.setGravity(btVector3(0, near ? -9.81 : 0.0, 0));
  btBoxShape shape(btVector3(0.02, 0.02, 0.02));
  std::vector<std::unique_ptr<btRigidBody>> bodies;
  const int side = static_cast<int>(std::ceil(std::sqrt(double(boxes))));
  for (int k = 0; k < boxes; ++k) {
    const double u = (k % side + 0.5) / side - 0.5, w = (k / side + 0.5) / side - 0.5;
    btTransform pose(btQuaternion::getIdentity(),
                     btVector3(btScalar(1.0 * u + (near ? 0.0 : 50.0)), 0.5, btScalar(1.0 * w)));
    auto body = std::make_unique<btRigidBody>(btScalar(0), nullptr, &shape);
    body->setWorldTransform(pose);
    world.addRigidBody(body.get());
    bodies.push_back(std::move(body));
  }
  Result r;
  {
    bullet::Coupling coupling(&world);
    ClothGridSettings grid;
    grid.nx = grid.ny = size;
    grid.width = grid.height = 1.2;
    grid.mass = 0.3;
    grid.origin = {-0.6, 0.6, -0.6};
    grid.down = {0, 0, 1};
    add_cloth_grid(coupling.system(), grid);
    coupling.system().step_settings().sleep = false;  // the far case hangs still: it must keep paying
    for (int frame = 0; frame < frames; ++frame) {
      for (int tick = 0; tick < 4; ++tick) {
        world.stepSimulation(btScalar(1.0 / 240), 1, btScalar(1.0 / 240));
        const StepStats& s = coupling.last_stats();
        r.step3_ms += s.ms.process_collisions;
        r.tick_ms += s.ms.total;
      }
    }
    r.lowest = coupling.system().particles().x.row(1).minCoeff();
  }
  for (auto& body : bodies) world.removeRigidBody(body.get());
  r.step3_ms /= frames;
  r.tick_ms /= frames;
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  int runs = 5, frames = 60, size = 40;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--runs") && i + 1 < argc) runs = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--size") && i + 1 < argc) size = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--runs N] [--frames N] [--size N]\n", argv[0]);
      return 2;
    }
  }
  if (runs < 1 || frames < 1 || size < 2) {
    std::fprintf(stderr, "sinew-bench-contacts: --runs and --frames must be >= 1, --size >= 2\n");
    return 2;
  }
  std::printf("machine: %s, %u hardware threads; one sinew thread; %d x %d cloth, %d frames, median of %d runs\n",
              bench::cpu_model().c_str(), std::thread::hardware_concurrency(), size, size, frames, runs);
  std::printf("| boxes | where | step 3 ms / frame | tick ms / frame | cloth's lowest node |\n|---|---|---|---|---|\n");
  for (const bool near : {false, true})
    for (const int boxes : {1, 10, 100}) {
      std::vector<double> step3, tick;
      double lowest = 0.0;
      for (int k = 0; k < runs; ++k) {
        const Result r = run(boxes, near, size, frames);
        step3.push_back(r.step3_ms);
        tick.push_back(r.tick_ms);
        lowest = r.lowest;
      }
      std::printf("| %d | %s | %.3f | %.3f | %.3f m |\n", boxes, near ? "under the cloth" : "50 m away",
                  bench::median(step3), bench::median(tick), lowest);
    }
  return 0;
}
