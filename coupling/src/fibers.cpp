// Fibers embedded in a meshfree matrix: see the header.
#include "sinew/fibers.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <numbers>
#include <set>
#include <sstream>

namespace sinew {

EmbeddedFibers embed_fibers(System& system, MeshfreeCorotated& matrix, double h, const std::vector<Vectors3>& polylines,
                            const FiberSettings& settings) {
  if (!(std::isfinite(h) && h > 0.0)) fail("embed_fibers: support radius ", h, " must be positive and finite");
  if (!(settings.lambda >= 0.0 && settings.lambda < 1.0))
    fail("embed_fibers: lambda ", settings.lambda, " is outside [0, 1)");
  const std::vector<Index>& material = matrix.particles();
  const Vectors3& x = system.particles().x;  // the material at rest
  EmbeddedFibers out;
  std::set<Index> carriers;
  // A piece's points wait until it closes: a piece of one point (a stray point between two outside
  // the material) adds no particle, binding or carrier.
  struct Point {
    Vec3 at;
    std::vector<Index> parents;
    std::vector<double> weights;
  };
  std::vector<Point> piece;
  const auto close = [&] {
    if (piece.size() >= 2) {
      std::vector<Index> fiber;
      for (Point& point : piece) {
        const Index sp = system.add_particle(point.at, Vec3::Zero(), 0.0);
        system.bind_linear(sp, point.parents, point.weights);
        system.set_collision_filter(sp, kDefaultCollisionGroup, 0);
        carriers.insert(point.parents.begin(), point.parents.end());
        fiber.push_back(sp);
        out.parents.push_back(std::move(point.parents));
        out.weights.push_back(std::move(point.weights));
      }
      out.fibers.push_back(std::move(fiber));
    } else {
      out.dropped += static_cast<Index>(piece.size());
    }
    piece.clear();
  };
  for (std::size_t k = 0; k < polylines.size(); ++k) {
    for (Index p = 0; p < polylines[k].cols(); ++p) {
      const Vec3 X = polylines[k].col(p);
      if (!X.allFinite()) fail("embed_fibers: polyline ", k, " point ", p, " is not finite");
      Point point;
      double total = 0.0;
      for (const Index i : material) {
        const double q = (x.col(i) - X).norm() / h;
        if (q >= 1.0) continue;
        const double w = (1.0 + 3.0 * q) * std::pow(1.0 - q, 3);  // Lucy's kernel; its scale cancels
        point.parents.push_back(i);
        point.weights.push_back(w);
        total += w;
      }
      if (point.parents.empty()) {  // outside the material
        ++out.dropped;
        close();
        continue;
      }
      point.at = Vec3::Zero();
      for (std::size_t a = 0; a < point.parents.size(); ++a) {
        point.weights[a] /= total;
        point.at += point.weights[a] * x.col(point.parents[a]);
      }
      piece.push_back(std::move(point));
    }
    close();
  }
  if (out.fibers.empty()) return out;
  const double lambda = settings.lambda;
  out.force = &system.add_force(
      std::make_unique<ElasticRods>(out.fibers, system.particles().x,
                                    ElasticRodsSettings{.stretch_stiffness = lambda * settings.stretch_stiffness,
                                                        .bending_stiffness = lambda * settings.bending_stiffness,
                                                        .beta = settings.beta,
                                                        .implicit = settings.implicit}));
  if (lambda > 0.0)
    for (const Index i : carriers) matrix.set_volume_fraction(i, 1.0 - lambda);
  return out;
}

namespace {

// x at height y along a stroke monotone in y (2 x n: rows x, y), linearly between its points.
double along_height(const Eigen::Matrix2Xd& stroke, double y) {
  const bool rising = stroke(1, stroke.cols() - 1) > stroke(1, 0);
  Index lo = 0, hi = stroke.cols() - 1;
  while (hi - lo > 1) {  // bisection on the monotone heights
    const Index mid = (lo + hi) / 2;
    if ((stroke(1, mid) <= y) == rising) lo = mid;
    else hi = mid;
  }
  const double y0 = stroke(1, lo), y1 = stroke(1, hi);
  const double t = y1 == y0 ? 0.0 : std::clamp((y - y0) / (y1 - y0), 0.0, 1.0);
  return stroke(0, lo) + t * (stroke(0, hi) - stroke(0, lo));
}

void check_stroke(const Eigen::Matrix2Xd& stroke, const char* view) {
  if (stroke.cols() < 2)
    fail("fiber_from_strokes: the ", view, " stroke has ", stroke.cols(), " points, expected 2 or more");
  if (!stroke.allFinite()) fail("fiber_from_strokes: the ", view, " stroke has a non-finite point");
  const double direction = stroke(1, stroke.cols() - 1) - stroke(1, 0);
  if (direction == 0.0) fail("fiber_from_strokes: the ", view, " stroke does not move along the shared axis y");
  for (Index i = 1; i < stroke.cols(); ++i)
    if ((stroke(1, i) - stroke(1, i - 1)) * direction < 0.0)
      fail("fiber_from_strokes: the ", view, " stroke turns back along y at its point ", i,
           ": a stroke must run monotonically along the axis the views share");
}

}  // namespace

Vectors3 fiber_from_strokes(const Eigen::Matrix2Xd& front, const Eigen::Matrix2Xd& side, double spacing) {
  if (!(std::isfinite(spacing) && spacing > 0.0)) fail("fiber_from_strokes: spacing ", spacing, " must be positive");
  check_stroke(front, "front");
  check_stroke(side, "side");
  const auto range = [](const Eigen::Matrix2Xd& s) {
    return std::pair{std::min(s(1, 0), s(1, s.cols() - 1)), std::max(s(1, 0), s(1, s.cols() - 1))};
  };
  const auto [f0, f1] = range(front);
  const auto [s0, s1] = range(side);
  const double y0 = std::max(f0, s0), y1 = std::min(f1, s1);
  if (!(y1 > y0))
    fail("fiber_from_strokes: the strokes share no height (front ", f0, "..", f1, ", side ", s0, "..", s1, ")");
  // Densely along y (a hundredth of the spacing or finer, per stroke point), in the front stroke's
  // direction, then by arc length in 3D.
  constexpr double kMostPoints = 1e6;  // a fiber of more points than this is a spacing mistake
  if ((y1 - y0) / spacing > kMostPoints)
    fail("fiber_from_strokes: spacing ", spacing, " over a height of ", y1 - y0, " would make more than ", kMostPoints,
         " points");
  const bool down = front(1, front.cols() - 1) < front(1, 0);
  const Index dense = std::max<Index>(
      {Index(2), 4 * (front.cols() + side.cols()), static_cast<Index>(std::ceil(100.0 * (y1 - y0) / spacing))});
  Vectors3 path(3, dense);
  for (Index i = 0; i < dense; ++i) {
    const double t = double(i) / double(dense - 1);
    const double y = down ? y1 - t * (y1 - y0) : y0 + t * (y1 - y0);
    path.col(i) = Vec3(along_height(front, y), y, along_height(side, y));
  }
  std::vector<double> arc(static_cast<std::size_t>(dense), 0.0);
  for (Index i = 1; i < dense; ++i)
    arc[static_cast<std::size_t>(i)] = arc[static_cast<std::size_t>(i) - 1] + (path.col(i) - path.col(i - 1)).norm();
  const double length = arc.back();
  if (length / spacing > kMostPoints)
    fail("fiber_from_strokes: spacing ", spacing, " along a fiber ", length, " long would make more than ", kMostPoints,
         " points");
  const Index segments = std::max<Index>(1, static_cast<Index>(std::lround(length / spacing)));
  Vectors3 out(3, segments + 1);
  Index at = 0;
  for (Index k = 0; k <= segments; ++k) {
    const double target = length * double(k) / double(segments);
    while (at + 2 < dense && arc[static_cast<std::size_t>(at) + 1] < target) ++at;
    const double a = arc[static_cast<std::size_t>(at)], b = arc[static_cast<std::size_t>(at) + 1];
    const double t = b > a ? std::clamp((target - a) / (b - a), 0.0, 1.0) : 0.0;
    out.col(k) = path.col(at) + t * (path.col(at + 1) - path.col(at));
  }
  return out;
}

std::vector<Vectors3> read_fibers(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail("read_fibers: cannot read '", path, "'");
  std::vector<Vectors3> fibers;
  std::vector<Vec3> points;
  bool open = false;
  int started = 0;
  const auto close = [&](int line) {
    if (!open) return;
    if (points.size() < 2)
      fail("read_fibers: '", path, "' line ", line, ": the fiber started on line ", started, " has ", points.size(),
           " points, expected 2 or more");
    Vectors3 fiber(3, static_cast<Index>(points.size()));
    for (std::size_t i = 0; i < points.size(); ++i) fiber.col(static_cast<Index>(i)) = points[i];
    fibers.push_back(fiber);
    points.clear();
  };
  std::string text;
  int line = 0;
  while (std::getline(in, text)) {
    ++line;
    const std::string content = text.substr(0, text.find('#'));
    std::istringstream words(content);
    std::string first;
    if (!(words >> first)) continue;
    if (first == "fiber") {
      close(line);
      open = true;
      started = line;
      continue;
    }
    std::istringstream numbers(content);
    Vec3 p;
    std::string extra;
    if (!(numbers >> p.x() >> p.y() >> p.z()) || (numbers >> extra) || !p.allFinite())
      fail("read_fibers: '", path, "' line ", line, ": expected 'fiber' or three finite numbers, got '", text, "'");
    if (!open) fail("read_fibers: '", path, "' line ", line, ": a point before the first 'fiber'");
    points.push_back(p);
  }
  close(line + 1);
  return fibers;
}

void write_fibers(const std::string& path, const std::vector<Vectors3>& fibers) {
  for (std::size_t f = 0; f < fibers.size(); ++f) {
    if (fibers[f].cols() < 2) fail("write_fibers: fiber ", f, " has ", fibers[f].cols(), " points, expected 2 or more");
    if (!fibers[f].allFinite()) fail("write_fibers: fiber ", f, " has a non-finite point");
  }
  std::ofstream out(path);
  if (!out) fail("write_fibers: cannot write '", path, "'");
  out << "# fibers: a line 'fiber', then one 'x y z' line per point (sinew::read_fibers)\n";
  char line[96];
  for (const Vectors3& fiber : fibers) {
    out << "fiber\n";
    for (Index i = 0; i < fiber.cols(); ++i) {
      std::snprintf(line, sizeof line, "%.17g %.17g %.17g\n", fiber(0, i), fiber(1, i), fiber(2, i));
      out << line;
    }
  }
  if (!out) fail("write_fibers: writing '", path, "' failed");
}

}  // namespace sinew
