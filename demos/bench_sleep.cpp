// sinew-bench-sleep: what sleeping saves (StepSettings::sleep). A cloth hung straight down from
// kinematic points along its top row settles under gravity at 60 frames per second; the program
// prints when it falls asleep, then the median time per frame asleep and, with sleeping turned off,
// awake on the same resting cloth (the median over runs of each run's median frame).
//
//   sinew-bench-sleep [--runs N] [--frames N] [--size N] [--threads N]
#include "machine.hpp"
#include "sinew/builders.hpp"

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

namespace {

using namespace sinew;

double ms_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

int main(int argc, char** argv) {
  int runs = 5, frames = 60, size = 40, threads = 1;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--runs") && i + 1 < argc) runs = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--size") && i + 1 < argc) size = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--runs N] [--frames N] [--size N] [--threads N]\n", argv[0]);
      return 2;
    }
  }
  const double frame = 1.0 / 60;
  std::printf("machine: %s, %u hardware threads; step threads %d\n", bench::cpu_model().c_str(),
              std::thread::hardware_concurrency(), threads);
  std::vector<double> asleep_ms, awake_ms, onset_s;
  for (int run = 0; run < runs; ++run) {
    System system;
    ClothGridSettings c;
    c.nx = c.ny = size;
    const ClothGrid cloth = add_cloth_grid(system, c);
    const std::array<double, 1> one{1.0};
    for (int i = 0; i < size; ++i) {
      const Index pin = system.add_kinematic_particle(system.particles().x.col(cloth.node(i, 0)));
      system.bind_linear(cloth.node(i, 0), std::array<Index, 1>{pin}, one);
    }
    system.step_settings().threads = threads;
    int frame_count = 0;
    while (!system.asleep() && frame_count < 60 * 60) {
      system.advance(frame);
      ++frame_count;
    }
    if (!system.asleep()) {
      std::printf("run %d: not asleep after 60 s\n", run);
      return 1;
    }
    onset_s.push_back(frame_count * frame);
    std::vector<double> asleep, awake;
    for (int f = 0; f < frames; ++f) {
      const auto start = std::chrono::steady_clock::now();
      system.advance(frame);
      asleep.push_back(ms_since(start));
    }
    system.step_settings().sleep = false;
    for (int f = 0; f < frames; ++f) {
      const auto start = std::chrono::steady_clock::now();
      system.advance(frame);
      awake.push_back(ms_since(start));
    }
    asleep_ms.push_back(bench::median(asleep));
    awake_ms.push_back(bench::median(awake));
  }
  std::printf("%d x %d cloth, 1/60 s frames, %d runs of %d frames each\n", size, size, runs, frames);
  std::printf("falls asleep after %.3f s (median)\n", bench::median(onset_s));
  std::printf("ms per frame at rest: awake %.4f, asleep %.4f (medians)\n", bench::median(awake_ms),
              bench::median(asleep_ms));
  return 0;
}
