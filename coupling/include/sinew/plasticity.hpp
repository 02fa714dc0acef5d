// Sub-element plasticity through soft bindings (Sifakis et al. 2007, section 4, figure 9).
//
// A refined copy of a volume's surface is made of massless targets hard-bound in the volume's tets,
// each with a soft-bound particle tied to it by a binding spring (section 3.2); the soft particles
// meet colliders, the targets do not. When a collider stretches a spring past the yield length L_y,
// the target moves in material space towards its soft particle until the spring is L_y long again,
// and is embedded anew in the tet that holds its new place (analogous to plastic yield: the
// surface's rest shape changes, the tets' does not). A target never leaves the material: a move that
// would take it outside the material's rest surface stops where it meets that surface.
//
// A re-embedding changes no mass and no velocity of any particle that has mass (System::reembed), so
// mass, momentum and angular momentum are kept; it shortens a stretched spring and moves nothing
// else, so the energy drops by what the spring stored past L_y (the plastic work).
#pragma once

#include "sinew/lattice.hpp"
#include "sinew/system.hpp"

#include <array>
#include <memory>
#include <vector>

namespace sinew {

struct YieldStats {
  Index moved = 0;            ///< targets re-embedded
  Index stopped = 0;          ///< of those, moves stopped at the material's surface
  double largest_move = 0.0;  ///< [m] longest move in material space
};

class PlasticSurface {
 public:
  /// The volume the targets live in: its tets at rest (rest_vertices 3 x N, tets indexing its
  /// columns), the particle of each vertex, and the material's closed rest surface (targets never
  /// leave it). `yield_length` [m] is L_y. Throws naming the problem (a yield length that is not
  /// positive and finite, a tet vertex with no particle, a surface SurfaceInside refuses).
  PlasticSurface(const Vectors3& rest_vertices, std::vector<std::array<Index, 4>> tets,
                 std::vector<Index> vertex_particles, const Vectors3& material_vertices,
                 const std::vector<std::array<Index, 3>>& material_triangles, double yield_length);
  ~PlasticSurface();
  PlasticSurface(PlasticSurface&&) noexcept;
  PlasticSurface& operator=(PlasticSurface&&) noexcept;

  /// A massless target at rest point X, embedded in the tet that holds X (System::add_embedded_point).
  /// Throws naming X when no tet holds it.
  Index add_target(System& system, const Vec3& X);
  /// Lets target `target` (made by add_target) yield to soft particle `soft`, soft-bound to it.
  void track(Index soft, Index target);

  /// Between steps: every tracked spring longer than L_y moves its target (see the top of the file).
  YieldStats yield(System& system);

  /// The rest (material-space) point target `target` is embedded at now.
  Vec3 material_point(Index target) const;
  double yield_length() const { return m_yield_length; }

 private:
  struct Target {
    Index particle = -1;
    Index soft = -1;  ///< -1 until tracked
    Index tet = -1;
    std::array<double, 4> weights{};
  };
  struct Material;

  /// The tet holding point p in the configuration x (the particles' positions; nullptr: at rest): a
  /// walk from tet `start` across faces of negative weight, then a search of every tet; -1 if none
  /// holds it. Its weights in `weights`.
  Index locate(const Vectors3* x, const Vec3& p, Index start, std::array<double, 4>& weights) const;
  Vec3 rest_point(Index tet, const std::array<double, 4>& weights) const;
  Target& target_of(Index particle);

  Vectors3 m_rest;
  std::vector<std::array<Index, 4>> m_tets;
  std::vector<std::array<Index, 4>> m_neighbour;  ///< across the face opposite vertex j, or -1
  std::vector<Index> m_particle_of;
  std::unique_ptr<Material> m_material;
  double m_yield_length = 0.0;
  std::vector<Target> m_targets;
};

}  // namespace sinew
