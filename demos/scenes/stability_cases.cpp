// The stability suite's cases (demos/bench/stability.hpp) in sinew, one scene each,
// "stability/<case>": each runs at its case's own frame and ticks, built as sinew-bench builds it.
#include "bench_scene.hpp"
#include "stability.hpp"

namespace sinew::scenes {
namespace {

bool register_stability_cases() {
  for (const bench::StabilityCase& c : bench::stability_cases())
    register_scene({.name = "stability/" + c.name,
                    .description = "stability case: " + c.what,
                    .kind = SceneKind::bench,
                    .make = [c](const SceneParams&) -> std::unique_ptr<Scene> {
                      const Index bodies = c.drop ? 1 : c.curtain.rings + 1;  // the plate, or the rod and rings
                      return std::make_unique<BenchScene>(bench::make_stability_run(c, "sinew"), c.frame_dt, c.steps,
                                                          bodies);
                    }});
  return true;
}

[[maybe_unused]] const bool registered = register_stability_cases();

}  // namespace
}  // namespace sinew::scenes
