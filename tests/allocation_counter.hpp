// Counts heap allocations while armed (replaces the global operator new in the test binary), to show
// that the step allocates nothing after its first call.
#pragma once

#include <atomic>

extern std::atomic<bool> g_count_allocations;
extern std::atomic<long> g_allocations;

/// The number of heap allocations while run() runs.
template <typename Run>
long allocations_during(Run&& run) {
  g_allocations = 0;
  g_count_allocations = true;
  run();
  g_count_allocations = false;
  return g_allocations.load();
}
