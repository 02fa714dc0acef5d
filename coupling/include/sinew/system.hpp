// sinew::System: particles, rigid-body particles, bindings and forces, advanced by the semi-implicit
// Newmark step of Sifakis et al. 2007 (section 3.3) with rigid bodies as 6-DOF parents (section 5).
//
// Set-up: add particles, rigid bodies, hard bindings, soft bindings, binding springs, forces and
// collision sources; every call validates its input and throws sinew::Error naming the bad item.
// The first step (or an explicit finalize()) resolves binding chains, passes masses to parents
// (m = W^T m_bar), computes effective masses and binding-spring damping.
//
// Topology may change between steps: particles, rigid bodies, bindings, soft bindings, binding
// springs, forces and collision sources can be added, and particles, soft bindings, binding springs,
// forces and elements removed. The next step sets everything up again from the changed model (the
// same next step, bit for bit, as a system built from scratch in that state). Removal keeps indices:
// a removed particle keeps its index (ParticleKind::removed), a removed binding spring its index;
// soft bindings and forces are taken out of their lists. A step that follows no change allocates
// nothing; a change may.
#pragma once

#include "sinew/binding_springs.hpp"
#include "sinew/collision.hpp"
#include "sinew/force.hpp"
#include "sinew/hard_bindings.hpp"
#include "sinew/particles.hpp"
#include "sinew/rigid_body_particles.hpp"
#include "sinew/soft_bindings.hpp"
#include "sinew/step_stats.hpp"

#include <functional>
#include <memory>
#include <span>
#include <vector>

namespace sinew {

class Newmark;

/// Where step 4 evaluates the binding springs' elastic force.
enum class BindingSpringStep4 : std::uint8_t {
  /// -K x^{n+1/2}, explicit, as printed in section 3.3 (undamped springs stay exactly neutral). A spring
  /// whose end turns with a rigid frame sees the arc the frame turns through (about dt^2 |w|^2 r a step)
  /// as stretch that the linearised solves did not predict; explicit here, k times that stretch becomes
  /// an impulse, and from about k dt^2 / m ~ 1e3 on a lever of a light body the step diverges.
  explicit_half_step,
  /// -K (x^{n+1/2} + dt/2 v^{n+1/2}), implicit (the default, as in the authors' code): the unpredicted
  /// stretch is taken up over the step instead of kicked, and very stiff springs get numerical damping.
  implicit_half_step,
  /// -K x^{n+1}: unstable for stiff springs (dt < (b + sqrt(b^2 + 8 mu k)) / 2k); kept so that tests
  /// can show why x^{n+1/2} is used.
  explicit_end_of_step,
};

struct SystemSettings {
  Vec3 gravity = Vec3(0.0, -9.81, 0.0);  ///< [m/s^2]
  /// Add the mass of points hard-bound to a rigid frame to that body (shifting its centre of mass
  /// and inertia), so no mass is lost. Off when another solver owns the body's mass properties.
  bool absorb_bound_mass_into_rigid_bodies = true;
};

/// Step 1's initial guess for v~^{n+1/2} (the answer is the same to the CG tolerance whichever is used;
/// only the iteration count changes).
enum class Step1Guess {
  /// Where the extrapolation predicts a change well above the tolerance (tenfold), both guesses
  /// below are tried once every 8 such steps and the one with the smaller preconditioned residual
  /// (r . P^-1 r; or the one that already meets the tolerance) kept for the following ones; v^n
  /// otherwise.
  adaptive,
  previous_velocity,  ///< v^n
  /// v^n + (dt / dt_last) (v^n - v^{n-1/2}) on every step after the first: exact under constant
  /// acceleration, but doubles the last step's error in stiff modes that ring from step to step
  /// (implicit elasticity at long steps) and the last answer's own error.
  extrapolated,
};

struct StepSettings {
  /// CG stops when every component of the preconditioned residual z = P^-1 (c - S v) is at most
  /// this [m/s] (absolute, max-norm, on particle velocities and rigid twists alike). It bounds the
  /// velocity error of stiff, local modes directly and that of smooth modes to within the
  /// preconditioner's conditioning. Absolute on purpose: a tolerance relative to the initial residual
  /// would tighten for a good initial guess (step 4 starts from step 1's answer) and loosen for a
  /// poor one, and one relative to |v| would loosen with speed.
  double cg_tolerance = 1e-9;
  /// CG also stops when sqrt(r^T M^-1 r / M), r the residual, M the mass matrix and M its total over
  /// the unknowns, is at most this [m/s] (0: off). That bounds the solve's mass-weighted RMS velocity
  /// error whatever the preconditioner (S - M is positive semidefinite), where the max-norm of z can
  /// understate it: a stiff spring's blocks shrink z along the common motion of its ends. advance()
  /// sets it from relative_tolerance under `automatic`.
  double cg_rms_tolerance = 0.0;
  /// CG stops after this many iterations and the step goes on with what it has (StepStats::cg_converged
  /// turns false): a bound on the step's cost when a solve stalls, not a convergence criterion.
  int cg_max_iterations = 1000;
  /// Block Jacobi: each particle's 3x3 diagonal block of the implicit system (from forces that
  /// provide them, ImplicitBlocks::add_diagonal_blocks, else a third of their trace times I), each
  /// rigid body's 6x6 block with what its hard-bound points carry. Off: the mass matrix alone.
  bool jacobi_preconditioner = true;
  /// Aggregation multigrid on the particles (one V-cycle per CG iteration, block-Jacobi smoothing,
  /// coarse operators summed from the forces' pair blocks), the rigid bodies' 6x6 blocks as in block
  /// Jacobi. Its iteration count hardly grows with resolution or step where block Jacobi's grows as
  /// dt / dx, so it pays off for implicit elasticity at large steps or fine meshes, where fewer
  /// iterations outweigh a V-cycle's cost of a few products of the implicit system (figures:
  /// demos/bench/README.md). Needs jacobi_preconditioner.
  bool multigrid = false;
  /// Elastic forces with a definite differential (edge springs) enter both velocity solves
  /// implicitly, linearised once: (M - dt/2 D - dt^2/4 K+) v = M v_start + dt/2 F(x), at x^n in
  /// step 1 and x^{n+1/2} in step 4; they then no longer limit advance()'s substep. This damps their
  /// stiff modes and is first-order accurate in them (kept explicit in step 4 the linearised scheme
  /// is unstable for stiff springs turning); off by default, as in the paper.
  bool implicit_elasticity = false;
  /// With implicit_elasticity: Newton iterations after step 1's solve. Each relinearises the implicit
  /// forces where the half step ends, x^n + dt/2 v~^{n+1/2} (F(x_mid) and K+(x_mid)), and solves step
  /// 1 again: (M - dt/2 D - dt^2/4 K+) v = M v^n + dt/2 F(x_mid) - dt^2/4 K+ v_prev. One linearisation
  /// is too coarse where a long step turns the springs a lot: a cloth at one long step per frame can
  /// gain energy at each step, which one iteration holds. Each costs a force evaluation and a solve.
  /// Every force is evaluated at x_mid, so forces kept explicit (tets, membranes, bending without its
  /// implicit flag) take a fixed-point update there instead of staying at x^n. K+ drops the indefinite
  /// part of the stiffness, so the iterations converge linearly, not quadratically: one or two are
  /// what pays (figures behind this: demos/bench/README.md).
  int newton_iterations = 0;
  /// Step 3 spreads what it moves through the step-1 operator's implicit forces: where the collision
  /// sources put particles back out of a surface (by up to their approach times dt), the rest of the
  /// deformable follows as the first solve would have moved it with those particles held there
  /// (Newmark::spread_collisions): solves on the particles (one, and up to three more while the
  /// contacts that hold change) when some particle moved by more than cg_tolerance dt. Off, a stiff
  /// solid landing at speed v is squashed by v dt in its contact layer alone, an elastic energy the
  /// step then returns as a bounce. Only where a solid's elasticity (Force::volumetric: tets, a
  /// meshfree matrix) is implicit in step 1; a cloth, one layer thick, has no layer behind its contact
  /// to squash (spread, the curtain's rings dragged the cloth harder: its handle's binding spring
  /// stretched 11 cm against 2.8 cm over 1000 frames).
  bool spread_collisions = true;
  /// Threads for the step's loops (0: every hardware thread). Results are bit-identical for any
  /// count (sinew/parallel.hpp); small scenes stay on one thread whatever this says.
  int threads = 1;
  Step1Guess step1_guess = Step1Guess::adaptive;
  BindingSpringStep4 binding_springs_in_step4 = BindingSpringStep4::implicit_half_step;
  /// At the step's end, a damped binding spring whose relative motion would decay within a small part
  /// of the step (stiff against its ends' masses) holds its ends together in velocity too, by equal
  /// and opposite impulses: the step's end velocity keeps and flips a stiff mode's velocity error
  /// from step to step, which a rigid solver reading it (contacts, joints) turns into energy.
  bool settle_stiff_binding_springs = true;
  /// Fraction of the elastic stable step used by advance(), in (0, 1]: the stable step is an
  /// estimate, so a margin below 1 keeps advance() clear of its edge.
  double cfl = 0.9;
  /// advance() throws rather than take more substeps than this in one frame: a stable step that
  /// small usually means a stiffness or mass set wrongly, not a scene worth grinding through.
  int max_substeps = 100000;
  /// advance() chooses the scheme of each frame from the scene (System::advance says how): explicit
  /// elasticity while it needs few substeps, else implicit elasticity (dihedral bending included) when
  /// that is cheaper, in substeps short enough that the elements turn little within one
  /// in one (turn_work_per_implicit_step). On, the settings above are where the choice starts: implicit_elasticity set
  /// by the user is kept (and its substeps bounded the same way). Off, advance() runs exactly the settings above.
  /// System::step runs the settings above either way.
  bool automatic = true;
  /// With implicit elasticity the solves linearise the elastic forces where the step starts; a
  /// stretched spring that turns within the step is then pulled along a stale direction, which feeds
  /// energy into a spinning cloth. advance() under `automatic` takes substeps short enough that this
  /// missed work (Force::turn_work_rate times the squared step) is at most this fraction of the
  /// scene's kinetic and elastic energy in each step; so is the energy that moving along tangents
  /// instead of arcs stores in elements that had no stress to turn (Force::turn_stretch_rate times
  /// the fourth power of the step).
  double turn_work_per_implicit_step = 0.01;
  /// Under `automatic`, the solves of the scheme advance() chose stop (cg_rms_tolerance) at this
  /// fraction of a substep's velocity change a dt, a the last frame's RMS acceleration (|gravity|
  /// before the first), or of sleep_speed where that is larger (a scene at rest); explicit frames at
  /// System::kExplicitToleranceFactor of it; with sleep on, at most sleep_speed / 10.
  /// The accuracy a user states: smaller is more accurate and slower; 0 keeps cg_tolerance. At 3e-2 a
  /// chain of 20 capsules on k = 1e12 binding springs gained 1.2% of its energy in 2 s
  /// (Stiffness/CapsuleChain.HoldsAtOneTickPerFrame), though every sinew-schemes scene held even at
  /// 1e-1 and the hanging cloth took 26% fewer CG iterations at 3e-2.
  double relative_tolerance = 1e-2;
  /// Step 1 takes each body's inertia at its half-step orientation, R(theta/2) I R(theta/2)^T, which
  /// gives w^{n+1/2} ~ w + dt/2 I^-1 (L x w): the torque-free drift of an asymmetric body's angular
  /// velocity, to second order. Off: the inertia at t^n (first order).
  bool gyroscopic_correction = true;
  /// A rigid body turns by at most this angle [rad] in one step; a faster spin keeps its angular
  /// velocity but its frame and the points on it move as if it turned by this much (Bullet limits
  /// every body's turn to pi/4 per step the same way, and the Bullet coupling sets that value).
  double max_rotation_per_step = kInfinity;
  /// Step 1 is solved again, from its last answer, while some body's turn over the step differs from
  /// the one its points' arms were set from by more than cg_tolerance (as a velocity at the body's
  /// reach): the arms make the points' step velocities their actual chords (see Newmark::set_turns).
  /// At most this many solves; StepStats::cg_converged turns false if the turn still moves.
  int rotation_iterations = 20;
  /// A step stops as diverged (sinew::Error naming the particle or body, and the state of its start
  /// kept) when one item's kinetic energy exceeds this many times the scene's energy budget: its
  /// energy at the first step plus the work gravity, applied forces, kinematic motion and collisions
  /// can have done since (coupling/README.md, "The step: five phases"). An instability grows
  /// geometrically, so a generous factor delays the stop by a few steps only. 0 turns the check off.
  double divergence_factor = 100.0;
  /// advance() puts the system to sleep (as Bullet deactivates a body at rest) once every dynamic
  /// particle (free, soft-spring) has moved slower than sleep_speed, every dynamic rigid-body
  /// particle's fastest point (centre speed plus |w| times its reach: its bound points, its radius of
  /// gyration) too, and every kinematic particle and body has stood still, at the end of every frame
  /// for sleep_time: velocities are then set to zero and, until something wakes it, advance() holds
  /// the state and does nothing else (System::advance lists what wakes it). Off: every frame steps.
  bool sleep = true;
  /// [m/s] Cloth settling under gravity creeps at 1e-4 to 1e-3 m/s long after it looks still; a scene
  /// in motion moves at 0.1 m/s or more. Zeroing a speed below this changes a particle's position by
  /// less than sleep_speed times a frame (under 0.1 mm at 60 Hz).
  double sleep_speed = 5e-3;
  /// [s] How long every speed must stay below sleep_speed: longer than a slow swing's turning point
  /// (a pendulum of length L stands still for a fraction of sqrt(L/g) ~ 0.3 s at 1 m).
  double sleep_time = 1.0;
};
/// Throws sinew::Error naming the first setting out of range; System::step and advance call it.
void validate(const StepSettings& settings);

/// One row of a joint between rigid-body particles (a rigid solver's bilateral constraint, for
/// instance a slider's): J_a . (v_a, w_a) + J_b . (v_b, w_b) = target, with v the centre-of-mass
/// velocity and w the angular velocity, both world, and body_b = -1 for a joint to the fixed world.
/// Both solves of the step keep the dynamic bodies' twists on these rows (projected CG, like the
/// collision normals), so that the bodies move in the step as the joints will let them.
/// Rows on kinematic bodies use their prescribed twists.
///
/// A unilateral row is a contact between two bodies (a rigid solver's contact point): J = (n, r_a x n)
/// on body_a and (-n, -r_b x n) on body_b, n the unit normal from b towards a at `point`, and the row
/// holds J . t >= target - max(gap, 0) / dt, so a contact apart by `gap` may close over the step and
/// no further. The step chooses which contacts hold (those its bodies' applied forces drive closed
/// within a step, and those its answer would cross), makes each one it closes an inelastic collision,
/// and updates `gap` by the step's relative motion, so substeps within one call see it close. A held
/// contact with `friction` sticks in the solves (no tangential motion at `point`) while its multipliers
/// stay in Coulomb's cone, and slides otherwise. At the end of each step the held contacts also keep
/// v^{n+1} from approaching, by pushes only, with friction bounded by the impulse the contact carried
/// over the step. Contacts whose targets disagree (several points of one touching pair) are held at
/// the least-norm twists that meet them all.
struct JointRow {
  Index body_a = -1;
  Vec6 j_a = Vec6::Zero();
  Index body_b = -1;
  Vec6 j_b = Vec6::Zero();
  double target = 0.0;  ///< [m/s]
  bool unilateral = false;
  double gap = 0.0;           ///< [m] unilateral rows: the contact's separation along n (< 0 overlapping)
  double friction = 0.0;      ///< unilateral rows: Coulomb's coefficient at the contact
  Vec3 point = Vec3::Zero();  ///< [m] unilateral rows: the contact point, for friction's levers
};

class System {
 public:
  explicit System(const SystemSettings& settings = {});
  ~System();
  System(System&&) noexcept;
  System& operator=(System&&) noexcept;

  // ---- set-up ----------------------------------------------------------------------------------
  /// A free particle; mass >= 0 (a particle with zero mass must be bound or get mass from children).
  Index add_particle(const Vec3& x, const Vec3& v, double mass);
  /// A particle with prescribed motion: it moves with its velocity v, which the caller may change
  /// between steps.
  Index add_kinematic_particle(const Vec3& x, const Vec3& v = Vec3::Zero());
  Index add_rigid_body(const RigidBodySettings& settings);
  /// Changes rigid body `body`'s mass between steps, as a rigid solver may (a body made static or
  /// kinematic and back, or given a new mass): kinematic (infinite mass, prescribed twist), or
  /// dynamic with `mass` and principal moments `inertia` about its own centre of mass and principal
  /// frame, which stay where they are. Masses merged into bodies are taken out first; the next step
  /// sets the system up again. Validated as add_rigid_body, naming the body.
  void set_rigid_body_mass(Index body, bool kinematic, double mass = 1.0, const Vec3& inertia = Vec3::Ones());
  // Hard bindings may be added and removed after set-up too (the next step redistributes masses); not
  // those on rigid frames while SystemSettings::absorb_bound_mass_into_rigid_bodies merges their mass.
  /// Hard binding of `particle` to parents with barycentric weights (sum 1). Returns its index.
  Index bind_linear(Index particle, std::span<const Index> parents, std::span<const double> weights);
  /// Hard binding of `particle` to rigid body `body` at offset r0 in the body's principal frame.
  Index bind_rigid(Index particle, Index body, const Vec3& r0);
  /// Hard binding to a rigid body at the particle's current position.
  Index bind_rigid_here(Index particle, Index body);
  /// A massless point embedded in the deformable: hard-bound to a segment, triangle or tet (or a
  /// single node, weight 1) by barycentric weights that sum to one; an end for binding springs.
  /// Returns the new particle.
  Index add_embedded_point(std::span<const Index> parents, std::span<const double> weights);
  /// Re-embeds a massless point embedded in particles (a hard-bound target) in new parents, at any time
  /// (plastic flow moves targets in material space, figure 9): x_e and v_e become W x and W v of the
  /// new parents. Nothing else changes, so no set-up follows: the point carries no mass, the soft
  /// particles tied to it keep the mass they have now (a soft particle whose mass followed its
  /// target's effective mass keeps its present value from here on), and the binding springs at it are
  /// damped from its new effective mass. Mass, momentum and angular momentum are unchanged. Points that
  /// were bound to this one were flattened onto its old parents at set-up and stay there. Throws naming
  /// the particle, changing nothing, when it is not such a point, has mass, or the parents or weights
  /// are not a barycentric embedding in free or kinematic particles.
  void reembed(Index particle, std::span<const Index> parents, std::span<const double> weights);
  /// Releases a hard-bound particle: it becomes free with the mass it was created with and keeps its
  /// current position and velocity. Returns false if it was not hard-bound.
  bool unbind(Index particle);
  Index add_soft_binding(const SoftBindingSettings& settings);
  /// A zero-rest-length binding spring between any two points (e.g. hard-bound points on two rigid
  /// bodies: a point joint, figure 13).
  Index add_binding_spring(const BindingSpringSettings& settings);
  /// Moves a binding spring's ends to particles a and b, at any time (a viewer's mouse spring moves to
  /// whatever point is grabbed); its damping is recomputed from the new ends' effective masses.
  void set_binding_spring_ends(Index spring, Index a, Index b);
  /// Switches a binding spring off (it then exerts nothing) or back on, at any time.
  void set_binding_spring_active(Index spring, bool active);
  /// The force binding spring `spring` exerts on its first end now (the second end carries its opposite).
  Vec3 binding_spring_force(Index spring) const;
  /// The force a hard-bound point passed to its parents (through W^T) in the last step's second solve:
  /// what its elements and springs pulled it with, which the binding carried.
  Vec3 hard_binding_force(Index particle) const;
  // ---- topology changes between steps (see the top of this file) -------------------------------
  /// Takes particles out of the simulation: each becomes ParticleKind::removed (no mass, no unknowns,
  /// its state frozen, its index reserved), leaving its hard binding, the soft bindings it is part
  /// of, the binding springs it ends and every force element it is a node of (Force::
  /// remove_elements_touching), and the collision surface triangles it is a vertex of. Throws naming
  /// the item, changing nothing, when a particle does not exist, was removed already, or is a parent
  /// of a hard binding (unbind or remove that point first).
  void remove_particles(std::span<const Index> particles);
  /// Drops every force element with a node in `particles`, keeping the particles (cutting).
  void remove_elements_touching(std::span<const Index> particles);
  /// Removes soft binding `soft` (and its binding spring): its particle becomes free with the mass it
  /// was created with. Later soft bindings' indices move down by one.
  void remove_soft_binding(Index soft);
  /// Removes a binding spring for good; its index stays reserved (and the spring inactive).
  void remove_binding_spring(Index spring);
  /// Removes a force added with add_force (references to it become invalid).
  void remove_force(const Force& force);

  /// Adds a force; validates its indices now.
  template <typename F>
  F& add_force(std::unique_ptr<F> force) {
    F& ref = *force;
    add_force_impl(std::move(force));
    return ref;
  }
  /// Appends a collision source to step 3's list; sources run in the order they were added.
  CollisionSource& add_collision_source(std::unique_ptr<CollisionSource> source);
  std::span<const std::unique_ptr<CollisionSource>> collision_sources() const { return m_collision_sources; }
  /// Registers deformable surface triangles (particle indices) for the collision sources, and each of
  /// their edges once; the builders call it for every cloth and volume surface.
  void add_collision_surface(std::span<const std::array<Index, 3>> triangles);
  /// Collision filter of a particle (Bullet's convention: group bits, and the groups it collides with).
  void set_collision_filter(Index particle, std::uint32_t group, std::uint32_t mask);
  const CollisionGeometry& collision_geometry() const { return m_geometry; }
  /// Replaces the joint rows between rigid-body particles (see JointRow); they hold until replaced,
  /// so a caller whose joints turn with the bodies sets them before every step. Validated here.
  void set_joint_rows(std::vector<JointRow> rows);
  const std::vector<JointRow>& joint_rows() const { return m_joint_rows; }
  StepSettings& step_settings() { return m_step_settings; }
  /// Changes gravity between steps (a rigid solver's world may change its own); validated.
  void set_gravity(const Vec3& gravity);
  const SystemSettings& settings() const { return m_settings; }

  /// Resolves binding chains, distributes masses, computes effective masses and spring damping.
  /// Called by the first step; idempotent. Topology changes afterwards throw.
  void finalize();
  bool finalized() const { return m_finalized; }
  /// True when the model changed since the last set-up (the next step sets it up again first).
  bool needs_set_up() const { return !m_finalized || m_topology_changed; }
  /// How many set-ups finalize() has run (a caller keeping state derived from one can tell it is stale).
  std::uint64_t set_ups() const { return m_set_ups; }

  // ---- time stepping -------------------------------------------------------------------------
  /// One Newmark step of size dt.
  StepStats step(double dt);
  /// Advances by frame_dt in equal substeps. With StepSettings::automatic off: substeps no larger than
  /// cfl * stable_dt(). On (the default), the scheme of the frame is chosen from the scene:
  ///  - explicit elasticity (as set) while it needs at most kCheapExplicitSubsteps substeps;
  ///  - else implicit elasticity, in substeps bounded by the forces that cannot join the solves and by
  ///    the turn of the elements (StepSettings::turn_work_per_implicit_step); a force that offers a
  ///    definite differential only when asked (bending) stays explicit where that multiplies the
  ///    substep count by at most kKeepExplicitFactor (less where contact work makes substeps dear;
  ///    the count is raised to its own); a force joins
  ///    the substep taken; when its cost is lower: each scheme's
  ///    cost per substep is kSubstepCost plus its CG iterations plus its contact work
  ///    (StepStats::contact_work, as CG iterations at kCgWorkPerParticle), counted from the last frames
  ///    that used it (deterministic: counts, not clocks); once explicit has a count, an implicit
  ///    scheme never run, or not run for kRetryImplicitFrames frames, is tried where it takes fewer
  ///    substeps, so its count is measured, not guessed or stale; the first frame takes the cheaper
  ///    guess, later frames switch only for a clear gain (twice it to an explicit step never counted,
  ///    whose guess leaves out its CG iterations); explicit frames take enough substeps that no body
  ///    turns more than kMaxExplicitTurn in one;
  ///  - the solves of a frame it chose stop (StepSettings::cg_rms_tolerance, a bound on the RMS
  ///    velocity error) at StepSettings::relative_tolerance of a substep's velocity change a dt, a the
  ///    last frame's RMS acceleration, or of sleep_speed where larger (explicit frames, second-order
  ///    accurate, at kExplicitToleranceFactor of that), unless cg_tolerance is met first;
  ///  - implicit_elasticity set by the user: as set (its solves at cg_tolerance), in substeps bounded
  ///    by the turn the same way.
  ///
  /// Sleeping (StepSettings::sleep): after a frame that leaves the scene at rest for sleep_time, the
  /// system falls asleep (velocities of dynamic rows and bodies set to zero, the state recorded); an
  /// asleep advance() evaluates no force and solves nothing: it checks, in one pass, that nothing woke
  /// the system, holds the state, moves time on and returns StepStats::asleep. It wakes (and steps
  /// this frame as usual) when: a free, soft-spring or kinematic particle's position or velocity, or
  /// any mass, is not exactly as recorded (the caller set it); gravity changed; the topology changed
  /// (needs_set_up()); a kinematic body moved or has a twist; a dynamic body's fastest point moves
  /// faster than sleep_speed, its frame moved from the recorded one by more than sleep_speed times
  /// the frame, or its applied force or torque changed by more than would give it sleep_speed over
  /// sleep_time; a binding spring was switched or moved, a
  /// collision surface or filter changed or an impulse applied through this class; sleep was turned
  /// off; or wake() was called (the Bullet coupling calls it when a moving body approaches).
  StepStats advance(double frame_dt);
  /// True while the system sleeps (see advance()).
  bool asleep() const { return m_asleep; }
  /// Wakes the system: the next advance() steps. Also restarts the count towards sleep_time.
  void wake();
  /// The box holding every particle that is not removed, recorded when the system fell asleep (what
  /// a rigid solver tests its moving bodies against); empty while awake.
  const Eigen::AlignedBox3d& sleeping_bounds() const { return m_sleep.bounds; }
  /// How long (simulated seconds) the scene has been at rest by advance()'s test, while awake.
  double rest_time() const { return m_rest_time; }
  /// advance() stays explicit up to this many substeps per frame.
  static constexpr int kCheapExplicitSubsteps = 2;
  /// advance()'s implicit frames keep a force that offers a definite differential only when asked
  /// (dihedral bending) explicit where that multiplies the substep count by at most this (sinew-schemes: dihedral
  /// bending kept explicit at four substeps a frame took half the time of bending implicit at one, with less error, on
  /// the hanging cloth).
  static constexpr int kKeepExplicitFactor = 4;
  /// advance()'s explicit frames stop their solves at this fraction of StepSettings::relative_tolerance:
  /// explicit elasticity is second-order accurate, so a solve error that implicit frames' first-order
  /// error hides would show there (sinew-schemes: at 1e-2 the net's error doubled, at 1e-4 it is the
  /// reference's own).
  static constexpr double kExplicitToleranceFactor = 1e-2;
  /// advance()'s explicit frames take substeps short enough that no body with particles hard-bound
  /// to it turns more than this [rad] in one: a particle whirled by a body turning at w oscillates
  /// at about w about its orbit, and explicit elasticity holds such a mode only while w dt < 2 (a
  /// cloth hard-bound to a 2 kg box spun to 3000 rad/s by a stretched tie grew its energy 1.45
  /// times a frame at w dt = 2.8).
  static constexpr double kMaxExplicitTurn = 1.0;
  /// advance() runs an implicit frame again after this many explicit frames where it takes fewer
  /// substeps, so the implicit CG count the cost model compares follows the scene (a count from one
  /// hard frame, a teleport's, would otherwise keep the scheme explicit for good).
  static constexpr int kRetryImplicitFrames = 30;
  /// advance()'s guess of an implicit substep's CG iterations on a first frame, before any count.
  static constexpr double kImplicitIterationsGuess = 30.0;
  /// advance()'s cost model counts a substep's own work (force evaluations, collisions, the solves'
  /// set-up: right-hand sides, preconditioner blocks) as this many CG iterations (sinew-schemes: at 1,
  /// once loose solves made explicit substeps cheap in iterations, the hello scene chose 13 explicit
  /// substeps a frame at 2.4 ms over 4.6 implicit ones at 1.0 ms).
  static constexpr double kSubstepCost = 4.0;
  /// advance()'s cost model counts a CG iteration as this many items of contact work
  /// (CollisionSource::work) per particle: on the twist scene at 100 x 100 one work item took 5.8 ns
  /// and one CG iteration 30 ns a particle (one thread). Without it the model saw a substep of
  /// self-contact as free and chose 49 explicit substeps a tick where 4 implicit ones cost a third.
  static constexpr double kCgWorkPerParticle = 5.0;
  /// The explicit elastic forces' stable step (binding springs and implicitly treated forces impose none).
  double stable_dt();
  double time() const { return m_time; }

  // ---- state ---------------------------------------------------------------------------------
  Particles& particles() { return m_particles; }
  const Particles& particles() const { return m_particles; }
  RigidBodyParticles& rigid_bodies() { return m_bodies; }
  const RigidBodyParticles& rigid_bodies() const { return m_bodies; }
  const HardBindings& hard_bindings() const { return m_hard; }
  const SoftBindings& soft_bindings() const { return m_soft; }
  const BindingSprings& binding_springs() const { return m_springs; }
  std::span<const std::unique_ptr<Force>> forces() const { return m_forces; }
  /// The mass each particle was given at creation (before distribution to parents).
  const VectorXd& input_mass() const { return m_input_mass; }
  /// Effective mass of any row: mass for free rows, eq. 4 for bound ones, +inf for kinematic.
  double effective_mass(Index particle) const;
  /// Effective mass of a rigid-bound row along a unit direction n: 1 / (n^T K n).
  double effective_mass_along(Index particle, const Vec3& n) const;

  /// Applies impulse j at a particle: to itself if free, to its parents if hard-bound (section 2:
  /// dv_i = w_i j / m_i, so the bound point's velocity changes by j / m_e), or to its rigid frame
  /// (dv_c = j/m, dw = I^-1 (r x j)). Bound rows are re-clamped.
  void apply_impulse(Index particle, const Vec3& j);

  /// Recomputes hard-bound rows (x = W x_parents, v = W v_parents) after the caller moved parents.
  void clamp_bound_rows();

  // ---- diagnostics ------------------------------------------------------------------------------
  /// Momentum of the parents (free particles and dynamic rigid bodies), optionally with the soft-
  /// bound particles' duplicated mass.
  Vec3 linear_momentum(bool include_soft = false) const;
  /// Angular momentum about the origin, same members as linear_momentum.
  Vec3 angular_momentum(bool include_soft = false) const;
  double kinetic_energy(bool include_soft = false) const;
  /// Elastic + binding-spring + gravitational potential energy (gravity relative to the origin).
  double potential_energy();
  /// Largest |x_b - W x| over hard-bound rows: zero by construction, measured to prove it.
  double max_hard_binding_drift() const;
  /// FNV-1a hash of every position, velocity and rigid state bit: two runs are identical iff equal.
  std::uint64_t state_hash() const;

 private:
  void add_force_impl(std::unique_ptr<Force> force);
  /// Marks that the topology changed after set-up: the next step (or finalize()) sets it up again.
  void note_topology_change();
  /// Every force drops the elements with a node flagged in `removed`.
  void remove_elements_of(std::span<const std::uint8_t> removed);
  void require_finalized(const char* what) const;
  void compute_effective_masses();

  SystemSettings m_settings;
  StepSettings m_step_settings;
  std::vector<JointRow> m_joint_rows;
  Particles m_particles;
  VectorXd m_input_mass;
  RigidBodyParticles m_bodies;
  HardBindings m_hard;
  SoftBindings m_soft;
  BindingSprings m_springs;
  std::vector<std::unique_ptr<Force>> m_forces;
  std::vector<std::unique_ptr<CollisionSource>> m_collision_sources;
  CollisionGeometry m_geometry;
  VectorXd m_inverse_effective_mass;      // per row, 0 for infinite mass
  VectorXd m_effective_mass;              // per row, +inf for kinematic, m_e for bound rows
  std::vector<double> m_force_stable_dt;  // Force::stable_dt per force at these masses (stable_dt())
  // advance() under StepSettings::automatic: CG iterations per substep last seen with explicit and
  // with implicit elasticity (the cost model), and whether the last frame chose implicit.
  // A negative count: that scheme has not run yet (once explicit has run, an implicit frame is tried
  // where it takes fewer substeps, so its cost is counted rather than guessed).
  double m_explicit_iterations = -1.0;
  double m_implicit_iterations = -1.0;
  double m_contact_iterations = 0.0;  // the last frame's contact work per substep, as CG iterations
  bool m_chose_implicit = false;
  int m_explicit_frames = 0;  // explicit frames since the last implicit one
  // The last frame's RMS acceleration (rms_acceleration()), which sets the next frame's tolerance,
  // and the velocities at the frame's start it is measured from (kept to reuse their storage).
  double m_frame_acceleration = -1.0;  // -1: no frame yet
  Vectors3 m_frame_v_start;
  Vectors3 m_frame_body_v_start;
  /// The mass-weighted RMS velocity change of the particles and bodies that carry momentum
  /// (free and soft-spring particles, dynamic bodies) since m_frame_v_start and
  /// m_frame_body_v_start, over frame_dt (0 where undefined).
  double rms_acceleration(double frame_dt) const;
  /// The substep count advance() runs frame_dt in, for the stable step `limit` (0 where the count
  /// would exceed StepSettings::max_substeps: advance() then reports it).
  int substeps_for(double frame_dt, double limit) const;
  /// Substeps that keep implicit elasticity's linearisation error over frame_dt within
  /// StepSettings::turn_work_per_implicit_step (advance() under StepSettings::automatic).
  int turn_substeps(double frame_dt, double energy);
  /// Kinetic energy plus the elastic forces' energy (what advance()'s choice weighs against).
  double visible_energy();
  StepStats run_substeps(double frame_dt, int substeps);
  /// advance() while awake: the scheme chosen for the frame and its substeps.
  StepStats advance_awake(double frame_dt);
  /// Whether the state after a frame is at rest by StepSettings::sleep_speed (advance()'s test).
  bool at_rest() const;
  /// Zeroes the dynamic velocities and records what the wake test compares against.
  void fall_asleep();
  /// Whether nothing woke the system since it fell asleep (advance()'s list), for a frame of frame_dt.
  bool still_asleep(double frame_dt) const;
  /// The distance from rigid body b's centre of its farthest point that matters to the deformables:
  /// its hard-bound points and its radius of gyration.
  double body_reach(Index b) const;
  // Sleeping (StepSettings::sleep): the state recorded when the system fell asleep.
  struct SleepRecord {
    Vectors3 x, v;
    VectorXd mass;
    Vectors3 body_x, body_force, body_torque;
    std::vector<Quat> body_q;
    VectorXd body_reach;
    Vec3 gravity = Vec3::Zero();
    Eigen::AlignedBox3d bounds;
  };
  SleepRecord m_sleep;
  bool m_asleep = false;
  double m_rest_time = 0.0;
  bool m_finalized = false;
  bool m_topology_changed = false;  // the topology changed since set-up: redo it before the next step
  std::uint64_t m_set_ups = 0;
  std::vector<ParticleKind> m_input_kind;  // free or kinematic, as created
  double m_time = 0.0;
  std::unique_ptr<Newmark> m_newmark;
};

}  // namespace sinew
