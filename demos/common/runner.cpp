#include "runner.hpp"

#include "intersections.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

namespace sinew::demos {

namespace {

std::string json_escaped(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    out += c == '\n' ? ' ' : c;
  }
  return out;
}

}  // namespace

Timing timing(const Options& o, const scenes::Scene& scene) {
  return {o.dt > 0 ? o.dt : scene.default_frame_dt(), o.substeps > 0 ? o.substeps : scene.default_substeps()};
}

int run_headless(const Program& program, const Options& o, const RunHooks& hooks) {
  const std::string name = json_escaped(o.scene);
  try {
    auto scene = scenes::make_scene(o.scene, o.params);
    const Timing t = timing(o, *scene);
    if (System* system = scene->deformable_system(); system && o.fixed_scheme)
      system->step_settings().automatic = false;
    if (hooks.before) hooks.before(*scene);
    scenes::SceneMeasures worst, now;
    double wall_ms = 0.0, energy_start = 0.0;
    // Scenes with contact between deformables (a "self contact" source): an independent checker
    // (FCL, intersections.hpp) counts intersecting triangle pairs at the end of every frame, outside
    // the timed part; the line reports the worst frame.
    std::unique_ptr<intersections::SurfaceIntersections> checker;
    std::size_t worst_intersections = 0;
    int worst_intersections_frame = 0;
    if (System* system = scene->deformable_system()) {
      bool self_contact = false;
      for (const auto& source : system->collision_sources()) self_contact |= source->name() == "self contact";
      if (self_contact && !system->collision_geometry().triangles.empty())
        checker = std::make_unique<intersections::SurfaceIntersections>(system->collision_geometry().triangles,
                                                                        system->particles().x);
    }
    for (int f = 1; f <= o.frames; ++f) {
      const auto start = std::chrono::steady_clock::now();
      scene->advance(t.frame_dt, t.substeps);
      wall_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
      now = scene->measure();
      if (!std::isfinite(now.energy)) fail("frame ", f, ": the energy is not finite");
      if (f == 1) energy_start = now.energy;  // after the first frame: masses are set up there
      worst.hard_binding_drift = std::max(worst.hard_binding_drift, now.hard_binding_drift);
      worst.binding_spring_stretch = std::max(worst.binding_spring_stretch, now.binding_spring_stretch);
      worst.deepest_penetration = std::max(worst.deepest_penetration, now.deepest_penetration);
      if (checker) {
        const std::size_t pairs = checker->count(scene->deformable_system()->particles().x);
        if (pairs > worst_intersections) {
          worst_intersections = pairs;
          worst_intersections_frame = f;
        }
      }
      if (hooks.after_frame) hooks.after_frame(*scene, f);
    }
    if (hooks.after) hooks.after(*scene, o.frames, t.frame_dt);
    std::string stats;
    if (const StepStats* s = scene->total_stats(); s != nullptr && s->substeps > 0) {
      char text[160];
      std::snprintf(text, sizeof text, "\"substeps_per_frame\": %.2f, \"cg_iterations_per_substep\": %.2f, ",
                    double(s->substeps) / o.frames,
                    double(s->cg_iterations_step1 + s->cg_iterations_step3 + s->cg_iterations_step4) / s->substeps);
      stats = text;
    }
    if (checker) {
      char text[120];
      std::snprintf(text, sizeof text, "\"intersecting_pairs_max\": %zu, \"intersecting_pairs_frame\": %d, ",
                    worst_intersections, worst_intersections_frame);
      stats += text;
    }
    stats += scene->json_fields();
    std::printf(
        "{\"scene\": \"%s\", \"particles\": %lld, \"rigid_bodies\": %lld, \"frames\": %d, \"frame_dt\": %.6g, "
        "\"ticks_per_frame\": %d, "
        "%s\"wall_ms_per_frame\": %.3f, \"max_hard_binding_drift\": %.3g, \"max_binding_spring_stretch\": %.3g, "
        "\"deepest_penetration\": %.3g, \"velocity_rms\": %.3g, \"energy_start\": %.6g, \"energy_end\": %.6g, "
        "\"finite\": true, "
        "\"state_hash\": \"%016llx\"}\n",
        name.c_str(), static_cast<long long>(now.particles), static_cast<long long>(now.rigid_bodies), o.frames,
        t.frame_dt, t.substeps, stats.c_str(), wall_ms / o.frames, worst.hard_binding_drift,
        worst.binding_spring_stretch, worst.deepest_penetration, now.velocity_rms, energy_start, now.energy,
        static_cast<unsigned long long>(scene->state_hash()));
  } catch (const Error& e) {
    std::printf("{\"scene\": \"%s\", \"finite\": false, \"error\": \"%s\"}\n", name.c_str(),
                json_escaped(e.what()).c_str());
    std::fprintf(stderr, "%s: %s\n", program.name, e.what());
    return 1;
  } catch (const std::exception& e) {  // files: a folder that cannot be made, a disk that is full
    std::fprintf(stderr, "%s: %s\n", program.name, e.what());
    return 1;
  }
  return 0;
}

}  // namespace sinew::demos
