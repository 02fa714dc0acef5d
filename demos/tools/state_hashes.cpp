// sinew-hashes: the state hash of every demo scene, the core scene and the benchmark's and stability
// suite's sinew settings after a fixed number of frames, one line each ("<name> <hash>").
//
// A change meant to keep behaviour (a refactor) must leave every line the same: `.ci/hashes` runs
// this program and compares its output with the committed tests/state_hashes.txt. The hashes depend
// on the compiler and the C library's maths, so they are compared on one machine, not in CI.
//
//   sinew-hashes [--frames N]
#include "bench_scene.hpp"
#include "scene.hpp"
#include "sinew_curtain.hpp"
#include "stability.hpp"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

namespace {

using namespace sinew;

void print(const std::string& name, std::uint64_t h) {
  std::printf("%-64s %016llx\n", name.c_str(), static_cast<unsigned long long>(h));
}

std::uint64_t curtain_hash(bench::CurtainRun& run, int frames, double frame_dt, int ticks) {
  for (int f = 0; f < frames; ++f) run.advance(frame_dt, ticks);
  return scenes::BenchScene::hash(run);
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 60;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: sinew-hashes [--frames N]\n");
      return 2;
    }
  }
  try {
    // Every registered Bullet scene at its own frame and ticks: sinew's state hash mixed with every
    // Bullet body's transform and velocities (BulletScene::state_hash).
    for (const scenes::SceneInfo& info : scenes::registered_scenes()) {
      if (info.kind != scenes::SceneKind::bullet) continue;
      auto scene = scenes::make_scene(info.name);
      for (int f = 0; f < frames; ++f) scene->advance(scene->default_frame_dt(), scene->default_substeps());
      print("scene/" + info.name, scene->state_hash());
    }

    {
      auto scene = scenes::make_scene("hanging-cloth", {.nx = 20, .ny = 20});
      for (int f = 0; f < frames / 2; ++f) scene->advance(1.0 / 60.0, 1);
      print("core/hanging-cloth-20", scene->state_hash());
    }

    // The benchmark's sinew settings (sinew-bench's make_run), a short run each.
    struct BenchSetting {
      const char* system;
      int n, ticks;
      double tol;
      int threads;
    };
    const BenchSetting bench_settings[] = {
        {"sinew", 20, 4, 1e-9, 1},
        {"sinew-implicit", 20, 1, 1e-3, 1},
        {"sinew-implicit", 40, 4, 1e-5, 1},
        {"sinew-implicit-bending", 20, 1, 1e-2, 1},
        {"sinew-multigrid", 40, 1, 1e-2, 1},
        {"sinew-multigrid", 40, 1, 1e-2, 2},
        {"sinew-multigrid", 100, 1, 1e-2, 2},
    };
    for (const BenchSetting& b : bench_settings) {
      bench::CurtainSpec spec;
      spec.n = b.n;
      bench::SinewSettings settings;
      const std::string system = b.system;
      settings.implicit_elasticity = system != "sinew";
      settings.multigrid = system == "sinew-multigrid";
      settings.cg_tolerance = b.tol;
      settings.threads = b.threads;
      spec.bending_implicit = settings.multigrid || system == "sinew-implicit-bending";
      auto run = bench::make_sinew_curtain(spec, settings);
      char name[160];
      std::snprintf(name, sizeof name, "bench/%s/n%d/ticks%d/tol%g/threads%d", b.system, b.n, b.ticks, b.tol,
                    b.threads);
      print(name, curtain_hash(*run, frames / 2, 1.0 / 60.0, b.ticks));
    }

    // The stability suite's sinew systems, a short run of each case.
    for (const bench::StabilityCase& c : bench::stability_cases())
      for (const char* system : {"sinew", "sinew-multigrid"}) {
        auto run = bench::make_stability_run(c, system);
        print("stability/" + c.name + "/" + system,
              curtain_hash(*run, std::min(frames / 2, c.frames), c.frame_dt, c.steps));
      }
  } catch (const sinew::Error& e) {
    std::fprintf(stderr, "sinew-hashes: %s\n", e.what());
    return 1;
  }
  return 0;
}
