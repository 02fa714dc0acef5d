// Small helpers shared by the test suites.
#pragma once

#include "sinew/types.hpp"

#include <random>
#include <string>

namespace sinew::test {

/// Fixed-seed generator: every test is deterministic.
inline std::mt19937_64& rng() {
  static std::mt19937_64 g(20070803);
  return g;
}
inline double uniform(double a = -1.0, double b = 1.0) { return std::uniform_real_distribution<double>(a, b)(rng()); }
inline Vec3 random_vec3(double scale = 1.0) { return scale * Vec3(uniform(), uniform(), uniform()); }
inline Quat random_rotation() { return Quat(uniform(), uniform(), uniform(), uniform()).normalized(); }

/// The message of the sinew::Error that f() throws, or "no error".
template <typename F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "no error";
}

}  // namespace sinew::test
