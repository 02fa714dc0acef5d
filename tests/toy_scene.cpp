// The scene recipe followed once, as a newcomer adding a scene would: one file, one registration line.
// A toy core scene, a single particle dropped from rest: the trapezoidal step is exact under constant
// acceleration, so after t it has fallen g t^2 / 2 (test_demos checks that through the shared runner).
#include "scene.hpp"

namespace sinew::scenes {
namespace {

class ToyDrop final : public CoreScene {
 public:
  ToyDrop() {
    m_system.add_particle(Vec3(0.0, 10.0, 0.0), Vec3::Zero(), 1.0);
    m_system.finalize();
  }
};

SINEW_REGISTER_SCENE({.name = "toy-drop",
                      .description = "test only: one particle falling from rest",
                      .kind = SceneKind::core,
                      .make = construct<ToyDrop>});

}  // namespace
}  // namespace sinew::scenes
