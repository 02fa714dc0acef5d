// The stability suite (issue 4): hard cases run on sinew and on Bullet 3.24's two cloth-to-rigid
// couplings, each for seconds of simulated time, reporting whether it stayed finite and bounded and,
// if not, at which frame it failed. The CTest suite (tests/test_stability.cpp) asserts that sinew
// survives every case; sinew-bench prints the table for all three systems.
//
// Every case but the drop is a variant of the benchmark curtain (curtain_bench.hpp), so the three
// systems run the same scene. The drop is its own small scene: a free cloth falling fast onto a thin
// static plate.
#pragma once

#include "curtain_bench.hpp"

#include <cstdio>
#include <memory>
#include <string>
#include <vector>

namespace sinew::bench {

/// A free cloth (the curtain's mesh, laid in the x-z plane) dropped onto a thin static box.
struct DropSpec {
  int n = 20;                        ///< nodes per side
  double size = 1.0;                 ///< cloth side [m]
  double cloth_mass = 0.5;           ///< [kg]
  double stretch_stiffness = 200.0;  ///< [N/m] per edge
  double stretch_damping = 0.05;     ///< [N s/m] per edge
  double bending_stiffness = 1e-4;   ///< [N m] (sinew only)
  double height = 0.3;               ///< the cloth's starting height above the plate's top face [m]
  double drop_speed = 10.0;          ///< initial downward speed of every node [m/s]
  double plate_size = 3.0;           ///< side of the square plate [m], larger than the cloth so it cannot slide off
  double plate_thickness = 0.01;     ///< [m]
  double thickness = 0.01;           ///< sinew's collision thickness (CouplingSettings::thickness) [m]
  double friction = 0.3;
  double gravity = 9.81;  ///< [m/s^2], along -y
};

struct StabilityCase {
  std::string name;
  std::string what;   ///< one line: what the case stresses
  bool drop = false;  ///< the drop scene (drop_spec) instead of a curtain (curtain)
  CurtainSpec curtain;
  DropSpec drop_spec;
  double frame_dt = 1.0 / 60.0;  ///< [s]
  int steps = 4;                 ///< Bullet ticks per frame (sinew substeps inside a tick as it needs)
  int frames = 120;
  /// sinew only: > 0 ties the bound nodes by binding springs of this stiffness [N/m] instead of hard
  /// bindings (SinewSettings::binding_spring_stiffness). The peers' anchors are what they always are.
  double binding_spring_stiffness = 0.0;
  /// The largest energy gain, as a fraction of energy_scale, that still counts as survival in the table.
  /// Beyond it the run is a blow-up. The tests hold sinew to a far tighter bound.
  double blow_up_gain = 0.5;
};

/// The suite, in the order the table prints it.
std::vector<StabilityCase> stability_cases();
/// The case called `name`; throws sinew::Error naming it when there is none.
StabilityCase stability_case(const std::string& name);

/// The systems the suite runs: "sinew", "sinew-multigrid" (springs and bending implicit, the
/// multigrid preconditioner), "bullet-classic", "bullet-deformable".
std::vector<std::string> stability_systems();

struct StabilityResult {
  std::string case_name;
  std::string system;
  bool run = true;  ///< false: the system cannot build this case (reason says why)
  bool survived = false;
  int failed_frame = -1;  ///< the first frame (1-based) after which the run was not healthy, or -1
  int frames = 0;         ///< frames completed
  std::string reason;     ///< why it failed ("non-finite", "left 1 km", "energy blow-up", "threw: ...") or was not run
  /// Energy measure: max over frames of (E(t) - E(0)) / energy_scale, where E is each system's
  /// energy() (kinetic + gravitational + the elastic energy its model has) and energy_scale is the
  /// energy the cloth brings: its kinetic energy at the start plus its weight times the height it can
  /// fall (the curtain's size, the drop's height), plus the rings' spin energy. The rings' own
  /// translation is left out of the scale so that heavy rings cannot hide a gain in the cloth. The
  /// scenes are passive (E can only fall) except where a kinematic parent moves: there E is taken in
  /// the frame moving with it, E - u (P_x - P_x(0)) (Galilean: the parents are at rest in that frame and
  /// do no work). E leaves out the binding springs' own potential energy (see spring_energy).
  double energy_gain = 0.0;
  double energy_scale = 0.0;  ///< [J]
  /// Max over frames of the binding springs' potential energy / energy_scale. A 1e12 N/m spring's stiff
  /// mode, which the trapezoidal velocity update (steps 4-5) neither damps nor amplifies, rings at
  /// sub-micrometre stretches that still store k s^2 / 2 (0.2 J at 6e-7 m): bounded by the stretch
  /// (max_drift), reported here, and kept out of energy_gain so that it cannot hide a gain elsewhere.
  double spring_energy = 0.0;
  /// Max over frames of attachment().bound_node: hard-binding drift, or the binding springs' stretch in
  /// the spring case [m]. For the deformable world it is 0 by its overwrite; see drift_before_overwrite.
  double max_drift = 0.0;
  double max_drift_before_overwrite = 0.0;  ///< [m]
  double max_ring_joint = 0.0;              ///< max distance of a ring's centre from the rod axis [m]
  /// Drop only: lowest height of a node above the plate's bottom face while over the plate, and whether
  /// a node was ever below it there (tunnelled through the plate).
  double min_clearance = kInfinity;  ///< [m]
  bool tunnelled = false;
  double wall_ms = 0.0;  ///< wall time of the run, set-up included [ms]
  std::string note;      ///< where the system's model differs from the case (CurtainRun::mismatch)
};

/// The scene of `c` built in `system`, at its start (the drop's runs report no attachment error).
std::unique_ptr<CurtainRun> make_stability_run(const StabilityCase& c, const std::string& system);

/// Runs `c` on `system` for c.frames frames of c.frame_dt (c.steps ticks each), stopping at the first
/// frame that leaves it unhealthy. A sinew::Error thrown by a step counts as a failure at that frame.
StabilityResult run_stability_case(const StabilityCase& c, const std::string& system);

/// Every case on every system, in table order; `progress`, when given, gets each line as it finishes.
std::vector<StabilityResult> run_stability_suite(const std::vector<std::string>& systems,
                                                 std::FILE* progress = nullptr);

/// The suite as an aligned table: case, system, survived, failed frame, reason, max energy gain, max
/// drift (and before overwrite), ring joint, wall ms; then one line per case saying what it stresses and
/// how the peers differ.
void print_stability_table(std::FILE* out, const std::vector<StabilityResult>& results);
/// The same columns as CSV, with a header line.
void write_stability_csv(std::FILE* out, const std::vector<StabilityResult>& results);

}  // namespace sinew::bench
