// sinew-core-demo: the hanging-cloth scene run headless; prints a one-line JSON summary.
//
//   sinew-core-demo [--frames N] [--fps F] [--nx N] [--ny N]
#include "cloth.hpp"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

int main(int argc, char** argv) {
  int frames = 120, nx = 40, ny = 40;
  double fps = 60.0;
  for (int i = 1; i < argc; ++i) {
    auto value = [&](const char* flag) {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "sinew-core-demo: %s needs a value\n", flag);
        std::exit(2);
      }
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--frames")) frames = std::atoi(value("--frames"));
    else if (!std::strcmp(argv[i], "--fps")) fps = std::atof(value("--fps"));
    else if (!std::strcmp(argv[i], "--nx")) nx = std::atoi(value("--nx"));
    else if (!std::strcmp(argv[i], "--ny")) ny = std::atoi(value("--ny"));
    else {
      std::fprintf(stderr, "usage: sinew-core-demo [--frames N] [--fps F] [--nx N] [--ny N]\n");
      return 2;
    }
  }
  try {
    sinew::System system;
    sinew::scenes::HangingClothSettings settings;
    settings.cloth.nx = nx;
    settings.cloth.ny = ny;
    sinew::scenes::add_hanging_cloth(system, settings);
    system.finalize();
    const double energy_start = system.kinetic_energy() + system.potential_energy();
    double drift = 0.0, stretch = 0.0, wall_ms = 0.0;
    int cg = 0, substeps = 0;
    for (int f = 0; f < frames; ++f) {
      const auto start = std::chrono::steady_clock::now();
      const sinew::StepStats stats = system.advance(1.0 / fps);
      wall_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
      cg += stats.cg_iterations_step1 + stats.cg_iterations_step4;
      substeps += stats.substeps;
      drift = std::max(drift, system.max_hard_binding_drift());
      stretch = std::max(stretch, system.binding_springs().max_stretch(system.particles().x));
    }
    const double energy_end = system.kinetic_energy() + system.potential_energy();
    std::printf(
        "{\"scene\": \"hanging-cloth\", \"particles\": %lld, \"rigid_bodies\": %lld, \"frames\": %d, "
        "\"substeps_per_frame\": %.2f, \"wall_ms_per_frame\": %.3f, \"cg_iterations_per_substep\": %.2f, "
        "\"max_hard_binding_drift\": %.3g, \"max_binding_spring_stretch\": %.3g, \"energy_start\": %.6g, "
        "\"energy_end\": %.6g, \"finite\": true, \"state_hash\": \"%016llx\"}\n",
        static_cast<long long>(system.particles().size()), static_cast<long long>(system.rigid_bodies().size()), frames,
        static_cast<double>(substeps) / frames, wall_ms / frames, static_cast<double>(cg) / substeps, drift, stretch,
        energy_start, energy_end, static_cast<unsigned long long>(system.state_hash()));
  } catch (const sinew::Error& e) {
    std::printf("{\"scene\": \"hanging-cloth\", \"finite\": false, \"error\": \"%s\"}\n", e.what());
    std::fprintf(stderr, "sinew-core-demo: %s\n", e.what());
    return 1;
  }
  return 0;
}
