// The benchmark curtain (demos/bench/curtain_bench.hpp) in sinew as sinew-bench runs its
// "sinew-implicit" setting: 40 x 40 nodes on ten rings held on the rod by Bullet slider constraints,
// implicit springs, block Jacobi to 1e-5 m/s, four 1/240 s ticks per frame.
#include "bench_scene.hpp"
#include "sinew_curtain.hpp"

namespace sinew::scenes {
namespace {

std::unique_ptr<Scene> make_bench_curtain(const SceneParams&) {
  bench::CurtainSpec spec;
  bench::SinewSettings settings;
  settings.implicit_elasticity = true;
  settings.cg_tolerance = 1e-5;
  return std::make_unique<BenchScene>(bench::make_sinew_curtain(spec, settings), 1.0 / 60.0, 4, spec.rings + 1);
}

SINEW_REGISTER_SCENE(
    {.name = "bench-curtain",
     .description = "the benchmark's curtain in sinew (40 x 40, ten rings on Bullet sliders, implicit springs)",
     .kind = SceneKind::bench,
     .make = make_bench_curtain});

}  // namespace
}  // namespace sinew::scenes
