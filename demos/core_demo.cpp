// sinew-core-demo [SCENE]: a core-only scene (no Bullet; hanging-cloth unless named) run headless;
// prints a one-line JSON summary. The flags are the shared command line's (common/cli.hpp); the
// core scenes step at --fps (or --dt) with System::advance substepping as stability needs.
#include "cli.hpp"
#include "runner.hpp"

int main(int argc, char** argv) {
  using namespace sinew;
  const demos::Program program{.name = "sinew-core-demo",
                               .flags = demos::kFrames | demos::kDt | demos::kSubsteps | demos::kGrid | demos::kScheme,
                               .kinds = {scenes::SceneKind::core},
                               .default_scene = "hanging-cloth",
                               .default_frames = 120};
  return demos::run_headless(program, demos::parse_command_line(program, argc, argv));
}
