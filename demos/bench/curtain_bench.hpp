// The benchmark curtain, built the same way in sinew and in Bullet 3.24's two soft-body couplings,
// so that speed and error can be compared side by side (sinew-bench, the stability suite).
//
// A square cloth (n x n nodes, `size` metres, `cloth_mass` kg) hangs in the x-y plane from `rings`
// rigid rings (each `ring_mass` kg) that slide along a static rod on the x axis (a Bullet slider
// constraint: free to slide along and turn about the rod). Node (i, 0) of the top row is bound to
// ring round(i * (rings - 1) / (n - 1)) when `bind_all`, else only the nodes nearest each ring are.
// Every node starts with `initial_velocity` (a swing along z plus a slide along x).
// The stability suite varies the parents: rings spun about the rod at the start, or rings that are
// static, kinematic or asleep (see RingParent).
#pragma once

#include "sinew/builders.hpp"
#include "sinew/types.hpp"

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace sinew::bench {

/// A node farther than this from the origin [m] has left the scene: the runs' healthy() bound.
inline constexpr double kFarAway = 1000.0;

/// sinew's cloth grid for a benchmark cloth (CurtainSpec, DropSpec): nodes, size, mass, stretch and
/// bending from the spec; placement and the rest are the caller's.
template <class ClothSpec>
ClothGridSettings cloth_grid_of(const ClothSpec& spec) {
  ClothGridSettings grid;
  grid.nx = grid.ny = spec.n;
  grid.width = grid.height = spec.size;
  grid.mass = spec.cloth_mass;
  grid.stretch_stiffness = spec.stretch_stiffness;
  grid.stretch_damping = spec.stretch_damping;
  grid.bending_stiffness = spec.bending_stiffness;
  return grid;
}

/// What the rings are as Bullet bodies (the parents of the bound nodes).
enum class RingParent {
  dynamic,    ///< dynamic rings on sliders, kept awake (the benchmark's curtain)
  sleeping,   ///< dynamic rings on sliders, at rest and asleep at the start, deactivation allowed
  kinematic,  ///< CF_KINEMATIC_OBJECT rings sliding along the rod at kinematic_speed; no sliders
  fixed,      ///< static rings (mass 0) at their rest centres; no sliders
};
/// "dynamic", "sleeping", "kinematic", "static".
const char* to_string(RingParent parent);

struct CurtainSpec {
  int n = 40;                        ///< nodes per side
  double size = 2.0;                 ///< [m]
  double cloth_mass = 0.5;           ///< [kg], lumped by area
  double stretch_stiffness = 200.0;  ///< per edge of the triangle mesh [N/m]
  double stretch_damping = 0.05;     ///< per edge, along it [N s/m]
  double bending_stiffness = 1e-4;   ///< dihedral [N m] (sinew); peers use their nearest model
  /// sinew's bending joins the implicit solves with implicit elasticity (ClothMaterial::bending_implicit).
  bool bending_implicit = false;
  int rings = 10;
  double ring_mass = 0.05;    ///< [kg]
  double ring_radius = 0.04;  ///< [m] (inertia of a thin ring: m R^2 about its axis)
  double rod_height = 2.1;    ///< y of the rod axis [m]; the top row hangs ring_radius below it
  bool bind_all = false;      ///< every top-row node bound (else one per ring)
  RingParent parent = RingParent::dynamic;
  /// Initial angular velocity of every ring about the rod (x) [rad/s], for RingParent::dynamic only: the
  /// spin-up is impulsive, the rings then turn freely on their sliders (the cloth's nodes start with
  /// initial_velocity; sinew's bound nodes take their ring's velocity, the peers' anchors correct theirs).
  double ring_spin = 0.0;
  /// Velocity of kinematic rings along the rod (x) [m/s]. They start moving one frame after the start:
  /// Bullet derives a kinematic body's velocity from the pose its motion state gives at the start of each
  /// stepSimulation, and that pose can only follow the time already simulated.
  double kinematic_speed = 0.2;
  Vec3 initial_velocity = Vec3(0.2, 0.0, 1.0);  ///< [m/s], every cloth node and ring
  double gravity = 9.81;                        ///< [m/s^2], along -y
};

/// Checks every field of the spec and throws sinew::Error naming the first bad one
/// ("curtain: rings = 12 exceeds n = 10").
void validate(const CurtainSpec& spec);

/// The top-row nodes bound to rings, as (node index i, ring index) pairs; nodes are numbered j * n + i
/// with j = 0 the top row.
std::vector<std::pair<int, int>> bound_nodes(const CurtainSpec& spec);

// ---- geometry shared by every system -------------------------------------------------------------
// Node (i, j) rests at x = -size/2 + i size/(n-1), y = rod_height - ring_radius - j size/(n-1), z = 0:
// the top row hangs one ring radius below the rod axis, the sheet hangs down in the x-y plane. Ring k's
// centre is on the rod axis at x = -size/2 + k size/(rings-1) (the middle for a single ring). The
// triangulation is sinew's add_cloth_grid with across = +x and down = -y: quad (i, j) is split along its
// diagonal (i, j)-(i+1, j+1) when i + j is even, along (i+1, j)-(i, j+1) when odd.

/// Rest position of node (i, j) [m].
Vec3 node_rest_position(const CurtainSpec& spec, int i, int j);
/// Centre of ring k at set-up [m]; the ring's frame starts unrotated, its axis along the rod (x).
Vec3 ring_rest_centre(const CurtainSpec& spec, int k);
/// Principal moments of inertia of a thin ring (x along the rod): m R^2 about its axis, m R^2 / 2 about
/// the two diameters [kg m^2].
Vec3 ring_inertia(const CurtainSpec& spec);

/// A bound node and its pivot, fixed in its ring's frame: the node's rest position in the ring's frame
/// at set-up, so every binding starts exactly satisfied.
struct BoundPivot {
  int node = 0;  ///< j * n + i (always j = 0)
  int ring = 0;
  Vec3 local = Vec3::Zero();  ///< [m], in the ring's frame
};
/// bound_nodes(spec) with their pivots.
std::vector<BoundPivot> bound_pivots(const CurtainSpec& spec);

/// How far the attachments are from what they should be, now.
struct AttachmentError {
  double bound_node = 0.0;                   ///< max |x_node - T_ring p_local| over bound nodes [m]
  double bound_node_before_overwrite = 0.0;  ///< the same before a system overwrites anchored nodes (else = bound_node)
  double ring_joint = 0.0;                   ///< max distance of a ring's centre from the rod axis [m]
};

/// One system running the benchmark curtain.
class CurtainRun {
 public:
  virtual ~CurtainRun() = default;
  /// "sinew", "bullet-classic" or "bullet-deformable".
  virtual std::string system() const = 0;
  /// Advances one frame of frame_dt in `steps` equal internal steps.
  virtual void advance(double frame_dt, int steps) = 0;
  /// Cloth node positions, 3 x n^2, node (i, j) at column j * n + i.
  virtual Vectors3 nodes() const = 0;
  virtual AttachmentError attachment() const = 0;
  /// Linear momentum of cloth and rings along the rod (x) [kg m/s]: nothing outside acts along x, so
  /// it stays at its initial value when the exchange conserves momentum.
  virtual double momentum_along_rod() const = 0;
  /// Kinetic + gravitational (+ elastic where the model has one) energy of cloth and rings [J].
  virtual double energy() const = 0;
  /// The part of energy() stored in binding springs [J] (sinew's spring case; 0 elsewhere).
  virtual double binding_spring_energy() const { return 0.0; }
  /// False once any position or velocity is non-finite or a node is more than 1 km away.
  virtual bool healthy() const = 0;
  /// Where the models cannot match the spec (empty when they match), for the benchmark's output.
  virtual std::string mismatch() const { return {}; }
};

}  // namespace sinew::bench

class btActionInterface;
class btCollisionShape;
class btMotionState;
class btDynamicsWorld;
class btRigidBody;
class btSliderConstraint;

namespace sinew::bench {

/// The static rod and the rings of the curtain, built into any Bullet dynamics world (the sinew, classic
/// and deformable systems share it). Each ring is a dynamic rigid body held on the rod by a
/// btSliderConstraint whose axis is the rod (x): free to slide along it and turn about it (both limits
/// set lower > upper, which Bullet reads as "no limit"), the other four degrees of freedom locked.
/// Nothing collides: rod and rings get a collision mask of 0 (their shapes, a cylinder and a sphere of
/// the ring's radius, only give Bullet an AABB; the deformable anchor also evaluates the sphere's
/// distance field once). The benchmark measures the binding, not contact.
/// The world's gravity must be set before construction (Bullet copies it into each body when added).
/// Dynamic rings start with the spec's initial velocity and ring_spin about the rod, deactivation disabled;
/// sleeping ones at rest and asleep (ISLAND_SLEEPING), deactivation allowed. Static and kinematic rings (spec.parent)
/// have no slider: the joint error then only says whether they stay on the axis. A kinematic ring's motion state gives
/// the pose start + kinematic_speed t, with t the time simulated before the current stepSimulation (counted by an
/// action at the end of every tick), so Bullet moves it in the standard way and reports the velocity of that move.
class RodAndRings {
 public:
  RodAndRings(btDynamicsWorld& world, const CurtainSpec& spec);
  /// Removes the constraints and bodies from the world (which must still exist).
  ~RodAndRings();
  RodAndRings(const RodAndRings&) = delete;
  RodAndRings& operator=(const RodAndRings&) = delete;

  int count() const { return static_cast<int>(m_rings.size()); }
  btRigidBody& ring(int k) const;
  btRigidBody& rod() const { return *m_rod; }

  /// T_ring p_local for ring k, evaluated with Bullet's own btTransform arithmetic so that a node Bullet
  /// placed at the pivot compares equal bit for bit [m].
  Vec3 world_point(int k, const Vec3& local) const;
  /// Largest distance of a ring's centre from the rod axis [m] (what the slider constraint should keep at 0).
  double joint_error() const;
  /// Sum of m v_x over the dynamic rings [kg m/s] (static and kinematic ones have infinite mass and are
  /// not part of the moving system).
  double momentum_along_rod() const;
  /// Kinetic (translation and spin) plus gravitational (m g y) energy of the dynamic rings [J].
  double energy(double gravity) const;

  /// Every ring's position, orientation and velocities finite and its centre within 1 km of the origin.
  bool healthy() const;

 private:
  btDynamicsWorld* m_world;
  double m_time = 0.0;  // simulated time, advanced at the end of every tick by m_clock [s]
  std::unique_ptr<btActionInterface> m_clock;
  std::unique_ptr<btCollisionShape> m_rod_shape, m_ring_shape;
  std::vector<std::unique_ptr<btMotionState>> m_states;
  std::unique_ptr<btRigidBody> m_rod;
  std::vector<std::unique_ptr<btRigidBody>> m_rings;
  std::vector<std::unique_ptr<btSliderConstraint>> m_sliders;
};

/// How far the bound nodes are from their pivots: bound_node = max |x_node - T_ring p_local| over
/// `pivots`, with `x` the 3 x n^2 node positions (column j * n + i); bound_node_before_overwrite is set
/// to the same value (a system that overwrites anchored nodes replaces it); ring_joint from the rings.
AttachmentError attachment_error(const RodAndRings& rings, const Vectors3& x, const std::vector<BoundPivot>& pivots);

}  // namespace sinew::bench
