// Contact between deformable surfaces and within one (cloth on cloth, a cloth folding onto itself):
// a collision source of step 3 (section 3.3) over every triangle and edge registered with
// System::add_collision_surface.
//
// Proximity, after Bridson et al.'s repulsions: a vertex closer than `thickness` to a triangle it is
// not a corner of, or an edge closer than that to an edge it shares no vertex with, is pushed apart
// along the normal on the side the pair was on at t^n (so a pair that crossed within the step is put
// back on its own side), and their relative normal velocity is stopped, with Coulomb friction on the
// tangential part. Both changes are impulses on the four points of the pair spread by their weights
// (the vertex 1 and the triangle's barycentric coordinates, or the two edges' segment parameters)
// and inverse masses, so linear momentum is kept exactly. Points that are not dynamic (kinematic,
// hard-bound) take none: they act as obstacles. Passes over all pairs repeat up to `passes` times,
// until one finds no pair closer than the thickness. No step-4 constraint is added (as against a
// dynamic body: the next step 3 stops any approach the second solve brings back).
//
// Not a guarantee: a pair that passes through each other by more than the thickness plus its
// relative motion's reach in one step is not found (no continuous test yet); the tests count
// intersecting triangle pairs with an independent checker (FCL) to measure how often that happens.
#pragma once

#include "sinew/collision.hpp"

#include <array>
#include <unordered_map>
#include <vector>

namespace sinew {

struct SelfCollisionSettings {
  double thickness = 0.005;  ///< [m] surfaces keep this distance from each other
  double friction = 0.3;     ///< Coulomb coefficient between surfaces
  int passes = 4;            ///< at most this many passes over the pairs per step
};

class SelfCollisions final : public CollisionSource {
 public:
  explicit SelfCollisions(const SelfCollisionSettings& settings = {});
  std::string_view name() const override { return "self contact"; }
  void process(CollisionContext& context) override;
  /// Pairs closer than the thickness found by the last call's first pass (vertex-triangle plus
  /// edge-edge), and how many passes it ran.
  int contacts() const { return m_contacts; }
  int passes_run() const { return m_passes_run; }

 private:
  /// Pushes the pair of `count` points with `weights` (summing to zero: +1 side, -1 side) apart along
  /// n by `gap` and stops their approach. Returns false when none of the points can move.
  bool respond(CollisionContext& c, const std::array<Index, 4>& points, const std::array<double, 4>& weights,
               const Vec3& n, double gap);
  /// Rebuilds the hash grids of the triangles' and edges' padded boxes at positions x.
  void bin(const CollisionContext& c);

  SelfCollisionSettings m_settings;
  int m_contacts = 0;
  int m_passes_run = 0;
  double m_cell = 0.0;
  std::unordered_map<long long, std::vector<Index>> m_triangle_grid, m_segment_grid;  // cell -> items
  std::vector<Eigen::AlignedBox3d> m_triangle_box, m_segment_box;
  std::vector<Index> m_vertices;
  std::vector<Index> m_seen;  // per edge: the edge it was last tested against in this pass
};

}  // namespace sinew
