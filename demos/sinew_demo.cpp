// sinew-demo <scene>: runs one of the Bullet demo scenes headless and prints a one-line JSON summary.
//
//   sinew-demo curtain|net|plates|hello [--frames N] [--dt SECONDS] [--substeps N] [--out DIR]
//              [--render DIR] [--video FILE] [--size WxH] [--no-springs] [--no-hard] [--no-soft] [--parents]
//
// --out DIR writes DIR/frame_0001.obj, ... : the deformable surfaces and every rigid body's shape.
// --render DIR writes DIR/frame_0001.png, ... : pictures rendered offscreen (OSMesa), with the binding
// overlays (springs orange, hard-bound points red, soft-bound yellow, parents blue) the flags select.
// --video FILE assembles the frames into an MP4 or, for a .gif name, a GIF with ffmpeg.
#include "bullet_scenes.hpp"
#include "renderer.hpp"
#include "sinew/mesh/mesh_io.hpp"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <string>

#include <unistd.h>

namespace {

[[noreturn]] void usage(const char* problem) {
  std::fprintf(stderr,
               "sinew-demo: %s\nusage: sinew-demo curtain|net|plates|hello [--frames N] [--dt SECONDS] [--substeps N] [--out DIR]\n"
               "                  [--render DIR] [--video FILE] [--size WxH] [--no-springs] [--no-hard] [--no-soft] [--parents]\n",
               problem);
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) usage("which scene?");
  const std::string scene_name = argv[1];
  int frames = 240, substeps = 0;  // 0: the scene's own
  double dt = 1.0 / 60.0;
  std::string out, render_dir, video;
  int width = 960, height = 540;
  sinew::render::Overlays overlays;
  for (int i = 2; i < argc; ++i) {
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) usage("a flag needs a value");
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--frames")) frames = std::atoi(value());
    else if (!std::strcmp(argv[i], "--dt")) dt = std::atof(value());
    else if (!std::strcmp(argv[i], "--substeps")) substeps = std::atoi(value());
    else if (!std::strcmp(argv[i], "--out")) out = value();
    else if (!std::strcmp(argv[i], "--render")) render_dir = value();
    else if (!std::strcmp(argv[i], "--video")) video = value();
    else if (!std::strcmp(argv[i], "--size")) {
      if (std::sscanf(value(), "%dx%d", &width, &height) != 2 || width < 16 || height < 16 || width > 8192 || height > 8192)
        usage("--size takes WxH, each 16 to 8192 pixels");
    }
    else if (!std::strcmp(argv[i], "--no-springs")) overlays.binding_springs = false;
    else if (!std::strcmp(argv[i], "--no-hard")) overlays.hard_bound = false;
    else if (!std::strcmp(argv[i], "--no-soft")) overlays.soft_bound = false;
    else if (!std::strcmp(argv[i], "--parents")) overlays.parents = true;
    else usage("unknown flag");
  }
  if (frames < 1 || substeps < 0 || !(dt > 0)) usage("--frames, --substeps and --dt must be positive");
  try {
    auto scene = sinew::scenes::make_bullet_scene(scene_name);
    if (substeps == 0) substeps = scene->default_substeps();
    double drift = 0.0, stretch = 0.0, penetration = 0.0, wall_ms = 0.0, energy_start = 0.0;
    bool first = true;
    // Pictures: frames go to --render's directory, or to a temporary one that only --video needs.
    std::filesystem::path frames_dir = render_dir;
    const bool temporary_frames = render_dir.empty() && !video.empty();
    if (temporary_frames)
      frames_dir = std::filesystem::temp_directory_path() / ("sinew-demo-frames-" + std::to_string(::getpid()));
    // The temporary folder goes however the run ends.
    struct RemoveOnExit {
      std::filesystem::path path;
      ~RemoveOnExit() {
        std::error_code ignored;
        if (!path.empty()) std::filesystem::remove_all(path, ignored);
      }
    } remove_frames{temporary_frames ? frames_dir : std::filesystem::path()};
    if (!frames_dir.empty() && std::filesystem::exists(frames_dir) && !std::filesystem::is_directory(frames_dir))
      sinew::fail("--render: '", frames_dir.string(), "' exists and is not a folder");
    std::unique_ptr<sinew::render::Offscreen> offscreen;
    sinew::render::Camera camera;
    if (!frames_dir.empty()) {
      std::filesystem::create_directories(frames_dir);
      offscreen = std::make_unique<sinew::render::Offscreen>(width, height);
      camera = sinew::render::framing_camera(sinew::render::picture_of(*scene, overlays), double(width) / height);
    }
    for (int f = 0; f < frames; ++f) {
      const auto start = std::chrono::steady_clock::now();
      scene->advance(dt, substeps);
      wall_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
      if (first) {
        energy_start = scene->total_energy();  // after the first frame: masses are set up there
        first = false;
      }
      drift = std::max(drift, scene->hard_binding_drift());
      stretch = std::max(stretch, scene->system().binding_springs().max_stretch(scene->system().particles().x));
      penetration = std::max(penetration, scene->coupling().deepest_penetration());
      if (!out.empty()) {
        std::filesystem::create_directories(out);
        char file[64];
        std::snprintf(file, sizeof file, "frame_%04d.obj", f + 1);
        std::vector<sinew::mesh::TriangleMesh> meshes;
        std::vector<std::string> names;
        for (auto& surface : scene->surfaces()) {
          meshes.push_back({std::move(surface.vertices), std::move(surface.triangles)});
          names.push_back(surface.name);
        }
        sinew::mesh::save_triangle_meshes((std::filesystem::path(out) / file).string(), meshes, names);
      }
      if (offscreen) {
        const sinew::render::Picture picture = sinew::render::picture_of(*scene, overlays);
        sinew::render::follow(camera, picture);
        sinew::render::draw(picture, camera, width, height);
        char file[64];
        std::snprintf(file, sizeof file, "frame_%04d.png", f + 1);
        sinew::render::write_png((frames_dir / file).string(), width, height, offscreen->pixels());
      }
    }
    if (!video.empty()) {
      sinew::render::encode_video(frames_dir.string(), frames, 1.0 / dt, video);
    }
    const double energy_end = scene->total_energy();
    std::printf(
        "{\"scene\": \"%s\", \"particles\": %lld, \"rigid_bodies\": %zu, \"frames\": %d, \"wall_ms_per_frame\": %.3f, "
        "\"max_hard_binding_drift\": %.3g, \"max_binding_spring_stretch\": %.3g, \"deepest_penetration\": %.3g, "
        "\"energy_start\": %.6g, \"energy_end\": %.6g, \"finite\": true}\n",
        scene_name.c_str(), static_cast<long long>(scene->system().particles().size()), scene->bullet().bodies().size(), frames,
        wall_ms / frames, drift, stretch, penetration, energy_start, energy_end);
  } catch (const sinew::Error& e) {
    std::printf("{\"scene\": \"%s\", \"finite\": false, \"error\": \"%s\"}\n", scene_name.c_str(), e.what());
    std::fprintf(stderr, "sinew-demo: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {  // files: a folder that cannot be made, a disk that is full
    std::fprintf(stderr, "sinew-demo: %s\n", e.what());
    return 1;
  }
  return 0;
}
