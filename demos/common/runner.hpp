// The headless run shared by sinew-demo and sinew-core-demo: builds the scene the command line names,
// runs its frames and prints one JSON line ("finite": true, or false with the error).
#pragma once

#include "cli.hpp"

#include <functional>
#include <string>

namespace sinew::demos {

/// What a program adds to the plain run (sinew-demo's files and pictures).
struct RunHooks {
  std::function<void(scenes::Scene&)> before;                  ///< once the scene is built
  std::function<void(scenes::Scene&, int frame)> after_frame;  ///< frame counted from 1
  std::function<void(scenes::Scene&, int frames, double frame_dt)> after;
};

/// The frame and ticks a run uses: the command line's where given, else the scene's own.
struct Timing {
  double frame_dt;
  int substeps;
};
Timing timing(const Options& options, const scenes::Scene& scene);

/// Runs options.scene for options.frames frames and prints the JSON summary to stdout; returns the exit
/// status (1 when the scene throws: the JSON line then says "finite": false and names the error).
int run_headless(const Program& program, const Options& options, const RunHooks& hooks = {});

}  // namespace sinew::demos
