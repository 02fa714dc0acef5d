// The scene library: every scene sinew-demo, sinew-view, sinew-core-demo, the tests, sinew-hashes
// and .ci/gallery know is one file under demos/scenes/ that registers itself with one
// SINEW_REGISTER_SCENE line. Nothing else lists scene names: the programs, the CTest smoke tests
// (from `sinew-demo --list`) and the gallery ask this registry.
#pragma once

#include "sinew/step_stats.hpp"
#include "sinew/system.hpp"

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace sinew::scenes {

/// What a scene needs from its program: only the core (a sinew::System), a Bullet world (drawable:
/// sinew-demo --render and sinew-view take it), or the benchmark's curtain (sinew in the
/// benchmark's own Bullet world; run and measured, not drawn).
enum class SceneKind { core, bullet, bench };
/// "core", "bullet", "bench".
const char* to_string(SceneKind kind);

/// Options a program may pass to a scene's factory.
struct SceneParams {
  /// Cloth nodes across and down; 0: the scene's own. Only scenes registered with takes_grid accept
  /// them (sinew-core-demo --nx / --ny).
  int nx = 0, ny = 0;
};

/// What the runner reports about a scene after each frame.
struct SceneMeasures {
  Index particles = 0;
  Index rigid_bodies = 0;
  double hard_binding_drift = 0.0;      ///< [m]
  double binding_spring_stretch = 0.0;  ///< largest binding-spring length [m]
  double deepest_penetration = 0.0;     ///< into a collision shape [m]
  double energy = 0.0;                  ///< kinetic + potential, deformable and rigid [J]
  /// Root mean square of the free particles' speeds (the nodes with mass a user sees; not bound
  /// points nor soft-bound duplicates) [m/s]: a scene at rest reads near zero, a jittering one does not.
  double velocity_rms = 0.0;
};
/// SceneMeasures::velocity_rms of a system's particles.
double velocity_rms(const System& system);

class Scene {
 public:
  virtual ~Scene() = default;
  /// The frame the scene is meant to be watched at [s] (programs' --dt overrides it).
  virtual double default_frame_dt() const { return 1.0 / 60.0; }
  /// Internal ticks per frame the scene is meant to run with (programs' --substeps overrides it).
  virtual int default_substeps() const { return 4; }
  /// Advances one frame of frame_dt in `substeps` equal ticks.
  virtual void advance(double frame_dt, int substeps) = 0;
  virtual SceneMeasures measure() = 0;
  /// Bits of the whole state (sinew's and the rigid solver's): equal runs give equal hashes.
  virtual std::uint64_t state_hash() = 0;
  /// The sinew step's statistics summed over every tick so far, where the scene keeps them (else null).
  virtual const StepStats* total_stats() const { return nullptr; }
  /// The scene's deformable system, where it has one the programs may set up (--fixed-scheme).
  virtual System* deformable_system() { return nullptr; }
  /// The scene's own figures for the programs' JSON line, as `"key": value, ` fields (empty: none).
  virtual std::string json_fields() { return {}; }
};

using SceneFactory = std::function<std::unique_ptr<Scene>(const SceneParams&)>;

struct SceneInfo {
  std::string name;         ///< one word of letters, digits and - _ . / ("curtain", "stability/spin_100")
  std::string description;  ///< one line
  SceneKind kind = SceneKind::core;
  SceneFactory make = {};
  /// The frame .ci/gallery pictures (frames counted from 1 at default_frame_dt); 0: no picture.
  int gallery_frame = 0;
  bool takes_grid = false;  ///< the factory reads SceneParams::nx, ny
};

/// Adds a scene to the registry; throws sinew::Error for a name that is not one such word, a name taken
/// already, a description that is empty or not one line, or no factory. Returns true (for the
/// static registrar SINEW_REGISTER_SCENE).
bool register_scene(SceneInfo info);
/// Every registered scene, in registration order (within a program: the link order of the scene
/// files, that is the source order of demos/CMakeLists.txt's scene libraries, then test files).
const std::vector<SceneInfo>& registered_scenes();
/// The scene called `name`; throws sinew::Error naming it otherwise.
const SceneInfo& find_scene(const std::string& name);
/// Builds the scene called `name`; throws sinew::Error for an unknown name or grid parameters given
/// to a scene that does not take them.
std::unique_ptr<Scene> make_scene(const std::string& name, const SceneParams& params = {});

/// A factory for a scene class with a default constructor.
template <class SceneType>
std::unique_ptr<Scene> construct(const SceneParams&) {
  return std::make_unique<SceneType>();
}

/// A scene that is one sinew::System (no rigid solver beside it): ticks are System::advance calls,
/// each substepping as the step's stability needs.
class CoreScene : public Scene {
 public:
  int default_substeps() const override { return 1; }
  void advance(double frame_dt, int substeps) override;
  SceneMeasures measure() override;
  std::uint64_t state_hash() override { return m_system.state_hash(); }
  const StepStats* total_stats() const override { return &m_total; }
  System& system() { return m_system; }
  System* deformable_system() override { return &m_system; }

 protected:
  System m_system;
  StepStats m_total;
};

}  // namespace sinew::scenes

#define SINEW_SCENE_CONCAT_(a, b) a##b
#define SINEW_SCENE_CONCAT(a, b) SINEW_SCENE_CONCAT_(a, b)
/// Registers a scene when the program starts: SINEW_REGISTER_SCENE({.name = ..., .description = ...,
/// .kind = ..., .make = ...}), or any expression giving a SceneInfo (bullet_scene<T>({...})); one
/// line in the scene's own file. The file must reach the program as
/// an object file (demos/CMakeLists.txt's OBJECT scene libraries, or a test's own sources): a static
/// archive would drop it, since nothing refers to it by name.
#define SINEW_REGISTER_SCENE(...)                                                               \
  [[maybe_unused]] static const bool SINEW_SCENE_CONCAT(sinew_scene_registered_, __COUNTER__) = \
      ::sinew::scenes::register_scene(__VA_ARGS__)
