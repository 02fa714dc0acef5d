// What the benchmarks print about where they ran, and the median they report.
#pragma once

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

namespace sinew::bench {

/// The processor's model name from /proc/cpuinfo ("unknown" elsewhere).
inline std::string cpu_model() {
  std::FILE* f = std::fopen("/proc/cpuinfo", "r");
  if (!f) return "unknown";
  char line[512];
  std::string model = "unknown";
  while (std::fgets(line, sizeof line, f))
    if (!std::strncmp(line, "model name", 10)) {
      const char* colon = std::strchr(line, ':');
      model = colon ? colon + 2 : line;
      if (!model.empty() && model.back() == '\n') model.pop_back();
      break;
    }
  std::fclose(f);
  return model;
}

/// The median (mean of the middle two for an even count); 0 for none.
inline double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace sinew::bench
