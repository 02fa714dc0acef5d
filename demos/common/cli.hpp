// The command line shared by sinew-demo, sinew-view and sinew-core-demo: one parser, so a flag means
// the same in every program; each program says which flags it takes.
//
//   <program> [SCENE] [--list] [--frames N] [--dt SECONDS | --fps F] [--substeps N] [--nx N] [--ny N]
//             [--out DIR] [--render DIR] [--video FILE] [--size WxH] [--screenshot FILE]
//             [--no-springs] [--no-hard] [--no-soft] [--parents] [--fixed-scheme]
#pragma once

#include "scene.hpp"

#include <cstdio>
#include <string>
#include <vector>

namespace sinew::demos {

/// The flags, as bits of Program::flags.
enum Flag : unsigned {
  kFrames = 1u << 0,      ///< --frames N
  kDt = 1u << 1,          ///< --dt SECONDS and --fps F (F frames a second: dt = 1/F)
  kSubsteps = 1u << 2,    ///< --substeps N: ticks per frame (0: the scene's own)
  kGrid = 1u << 3,        ///< --nx N, --ny N: the cloth's resolution, for scenes that take one
  kFiles = 1u << 4,       ///< --out DIR (OBJ per frame), --render DIR (PNG per frame), --video FILE
  kSize = 1u << 5,        ///< --size WxH [pixels]
  kScreenshot = 1u << 6,  ///< --screenshot FILE
  kOverlays = 1u << 7,    ///< --no-springs, --no-hard, --no-soft, --parents
  kScheme = 1u << 8,      ///< --fixed-scheme: StepSettings::automatic off (the scene's settings as set)
};

struct Program {
  const char* name;
  unsigned flags;
  std::vector<scenes::SceneKind> kinds;  ///< the scene kinds it runs (and --list shows)
  const char* default_scene = nullptr;   ///< nullptr: the scene is required
  int default_frames = 240;              ///< 0: run until the window closes
  int default_width = 960, default_height = 540;
};

struct Options {
  std::string scene;
  bool list = false;  ///< --list: print the scenes and exit
  int frames = 0;
  double dt = 0.0;            ///< 0: the scene's own frame
  int substeps = 0;           ///< 0: the scene's own ticks per frame
  bool fixed_scheme = false;  ///< --fixed-scheme
  scenes::SceneParams params;
  std::string out, render, video, screenshot;
  int width = 0, height = 0;
  bool springs = true, hard_bound = true, soft_bound = true, parents = false;  ///< overlays
};

/// Reads argv for `program`. Prints the problem and the usage to stderr and exits with status 2 on a
/// bad command line (unknown flag, a flag this program does not take, a missing or malformed value);
/// with --list prints the scenes (print_scenes) and exits with status 0.
Options parse_command_line(const Program& program, int argc, char** argv);

/// One line per registered scene of the program's kinds: name, kind, gallery frame ("-": none) and
/// description, separated by spaces (the first three are one word each: `read -r name kind frame
/// description` splits a line).
void print_scenes(std::FILE* out, const Program& program);

}  // namespace sinew::demos
