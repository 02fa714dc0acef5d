#include "bullet_scenes.hpp"

#include "sinew/embedding.hpp"
#include "sinew/forces/dihedral_bending.hpp"
#include "sinew/forces/edge_springs.hpp"
#include "sinew/forces/triangle_membrane.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace sinew::scenes {
namespace {

// Figure 6 (section 2.2): a ribbon embedded in a point cloud. Three ribbons (80 x 10 cm, 33 x 5
// nodes, 50 g; membrane mu = lambda = 200 N/m, dihedral bending 0.3 N m) are clamped over their first
// 5 cm to a static Bullet bar and droop under gravity from flat:
//   reference  the ribbon alone, its own particles carrying its mass, membrane and bending forces;
//   meshfree   a point cloud in its plane (17 x 3 points, 5 cm apart, jittered by up to 8 mm) carries
//              the mass, held together by springs from each point to its kNeighbours nearest (a plain
//              nearest-neighbour meshfree discretisation); the ribbon's vertices are hard-bound to
//              their kNeighbours nearest points (moving-least-squares weights, point_cloud_weights)
//              and only follow;
//   embedded   the same cloud and binding, but the forces are the ribbon's own (its membrane and
//              bending on its massless vertices), mapped to the cloud through W^T; the cloud has none.
// The ribbon's distortion (its triangles' RMS Green strain) and its tip's sag are measured against the
// reference: the embedded ribbon resists the deformation it is built to resist; the springs' cloud
// cannot see the ribbon's bending (a sheet of springs has none), and strains the ribbon it carries.
class Ribbon final : public BulletScene {
 public:
  Ribbon() : BulletScene(btVector3(0, -9.81, 0)) {
    btCollisionShape* bar = m_world.keep(std::make_unique<btBoxShape>(btVector3(0.02f, 0.03f, 0.7f)));
    m_bar = m_world.add_body(bar, 0.0, at(btVector3(-0.02f, btScalar(kHeight), 0)));
    const char* names[3] = {"reference (ribbon alone)", "meshfree cloud", "ribbon forces on the cloud"};
    for (int r = 0; r < 3; ++r) {
      Strip& strip = m_strips[static_cast<std::size_t>(r)];
      strip.z = (r - 1) * kApart;
      add_strip(strip, r);
      add_surface(names[r], strip.triangles);
    }
  }

  void advance(double frame_dt, int substeps) override {
    BulletScene::advance(frame_dt, substeps);
    for (Strip& strip : m_strips) strip.worst = std::max(strip.worst, distortion(strip));
  }

  std::string json_fields() override {
    std::string text;
    const char* names[3] = {"reference", "meshfree", "embedded"};
    for (std::size_t r = 0; r < m_strips.size(); ++r) {
      const Strip& strip = m_strips[r];
      char part[256];
      std::snprintf(part, sizeof part,
                    "\"%s\": {\"cloud_points\": %zu, \"distortion\": %.4g, \"distortion_max_over_time\": %.4g, "
                    "\"tip_sag\": %.4f}, ",
                    names[r], strip.cloud.size(), distortion(strip), strip.worst, tip_sag(strip));
      text += part;
    }
    return text;
  }

  static constexpr double kLength = 0.8, kWidth = 0.1, kMass = 0.05, kHeight = 1.0, kApart = 0.3, kMu = 200.0,
                          kBending = 0.3, kCloudSpacing = 0.05, kJitter = 0.008, kSpring = 2000.0, kClamp = 1e4,
                          kClampLength = 0.05, kMembraneDamping = 0.01, kBendingDamping = 0.05, kSpringDamping = 0.5;
  static constexpr int kNx = 33, kNz = 5, kNeighbours = 8;

 private:
  struct Strip {
    double z = 0.0, worst = 0.0;
    std::vector<Index> nodes;  // the ribbon's vertices, kNx x kNz, i fastest
    std::vector<Index> cloud;  // the cloud's particles (none for the reference)
    std::vector<std::array<Index, 3>> triangles;
    Vectors3 rest;  // the ribbon's vertices at rest
  };

  // The ribbon's vertices at rest, flat at kHeight, along x from the bar, across z about strip.z.
  static Vectors3 ribbon_vertices(double z) {
    Vectors3 x(3, kNx * kNz);
    for (int j = 0; j < kNz; ++j)
      for (int i = 0; i < kNx; ++i)
        x.col(j * kNx + i) = Vec3(kLength * i / (kNx - 1), kHeight, z + kWidth * (double(j) / (kNz - 1) - 0.5));
    return x;
  }

  static std::vector<std::array<Index, 3>> ribbon_triangles() { return grid_triangles(kNx, kNz); }

  // Points in the ribbon's plane, kCloudSpacing apart along it, three across, jittered by up to
  // kJitter in the plane and half that out of it (a fixed sequence: every run the same cloud).
  static Vectors3 cloud_points(double z) {
    std::vector<Vec3> points;
    std::uint32_t state = 12345u;
    auto jitter = [&state] {
      state = state * 1664525u + 1013904223u;  // a linear congruential sequence
      return kJitter * (2.0 * (state >> 8) / double(1u << 24) - 1.0);
    };
    const int along = static_cast<int>(std::lround(kLength / kCloudSpacing));
    for (int i = 0; i <= along; ++i)
      for (const double across : {-0.5, 0.0, 0.5}) {
        const Vec3 p(kCloudSpacing * i, kHeight, z + kWidth * across);
        points.push_back(p + Vec3(jitter(), 0.5 * jitter(), jitter()));
      }
    Vectors3 x(3, static_cast<Index>(points.size()));
    for (std::size_t k = 0; k < points.size(); ++k) x.col(static_cast<Index>(k)) = points[k];
    return x;
  }

  void add_strip(Strip& strip, int kind) {
    strip.rest = ribbon_vertices(strip.z);
    const auto local = ribbon_triangles();
    const std::uint32_t none = 0;
    if (kind == 0) {
      ClothMaterial material;
      material.mass = kMass;
      material.stretch_stiffness = 0.0;
      material.membrane_mu = kMu;
      material.membrane_lambda = kMu;
      material.membrane_damping = kMembraneDamping;
      material.bending_stiffness = kBending;
      material.bending_damping = kBendingDamping;
      material.bending_implicit = true;
      strip.nodes = add_cloth_mesh(system(), strip.rest, local, material);
      for (const Index i : strip.nodes) system().set_collision_filter(i, kDefaultCollisionGroup, none);
      // The first kClampLength of it (a single column would be a hinge).
      for (int j = 0; j < kNz; ++j)
        for (int i = 0; i < kNx; ++i)
          if (strip.rest(0, j * kNx + i) < kClampLength + 1e-9)
            clamp(strip.nodes[static_cast<std::size_t>(j * kNx + i)]);
    } else {
      // The cloud: only the points some vertex is embedded in are kept.
      const Vectors3 cloud = cloud_points(strip.z);
      std::vector<PointCloudEmbedding> embedding;
      std::vector<Index> particle_of(static_cast<std::size_t>(cloud.cols()), -1);
      for (Index v = 0; v < strip.rest.cols(); ++v) {
        embedding.push_back(point_cloud_weights(cloud, strip.rest.col(v), kNeighbours));
        for (const Index p : embedding.back().parents) particle_of[static_cast<std::size_t>(p)] = 0;
      }
      const Index used = static_cast<Index>(std::count(particle_of.begin(), particle_of.end(), 0));
      for (Index p = 0; p < cloud.cols(); ++p) {
        if (particle_of[static_cast<std::size_t>(p)] < 0) continue;
        const Index i = system().add_particle(cloud.col(p), Vec3::Zero(), kMass / double(used));
        system().set_collision_filter(i, kDefaultCollisionGroup, none);
        particle_of[static_cast<std::size_t>(p)] = i;
        strip.cloud.push_back(i);
        if (cloud(0, p) < kClampLength + 0.5 * kCloudSpacing) clamp(i);
      }
      // The ribbon's vertices: massless, each x = W x_cloud.
      for (Index v = 0; v < strip.rest.cols(); ++v) {
        const Index i = system().add_particle(strip.rest.col(v), Vec3::Zero(), 0.0);
        system().set_collision_filter(i, kDefaultCollisionGroup, none);
        std::vector<Index> parents;
        for (const Index p : embedding[static_cast<std::size_t>(v)].parents)
          parents.push_back(particle_of[static_cast<std::size_t>(p)]);
        system().bind_linear(i, parents, embedding[static_cast<std::size_t>(v)].weights);
        strip.nodes.push_back(i);
      }
      const Vectors3& x = system().particles().x;
      if (kind == 1) {
        // Springs from each cloud point to its nearest, each pair once.
        std::vector<EdgeSprings::Edge> edges;
        for (const Index a : strip.cloud) {
          std::vector<Index> near(strip.cloud);
          std::sort(near.begin(), near.end(), [&](Index p, Index q) {
            const double dp = (x.col(p) - x.col(a)).squaredNorm(), dq = (x.col(q) - x.col(a)).squaredNorm();
            return dp < dq || (dp == dq && p < q);
          });
          for (int k = 1; k <= kNeighbours; ++k) {
            const Index b = near[static_cast<std::size_t>(k)];
            edges.push_back({std::min(a, b), std::max(a, b)});
          }
        }
        std::sort(edges.begin(), edges.end());
        edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
        system().add_force(
            std::make_unique<EdgeSprings>(std::move(edges), x, EdgeSpringsSettings{kSpring, kSpringDamping}));
      }
      std::vector<std::array<Index, 3>> triangles;
      for (const auto& t : local)
        triangles.push_back({strip.nodes[static_cast<std::size_t>(t[0])], strip.nodes[static_cast<std::size_t>(t[1])],
                             strip.nodes[static_cast<std::size_t>(t[2])]});
      if (kind == 2) {
        // The ribbon's own forces on its bound vertices; W^T takes them to the cloud.
        system().add_force(
            std::make_unique<TriangleMembrane>(triangles, x, TriangleMembraneSettings{kMu, kMu, kMembraneDamping}));
        system().add_force(std::make_unique<DihedralBending>(DihedralBending::hinges_from_triangles(triangles), x,
                                                             DihedralBendingSettings{kBending, kBendingDamping, true}));
      }
    }
    for (const auto& t : local)
      strip.triangles.push_back({strip.nodes[static_cast<std::size_t>(t[0])],
                                 strip.nodes[static_cast<std::size_t>(t[1])],
                                 strip.nodes[static_cast<std::size_t>(t[2])]});
  }

  // Ties particle i where it is to the bar.
  void clamp(Index i) {
    const Vec3 x = system().particles().x.col(i);
    coupling().attach(i, m_bar, x - Vec3(-0.02, kHeight, 0.0), kClamp);
  }

  // RMS over the ribbon's triangles of |E|, E = (F^T F - I) / 2 the Green strain against rest [-].
  double distortion(const Strip& strip) const {
    const Vectors3& x = m_coupling->system().particles().x;
    const auto local = ribbon_triangles();
    double sum = 0.0;
    for (std::size_t t = 0; t < local.size(); ++t) {
      const auto& v = local[t];
      Eigen::Matrix<double, 3, 2> ds, dm;
      ds << x.col(strip.nodes[static_cast<std::size_t>(v[1])]) - x.col(strip.nodes[static_cast<std::size_t>(v[0])]),
          x.col(strip.nodes[static_cast<std::size_t>(v[2])]) - x.col(strip.nodes[static_cast<std::size_t>(v[0])]);
      dm << strip.rest.col(v[1]) - strip.rest.col(v[0]), strip.rest.col(v[2]) - strip.rest.col(v[0]);
      // Rest in the ribbon's plane (x, z).
      Eigen::Matrix2d rest;
      rest << dm(0, 0), dm(0, 1), dm(2, 0), dm(2, 1);
      const Eigen::Matrix<double, 3, 2> F = ds * rest.inverse();
      const Eigen::Matrix2d E = 0.5 * (F.transpose() * F - Eigen::Matrix2d::Identity());
      sum += E.squaredNorm();
    }
    return std::sqrt(sum / double(local.size()));
  }

  // How far the tip's middle vertex is below the bar [m].
  double tip_sag(const Strip& strip) const {
    const Index tip = strip.nodes[static_cast<std::size_t>((kNz / 2) * kNx + kNx - 1)];
    return kHeight - m_coupling->system().particles().x(1, tip);
  }

  btRigidBody* m_bar = nullptr;
  std::array<Strip, 3> m_strips;
};

SINEW_REGISTER_SCENE({.name = "ribbon",
                      .description = "figure 6: a ribbon clamped to a Bullet bar, alone, carried by a meshfree point "
                                     "cloud, and embedded in the cloud with its own forces mapped to it",
                      .kind = SceneKind::bullet,
                      .make = [](const SceneParams&) { return std::make_unique<Ribbon>(); },
                      .gallery_frame = 180});

}  // namespace
}  // namespace sinew::scenes
