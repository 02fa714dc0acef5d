#include "scene.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>

namespace sinew::scenes {

namespace {

// Function-local, so that registrars in any file's static initialisation find it constructed.
std::vector<SceneInfo>& registry() {
  static std::vector<SceneInfo> scenes;
  return scenes;
}

}  // namespace

const char* to_string(SceneKind kind) {
  switch (kind) {
    case SceneKind::core: return "core";
    case SceneKind::bullet: return "bullet";
    case SceneKind::bench: return "bench";
  }
  return "?";
}

bool register_scene(SceneInfo info) {
  // Names become CTest names, file names (.ci/gallery) and shell words: letters, digits and - _ . /.
  const bool word = !info.name.empty() && std::all_of(info.name.begin(), info.name.end(), [](char ch) {
    return std::isalnum(static_cast<unsigned char>(ch)) || std::strchr("-_./", ch) != nullptr;
  });
  if (!word) fail("scene registry: scene name '", info.name, "' must be one word of letters, digits and - _ . /");
  if (info.description.empty() || info.description.find('\n') != std::string::npos)
    fail("scene registry: scene '", info.name, "' needs a one-line description");
  if (!info.make) fail("scene registry: scene '", info.name, "' has no factory");
  if (info.gallery_frame < 0)
    fail("scene registry: scene '", info.name, "': gallery_frame ", info.gallery_frame, " is negative");
  for (const SceneInfo& s : registry())
    if (s.name == info.name) fail("scene registry: scene '", info.name, "' is registered twice");
  registry().push_back(std::move(info));
  return true;
}

const std::vector<SceneInfo>& registered_scenes() { return registry(); }

const SceneInfo& find_scene(const std::string& name) {
  for (const SceneInfo& s : registry())
    if (s.name == name) return s;
  fail("unknown scene '", name, "' (--list names them)");
}

std::unique_ptr<Scene> make_scene(const std::string& name, const SceneParams& params) {
  const SceneInfo& info = find_scene(name);
  if (!info.takes_grid && (params.nx != 0 || params.ny != 0))
    fail("scene '", name, "' has a fixed cloth: --nx and --ny do not apply");
  if (params.nx < 0 || params.ny < 0 || params.nx == 1 || params.ny == 1)
    fail("scene '", name, "': --nx ", params.nx, " and --ny ", params.ny, " must be at least 2");
  return info.make(params);
}

void CoreScene::advance(double frame_dt, int substeps) {
  for (int k = 0; k < substeps; ++k) m_total += m_system.advance(frame_dt / substeps);
}

SceneMeasures CoreScene::measure() {
  SceneMeasures m;
  m.particles = m_system.particles().size();
  m.rigid_bodies = static_cast<Index>(m_system.rigid_bodies().size());
  m.hard_binding_drift = m_system.max_hard_binding_drift();
  m.binding_spring_stretch = m_system.binding_springs().max_stretch(m_system.particles().x);
  m.energy = m_system.kinetic_energy() + m_system.potential_energy();
  m.velocity_rms = velocity_rms(m_system);
  return m;
}

double velocity_rms(const System& system) {
  const Particles& p = system.particles();
  double sum = 0.0;
  Index count = 0;
  for (Index i = 0; i < p.size(); ++i)
    if (p.kind[i] == ParticleKind::free && p.mass[i] > 0.0) {
      sum += p.v.col(i).squaredNorm();
      ++count;
    }
  return count > 0 ? std::sqrt(sum / double(count)) : 0.0;
}

}  // namespace sinew::scenes
