// In its own translation unit so the compiler never inlines a replaced operator new next to a
// library's delete (which GCC 12 misreports as a mismatched pair).
#include "allocation_counter.hpp"

#include <cstdlib>
#include <new>

std::atomic<bool> g_count_allocations{false};
std::atomic<long> g_allocations{0};

void* operator new(std::size_t size) {
  if (g_count_allocations.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
