// What the Bullet scenes share: a Bullet world that owns its objects, and the scene base class (a
// plain Bullet world, set up as an application would, with sinew's coupling attached). The scenes
// themselves are one file each (curtain.cpp, net.cpp, plates.cpp, hello.cpp), registered in the
// scene library (scene.hpp).
#pragma once

#include "cloth.hpp"
#include "scene.hpp"
#include "sinew/bullet/convert.hpp"
#include "sinew/bullet/coupling.hpp"

#include <btBulletDynamicsCommon.h>

#include <memory>
#include <string>
#include <vector>

namespace sinew::scenes {

using bullet::to_bullet;
using bullet::to_eigen;
inline btTransform at(const btVector3& origin, const btQuaternion& rotation = btQuaternion::getIdentity()) {
  return btTransform(rotation, origin);
}

/// The coupling's defaults with CouplingSettings::self_collisions on (contact between the
/// deformables' surfaces).
inline bullet::CouplingSettings with_self_collisions() {
  bullet::CouplingSettings s;
  s.self_collisions = true;
  return s;
}

/// The registry entry of a Bullet scene class with a default constructor: `info` gives its name,
/// description and gallery frame; its kind and factory follow from the class.
template <class SceneType>
SceneInfo bullet_scene(SceneInfo info) {
  info.kind = SceneKind::bullet;
  info.make = construct<SceneType>;
  return info;
}

/// A Bullet world that owns its shapes, motion states, bodies and constraints.
class BulletWorld {
 public:
  explicit BulletWorld(const btVector3& gravity);
  ~BulletWorld();
  BulletWorld(const BulletWorld&) = delete;
  BulletWorld& operator=(const BulletWorld&) = delete;

  btDiscreteDynamicsWorld& world() { return *m_world; }
  /// Takes ownership of a shape and returns it.
  btCollisionShape* keep(std::unique_ptr<btCollisionShape> shape);
  /// A rigid body; mass 0 makes it static. `inertia` zero means "from the shape".
  btRigidBody* add_body(btCollisionShape* shape, double mass, const btTransform& at,
                        btVector3 inertia = btVector3(0, 0, 0), int group = btBroadphaseProxy::DefaultFilter,
                        int mask = btBroadphaseProxy::AllFilter);
  btTypedConstraint* add_constraint(std::unique_ptr<btTypedConstraint> constraint);
  const std::vector<btRigidBody*>& bodies() const { return m_body_list; }
  /// Kinetic plus gravitational energy of the dynamic bodies.
  double rigid_energy() const;

 private:
  std::unique_ptr<btDefaultCollisionConfiguration> m_configuration;
  std::unique_ptr<btCollisionDispatcher> m_dispatcher;
  std::unique_ptr<btDbvtBroadphase> m_broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> m_solver;
  std::unique_ptr<btDiscreteDynamicsWorld> m_world;
  std::vector<std::unique_ptr<btCollisionShape>> m_shapes;
  std::vector<std::unique_ptr<btDefaultMotionState>> m_states;
  std::vector<std::unique_ptr<btRigidBody>> m_bodies;
  std::vector<btRigidBody*> m_body_list;
  std::vector<std::unique_ptr<btTypedConstraint>> m_constraints;
};

/// One demo scene: a Bullet world, the coupling, and what the demo reports about it.
class BulletScene : public Scene {
 public:
  explicit BulletScene(const btVector3& gravity, const bullet::CouplingSettings& settings = {});
  /// Called before each frame with the time at its start (animates kinematic bodies).
  virtual void before_frame(double time) { (void)time; }
  /// Advances one frame: world.stepSimulation(frame_dt, substeps, frame_dt / substeps) (substeps:
  /// Bullet internal ticks; sinew steps once per tick, substepping inside as its stability needs).
  void advance(double frame_dt, int substeps) override;
  SceneMeasures measure() override;
  /// sinew's state hash mixed with every body's transform and velocities.
  std::uint64_t state_hash() override;

  BulletWorld& bullet() { return m_world; }
  bullet::Coupling& coupling() { return *m_coupling; }
  System& system() { return m_coupling->system(); }
  System* deformable_system() override { return &m_coupling->system(); }
  const StepStats* total_stats() const override { return &m_coupling->total_stats(); }
  double time() const { return m_time; }

  /// Largest distance of a hard-bound point from where its Bullet body's frame puts it [m].
  double hard_binding_drift();
  /// Deformable kinetic and potential energy plus the rigid bodies' [J].
  double total_energy();

  /// A triangle surface drawn for the scene: positions 3 x V and triangles indexing them.
  struct Surface {
    std::string name;
    Vectors3 vertices;
    std::vector<std::array<Index, 3>> triangles;
  };
  /// The deformable surfaces (cloth, volume skins) at the current state and every rigid body's
  /// collision shape, triangulated at its current pose (what --out exports each frame).
  std::vector<Surface> surfaces();

 protected:
  BulletWorld m_world;
  std::unique_ptr<bullet::Coupling> m_coupling;
  /// Scenes register the triangles of each deformable surface (particle indices) for drawing.
  void add_surface(std::string name, std::vector<std::array<Index, 3>> triangles) {
    m_surface_names.push_back(std::move(name));
    m_surface_triangles.push_back(std::move(triangles));
  }
  std::vector<std::string> m_surface_names;
  std::vector<std::vector<std::array<Index, 3>>> m_surface_triangles;
  double m_time = 0.0;
};

/// The registered scenes of kind SceneKind::bullet, in registration order.
std::vector<std::string> bullet_scene_names();
/// The registered Bullet scene called `name`; throws sinew::Error for an unknown name or a scene of
/// another kind.
std::unique_ptr<BulletScene> make_bullet_scene(const std::string& name);

}  // namespace sinew::scenes
