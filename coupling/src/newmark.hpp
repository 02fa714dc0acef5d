// The semi-implicit Newmark step of Sifakis et al. 2007, section 3.3 (internal to sinew::System).
//
// newmark.cpp holds the five steps in order and what they share (forces, right-hand sides, the
// initial guesses); the pieces they use live beside it: cg.* (conjugate gradients and its vector
// work), implicit_system.* (the operator S of eq. 8), preconditioner.* (block Jacobi, multigrid),
// constraints.* (collision stencils and joint rows, as projections). The step sees the system only
// through a StepModel (step_model.hpp).
#pragma once

#include "cg.hpp"
#include "constraints.hpp"
#include "divergence.hpp"
#include "implicit_system.hpp"
#include "preconditioner.hpp"
#include "step_model.hpp"

#include <algorithm>
#include <vector>

namespace sinew {

class Newmark {
 public:
  Newmark() : m_system(m_unknowns, m_constraints, m_preconditioner) {}
  Newmark(const Newmark&) = delete;
  Newmark& operator=(const Newmark&) = delete;

  StepStats step(const StepModel& s, double dt);
  /// Force a hard-bound row passed to its parents in the last step-4 force evaluation.
  Vec3 bound_force(Index particle) const {
    return particle < m_bound_force.cols() ? Vec3(m_bound_force.col(particle)) : Vec3::Zero();
  }

 private:
  // The five steps of section 3.3, in order.
  void implicit_half_velocity(const StepModel& s, double dt, StepStats& stats);   // 1: eq. 6-8
  void advance_positions(const StepModel& s, double dt);                          // 2
  void process_collisions(const StepModel& s, double dt, StepStats& stats);       // 3
  void backward_euler_velocity(const StepModel& s, double dt, StepStats& stats);  // 4
  void extrapolate_velocity(const StepModel& s);                                  // 5
  /// Step 3's end (StepSettings::spread_collisions): the rest of the deformables follow what the
  /// collision sources moved, through step 1's operator (see newmark.cpp).
  void spread_collisions(const StepModel& s, double dt, StepStats& stats);
  /// Step 5's end: stiff damped binding springs' ends move together (see newmark.cpp).
  void settle_stiff_binding_springs(const StepModel& s);
  // Contacts between rigid bodies (unilateral joint rows, see "Contacts" in newmark.cpp).
  void predict_contacts(const StepModel& s, double dt);
  bool revise_contacts(const StepModel& s, double dt);
  void prepare_rows(const StepModel& s, double dt, bool contacts);
  void collide_contacts(const StepModel& s, double dt);
  void hold_contacts_at_step_end(const StepModel& s);
  void advance_contact_gaps(const StepModel& s, double dt);
  static double row_velocity(const JointRow& row, const Vectors3& v, const Vectors3& w);
  static double contact_target(const JointRow& row, double dt) { return row.target - std::max(row.gap, 0.0) / dt; }
  void newton_iteration(const StepModel& s, double dt, StepStats& stats);  // after 1 (StepSettings)

  /// Step 1's initial guesses: v^n in m_y and, when one is to be tried, the other in m_guess (see
  /// the comment in the .cpp). Returns the alternative to pass to the solve, or null.
  GeneralizedVector* choose_step1_guess(const StepModel& s, double dt, bool& trial);
  void apply_surface_friction();                        // step 4's collision constraints' Coulomb friction
  void keep_half_velocity(const StepModel& s);          // step 1's answer in m_y -> m_v_half, m_twist_half, v, w
  void move_positions(const StepModel& s, double tau);  // x^n + tau v~^{n+1/2}, frames likewise (velocities kept)
  // The rigid frames over the step: their turns and the points' chords (see set_step_maps).
  static Vec3 turn_of(const Vec3& w, double dt, double limit);
  void predict_angular_velocities(double dt);
  enum class ChordForm { derivative, arm };
  void set_step_maps(const StepModel& s, double dt, bool inertias, ChordForm form);
  double chord_error(const StepModel& s, double dt) const;
  void add_bound_offset_impulse();
  void mix_turns(const Vectors3& answer);
  void add_geometric_stiffness(const StepModel& s, const SolveCoefficients& k, double dt, ChordForm form);
  void restore_positions(const StepModel& s);  // back to x^n, exactly

  /// Step1Guess::adaptive tries both step-1 guesses once in this many steps.
  static constexpr int kGuessTrialSteps = 8;
  /// A binding spring is settled at the step's end when its relative motion decays by e^-kSettleDecay
  /// within the step; kSettlePasses Gauss-Seidel passes over the springs (and the joints).
  static constexpr double kSettleDecay = 4.0;
  static constexpr int kSettlePasses = 4;
  /// Step 1 is solved again while its contacts' active set changes, at most this many times in all.
  static constexpr int kContactPasses = 4;
  /// spread_collisions solves again while the rows it lets go or holds again change, at most this
  /// many times in all.
  static constexpr int kSpreadPasses = 4;
  /// Gauss-Seidel passes at the step's end when rigid bodies touch (contacts with friction, with the
  /// springs' settling and the joints): a box sliding on four corners needs about this many to keep
  /// friction's torque from tipping it.
  static constexpr int kContactEndPasses = 16;
  static void record_solve(const SolveResult& result, int& iterations, StepStats& stats);
  void allocate(const StepModel& s);
  void save_state(const StepModel& s);
  /// World inertia of every body at the current orientations (the solve's configuration).
  void update_body_inertias(const StepModel& s);
  /// f, wrench: explicit elastic + external forces at the current x, distributed to parents and
  /// mapped onto soft particles, then the binding springs' -K x_springs, distributed. Returns the
  /// sum of mapped forces.
  Vec3 compute_forces(const StepModel& s, const Vectors3& x_springs, bool record_bound_forces = false);
  /// c = M v_start + h F; rigid rows (m v + h f, L + h tau).
  void build_rhs(const StepModel& s, double h, const Vectors3& v_start, const Vectors3& body_v, const Vectors3& body_L);
  /// Solves S y = c (S of eq. 8 with coefficients k) from the guess in m_y; `alternative`, `rule`:
  /// see ConjugateGradients::solve. Builds the preconditioner when `refresh` or when the last one
  /// was built for other coefficients.
  SolveResult solve(const StepModel& s, const SolveCoefficients& k, bool linear_solve, bool refresh,
                    GeneralizedVector* alternative = nullptr, Alternative rule = Alternative::if_exact);
  /// True when some term makes the solves implicit (else S = M, solved in one pass).
  bool needs_linear_solve(const StepModel& s) const {
    return m_has_damping || s.springs.size() > 0 || m_implicit_elasticity || m_constraints.has_joints();
  }
  /// Throws naming the phase and the first non-finite body or particle, and the force that gives
  /// non-finite values at the step's finite start (with `culprit`; after step 1 only).
  void check_finite(const StepModel& s, const char* phase, bool culprit = true);
  /// What the divergence check reads of the step (divergence.hpp).
  StepRecord record() const {
    return {m_unknowns, m_x_n, m_v_n, m_v_tilde_n, m_f, m_wrench, m_body_x_n, m_body_L_n, m_turn};
  }
  /// Puts back the positions, velocities and frames save_state kept (after a step that threw).
  void restore_start_state(const StepModel& s);
  /// Throws naming `source` unless c is a valid stencil on rows with unknowns.
  void check_constraint(const StepModel& s, const CollisionConstraint& c, std::string_view source) const;

  bool m_allocated = false;
  long m_step_count = 0;
  double m_dt = 0.0;  // the current step
  Unknowns m_unknowns;
  Constraints m_constraints;
  Preconditioner m_preconditioner;
  ImplicitSystem m_system;
  ConjugateGradients m_cg;
  Vectors3 m_x_n, m_v_n, m_x_np1, m_v_tilde_n, m_v_half;
  // spread_collisions: x~^{n+1} before step 3's sources, step 3's constraints while the spread holds
  // its own, the spread's answer and its imposed part, a zero right-hand side, per row: in a constraint.
  Vectors3 m_x_predicted, m_spread_imposed;
  std::vector<CollisionConstraint> m_step3_constraints;
  struct SpreadRow {
    CollisionConstraint row;
    Index owner;  // a tangent row: the index of its point's normal row; else -1
    bool active;
  };
  std::vector<SpreadRow> m_spread_rows;
  std::vector<std::size_t> m_spread_active;  // the rows in the constraints, in order
  GeneralizedVector m_spread, m_spread_rhs;
  std::vector<std::uint8_t> m_spread_held;
  Vectors3 m_f, m_g;
  Vectors3 m_bound_force;  // force on each hard-bound row before W^T, from the last step 4
  Vectors6 m_wrench;
  Vectors6 m_twist_half;  // step 1's half-step twists, step 4's initial guess
  Vectors3 m_body_x_n, m_body_v_n, m_body_w_n, m_body_L_n, m_body_x_np1;
  std::vector<Quat> m_body_q_n, m_body_q_np1;
  std::vector<Mat3> m_body_I;
  std::vector<Mat3> m_body_I_n;      // world inertias at q^n
  Vectors3 m_turn;                   // each body's turn over the step, theta (rotation vector)
  Vectors3 m_w_lin;                  // the angular velocities the chords are linearised at
  std::vector<Mat3> m_arm_maps;      // r0 -> the arm R(theta) R(q^n) r0 (the end-of-step offset)
  std::vector<Mat3> m_angular_maps;  // w -> the angular velocity the points move with, A w
  std::vector<Vec3> m_r_n;           // world offsets of the points on frames at t^n
  Vectors3 m_bound_offset;           // o on the rows of points on frames, 0 elsewhere
  bool m_has_bound_offset = false;
  VectorXd m_body_gyration;                  // radius of gyration of each dynamic body
  std::vector<Mat3> m_geometric;             // per body: the chords' geometric stiffness in step 1 (w-w block)
  GeneralizedVector m_lin;                   // the twists and velocities step 1 is linearised at
  Vectors3 m_mix_x, m_mix_g, m_mix_next;     // Anderson's mixing of the turns (mix_turns)
  GeneralizedVector m_saved_half;            // Newton's answer, while the arm form is tried from it
  ChordForm m_form = ChordForm::derivative;  // the form of this step's answer
  Vectors3 m_u;                              // scratch: velocities with the bound rows' chords
  GeneralizedVector m_c, m_y, m_product, m_product0;
  SolveCoefficients m_last_k;  // the last solve's coefficients (the operator m_c and m_y belong to)
  // Contacts: the rows this step's solves hold (bilateral joint rows, then the active contacts with
  // their step targets), each one's index in StepModel::joint_rows, and per joint row whether the
  // contact is active, its step-1 multiplier (impulse over dt/2) and its end-of-step impulses.
  bool m_has_contacts = false;
  std::vector<JointRow> m_rows;
  std::vector<Index> m_row_source;  // -1 - i for the tangent rows of a sticking contact i
  std::vector<Index> m_tangent_of;  // per m_rows entry: a tangent row's normal row (in m_rows), else -1
  std::vector<std::uint8_t> m_contact_active, m_contact_sliding;
  struct ContactPair {
    Index a, b;
    double load, push;  // sum of the normal multipliers, and of their positive parts
    Vec3 tangential;    // of the sticking contacts
    double friction;
    bool sticking;
  };
  std::vector<ContactPair> m_pairs;                       // revise_contacts' scratch
  std::vector<std::pair<Index, Index>> m_slipping_pairs;  // body pairs slipping at the last step's end
  VectorXd m_contact_impulse, m_lambda, m_end_normal, m_end_bound, m_collision_lambda;
  Vectors3 m_end_friction, m_predicted_v, m_predicted_w;
  GeneralizedVector m_guess;  // step 1's second initial guess M^-1 c (first step), later the extrapolation's increment
  GeneralizedVector m_last_half;  // the last step's v^{n+1/2} (particles and twists), for step 1's guess
  double m_last_dt = 0.0;         // that step's dt; 0 before the first step
  int m_guess_trial = 0;          // Step1Guess::adaptive: steps until both guesses are tried again
  bool m_extrapolate = false;     // Step1Guess::adaptive: the last trial's choice
  // Step 1 builds the preconditioner; step 4 keeps it when it was built for the same operator
  // coefficients (see solve()). The key it was built for:
  struct PreconditionerKey {
    SolveCoefficients k{-1.0, -1.0, -1.0};
    bool jacobi = false;
  } m_preconditioner_key;
  bool m_has_damping = false;
  bool m_implicit_elasticity = false;  // some elastic force enters the step-1 solve
  bool m_implicit_solid = false;       // some of them a solid's (Force::volumetric): step 3 spreads
  DivergenceCheck m_divergence;        // the energy budget each step is checked against
  Vectors6 m_scratch_wrench;           // the divergence check's, when it names the largest force
};

}  // namespace sinew
