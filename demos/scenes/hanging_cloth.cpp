// The core scene (no Bullet): the cloth of add_hanging_cloth hung from a dynamic rigid rod by
// binding springs, swinging after a sideways push; sinew-core-demo's default.
#include "cloth.hpp"
#include "scene.hpp"

namespace sinew::scenes {
namespace {

class HangingClothScene final : public CoreScene {
 public:
  explicit HangingClothScene(const SceneParams& params) {
    HangingClothSettings settings;
    if (params.nx > 0) settings.cloth.nx = params.nx;
    if (params.ny > 0) settings.cloth.ny = params.ny;
    add_hanging_cloth(m_system, settings);
    m_system.finalize();
  }
};

SINEW_REGISTER_SCENE(
    {.name = "hanging-cloth",
     .description = "a cloth hung from a free rigid rod by binding springs, swinging (core only, 40 x 40)",
     .kind = SceneKind::core,
     .make = [](const SceneParams& p) { return std::make_unique<HangingClothScene>(p); },
     .takes_grid = true});

}  // namespace
}  // namespace sinew::scenes
