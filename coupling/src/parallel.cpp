#include "sinew/parallel.hpp"

#include <atomic>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace sinew {

namespace {
std::atomic<int> g_threads{1};
}  // namespace

void set_thread_count(int threads) {
  if (threads < 0) fail("thread count ", threads, " must be >= 0 (0: every hardware thread)");
#ifdef _OPENMP
  if (threads == 0) threads = omp_get_num_procs();
#else
  threads = 1;  // built without OpenMP: loops run on the calling thread
#endif
  g_threads.store(threads, std::memory_order_relaxed);
}

int thread_count() { return g_threads.load(std::memory_order_relaxed); }

}  // namespace sinew
