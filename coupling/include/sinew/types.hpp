// Basic types shared by every part of sinew's coupling core.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace sinew {

using Index = std::int64_t;
using Vec3 = Eigen::Vector3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;
using VectorXd = Eigen::VectorXd;
/// Structure-of-arrays block of 3-vectors, one column per particle (3 x N).
using Vectors3 = Eigen::Matrix<double, 3, Eigen::Dynamic>;
/// Structure-of-arrays block of 6-vectors (linear then angular), one column per rigid body (6 x R).
using Vectors6 = Eigen::Matrix<double, 6, Eigen::Dynamic>;

inline constexpr double kInfinity = std::numeric_limits<double>::infinity();

/// Every failure sinew reports: bad settings, degenerate elements, non-finite state.
/// The message always names the offending item ("binding 17: weights sum to 0.93, expected 1").
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Builds a message from stream-able parts and throws sinew::Error.
template <typename... Parts>
[[noreturn]] void fail(const Parts&... parts) {
  std::ostringstream out;
  out.precision(6);
  (out << ... << parts);
  throw Error(out.str());
}

/// Cross-product matrix r* with r* a = r x a.
inline Mat3 cross_matrix(const Vec3& r) {
  Mat3 m;
  m << 0.0, -r.z(), r.y(), r.z(), 0.0, -r.x(), -r.y(), r.x(), 0.0;
  return m;
}

inline bool all_finite(const Vec3& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }

}  // namespace sinew
