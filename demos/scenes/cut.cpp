#include "bullet_scenes.hpp"

#include "sinew/cutting.hpp"
#include "sinew/forces/corotated_tets.hpp"
#include "sinew/refinement.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Figure 11: cutting with duplicated, partially filled elements. A 30 cm cube, a Kuhn tet mesh of
// 4 x 4 x 4 cells of 7.5 cm, is cut by the planes x = +-5 cm and z = +-5 cm (through the cells, not
// along their faces) into nine sticks of 10 x 10 x 30 cm (cut_by_planes: each tet a plane crosses is
// copied once per stick holding part of it, that copy's fill the part, its nodes copied per stick).
// The cube stands on a pedestal 8 cm wide: only the middle stick rests on it, the other eight fall
// to the ground, tumble and come to rest. Each stick's material surface (the cube's surface clipped
// by the planes: a box) is polygonised, embedded in its stick's copies (CutTets::locate) by massless
// hard-bound targets, and carried by soft particles on binding springs (section 3.2): they alone
// meet Bullet's bodies and each other (self collisions between the sticks' surfaces); the tets'
// nodes, which lie up to a cell outside the material, meet nothing. Each surface is inset by kInset,
// so that neighbouring sticks start 2 kInset apart, beyond the self-contact thickness. The soft
// particles carry kSoftMass each (an eighth of a stick's mass over its surface): with their targets'
// effective masses, the default, they summed to fifteen times the cube's and rang after the landing,
// passing energy back into the springs. No membrane among them: the sticks meet only large bodies,
// and a membrane on particles this light held the step to 9 substeps a tick (80 ms a frame
// without it, 600 with one).
class Cut final : public BulletScene {
 public:
  Cut() : BulletScene(btVector3(0, -9.81, 0), with_self_collisions()) {
    btCollisionShape* ground = m_world.keep(std::make_unique<btStaticPlaneShape>(btVector3(0, 1, 0), 0));
    m_world.add_body(ground, 0.0, btTransform::getIdentity())->setFriction(0.8);
    btCollisionShape* pedestal = m_world.keep(
        std::make_unique<btBoxShape>(btVector3(btScalar(kPedestal), btScalar(kPedestalTop / 2), btScalar(kPedestal))));
    m_world.add_body(pedestal, 0.0, at(btVector3(0, btScalar(kPedestalTop / 2), 0)))->setFriction(0.8);

    // The soft surfaces' bottom a contact thickness above the pedestal.
    const double bottom = kPedestalTop + bullet::CouplingSettings{}.thickness - kInset;
    Vectors3 vertices;
    std::vector<std::array<Index, 4>> tets;
    kuhn_block(Vec3(-kHalf, bottom, -kHalf), kCells, kCells, kCells, 2.0 * kHalf / kCells, vertices, tets);
    const std::vector<CutPlane> planes{{Vec3(-kCut, 0, 0), Vec3::UnitX()},
                                       {Vec3(kCut, 0, 0), Vec3::UnitX()},
                                       {Vec3(0, 0, -kCut), Vec3::UnitZ()},
                                       {Vec3(0, 0, kCut), Vec3::UnitZ()}};
    m_cut = cut_by_planes(vertices, tets, {}, planes);
    m_tets_before = tets.size();
    m_vertices_before = static_cast<std::size_t>(vertices.cols());

    // What meets the bodies are soft particles on 500 N/m springs from the tets: a landing stretches
    // those springs, not a layer of the solid, so spreading step 3's moves through the tets
    // (StepSettings::spread_collisions) buys only the first frame's 0.27 mJ (see demos/README.md)
    // at twice the frame's cost (192 ms against 101).
    System& s = system();
    s.step_settings().spread_collisions = false;
    // One particle per node copy, its mass lumped from its copies' filled volumes.
    const Index first = m_first = s.particles().size();
    std::vector<double> mass(static_cast<std::size_t>(m_cut.vertices.cols()), 0.0);
    m_piece_of_node.assign(mass.size(), -1);
    for (std::size_t c = 0; c < m_cut.tets.size(); ++c)
      for (const Index v : m_cut.tets[c]) {
        mass[static_cast<std::size_t>(v)] += kDensity * m_cut.fill[c] * volume(m_cut.tets[c]) / 4.0;
        m_piece_of_node[static_cast<std::size_t>(v)] = m_cut.piece[c];
      }
    for (Index v = 0; v < m_cut.vertices.cols(); ++v) {
      const Index i = s.add_particle(m_cut.vertices.col(v), Vec3::Zero(), mass[static_cast<std::size_t>(v)]);
      s.set_collision_filter(i, kDefaultCollisionGroup, 0);  // the nodes meet nothing; the surfaces do
    }
    std::vector<std::array<Index, 4>> particle_tets = m_cut.tets;
    for (auto& t : particle_tets)
      for (Index& v : t) v += first;
    CorotatedTetsSettings material{.young_modulus = kYoung, .poisson_ratio = 0.3, .beta = kDamping};
    material.volume_fraction = m_cut.fill;
    material.implicit = true;
    s.add_force(std::make_unique<CorotatedTets>(particle_tets, s.particles().x, material));
    for (const double f : m_cut.fill) m_partial += f < 1.0 ? 1 : 0;

    // Each stick's surface: its box of material, inset, embedded in its copies, with soft particles.
    const double edges[4] = {-kHalf, -kCut, kCut, kHalf};
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        const Vec3 lo(edges[a] + kInset, bottom + kInset, edges[b] + kInset);
        const Vec3 hi(edges[a + 1] - kInset, bottom + 2.0 * kHalf - kInset, edges[b + 1] - kInset);
        const Index piece = m_cut.piece_of(0.5 * (lo + hi));
        const ClosedSurface box = box_surface(lo, hi, kSurfaceCells);
        std::vector<Index> targets;
        for (Index k = 0; k < box.vertices.cols(); ++k) {
          std::array<double, 4> w{};
          const Index copy = m_cut.locate(piece, box.vertices.col(k), w);
          std::array<Index, 4> parents = m_cut.tets[static_cast<std::size_t>(copy)];
          for (Index& v : parents) v += first;
          targets.push_back(s.add_embedded_point(parents, w));
        }
        RefinedTriangles mesh = unrefined(box.vertices, box.triangles);
        std::fill(mesh.level.begin(), mesh.level.end(), 1);  // a soft particle at every vertex
        const SoftCopy copy = add_soft_copy(s, mesh, targets, kSoftStiffness, kAllCollisionGroups, 0.0, kSoftMass);
        s.add_collision_surface(copy.skin);
        add_surface("stick " + std::to_string(3 * a + b + 1), copy.skin);
        m_soft += copy.soft.size();
        m_sticks.push_back({piece, copy.soft});
      }
    m_energy_start = m_energy_max = energy();
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    m_energy_max = std::max(m_energy_max, energy());
  }

  std::string json_fields() override {
    // Per stick: its centre of mass (the nodes' masses) and speed; on the ground when its lowest
    // soft particle is within two thicknesses of it.
    const System& s = system();
    std::vector<double> m(m_sticks.size(), 0.0);
    std::vector<Vec3> p(m_sticks.size(), Vec3::Zero());
    for (std::size_t v = 0; v < m_piece_of_node.size(); ++v) {
      const Index i = static_cast<Index>(v) + m_first;
      for (std::size_t k = 0; k < m_sticks.size(); ++k)
        if (m_sticks[k].piece == m_piece_of_node[v]) {
          m[k] += s.particles().mass[i];
          p[k] += s.particles().mass[i] * s.particles().v.col(i);
        }
    }
    double fastest = 0.0;
    int on_ground = 0, on_pedestal = 0;
    for (std::size_t k = 0; k < m_sticks.size(); ++k) {
      fastest = std::max(fastest, (p[k] / m[k]).norm());
      double lowest = kInfinity;
      for (const Index i : m_sticks[k].soft) lowest = std::min(lowest, s.particles().x(1, i));
      if (lowest < 2.0 * bullet::CouplingSettings{}.thickness) ++on_ground;
      if (std::abs(lowest - kPedestalTop) < 2.0 * bullet::CouplingSettings{}.thickness) ++on_pedestal;
    }
    char text[640];
    std::snprintf(text, sizeof text,
                  "\"pieces\": %ld, \"tets_before\": %zu, \"tet_copies\": %zu, \"partly_filled\": %d, "
                  "\"nodes_before\": %zu, \"node_copies\": %ld, \"soft_particles\": %zu, "
                  "\"sticks_on_ground\": %d, \"sticks_on_pedestal\": %d, \"fastest_stick\": %.4f, "
                  "\"energy_at_start\": %.5f, \"energy_max\": %.5f, ",
                  static_cast<long>(m_cut.pieces()), m_tets_before, m_cut.tets.size(), m_partial, m_vertices_before,
                  static_cast<long>(m_cut.vertices.cols()), m_soft, on_ground, on_pedestal, fastest, m_energy_start,
                  m_energy_max);
    return text;
  }

  static constexpr double kHalf = 0.15, kCut = 0.05, kInset = 0.004, kPedestal = 0.04, kPedestalTop = 0.4,
                          kDensity = 300.0, kYoung = 1e5, kDamping = 0.02, kSoftStiffness = 500.0, kSoftMass = 5e-4;
  static constexpr int kCells = 4, kSurfaceCells = 6;

 private:
  struct Stick {
    Index piece = -1;
    std::vector<Index> soft;
  };
  // The scene's energy with the soft particles' own: their kinetic energy and weight (they carry
  // kSoftMass each, which BulletScene::total_energy leaves out with every soft particle's).
  double energy() {
    const System& s = system();
    double e = total_energy();
    const Vec3 g = s.settings().gravity;
    for (const Stick& stick : m_sticks)
      for (const Index i : stick.soft)
        e += 0.5 * s.particles().mass[i] * s.particles().v.col(i).squaredNorm() -
             s.particles().mass[i] * g.dot(s.particles().x.col(i));
    return e;
  }
  double volume(const std::array<Index, 4>& t) const {
    const auto& x = m_cut.vertices;
    return (x.col(t[1]) - x.col(t[0])).cross(x.col(t[2]) - x.col(t[0])).dot(x.col(t[3]) - x.col(t[0])) / 6.0;
  }

  CutTets m_cut;
  Index m_first = 0;  // the first node copy's particle
  std::vector<Index> m_piece_of_node;
  std::vector<Stick> m_sticks;
  std::size_t m_tets_before = 0, m_vertices_before = 0, m_soft = 0;
  int m_partial = 0;
  double m_energy_start = 0.0, m_energy_max = -kInfinity;
};

SINEW_REGISTER_SCENE(bullet_scene<Cut>(
    {.name = "cut",
     .description = "figure 11: a cube cut into nine sticks by partly filled element copies; eight fall off a "
                    "pedestal, their soft-bound surfaces meeting the ground and each other",
     .gallery_frame = 16}));

}  // namespace
}  // namespace sinew::scenes
