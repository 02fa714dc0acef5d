#include "constraints.hpp"

#include "sinew/parallel.hpp"

#include <algorithm>
#include <utility>

namespace sinew {

void Constraints::reset(const Unknowns& unknowns) {
  m_unknowns = &unknowns;
  m_collisions.clear();
  m_collisions.reserve(static_cast<std::size_t>(unknowns.n));
  m_single.clear();
  m_single.reserve(static_cast<std::size_t>(unknowns.n));
  m_collision_groups.clear();
  m_collision_root.assign(static_cast<std::size_t>(unknowns.n), -1);
  m_collision_count.assign(static_cast<std::size_t>(unknowns.n), 0);
  m_collision_group_of.assign(static_cast<std::size_t>(unknowns.n), -1);
  m_joint_group_count = 0;
}

// Union-find over the particles of the constraints; a root with one constraint is a single, the others
// become groups. The particle arrays are reset to -1 / 0 afterwards for the next step (no allocation
// while every constraint is alone).
namespace {
// Below this fraction of a collision group's largest singular value, a direction of its rows is
// driven to its target only up to twice the targets' size (prepare_collisions).
constexpr double kWeakRow = 1e-2;
// A joint group's rows hold each direction of its bodies' twists with a strength, its singular value;
// held as an equality, a direction of strength sigma carries multipliers of (force along it) / sigma.
// In a group with contacts, directions below 1e-5 of the strongest are left free: they are
// round-off, or contact normals a hair off true, not a constraint. Curtain rings bunched on their
// rod, their contact normals with the rod and with each other all but perpendicular to it, had their
// common slide along the rod held at 2e-7 to 2e-6 of the rows' strength: at one 1/60 s tick three of
// them stood still while the handle's spring pulled 540 N (stretched 1.08 m). A pot standing on two
// contact points had its tilt about the line through them held at 1e-9 to 3e-8, by round-off alone.
// Groups of joint rows alone keep 1e-10 (kNullJointDirection): a twist mixes m/s and rad/s, so a
// hinge whose pivot is L from its body's centre holds the swing off its axis at about 1/L^2 of its
// strongest direction, below 1e-5 for L above 3 m in a world measured in centimetres.
constexpr double kNullJointDirection = 1e-10;
constexpr double kWeakJointDirection = 1e-5;
}  // namespace

void Constraints::prepare_collisions() {
  m_single.clear();
  m_collision_groups.clear();
  std::vector<Index>& root = m_collision_root;
  auto find = [&](Index i) {
    while (root[i] != i) i = root[i] = root[root[i]];
    return i;
  };
  for (const CollisionConstraint& c : m_collisions)
    for (int a = 0; a < c.size; ++a) {
      const Index i = c.particles[static_cast<std::size_t>(a)];
      if (root[i] < 0) root[i] = i;
      const Index r0 = find(c.particles[0]), r = find(i);
      if (r != r0) root[std::max(r, r0)] = std::min(r, r0);
    }
  for (const CollisionConstraint& c : m_collisions) ++m_collision_count[find(c.particles[0])];
  for (std::size_t k = 0; k < m_collisions.size(); ++k) {
    const Index r = find(m_collisions[k].particles[0]);
    if (m_collision_count[r] == 1) {
      m_single.push_back(k);
      continue;
    }
    if (m_collision_group_of[r] < 0) {
      m_collision_group_of[r] = static_cast<Index>(m_collision_groups.size());
      m_collision_groups.emplace_back();
    }
  }
  if (!m_collision_groups.empty()) {
    Index largest = 0, largest_rank = 0;
    // Rows J (one per constraint, w_a n^T on each stencil particle's 3 columns) and targets per group.
    std::vector<std::vector<std::size_t>> rows(m_collision_groups.size());
    for (std::size_t k = 0; k < m_collisions.size(); ++k) {
      const Index g = m_collision_group_of[find(m_collisions[k].particles[0])];
      if (g < 0) continue;
      rows[static_cast<std::size_t>(g)].push_back(k);
      for (int a = 0; a < m_collisions[k].size; ++a)
        m_collision_groups[static_cast<std::size_t>(g)].particles.push_back(
            m_collisions[k].particles[static_cast<std::size_t>(a)]);
    }
    for (std::size_t g = 0; g < m_collision_groups.size(); ++g) {
      CollisionGroup& group = m_collision_groups[g];
      std::sort(group.particles.begin(), group.particles.end());
      group.particles.erase(std::unique(group.particles.begin(), group.particles.end()), group.particles.end());
      const Index k = static_cast<Index>(group.particles.size()), m = static_cast<Index>(rows[g].size());
      Eigen::MatrixXd J = Eigen::MatrixXd::Zero(m, 3 * k);
      VectorXd t(m);
      for (Index i = 0; i < m; ++i) {
        const CollisionConstraint& c = m_collisions[rows[g][static_cast<std::size_t>(i)]];
        t[i] = c.normal_velocity;
        for (int a = 0; a < c.size; ++a) {
          const auto slot = std::lower_bound(group.particles.begin(), group.particles.end(),
                                             c.particles[static_cast<std::size_t>(a)]) -
                            group.particles.begin();
          J.row(i).segment<3>(3 * slot) += c.weights[static_cast<std::size_t>(a)] * c.normal.transpose();
        }
      }
      const Eigen::JacobiSVD<Eigen::MatrixXd> svd(J, Eigen::ComputeThinU | Eigen::ComputeThinV);
      const VectorXd& sigma = svd.singularValues();
      Index rank = 0;
      while (rank < sigma.size() && sigma[rank] > 1e-10 * sigma[0]) ++rank;
      group.basis = svd.matrixV().leftCols(rank);
      // Nearly dependent rows (a node's own contact and an edge contact that holds it with most of
      // its weight, their normals alike) meet slightly different targets only by velocities of
      // (their difference) / sigma, hundreds of metres a second. Along a direction the rows hold less
      // than a hundredth as firmly as their strongest, the least-norm velocity is kept only up to
      // twice the targets' size (consistent targets, such as a surface moving along its normal, give
      // about that), and that direction carries no multiplier (its reaction is not resolved).
      VectorXd inverse = VectorXd::Zero(rank);
      for (Index i = 0; i < rank; ++i)
        if (sigma[i] >= kWeakRow * sigma[0]) inverse[i] = 1.0 / sigma[i];
      VectorXd coefficients = svd.matrixU().leftCols(rank).transpose() * t;
      const double cap = 2.0 * t.norm();
      for (Index i = 0; i < rank; ++i)
        coefficients[i] =
            inverse[i] > 0.0 ? coefficients[i] * inverse[i] : std::clamp(coefficients[i] / sigma[i], -cap, cap);
      group.particular = group.basis * coefficients;
      group.rows = rows[g];
      group.multipliers = svd.matrixU().leftCols(rank) * inverse.asDiagonal();
      largest = std::max(largest, 3 * k);
      largest_rank = std::max(largest_rank, rank);
    }
    m_group_scratch.resize(largest);
    m_group_coefficients.resize(largest_rank);
  }
  for (const CollisionConstraint& c : m_collisions)
    for (int a = 0; a < c.size; ++a) {
      const Index i = c.particles[static_cast<std::size_t>(a)];
      m_collision_count[i] = 0;
      m_collision_group_of[i] = -1;
      root[i] = -1;
    }
}

void Constraints::project_collision_groups(GeneralizedVector& u, bool impose_targets) const {
  for (const CollisionGroup& g : m_collision_groups) {
    const Index k = static_cast<Index>(g.particles.size());
    // Scratch sized by prepare_collisions: no allocation inside the solves' iterations.
    auto u_g = m_group_scratch.head(3 * k);
    auto coefficients = m_group_coefficients.head(g.basis.cols());
    for (Index j = 0; j < k; ++j) u_g.segment<3>(3 * j) = u.particles.col(g.particles[static_cast<std::size_t>(j)]);
    coefficients.noalias() = g.basis.transpose() * u_g;
    u_g.noalias() -= g.basis * coefficients;
    if (impose_targets) u_g += g.particular;
    for (Index j = 0; j < k; ++j) u.particles.col(g.particles[static_cast<std::size_t>(j)]) = u_g.segment<3>(3 * j);
  }
}

void Constraints::collision_multipliers(const GeneralizedVector& r, VectorXd& lambda) const {
  lambda.setZero(static_cast<Index>(m_collisions.size()));
  for (std::size_t k : m_single) {
    const CollisionConstraint& c = m_collisions[k];
    double jr = 0.0, jj = 0.0;
    for (int a = 0; a < c.size; ++a) {
      const double w = c.weights[static_cast<std::size_t>(a)];
      jr += w * c.normal.dot(r.particles.col(c.particles[static_cast<std::size_t>(a)]));
      jj += w * w;
    }
    if (jj > 0.0) lambda[static_cast<Index>(k)] = jr / jj;
  }
  // J = U Sigma V^T on the group's rank: J^T lambda = r gives lambda = U Sigma^-1 V^T r.
  for (const CollisionGroup& g : m_collision_groups) {
    const Index k = static_cast<Index>(g.particles.size());
    VectorXd r_g(3 * k);
    for (Index j = 0; j < k; ++j) r_g.segment<3>(3 * j) = r.particles.col(g.particles[static_cast<std::size_t>(j)]);
    const VectorXd l = g.multipliers * (g.basis.transpose() * r_g);
    for (std::size_t i = 0; i < g.rows.size(); ++i) lambda[static_cast<Index>(g.rows[i])] = l[static_cast<Index>(i)];
  }
}

void Constraints::impose_collisions(GeneralizedVector& u) const {
  for (std::size_t k : m_single) shift(m_collisions[k], u, m_collisions[k].normal_velocity);
  project_collision_groups(u, true);
}

void Constraints::project(GeneralizedVector& u) const {
  const VectorXd& mask = m_unknowns->dynamic_mask;
  parallel::for_light_ranges(m_unknowns->n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i)
      if (mask[i] == 0.0) u.particles.col(i).setZero();
  });
  project_constraints(u);
}

void Constraints::project_constraints(GeneralizedVector& u) const {
  for (Index b = 0; b < m_unknowns->r; ++b)
    if (m_hold_bodies || !m_unknowns->dynamic_body[b]) u.rigid.col(b).setZero();
  for (std::size_t k : m_single) shift(m_collisions[k], u, 0.0);
  project_collision_groups(u, false);
  project_joint_groups(u, false);
}

// The stencil's row J = [w_1 n^T ... w_k n^T] (n a unit vector): J J^T = sum w^2, and
// u <- u + J^T (J J^T)^-1 (target - J u) sets J u to the target, moving u the least. With target 0
// it is the orthogonal projection onto the row's null space, symmetric as projected CG needs. One
// particle of weight 1 (a node against a surface) takes the short form.
void Constraints::shift(const CollisionConstraint& c, GeneralizedVector& u, double target) {
  if (c.size == 1 && c.weights[0] == 1.0) {
    auto col = u.particles.col(c.particles[0]);
    if (target == 0.0) {
      col -= c.normal.dot(col) * c.normal;
    } else {
      col += (target - c.normal.dot(col)) * c.normal;
    }
    return;
  }
  double ju = 0.0, jj = 0.0;
  for (int a = 0; a < c.size; ++a) {
    const double w = c.weights[static_cast<std::size_t>(a)];
    ju += w * c.normal.dot(u.particles.col(c.particles[static_cast<std::size_t>(a)]));
    jj += w * w;
  }
  if (!(jj > 0.0)) return;
  const double lambda = (target - ju) / jj;
  for (int a = 0; a < c.size; ++a)
    u.particles.col(c.particles[static_cast<std::size_t>(a)]) +=
        (c.weights[static_cast<std::size_t>(a)] * lambda) * c.normal;
}

// Each joint group's twists u_g -> u_g - Q Q^T u_g (the rows' null space), plus the particular
// solution when the rows' targets are imposed; in scratch kept between steps (no allocation).
void Constraints::project_joint_groups(GeneralizedVector& u, bool impose_targets) const {
  if (m_hold_bodies) {
    u.rigid.setZero();
    return;
  }
  for (std::size_t gi = 0; gi < m_joint_group_count; ++gi) {
    const JointGroup& g = m_joint_groups[gi];
    const Index k = static_cast<Index>(g.bodies.size());
    auto u_g = m_joint_scratch.head(6 * k);
    auto coefficients = m_joint_coefficients.head(g.basis.cols());
    for (Index j = 0; j < k; ++j) u_g.segment<6>(6 * j) = u.rigid.col(g.bodies[j]);
    coefficients.noalias() = g.basis.transpose() * u_g;
    u_g.noalias() -= g.basis * coefficients;
    if (impose_targets) u_g += g.particular;
    for (Index j = 0; j < k; ++j) u.rigid.col(g.bodies[j]) = u_g.segment<6>(6 * j);
  }
}

// Contact rows (JointRow::unilateral) bound the twists from one side, J t >= b, and the step holds
// the ones that push as equalities. Their targets need not agree: a ring resting on a rod, four points
// of its polygon in the rod, had rows of rank two or three with push-out targets of 0.07 and 0.33 m/s,
// whose least-norm twists on all four were 1e7 m/s. Targets that agree (the least-norm twists on the
// rows' well-conditioned span, singular values above 1e-3 of the largest, meet them) are kept; otherwise the group
// finds the least-norm twists t* with its joint rows met and its contacts at or above their targets (min |t|^2 / 2, a
// small quadratic programme, by Gauss-Seidel on its dual: t = J^T lambda, lambda >= 0 on the contacts, at most
// kQpPasses passes), and holds every row at J t*: targets that agree by construction, each contact at or above its own.
void Constraints::agree_contact_targets(JointGroup& group, const std::vector<JointRow>& rows,
                                        const std::vector<Index>* tangent_of) {
  const Index m = group.J.rows();
  const VectorXd& sigma = group.svd.singularValues();
  Index rank = 0;
  while (rank < sigma.size() && sigma[rank] > 1e-3 * sigma[0]) ++rank;
  VectorXd c = group.svd.matrixU().leftCols(rank).transpose() * group.t;
  c.array() /= sigma.head(rank).array();
  const VectorXd least = group.svd.matrixV().leftCols(rank) * c;
  const double scale = std::max(1.0, group.t.cwiseAbs().maxCoeff());
  if ((group.J * least - group.t).cwiseAbs().maxCoeff() <= 1e-9 * scale) return;
  // A sticking row's multiplier stays within mu times its normal's (Coulomb's pyramid): held rigidly,
  // sticking can forbid what pushing out needs, and the programme has no solution.
  m_local_row.assign(rows.size(), -1);
  for (Index i = 0; i < m; ++i) m_local_row[static_cast<std::size_t>(group.rows[i])] = i;
  auto normal_of = [&](Index i) -> Index {
    if (!tangent_of) return -1;
    const Index n = (*tangent_of)[static_cast<std::size_t>(group.rows[i])];
    return n < 0 ? -1 : m_local_row[static_cast<std::size_t>(n)];
  };
  VectorXd lambda = VectorXd::Zero(m), t = VectorXd::Zero(group.J.cols());
  const VectorXd norm2 = group.J.rowwise().squaredNorm();
  for (int pass = 0; pass < kQpPasses; ++pass) {
    double change = 0.0;
    for (Index i = 0; i < m; ++i) {
      if (!(norm2[i] > 0.0)) continue;
      double next = lambda[i] + (group.t[i] - group.J.row(i).dot(t)) / norm2[i];
      if (rows[group.rows[i]].unilateral) next = std::max(next, 0.0);
      if (const Index n = normal_of(i); n >= 0) {
        const double bound = rows[group.rows[n]].friction * lambda[n];
        next = std::clamp(next, -bound, bound);
      }
      const double d = next - lambda[i];
      if (d == 0.0) continue;
      lambda[i] = next;
      t.noalias() += d * group.J.row(i).transpose();
      change = std::max(change, std::abs(d) * std::sqrt(norm2[i]));
    }
    if (change <= 1e-14 * std::max(1.0, t.norm())) break;
  }
  group.t.noalias() = group.J * t;
}

// J = U S V^T (the group's thin SVD), so J^T lambda = r gives lambda = U S^-1 V^T r over the rank.
void Constraints::joint_multipliers(const GeneralizedVector& r, std::size_t rows, VectorXd& lambda) const {
  lambda.setZero(static_cast<Index>(rows));
  for (std::size_t gi = 0; gi < m_joint_group_count; ++gi) {
    const JointGroup& g = m_joint_groups[gi];
    const Index k = static_cast<Index>(g.bodies.size()), rank = g.basis.cols();
    if (rank == 0) continue;
    VectorXd r_g(6 * k);
    for (Index j = 0; j < k; ++j) r_g.segment<6>(6 * j) = r.rigid.col(g.bodies[j]);
    VectorXd c = g.basis.transpose() * r_g;
    c.array() /= g.svd.singularValues().head(rank).array();
    const VectorXd l = g.svd.matrixU().leftCols(rank) * c;
    for (std::size_t i = 0; i < g.rows.size(); ++i) lambda[g.rows[i]] = l[static_cast<Index>(i)];
  }
}

// Joint rows J u = t on the dynamic bodies (kinematic bodies' twists moved to t). The CG then works
// in the rows' null space, like the collision normals: P = I - Q Q^T with Q an orthonormal basis of
// the rows (redundant rows, as two joints on one axis give, drop out by rank), and the joints'
// reactions are the multipliers J^T lambda the projection removes.
void Constraints::prepare_joints(const std::vector<JointRow>& rows, const RigidBodyParticles& bodies,
                                 const std::vector<Index>* tangent_of) {
  m_joint_group_count = 0;
  if (rows.empty()) return;
  const Index body_count = m_unknowns->r;
  const auto& dynamic_body = m_unknowns->dynamic_body;
  // Groups of dynamic bodies linked by rows (union-find), in the order of their first row.
  std::vector<Index>& root = m_joint_root;
  root.resize(static_cast<std::size_t>(body_count));
  for (Index b = 0; b < body_count; ++b) root[b] = b;
  auto find = [&](Index b) {
    while (root[b] != b) b = root[b] = root[root[b]];
    return b;
  };
  auto dynamic = [&](Index b) { return b >= 0 && dynamic_body[b]; };
  for (const JointRow& row : rows)
    if (dynamic(row.body_a) && dynamic(row.body_b)) {
      const Index a = find(row.body_a), b = find(row.body_b);
      if (a != b) root[std::max(a, b)] = std::min(a, b);
    }
  std::vector<Index>& group_of = m_joint_group_of;
  group_of.assign(static_cast<std::size_t>(body_count), -1);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const JointRow& row = rows[i];
    const Index body = dynamic(row.body_a) ? row.body_a : dynamic(row.body_b) ? row.body_b : -1;
    if (body < 0) continue;  // between prescribed bodies: nothing to solve
    const Index r = find(body);
    if (group_of[r] < 0) {
      group_of[r] = static_cast<Index>(m_joint_group_count++);
      if (m_joint_groups.size() < m_joint_group_count) m_joint_groups.emplace_back();
      m_joint_groups[m_joint_group_count - 1].rows.clear();
      m_joint_groups[m_joint_group_count - 1].bodies.clear();
    }
    m_joint_groups[group_of[r]].rows.push_back(static_cast<Index>(i));
  }
  for (Index b = 0; b < body_count; ++b)
    if (dynamic_body[b] && group_of[find(b)] >= 0) m_joint_groups[group_of[find(b)]].bodies.push_back(b);
  Index largest = 0, largest_rank = 0;
  for (std::size_t g = 0; g < m_joint_group_count; ++g) {
    JointGroup& group = m_joint_groups[g];
    const Index k = static_cast<Index>(group.bodies.size());
    largest = std::max(largest, k);
    auto slot = [&](Index b) {
      return static_cast<Index>(std::lower_bound(group.bodies.begin(), group.bodies.end(), b) - group.bodies.begin());
    };
    const Index m = static_cast<Index>(group.rows.size());
    group.J.setZero(m, 6 * k);
    group.t.resize(m);
    for (Index i = 0; i < m; ++i) {
      const JointRow& row = rows[group.rows[i]];
      group.t[i] = row.target;
      for (const auto& [body, j] : {std::pair{row.body_a, row.j_a}, std::pair{row.body_b, row.j_b}}) {
        if (body < 0) continue;
        if (dynamic_body[body]) {
          group.J.row(i).segment<6>(6 * slot(body)) += j.transpose();
        } else {
          group.t[i] -= j.head<3>().dot(bodies.v.col(body)) + j.tail<3>().dot(bodies.w.col(body));
        }
      }
    }
    // The SVD keeps its work space between steps (Eigen reallocates only when the shape changes). It
    // depends on J alone: agree_contact_targets reads it and changes only the targets.
    group.svd.compute(group.J, Eigen::ComputeThinU | Eigen::ComputeThinV);
    if (std::any_of(group.rows.begin(), group.rows.end(), [&](Index r) { return rows[r].unilateral; }))
      agree_contact_targets(group, rows, tangent_of);
    const VectorXd& sigma = group.svd.singularValues();
    Index rank = 0;
    // Directions the rows hold less than this as firmly as their strongest are left free (see
    // kWeakJointDirection).
    const bool contacts =
        std::any_of(group.rows.begin(), group.rows.end(), [&](Index r) { return rows[r].unilateral; });
    const double weakest = contacts ? kWeakJointDirection : kNullJointDirection;
    while (rank < sigma.size() && sigma[rank] > weakest * sigma[0]) ++rank;
    largest_rank = std::max(largest_rank, rank);
    group.basis = group.svd.matrixV().leftCols(rank);
    group.coefficients.resize(rank);
    group.coefficients.noalias() = group.svd.matrixU().leftCols(rank).transpose() * group.t;
    group.coefficients.array() /= sigma.head(rank).array();
    group.particular.resize(6 * k);
    group.particular.noalias() = group.basis * group.coefficients;
  }
  m_joint_scratch.resize(6 * largest);
  m_joint_coefficients.resize(largest_rank);
}

}  // namespace sinew
