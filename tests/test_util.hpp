// Small helpers shared by the test suites.
#pragma once

#include "sinew/builders.hpp"
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

/// A square cloth of n x n nodes and side `size` [m], node (0, 0) at `origin`, hanging along -y, with
/// the builders' default material (the tests set what they need on top).
inline ClothGridSettings square_cloth(int n, double size, const Vec3& origin) {
  ClothGridSettings c;
  c.nx = c.ny = n;
  c.width = c.height = size;
  c.origin = origin;
  return c;
}

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
