// sinew-bench-step: speed of the Newmark step on the hanging-cloth scene (cloth with edge springs,
// dihedral bending and damping, its top row tied by implicit binding springs to a dynamic rigid
// rod). Prints, per resolution, the median over runs of the time per substep and per phase, CG
// iterations, the substep the elastic forces allow, the time per simulated second, and the error of
// the bottom edge against a run at a quarter of the substep (so speed stands beside accuracy).
//
//   sinew-bench-step [--runs N] [--steps N] [--sizes 40,100] [--threads N]
#include "cloth.hpp"
#include "machine.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace sinew;
using bench::cpu_model;
using bench::median;

struct Scene {
  System system;
  scenes::HangingCloth handles;
  explicit Scene(int n, int threads) {
    scenes::HangingClothSettings settings;
    settings.cloth.nx = settings.cloth.ny = n;
    handles = scenes::add_hanging_cloth(system, settings);
    system.step_settings().threads = threads;
    system.finalize();
    if (const char* tol = std::getenv("SINEW_CG_TOL")) system.step_settings().cg_tolerance = std::atof(tol);
  }
  Vectors3 bottom_edge() const {
    const auto& cloth = handles.cloth;
    Vectors3 out(3, cloth.nx);
    for (int i = 0; i < cloth.nx; ++i) out.col(i) = system.particles().x.col(cloth.node(i, cloth.ny - 1));
    return out;
  }
};

}  // namespace

int main(int argc, char** argv) {
  int runs = 5, steps = 48, threads = 1;
  std::vector<int> sizes{40, 100};
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--runs") && i + 1 < argc) runs = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--steps") && i + 1 < argc) steps = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--sizes") && i + 1 < argc) {
      sizes.clear();
      std::stringstream list(argv[++i]);
      std::string item;
      while (std::getline(list, item, ',')) sizes.push_back(std::atoi(item.c_str()));
    } else {
      std::fprintf(stderr, "usage: sinew-bench-step [--runs N] [--steps N] [--sizes 40,100] [--threads N]\n");
      return 2;
    }
  }
  std::printf("machine: %s, %u hardware threads; sinew threads: %d\n", cpu_model().c_str(),
              std::thread::hardware_concurrency(), threads);
  std::printf(
      "scene: cloth n x n, 2 m x 2 m, 0.5 kg, springs k=200 N/m b=0.05, bending 1e-4, binding springs 1e5 N/m to a 0.5 "
      "kg rod\n");
  std::printf("%5s %7s %9s %10s %9s %8s %8s %8s %8s %8s %9s %12s\n", "n", "nodes", "dt [ms]", "ms/step", "step1",
              "step2", "step3", "step4", "step5", "cg it", "ms/sim-s", "edge err [m]");
  for (int n : sizes) {
    std::vector<double> total, p1, p2, p3, p4, p5, iterations;
    double dt = 0.0;
    Index nodes = 0;
    for (int run = 0; run < runs; ++run) {
      Scene scene(n, threads);
      dt = scene.system.step_settings().cfl * scene.system.stable_dt();
      nodes = scene.system.particles().size();
      for (int i = 0; i < 3; ++i) scene.system.step(dt);  // warm-up: first-call allocation
      PhaseTimes sum;
      int cg = 0;
      const auto start = std::chrono::steady_clock::now();
      for (int i = 0; i < steps; ++i) {
        const StepStats s = scene.system.step(dt);
        sum += s.ms;
        cg += s.cg_iterations_step1 + s.cg_iterations_step3 + s.cg_iterations_step4;
      }
      total.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count() /
                      steps);
      p1.push_back(sum.implicit_half_velocity / steps);
      p2.push_back(sum.advance_positions / steps);
      p3.push_back(sum.process_collisions / steps);
      p4.push_back(sum.backward_euler_velocity / steps);
      p5.push_back(sum.extrapolate_velocity / steps);
      iterations.push_back(static_cast<double>(cg) / steps);
    }
    // Accuracy beside speed: the bottom edge after 0.1 s at the benchmark substep against a run at a
    // quarter of it (second order: the reference's own error is about 1/16 of the reported one).
    const double horizon = 0.1;
    auto run_to = [&](double step) {
      Scene scene(n, threads);
      const int count = static_cast<int>(std::ceil(horizon / step - 1e-9));
      for (int i = 0; i < count; ++i) scene.system.step(horizon / count);
      return scene.bottom_edge();
    };
    const Vectors3 coarse = run_to(dt), fine = run_to(dt / 4);
    const double error = (coarse - fine).colwise().norm().maxCoeff();
    const double ms_step = median(total);
    std::printf("%5d %7lld %9.4f %10.3f %9.3f %8.3f %8.3f %8.3f %8.3f %8.1f %9.0f %12.2e\n", n,
                static_cast<long long>(nodes), dt * 1e3, ms_step, median(p1), median(p2), median(p3), median(p4),
                median(p5), median(iterations), ms_step / dt, error);
  }
  std::printf("ms/step: median over %d runs of %d steps; ms/sim-s: wall time per simulated second at that step.\n",
              runs, steps);
  return 0;
}
