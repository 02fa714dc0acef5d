// sinew-demo SCENE: runs a registered scene headless and prints a one-line JSON summary;
// `sinew-demo --list` names the scenes. The flags are the shared command line's (common/cli.hpp).
//
// --out DIR writes DIR/frame_0001.obj, ... : the deformable surfaces and every rigid body's shape.
// --render DIR writes DIR/frame_0001.png, ... : pictures rendered offscreen (OSMesa), with the binding
// overlays (springs orange, hard-bound points red, soft-bound yellow, parents blue) the flags select.
// --video FILE assembles the frames into an MP4 or, for a .gif name, a GIF with ffmpeg.
// The files are for Bullet scenes (kind "bullet" in --list); the others are run and measured.
#include "bullet_scenes.hpp"
#include "cli.hpp"
#include "renderer.hpp"
#include "runner.hpp"
#include "sinew/mesh/mesh_io.hpp"

#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include <unistd.h>

namespace {

using namespace sinew;

// The pictures and meshes a run writes (Bullet scenes only: the command line refuses the rest).
struct Files {
  const demos::Options& o;
  std::filesystem::path frames_dir;
  bool temporary_frames = false;
  std::unique_ptr<render::Offscreen> offscreen;
  render::Camera camera;
  render::Overlays overlays;

  explicit Files(const demos::Options& options) : o(options), frames_dir(options.render) {
    overlays.binding_springs = o.springs;
    overlays.hard_bound = o.hard_bound;
    overlays.soft_bound = o.soft_bound;
    overlays.parents = o.parents;
    // Frames go to --render's directory, or to a temporary one that only --video needs.
    temporary_frames = o.render.empty() && !o.video.empty();
    if (temporary_frames)
      frames_dir = std::filesystem::temp_directory_path() / ("sinew-demo-frames-" + std::to_string(::getpid()));
  }
  ~Files() {  // the temporary folder goes however the run ends
    std::error_code ignored;
    if (temporary_frames) std::filesystem::remove_all(frames_dir, ignored);
  }

  void before(scenes::Scene& scene) {
    if (frames_dir.empty()) return;
    if (std::filesystem::exists(frames_dir) && !std::filesystem::is_directory(frames_dir))
      fail("--render: '", frames_dir.string(), "' exists and is not a folder");
    std::filesystem::create_directories(frames_dir);
    offscreen = std::make_unique<render::Offscreen>(o.width, o.height);
    camera = render::framing_camera(render::picture_of(bullet(scene), overlays), double(o.width) / o.height);
  }

  void after_frame(scenes::Scene& scene, int frame) {
    char file[64];
    if (!o.out.empty()) {
      std::filesystem::create_directories(o.out);
      std::snprintf(file, sizeof file, "frame_%04d.obj", frame);
      std::vector<mesh::TriangleMesh> meshes;
      std::vector<std::string> names;
      for (auto& surface : bullet(scene).surfaces()) {
        meshes.push_back({std::move(surface.vertices), std::move(surface.triangles)});
        names.push_back(surface.name);
      }
      mesh::save_triangle_meshes((std::filesystem::path(o.out) / file).string(), meshes, names);
    }
    if (offscreen) {
      const render::Picture picture = render::picture_of(bullet(scene), overlays);
      render::follow(camera, picture);
      render::draw(picture, camera, o.width, o.height);
      std::snprintf(file, sizeof file, "frame_%04d.png", frame);
      render::write_png((frames_dir / file).string(), o.width, o.height, offscreen->pixels());
    }
  }

  void after(int frames, double frame_dt) const {
    if (!o.video.empty()) render::encode_video(frames_dir.string(), frames, 1.0 / frame_dt, o.video);
  }

  static scenes::BulletScene& bullet(scenes::Scene& scene) { return dynamic_cast<scenes::BulletScene&>(scene); }
};

}  // namespace

int main(int argc, char** argv) {
  const demos::Program program{.name = "sinew-demo",
                               .flags = demos::kFrames | demos::kDt | demos::kSubsteps | demos::kGrid | demos::kFiles |
                                        demos::kSize | demos::kOverlays | demos::kScheme,
                               .kinds = {scenes::SceneKind::bullet, scenes::SceneKind::core, scenes::SceneKind::bench}};
  const demos::Options options = demos::parse_command_line(program, argc, argv);
  Files files(options);
  demos::RunHooks hooks;
  if (!options.out.empty() || !files.frames_dir.empty()) {
    hooks.before = [&](scenes::Scene& s) { files.before(s); };
    hooks.after_frame = [&](scenes::Scene& s, int frame) { files.after_frame(s, frame); };
    hooks.after = [&](scenes::Scene&, int frames, double frame_dt) { files.after(frames, frame_dt); };
  }
  return demos::run_headless(program, options, hooks);
}
