// FNV-1a over raw bytes: the scenes' state hashes (sinew's own, mixed with a rigid solver's state)
// and sinew-hashes' records. The bytes of doubles, so equal only for bit-identical states.
#pragma once

#include <cstddef>
#include <cstdint>

namespace sinew::scenes {

struct FnvHash {
  std::uint64_t h = 1469598103934665603ull;
  void mix(const void* data, std::size_t bytes) {
    const auto* c = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < bytes; ++i) h = (h ^ c[i]) * 1099511628211ull;
  }
  void mix(double d) { mix(&d, sizeof d); }
  void mix(std::uint64_t u) { mix(&u, sizeof u); }
};

}  // namespace sinew::scenes
