// Fibers embedded in a meshfree matrix (Liu et al. 2012, section 4.3, eq. 16-18): each structure
// particle is a massless particle hard-bound to the material particles within the support radius by
// Shepard weights phi_i = W(|X - X_i|) / sum_j W(|X - X_j|), fixed at rest (sinew's hard bindings:
// positions and velocities through W, the fiber forces back through W^T, eq. 17). Its rest position
// is the embedded one, sum_i phi_i X_i, not the drawn point (Shepard weights do not reproduce linear
// fields), so a fiber is unstressed at rest. A drawn point with no material particle within h is
// outside the material: it is dropped and its fiber split there; pieces of fewer than two points go.
//
// Volume fraction (eq. 18, corrected): the material particles that carry a fiber (any weight of a
// structure particle on them) keep 1 - lambda of their matrix stencil (MeshfreeCorotated::
// set_volume_fraction), and the fiber's EA and EI are the fiber material's times lambda, one lambda
// per fiber (scaling a fiber's shares per material particle would break Newton's third law); the
// composite is (1 - lambda) matrix + lambda fiber where fibers are and matrix elsewhere, each volume
// counted once.
#pragma once

#include "sinew/forces/elastic_rods.hpp"
#include "sinew/forces/meshfree_corotated.hpp"
#include "sinew/system.hpp"

#include <string>
#include <vector>

namespace sinew {

struct FiberSettings {
  double stretch_stiffness = 1.0;   ///< the fiber material's EA [N]
  double bending_stiffness = 1e-4;  ///< its EI [N m^2]
  double beta = 0.0;                ///< axial damping time [s]
  double lambda = 0.5;              ///< volume fraction, in [0, 1)
  bool implicit = false;            ///< ElasticRodsSettings::implicit
};

struct EmbeddedFibers {
  std::vector<std::vector<Index>> fibers;  ///< structure particles of each (possibly split) fiber
  ElasticRods* force = nullptr;            ///< null when every point fell outside the material
  Index dropped = 0;                       ///< drawn points outside the material, and stray single points between such
  /// Per structure particle (the fibers' particles in order): its material parents and weights.
  std::vector<std::vector<Index>> parents;
  std::vector<std::vector<double>> weights;
};

/// Embeds `polylines` (each 3 x n drawn points at rest) in `matrix` (added to `system`, its material
/// particles at rest now; h its support radius), adds the fibers' ElasticRods and sets the carrying
/// particles' volume fractions. Throws sinew::Error naming a bad setting or a non-finite point.
EmbeddedFibers embed_fibers(System& system, MeshfreeCorotated& matrix, double h, const std::vector<Vectors3>& polylines,
                            const FiberSettings& settings);

/// Drawing a fiber (section 5): one stroke in the front view (x, y) and one in the side view (z, y),
/// sharing the vertical axis y, make the 3D polyline (x(y), y, z(y)) over the heights both strokes
/// cover, resampled by arc length at `spacing` (the material particles' spacing keeps the fiber as
/// fine as the matrix that carries it). Each stroke is 2 x n, its points in drawing order, and must
/// run monotonically along y (a stroke that turns back has no single x at a height): otherwise, or
/// for strokes that share no height, fewer than two points, non-finite points or a bad spacing,
/// sinew::Error names the problem. The resampled ends are the ends of the shared height range.
Vectors3 fiber_from_strokes(const Eigen::Matrix2Xd& front, const Eigen::Matrix2Xd& side, double spacing);

/// Reads fibers from a plain text file for scripts and tests: a line `fiber` starts a polyline, every
/// other non-blank line holds three numbers, a point x y z of the current polyline; `#` starts a
/// comment. Throws sinew::Error naming the file and the line of anything else, a point before the
/// first `fiber`, or a polyline of fewer than two points; and a file that cannot be read.
std::vector<Vectors3> read_fibers(const std::string& path);

/// Writes fibers in read_fibers' format, every coordinate to 17 significant digits (read back to the
/// bit): what sinew-view's drawing panel saves. Throws sinew::Error naming a fiber of fewer than two
/// points or a non-finite point, or the file when it cannot be written.
void write_fibers(const std::string& path, const std::vector<Vectors3>& fibers);

}  // namespace sinew
