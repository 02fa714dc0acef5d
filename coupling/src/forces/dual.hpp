// Forward-mode dual numbers and a minimal 3-vector, private to the forces.
//
// A kernel templated on its scalar and evaluated with Dual{x, dx} returns f(x) in .v and the
// directional derivative (df/dx) dx in .d, exact to round-off. Used where an analytic Hessian would
// be long and error-prone and the differential is off the hot path (dihedral bending).
#pragma once

#include <cmath>

namespace sinew::detail {

struct Dual {
  double v = 0.0;  ///< value
  double d = 0.0;  ///< directional derivative

  constexpr Dual() = default;
  constexpr Dual(double value, double derivative = 0.0) : v(value), d(derivative) {}  // NOLINT: implicit from double

  friend constexpr Dual operator+(Dual a, Dual b) { return {a.v + b.v, a.d + b.d}; }
  friend constexpr Dual operator-(Dual a, Dual b) { return {a.v - b.v, a.d - b.d}; }
  friend constexpr Dual operator-(Dual a) { return {-a.v, -a.d}; }
  friend constexpr Dual operator*(Dual a, Dual b) { return {a.v * b.v, a.d * b.v + a.v * b.d}; }
  friend constexpr Dual operator/(Dual a, Dual b) { return {a.v / b.v, (a.d * b.v - a.v * b.d) / (b.v * b.v)}; }
};

inline Dual sqrt(Dual a) {
  const double s = std::sqrt(a.v);
  return {s, a.d / (2.0 * s)};
}

inline Dual atan2(Dual y, Dual x) { return {std::atan2(y.v, x.v), (x.v * y.d - y.v * x.d) / (x.v * x.v + y.v * y.v)}; }

inline double value_of(double a) { return a; }
inline double value_of(Dual a) { return a.v; }

template <typename T>
struct Vec {
  T x, y, z;

  friend Vec operator+(const Vec& a, const Vec& b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
  friend Vec operator-(const Vec& a, const Vec& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
  friend Vec operator*(const Vec& a, const T& s) { return {a.x * s, a.y * s, a.z * s}; }
};

template <typename T>
T dot(const Vec<T>& a, const Vec<T>& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}

template <typename T>
Vec<T> cross(const Vec<T>& a, const Vec<T>& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

}  // namespace sinew::detail
