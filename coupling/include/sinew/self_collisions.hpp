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
// hard-bound) take none: they act as obstacles. The first pass finds the pairs through hash grids of
// the triangles' and edges' padded boxes; up to `passes - 1` more passes revisit the pairs it found
// within twice the thickness, until one pushes none. No step-4 constraint is added (as against a
// dynamic body: the next step 3 stops any approach the second solve brings back).
//
// The guarantee is continuous (SelfCollisionSettings::continuous, on by default): after the passes,
// every vertex-triangle and edge-edge pair is tested on the straight paths from x^n to the step's
// end (sinew/ccd.hpp), and the points of pairs that touch on them move as rigid impact zones
// (Provot 1997; Bridson, Fedkiw and Anderson 2002), merged round after round until none touches.
// Surfaces that intersect nowhere at t^n then intersect nowhere at the end of the step, whatever
// their speed (SelfCollisions.AClothTooFastForTheThicknessDoesNotPassThroughAnother), except where a
// zone holds points the contact cannot move that do not move together (unresolved()). Proximity is
// what keeps the thickness and friction; the zones are the fail-safe, and inelastic.
#pragma once

#include "sinew/collision.hpp"

#include "sinew/ccd.hpp"

#include <array>
#include <vector>

namespace sinew {

struct SelfCollisionSettings {
  double thickness = 0.005;  ///< [m] surfaces keep this distance from each other
  double friction = 0.3;     ///< Coulomb coefficient between surfaces
  int passes = 4;            ///< at most this many passes over the pairs per step
  /// The continuous test after the passes: pairs that touch on the straight paths from t^n to the
  /// end of the step are merged into rigid impact zones, so the surfaces end the step intersecting
  /// nowhere they did not at its start.
  bool continuous = true;
  int zone_rounds = 64;  ///< at most this many rounds of tests and zone merges per step
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
  /// The continuous test of the last call: pairs it found touching on the paths in its first round,
  /// points moved rigidly in impact zones, rounds run, and pairs still touching when the rounds ran
  /// out or where a zone held points the contact cannot move that do not move together (0 when the
  /// step is free of crossings).
  int crossings() const { return m_crossings; }
  int zone_points() const { return m_zone_points; }
  int zone_rounds_run() const { return m_zone_rounds_run; }
  int unresolved() const { return m_unresolved; }
  /// Sums of the counts above over every call since construction (a frame's substeps included).
  struct Totals {
    long long steps = 0, contacts = 0, crossings = 0, zone_points = 0, unresolved = 0;
  };
  const Totals& totals() const { return m_totals; }
  double work() const override { return m_work; }
  /// Its pairs are resolved at the positions it sees, and its continuous test's guarantee (no triangle
  /// pair crossing at the step's end) is about them: the spread of the other sources' moves comes first.
  bool needs_final_positions() const override { return true; }

 private:
  /// Pushes the pair of `count` points with `weights` (summing to zero: +1 side, -1 side) apart along
  /// n by `gap` and stops their approach. Returns false when none of the points can move.
  bool respond(CollisionContext& c, const std::array<Index, 4>& points, const std::array<double, 4>& weights,
               const Vec3& n, double gap);
  /// Rebuilds the hash grids of the triangles' and edges' padded boxes at positions x.
  void bin(const CollisionContext& c);
  /// The continuous test and impact zones (after the proximity passes).
  void resolve_crossings(CollisionContext& c);
  /// Pairs touching on the paths from x_n to x among those with a point marked in m_changed, into
  /// m_pairs; returns how many.
  int find_crossings(const CollisionContext& c);
  /// Moves every zone rigidly (or with its fixed points) from x_n; marks what moved in m_changed.
  void move_zones(CollisionContext& c);
  Index zone_of(Index i);

  SelfCollisionSettings m_settings;
  int m_contacts = 0;
  int m_passes_run = 0;
  double m_cell = 0.0;
  ccd::BoxGrid m_triangle_grid, m_segment_grid;
  std::vector<Eigen::AlignedBox3d> m_triangle_box, m_segment_box;
  std::vector<Index> m_vertices;
  std::vector<Index> m_seen;  // per edge: the edge it was last tested against in this pass
  Totals m_totals;
  std::vector<std::array<Index, 2>> m_near_vertex_triangle, m_near_edge_edge;  // the first pass's near pairs
  int m_crossings = 0, m_zone_points = 0, m_zone_rounds_run = 0, m_unresolved = 0;
  double m_work = 0.0;  // CollisionSource::work() of the last call
  ccd::BoxGrid m_swept_triangle_grid, m_swept_segment_grid;
  std::vector<Eigen::AlignedBox3d> m_swept_triangle_box, m_swept_segment_box;
  std::vector<std::array<Index, 4>> m_pairs;        // the points of each touching pair
  Vectors3 m_x_proposed;                            // x after the proximity passes
  std::vector<Index> m_parent;                      // union-find over particles (-1: in no zone)
  std::vector<char> m_changed;                      // per particle: moved by the last round
  std::vector<Index> m_members;                     // zone members, sorted by zone then index
  std::vector<std::array<Index, 2>> m_zone_member;  // (zone, particle)
  std::vector<Index> m_triangle_seen;               // per triangle: the vertex it was last tested against
};

}  // namespace sinew
