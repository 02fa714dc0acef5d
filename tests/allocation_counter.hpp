// Counts heap allocations while armed (replaces the global operator new in the test binary), to show
// that the step allocates nothing after its first call.
#pragma once

#include <atomic>

extern std::atomic<bool> g_count_allocations;
extern std::atomic<long> g_allocations;
