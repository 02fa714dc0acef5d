// The semi-implicit Newmark step of Sifakis et al. 2007, section 3.3 (internal to sinew::System).
#pragma once

#include "sinew/system.hpp"

#include "multigrid.hpp"

#include <Eigen/Core>

#include <Eigen/SVD>

#include <vector>

namespace sinew {

class Newmark {
 public:
  StepStats step(System& s, double dt);
  /// Force a hard-bound row passed to its parents in the last step-4 force evaluation.
  Vec3 bound_force(Index particle) const {
    return particle < m_bound_force.cols() ? Vec3(m_bound_force.col(particle)) : Vec3::Zero();
  }

 private:
  // The five steps of section 3.3, in order.
  void implicit_half_velocity(System& s, double dt, StepStats& stats);   // 1: eq. 6-8
  void advance_positions(System& s, double dt);                          // 2
  void process_collisions(System& s, double dt);                         // 3
  void backward_euler_velocity(System& s, double dt, StepStats& stats);  // 4
  void newton_iteration(System& s, double dt, StepStats& stats);        // after 1 (StepSettings)
  void keep_half_velocity(System& s);  // step 1's answer in m_y -> m_v_half, m_twist_half, v, w
  void move_positions(System& s, double tau);  // x^n + tau v~^{n+1/2}, frames likewise (velocities kept)
  void restore_positions(System& s);           // back to x^n, exactly
  void extrapolate_velocity(System& s);                                  // 5

  /// Step1Guess::adaptive tries both step-1 guesses once in this many steps.
  static constexpr int kGuessTrialSteps = 8;
  struct SolveResult {
    int iterations = 0;
    double residual = 0;
    bool converged = true;
    bool took_alternative = false;  ///< solve() started from its alternative guess
  };
  static void record_solve(const SolveResult& result, int& iterations, StepStats& stats);
  /// When solve() takes its alternative guess: only when that is exact to 1e-3 of the tolerance
  /// (max-norm of the preconditioned residual, and better than the first), or, unless the first
  /// guess already meets the tolerance, when the alternative does or its r . z
  /// (r^T P^-1 r, P the preconditioner: the energy norm CG reduces, an estimate of the initial error's
  /// A-norm) is the smaller. Chosen by the max-norm, the guess with the smaller peak sometimes needed
  /// more iterations (30x30 multigrid cloth at 1/60 s, tol 1e-2: 536 against 401 over 40 solves).
  enum class Alternative { if_exact, if_smaller };
  void allocate(const System& s);
  void save_state(System& s);
  /// World inertia of every body at the current orientations (the solve's configuration).
  void update_body_inertias(const System& s);
  /// f, wrench: explicit elastic + external forces at the current x, distributed to parents and
  /// mapped onto soft particles, then the binding springs' -K x_springs, distributed. Returns the
  /// sum of mapped forces.
  Vec3 compute_forces(System& s, const Vectors3& x_springs, bool record_bound_forces = false);
  /// c = M v_start + h F; rigid rows (m v + h f, L + h tau).
  void build_rhs(const System& s, double h, const Vectors3& v_start, const Vectors3& body_v, const Vectors3& body_L);
  /// Solves (M - h D - h beta K_springs - h beta_el K+_elastic) y = c by preconditioned CG, y holding
  /// the initial guess (K, D negative semi-definite); with `alternative`, a second guess taken
  /// instead by `rule` (see Alternative).
  SolveResult solve(System& s, double h, double beta, double beta_el, bool linear_solve,
                    GeneralizedVector* alternative = nullptr, Alternative rule = Alternative::if_exact);
  void apply(System& s, double h, double beta, double beta_el, const GeneralizedVector& u, GeneralizedVector& out);
  void build_preconditioner(System& s, double h, double beta, double beta_el, bool jacobi);
  void precondition(const GeneralizedVector& r, GeneralizedVector& z);
  void project(GeneralizedVector& u) const;
  /// project() without the particle mask: for vectors already zero on rows without unknowns.
  void project_constraints(GeneralizedVector& u) const;
  /// Groups the dynamic bodies that joint rows connect and factors each group's rows (SVD), once per
  /// step: the orthonormal basis of the rows' span and the least-norm twists meeting the targets.
  void prepare_joints(const System& s);
  /// Sets the joint rows' components of the rigid twists in u to their targets (the rest is kept).
  void impose_joints(GeneralizedVector& u) const;
  void project_joint_groups(GeneralizedVector& u, bool impose_targets) const;
  /// Copies each synchronized soft particle's target state into it (section 3.1).
  void synchronize(System& s, bool positions, bool velocities);
  /// Adds each synchronized soft row's force to its target row and clears the soft row.
  void gather_synchronized(System& s, Vectors3& f) const;
  /// Pushes collision drift of synchronized soft particles to their targets' parents (section 3.1).
  void push_synchronized_drift(System& s);
  void check_finite(const System& s, const char* phase) const;

  bool m_allocated = false;
  long m_step_count = 0;
  Index m_n = 0, m_r = 0;
  VectorXd m_dof_mass;      // mass of dynamic rows, 0 elsewhere
  VectorXd m_dynamic_mask;  // 1 on dynamic rows, 0 elsewhere
  std::vector<std::uint8_t> m_dynamic_body;
  Vectors3 m_x_n, m_v_n, m_x_np1, m_v_tilde_n, m_v_half;
  Vectors3 m_f, m_g, m_tmp_v, m_apply_f;
  Vectors3 m_bound_force;  // force on each hard-bound row before W^T, from the last step 4
  Vectors6 m_wrench, m_apply_wrench;
  Vectors6 m_twist_half;  // step 1's half-step twists, step 4's initial guess
  Vectors3 m_body_x_n, m_body_v_n, m_body_w_n, m_body_L_n, m_body_x_np1;
  std::vector<Quat> m_body_q_n, m_body_q_np1;
  std::vector<Mat3> m_body_I;
  std::vector<Eigen::Matrix<double, 6, 6>> m_body_preconditioner;
  VectorXd m_diag;                                      // scalar diagonal of forces without blocks
  Eigen::Matrix<double, 9, Eigen::Dynamic> m_diag_blocks;     // 3x3 diagonal blocks, column-major
  Eigen::Matrix<double, 9, Eigen::Dynamic> m_inverse_blocks;  // their inverses (with mass), 0 off the unknowns
  VectorXd m_dof_mass3, m_h_mask3;  // m_dof_mass and h m_dynamic_mask per coordinate (3N)
  double m_h_mask_h = -1.0;         // the h m_h_mask3 holds
  GeneralizedVector m_c, m_y, m_r_vec, m_z, m_p, m_q;
  GeneralizedVector m_guess;  // step 1's second initial guess M^-1 c (first step), later the extrapolation's increment
  GeneralizedVector m_last_half;  // the last step's v^{n+1/2} (particles and twists), for step 1's guess
  double m_last_dt = 0.0;         // that step's dt; 0 before the first step
  int m_guess_trial = 0;          // Step1Guess::adaptive: steps until both guesses are tried again
  bool m_extrapolate = false;     // Step1Guess::adaptive: the last trial's choice
  std::vector<CollisionConstraint> m_constraints;
  struct JointGroup {
    std::vector<Index> bodies;  // ascending
    Eigen::MatrixXd basis;      // 6k x rank, orthonormal, spanning the rows
    VectorXd particular;        // 6k, in the span: the least-norm twists on the targets
    // Set-up scratch, kept so that a step whose joints have the same shape as the last allocates nothing.
    std::vector<Index> rows;    // indices into the system's joint rows
    Eigen::MatrixXd J;
    VectorXd t, coefficients;
    Eigen::JacobiSVD<Eigen::MatrixXd> svd;
  };
  // The first m_joint_group_count entries are this step's groups; entries past it keep their storage.
  std::vector<JointGroup> m_joint_groups;
  std::size_t m_joint_group_count = 0;
  std::vector<Index> m_joint_root, m_joint_group_of;
  mutable VectorXd m_joint_scratch, m_joint_coefficients;
  AggregationMultigrid m_multigrid;  // StepSettings::multigrid
  std::vector<AggregationMultigrid::PairBlockSource> m_pair_sources;  // build_preconditioner's scratch
  bool m_use_multigrid = false;      // this solve preconditions with the multigrid
  // Step 1 builds the preconditioner; step 4 keeps it when it was built for the same operator
  // parameters (see solve()). The key it was built for:
  bool m_refresh_preconditioner = true;
  struct PreconditionerKey {
    double h = -1.0, beta = -1.0, beta_el = -1.0;
    bool jacobi = false;
  } m_preconditioner_key;
  bool m_has_damping = false;
  bool m_implicit_elasticity = false;  // some elastic force enters the step-1 solve
};

}  // namespace sinew
