#include "sinew/collision.hpp"

#include "sinew/dofs.hpp"
#include "sinew/hard_bindings.hpp"
#include "sinew/soft_bindings.hpp"

#include <utility>

namespace sinew {

void CollisionContext::apply_body_impulse(Index body, const Vec3& point, const Vec3& j) {
  RigidBodyParticles& b = *m_bodies;
  if (body < 0 || body >= b.size())
    fail("collision impulse on rigid body ", body, ", which does not exist (there are ", b.size(), ")");
  if (!all_finite(j) || !all_finite(point)) fail("collision impulse on rigid body ", body, " is not finite");
  if (b.kinematic[body]) return;
  const Vec3 r = point - b.x.col(body);
  b.v.col(body) += j / b.mass[body];
  b.w.col(body) += b.world_inverse_inertia(body) * r.cross(j);
  m_body_L->col(body) += r.cross(j);
}

Index CollisionContext::target_of(Index particle) const {
  if (!m_soft || !particles) return -1;
  if (m_target.empty()) {
    m_target.assign(static_cast<std::size_t>(particles->size()), -1);
    for (Index k = 0; k < m_soft->size(); ++k)
      if (m_soft->coupling[static_cast<std::size_t>(k)] == SoftCoupling::synchronized)
        m_target[static_cast<std::size_t>(m_soft->particle[static_cast<std::size_t>(k)])] =
            m_soft->target[static_cast<std::size_t>(k)];
  }
  return m_target[static_cast<std::size_t>(particle)];
}

bool CollisionContext::synchronize(Index particle) {
  const Index t = target_of(particle);
  if (t < 0) return false;
  Vectors3& px = *x;
  Vectors3& pv = *v;
  if (const Index k = m_hard->linear_binding_of(t); k >= 0) {
    // A linear binding maps positions as it maps velocities: x_t = sum_i w_i x_i.
    px.col(t) = m_hard->linear().point_velocity(k, px, *bodies);
    pv.col(t) = m_hard->linear().point_velocity(k, pv, *bodies);
  }
  px.col(particle) = px.col(t);
  pv.col(particle) = pv.col(t);
  return true;
}

void CollisionContext::push_drift(Index particle) {
  const Index t = target_of(particle);
  if (t < 0) return;
  Vectors3& px = *x;
  Vectors3& pv = *v;
  const Vec3 dx = px.col(particle) - px.col(t), dv = pv.col(particle) - pv.col(t);
  if (dx.isZero(0.0) && dv.isZero(0.0)) return;
  m_hard->push_drift(t, dx, dv, *m_particles, *m_bodies, *m_effective_mass, *m_body_L);
  synchronize(particle);
}

bool CollisionContext::target_stencil(Index particle, CollisionConstraint& c) const {
  const Index t = target_of(particle);
  if (t < 0) return false;
  const Index k = m_hard->linear_binding_of(t);
  if (k < 0) return false;
  const auto parents = m_hard->linear().parents(k);
  const auto weights = m_hard->linear().weights(k);
  if (parents.size() > 4) return false;
  c.size = 0;
  for (std::size_t j = 0; j < parents.size(); ++j) {
    if (!is_dynamic(particles->kind[parents[j]])) return false;
    if (weights[j] == 0.0) continue;
    c.particles[static_cast<std::size_t>(c.size)] = parents[j];
    c.weights[static_cast<std::size_t>(c.size)] = weights[j];
    ++c.size;
  }
  return c.size > 0;
}

namespace {
class FunctionSource final : public CollisionSource {
 public:
  FunctionSource(std::string name, std::function<void(CollisionContext&)> process)
      : m_name(std::move(name)), m_process(std::move(process)) {}
  std::string_view name() const override { return m_name; }
  void process(CollisionContext& context) override { m_process(context); }

 private:
  std::string m_name;
  std::function<void(CollisionContext&)> m_process;
};
}  // namespace

std::unique_ptr<CollisionSource> make_collision_source(std::string name,
                                                       std::function<void(CollisionContext&)> process) {
  if (!process) fail("collision source '", name, "': no function");
  return std::make_unique<FunctionSource>(std::move(name), std::move(process));
}

}  // namespace sinew
