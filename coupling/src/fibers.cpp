// Fibers embedded in a meshfree matrix: see the header.
#include "sinew/fibers.hpp"

#include <cmath>
#include <memory>
#include <numbers>
#include <set>

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
  for (std::size_t k = 0; k < polylines.size(); ++k) {
    std::vector<Index> piece;
    const auto close = [&] {
      if (piece.size() >= 2) out.fibers.push_back(piece);
      piece.clear();
    };
    for (Index p = 0; p < polylines[k].cols(); ++p) {
      const Vec3 X = polylines[k].col(p);
      if (!X.allFinite()) fail("embed_fibers: polyline ", k, " point ", p, " is not finite");
      std::vector<Index> parents;
      std::vector<double> weights;
      double total = 0.0;
      for (const Index i : material) {
        const double q = (x.col(i) - X).norm() / h;
        if (q >= 1.0) continue;
        const double w = (1.0 + 3.0 * q) * std::pow(1.0 - q, 3);  // Lucy's kernel; its scale cancels
        parents.push_back(i);
        weights.push_back(w);
        total += w;
      }
      if (parents.empty()) {  // outside the material
        ++out.dropped;
        close();
        continue;
      }
      Vec3 at = Vec3::Zero();
      for (std::size_t a = 0; a < parents.size(); ++a) {
        weights[a] /= total;
        at += weights[a] * x.col(parents[a]);
        carriers.insert(parents[a]);
      }
      const Index sp = system.add_particle(at, Vec3::Zero(), 0.0);
      system.bind_linear(sp, parents, weights);
      system.set_collision_filter(sp, kDefaultCollisionGroup, 0);
      piece.push_back(sp);
      out.parents.push_back(std::move(parents));
      out.weights.push_back(std::move(weights));
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

}  // namespace sinew
