#include "constraints.hpp"

#include "sinew/parallel.hpp"

#include <algorithm>
#include <utility>

namespace sinew {

void Constraints::reset(const Unknowns& unknowns) {
  m_unknowns = &unknowns;
  m_collisions.clear();
  m_collisions.reserve(static_cast<std::size_t>(unknowns.n));
  m_joint_group_count = 0;
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
    if (!m_unknowns->dynamic_body[b]) u.rigid.col(b).setZero();
  for (const CollisionConstraint& c : m_collisions) {
    auto col = u.particles.col(c.particle);
    col -= c.normal.dot(col) * c.normal;
  }
  project_joint_groups(u, false);
}

// Each joint group's twists u_g -> u_g - Q Q^T u_g (the rows' null space), plus the particular
// solution when the rows' targets are imposed; in scratch kept between steps (no allocation).
void Constraints::project_joint_groups(GeneralizedVector& u, bool impose_targets) const {
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

// Joint rows J u = t on the dynamic bodies (kinematic bodies' twists moved to t). The CG then works
// in the rows' null space, like the collision normals: P = I - Q Q^T with Q an orthonormal basis of
// the rows (redundant rows, as two joints on one axis give, drop out by rank), and the joints'
// reactions are the multipliers J^T lambda the projection removes.
void Constraints::prepare_joints(const std::vector<JointRow>& rows, const RigidBodyParticles& bodies) {
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
    // The SVD keeps its work space between steps (Eigen reallocates only when the shape changes).
    group.svd.compute(group.J, Eigen::ComputeThinU | Eigen::ComputeThinV);
    const VectorXd& sigma = group.svd.singularValues();
    Index rank = 0;
    while (rank < sigma.size() && sigma[rank] > 1e-10 * sigma[0]) ++rank;
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
