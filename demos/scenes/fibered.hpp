// What the fibers scenes share (stalk, plant, leaf): a meshfree matrix on a lattice of
// material particles, laid out by a map of the lattice (straight, bent, tapered), with fibers drawn
// into it (embed_fibers), and the lattice's outer faces to draw.
#pragma once

#include "sinew/fibers.hpp"

#include <array>
#include <functional>
#include <vector>

namespace sinew::scenes {

struct FiberedLatticeSettings {
  int nx = 2, ny = 2, nz = 2;     ///< particles across (i), across (j) and along (k)
  double particle_mass = 1e-3;    ///< [kg]
  double particle_volume = 1e-6;  ///< V_i [m^3]
  MeshfreeCorotatedSettings matrix;
};

struct FiberedLattice {
  int nx = 0, ny = 0, nz = 0;
  std::vector<Index> material;  ///< particle (i, j, k) at (k ny + j) nx + i
  MeshfreeCorotated* matrix = nullptr;
  EmbeddedFibers fibers;  ///< empty without fibers

  Index at(int i, int j, int k) const { return material[static_cast<std::size_t>((k * ny + j) * nx + i)]; }
  /// The mean position of layer k.
  Vec3 layer_centre(const Vectors3& x, int k) const {
    Vec3 c = Vec3::Zero();
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) c += x.col(at(i, j, k));
    return c / double(nx * ny);
  }
  Index structure_particles() const {
    Index n = 0;
    for (const auto& f : fibers.fibers) n += static_cast<Index>(f.size());
    return n;
  }
  /// The lattice's outer faces, two triangles a quad, outward for a map taking i, k, j to a
  /// right-handed frame (as i -> x, k -> y, j -> z).
  std::vector<std::array<Index, 3>> skin() const {
    std::vector<std::array<Index, 3>> out;
    const auto quad = [&](Index a, Index b, Index c, Index d) {
      out.push_back({a, b, c});
      out.push_back({a, c, d});
    };
    const int li = nx - 1, lj = ny - 1, top = nz - 1;
    for (int k = 0; k < top; ++k) {
      for (int i = 0; i < li; ++i) {
        quad(at(i, 0, k), at(i + 1, 0, k), at(i + 1, 0, k + 1), at(i, 0, k + 1));
        quad(at(i, lj, k), at(i, lj, k + 1), at(i + 1, lj, k + 1), at(i + 1, lj, k));
      }
      for (int j = 0; j < lj; ++j) {
        quad(at(0, j, k), at(0, j, k + 1), at(0, j + 1, k + 1), at(0, j + 1, k));
        quad(at(li, j, k), at(li, j + 1, k), at(li, j + 1, k + 1), at(li, j, k + 1));
      }
    }
    for (int j = 0; j < lj; ++j)
      for (int i = 0; i < li; ++i) {
        quad(at(i, j, 0), at(i, j + 1, 0), at(i + 1, j + 1, 0), at(i + 1, j, 0));
        quad(at(i, j, top), at(i + 1, j, top), at(i + 1, j + 1, top), at(i, j + 1, top));
      }
    return out;
  }
};

/// Adds the lattice's particles (particle (i, j, k) at place(i, j, k), at rest), its matrix, and the
/// fibers `lines` (drawn at rest; none: a plain matrix) embedded with `fibers`.
inline FiberedLattice add_fibered_lattice(System& system, const FiberedLatticeSettings& settings,
                                          const std::function<Vec3(int, int, int)>& place,
                                          const std::vector<Vectors3>& lines = {}, const FiberSettings& fibers = {}) {
  FiberedLattice body;
  body.nx = settings.nx, body.ny = settings.ny, body.nz = settings.nz;
  for (int k = 0; k < body.nz; ++k)
    for (int j = 0; j < body.ny; ++j)
      for (int i = 0; i < body.nx; ++i)
        body.material.push_back(system.add_particle(place(i, j, k), Vec3::Zero(), settings.particle_mass));
  body.matrix = &system.add_force(std::make_unique<MeshfreeCorotated>(
      body.material, system.particles().x, std::vector<double>(body.material.size(), settings.particle_volume),
      settings.matrix));
  if (!lines.empty()) body.fibers = embed_fibers(system, *body.matrix, settings.matrix.support_radius, lines, fibers);
  return body;
}

}  // namespace sinew::scenes
