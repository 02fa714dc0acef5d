#include "cli.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <string_view>

namespace sinew::demos {

namespace {

[[noreturn]] void usage(const Program& p, const std::string& problem) {
  std::string synopsis = std::string(p.name) + (p.default_scene ? " [SCENE]" : " SCENE") + " [--list]";
  if (p.flags & kFrames) synopsis += " [--frames N]";
  if (p.flags & kDt) synopsis += " [--dt SECONDS | --fps F]";
  if (p.flags & kSubsteps) synopsis += " [--substeps N]";
  if (p.flags & kGrid) synopsis += " [--nx N] [--ny N]";
  if (p.flags & kFiles) synopsis += " [--out DIR] [--render DIR] [--video FILE]";
  if (p.flags & kSize) synopsis += " [--size WxH]";
  if (p.flags & kScreenshot) synopsis += " [--screenshot FILE]";
  if (p.flags & kOverlays) synopsis += " [--no-springs] [--no-hard] [--no-soft] [--parents]";
  if (p.flags & kScheme) synopsis += " [--fixed-scheme]";
  std::fprintf(stderr, "%s: %s\nusage: %s\n(%s --list names the scenes)\n", p.name, problem.c_str(), synopsis.c_str(),
               p.name);
  std::exit(2);
}

int whole_number(const Program& p, const char* flag, const char* text) {
  errno = 0;
  char* end = nullptr;
  const long v = std::strtol(text, &end, 10);
  if (end == text || *end != '\0' || errno != 0 || v < 0 || v > 1000000000)
    usage(p, std::string(flag) + " takes a whole number from 0, got '" + text + "'");
  return static_cast<int>(v);
}

double positive_number(const Program& p, const char* flag, const char* text) {
  char* end = nullptr;
  const double v = std::strtod(text, &end);
  if (end == text || *end != '\0' || !(v > 0) || !(v < 1e9))
    usage(p, std::string(flag) + " takes a positive number, got '" + text + "'");
  return v;
}

}  // namespace

Options parse_command_line(const Program& p, int argc, char** argv) {
  Options o;
  o.frames = p.default_frames;
  o.width = p.default_width;
  o.height = p.default_height;
  bool fps_given = false, dt_given = false;
  for (int i = 1; i < argc; ++i) {
    const std::string_view arg = argv[i];
    if (arg.empty() || arg[0] != '-') {
      if (!o.scene.empty()) usage(p, "one scene at a time ('" + o.scene + "' and '" + std::string(arg) + "')");
      o.scene = arg;
      continue;
    }
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) usage(p, std::string(arg) + " needs a value");
      return argv[++i];
    };
    auto takes = [&](unsigned flag) {
      if (!(p.flags & flag)) usage(p, std::string(arg) + " is not a flag of " + p.name);
    };
    if (arg == "--list") o.list = true;
    else if (arg == "--frames") takes(kFrames), o.frames = whole_number(p, "--frames", value());
    else if (arg == "--dt") takes(kDt), o.dt = positive_number(p, "--dt", value()), dt_given = true;
    else if (arg == "--fps") takes(kDt), o.dt = 1.0 / positive_number(p, "--fps", value()), fps_given = true;
    else if (arg == "--substeps") takes(kSubsteps), o.substeps = whole_number(p, "--substeps", value());
    else if (arg == "--nx") takes(kGrid), o.params.nx = whole_number(p, "--nx", value());
    else if (arg == "--ny") takes(kGrid), o.params.ny = whole_number(p, "--ny", value());
    else if (arg == "--out") takes(kFiles), o.out = value();
    else if (arg == "--render") takes(kFiles), o.render = value();
    else if (arg == "--video") takes(kFiles), o.video = value();
    else if (arg == "--screenshot") takes(kScreenshot), o.screenshot = value();
    else if (arg == "--size") {
      takes(kSize);
      const char* text = value();
      char tail = 0;
      if (std::sscanf(text, "%dx%d%c", &o.width, &o.height, &tail) != 2 || o.width < 16 || o.height < 16 ||
          o.width > 8192 || o.height > 8192)
        usage(p, std::string("--size takes WxH, each 16 to 8192 pixels, got '") + text + "'");
    } else if (arg == "--no-springs") takes(kOverlays), o.springs = false;
    else if (arg == "--no-hard") takes(kOverlays), o.hard_bound = false;
    else if (arg == "--no-soft") takes(kOverlays), o.soft_bound = false;
    else if (arg == "--parents") takes(kOverlays), o.parents = true;
    else if (arg == "--fixed-scheme") takes(kScheme), o.fixed_scheme = true;
    else usage(p, "unknown flag " + std::string(arg));
  }
  if (o.list) {
    print_scenes(stdout, p);
    std::exit(0);
  }
  if (dt_given && fps_given) usage(p, "--dt and --fps both set the frame: give one");
  if (o.scene.empty()) {
    if (!p.default_scene) usage(p, "which scene?");
    o.scene = p.default_scene;
  }
  if ((p.flags & kFrames) && p.default_frames > 0 && o.frames < 1) usage(p, "--frames must be at least 1");
  if (!o.screenshot.empty() && o.frames < 1) usage(p, "--screenshot needs --frames N (at least 1)");
  const auto listed = [&](const scenes::SceneInfo& s) { return s.name == o.scene; };
  const auto& all = scenes::registered_scenes();
  const auto found = std::find_if(all.begin(), all.end(), listed);
  if (found == all.end()) usage(p, "unknown scene '" + o.scene + "'");
  if (std::find(p.kinds.begin(), p.kinds.end(), found->kind) == p.kinds.end())
    usage(p, "'" + o.scene + "' is a " + scenes::to_string(found->kind) + " scene, which " + p.name + " does not run");
  if ((!o.out.empty() || !o.render.empty() || !o.video.empty()) && found->kind != scenes::SceneKind::bullet)
    usage(p, "--out, --render and --video draw Bullet scenes; '" + o.scene + "' is a " +
                 scenes::to_string(found->kind) + " scene");
  return o;
}

void print_scenes(std::FILE* out, const Program& p) {
  for (const scenes::SceneInfo& s : scenes::registered_scenes()) {
    if (std::find(p.kinds.begin(), p.kinds.end(), s.kind) == p.kinds.end()) continue;
    const std::string frame = s.gallery_frame > 0 ? std::to_string(s.gallery_frame) : "-";
    std::fprintf(out, "%-44s %-6s %-4s %s\n", s.name.c_str(), scenes::to_string(s.kind), frame.c_str(),
                 s.description.c_str());
  }
}

}  // namespace sinew::demos
