#include "sinew/collision.hpp"

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
