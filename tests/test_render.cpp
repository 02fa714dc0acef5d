// Pictures of every demo, rendered offscreen (OSMesa): the cloth's pixels are where its projected
// bounding box says and nowhere else, the picture is not blank, and two runs give the same bytes.
#include "bullet_scenes.hpp"
#include "renderer.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <set>
#include <string>

namespace sinew {
namespace {

constexpr int kWidth = 240, kHeight = 160;

struct Rendered {
  std::vector<std::uint8_t> shaded, mask;
  std::array<double, 4> box;  // projected subject bounding box: x0, y0, x1, y1 [pixels]
  bool sheet = true;          // the subject is a cloth (else the net's rods and ball: mostly holes)
};

Rendered render_scene(const std::string& name, int frames) {
  auto scene = scenes::make_bullet_scene(name);
  for (int f = 0; f < frames; ++f) scene->advance(1.0 / 60, scene->default_substeps());
  const render::Picture picture = render::picture_of(*scene, render::Overlays{});
  const render::Camera camera = render::framing_camera(picture, double(kWidth) / kHeight);
  render::Offscreen offscreen(kWidth, kHeight);
  Rendered out;
  out.sheet = picture.has_deformables();
  render::draw(picture, camera, kWidth, kHeight, render::Mode::subject_mask);
  out.mask = offscreen.pixels();
  render::draw(picture, camera, kWidth, kHeight);
  out.shaded = offscreen.pixels();
  // The projection of the subject's vertices (the cloth; the rods and ball of the net, which has no
  // deformable), not of its box's corners, whose projection is larger.
  out.box = {1e9, 1e9, -1e9, -1e9};
  for (const render::DrawMesh& m : picture.meshes) {
    if (!picture.is_subject(m)) continue;
    for (Index i = 0; i < m.vertices.cols(); ++i) {
      const Vec3 p = camera.project(m.vertices.col(i), kWidth, kHeight);
      out.box = {std::min(out.box[0], p.x()), std::min(out.box[1], p.y()), std::max(out.box[2], p.x()),
                 std::max(out.box[3], p.y())};
    }
  }
  return out;
}

class RenderScene : public ::testing::TestWithParam<std::string> {};

TEST_P(RenderScene, ClothWhereItsBoxSaysAndStableBetweenRuns) {
  const Rendered r = render_scene(GetParam(), 3);
  ASSERT_LT(r.box[0], r.box[2]);
  // The framing camera keeps the whole cloth in view.
  EXPECT_GE(r.box[0], 0.0);
  EXPECT_GE(r.box[1], 0.0);
  EXPECT_LE(r.box[2], kWidth);
  EXPECT_LE(r.box[3], kHeight);
  long inside = 0, outside = 0;
  for (int y = 0; y < kHeight; ++y)
    for (int x = 0; x < kWidth; ++x) {
      if (r.mask[4 * (y * kWidth + x)] < 128) continue;
      // Pixel centres at +0.5; one pixel of slack for rasterisation at the box's edges.
      const bool in_box =
          x + 0.5 >= r.box[0] - 1 && x + 0.5 <= r.box[2] + 1 && y + 0.5 >= r.box[1] - 1 && y + 0.5 <= r.box[3] + 1;
      (in_box ? inside : outside) += 1;
    }
  EXPECT_EQ(outside, 0) << "cloth pixels outside the cloth's projected bounding box";
  const double box_area = (r.box[2] - r.box[0]) * (r.box[3] - r.box[1]);
  // A cloth seen at an angle fills a good part of its box; a net of thin rods much less of it.
  EXPECT_GT(inside, (r.sheet ? 0.15 : 0.05) * box_area)
      << "the subject covers too little of its box: " << inside << " of " << box_area;

  // The shaded picture: not blank, many shades, and the cloth's pixels are not the background's.
  std::set<std::uint32_t> colours;
  long cloth_drawn = 0, cloth = 0;
  for (int i = 0; i < kWidth * kHeight; ++i) {
    const std::uint8_t* p = &r.shaded[4 * i];
    colours.insert(std::uint32_t(p[0]) << 16 | std::uint32_t(p[1]) << 8 | p[2]);
    if (r.mask[4 * i] >= 128) {
      ++cloth;
      // Background is (237, 240, 245); cloth is blue in front, ochre behind, rigid bodies grey: all far
      // from it.
      if (std::abs(p[0] - 237) + std::abs(p[1] - 240) + std::abs(p[2] - 245) > 60) ++cloth_drawn;
    }
  }
  EXPECT_GT(colours.size(), 8u) << "a nearly blank picture";
  EXPECT_GT(cloth_drawn, 0.9 * cloth) << "the subject's pixels look like background";

  const Rendered again = render_scene(GetParam(), 3);
  EXPECT_TRUE(again.shaded == r.shaded) << "two runs rendered different pictures";
  EXPECT_TRUE(again.mask == r.mask);
}

INSTANTIATE_TEST_SUITE_P(EveryDemo, RenderScene, ::testing::ValuesIn(scenes::bullet_scene_names()),
                         [](const auto& param_info) {
                           std::string name = param_info.param;  // a test name takes letters, digits and _
                           for (char& c : name)
                             if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
                           return name;
                         });

// The camera's projection against a hand computation: the target lands in the image's centre, a point
// one unit to the camera's right lands right of it, and depth grows away from the eye.
TEST(RenderCamera, ProjectsTheTargetToTheCentre) {
  render::Camera camera;
  camera.target = Vec3(1, 2, 3);
  camera.yaw = 0.0;
  camera.pitch = 0.0;
  camera.distance = 5.0;
  const Vec3 centre = camera.project(camera.target, 200, 100);
  EXPECT_NEAR(centre.x(), 100.0, 1e-9);
  EXPECT_NEAR(centre.y(), 50.0, 1e-9);
  // Eye on +z of the target looking down -z: +x is to the right, +y up (pixel y down).
  const double f = 1.0 / std::tan(0.5 * camera.fov_y * 3.14159265358979323846 / 180.0);
  const Vec3 right = camera.project(camera.target + Vec3(1, 0, 0), 200, 100);
  EXPECT_NEAR(right.x(), 100.0 + 0.5 * 200 * f / 2.0 / 5.0, 1e-9);  // x_ndc = f / aspect * 1 / 5
  const Vec3 up = camera.project(camera.target + Vec3(0, 1, 0), 200, 100);
  EXPECT_NEAR(up.y(), 50.0 - 0.5 * 100 * f / 5.0, 1e-9);
  EXPECT_LT(camera.project(camera.target + Vec3(0, 0, 1), 200, 100).z(), centre.z());
}

TEST(RenderCamera, UnprojectInvertsProject) {
  render::Camera camera;
  camera.target = Vec3(0.3, 1.0, -0.2);
  camera.distance = 3.0;
  for (const Vec3& p : {Vec3(0, 0, 0), Vec3(1, 2, 0.5), Vec3(-0.4, 0.9, 0.1)}) {
    const Vec3 q = camera.project(p, 640, 480);
    EXPECT_LT((camera.unproject(q.x(), q.y(), q.z(), 640, 480) - p).norm(), 1e-9);
  }
}

// The viewer's grab: the free particle drawn nearest the cursor, the front one of two on the same
// line of sight, none beyond the radius, never a kinematic one.
TEST(RenderPick, PicksTheNearestFreeParticleInFront) {
  System s;
  render::Camera camera;
  camera.yaw = 0.0;
  camera.pitch = 0.0;
  camera.distance = 5.0;  // eye at (0, 0, 5) looking down -z
  const Index back = s.add_particle(Vec3(0, 0, -1), Vec3::Zero(), 1.0);
  const Index front = s.add_particle(Vec3(0, 0, 1), Vec3::Zero(), 1.0);
  const Index aside = s.add_particle(Vec3(0.5, 0, 0), Vec3::Zero(), 1.0);
  s.add_kinematic_particle(Vec3(0, 0.2, 2));
  const int w = 400, h = 300;
  double depth = 0.0;
  EXPECT_EQ(render::pick_particle(s, camera, 200, 150, 10, w, h, &depth), front);
  EXPECT_NEAR(depth, camera.project(Vec3(0, 0, 1), w, h).z(), 1e-12);
  const Vec3 at_aside = camera.project(Vec3(0.5, 0, 0), w, h);
  EXPECT_EQ(render::pick_particle(s, camera, at_aside.x() + 3, at_aside.y() - 2, 10, w, h), aside);
  EXPECT_EQ(render::pick_particle(s, camera, at_aside.x() + 30, at_aside.y(), 10, w, h), -1);
  const Vec3 at_kinematic = camera.project(Vec3(0, 0.2, 2), w, h);
  EXPECT_NE(render::pick_particle(s, camera, at_kinematic.x(), at_kinematic.y(), 3, w, h), 3)
      << "picked the kinematic cursor";
  (void)back;
}

TEST(RenderFiles, BadSizesAndPathsAreNamed) {
  EXPECT_THROW(render::Offscreen(0, 10), Error);
  std::vector<std::uint8_t> pixels(4 * 4 * 4, 255);
  EXPECT_THROW(render::write_png("/proc/forbidden/x.png", 4, 4, pixels), Error);
  EXPECT_THROW(render::write_png("/tmp/x.png", 5, 4, pixels), Error);
}

}  // namespace
}  // namespace sinew
