#include "renderer.hpp"

#include <GL/gl.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <optional>

#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>

namespace sinew::render {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Colours: figure 1's legend for the overlays, muted tones for the solids.
constexpr float kBackground[4] = {0.93f, 0.94f, 0.96f, 1.0f};
constexpr float kClothFront[4] = {0.36f, 0.52f, 0.78f, 1.0f};
constexpr float kClothBack[4] = {0.86f, 0.66f, 0.40f, 1.0f};
constexpr float kRigid[4] = {0.62f, 0.62f, 0.64f, 1.0f};
constexpr float kGroundA[4] = {0.80f, 0.81f, 0.83f, 1.0f};
constexpr float kGroundB[4] = {0.72f, 0.73f, 0.76f, 1.0f};
constexpr float kSpring[3] = {1.0f, 0.55f, 0.0f};
constexpr float kHard[3] = {0.85f, 0.05f, 0.05f};
constexpr float kSoft[3] = {0.95f, 0.85f, 0.05f};
constexpr float kParent[3] = {0.10f, 0.25f, 0.95f};
const Vec3 kLightDirection = Vec3(0.35, 1.0, 0.45).normalized();  // towards the light

std::array<Vec3, 2> empty_box() {
  const double inf = std::numeric_limits<double>::infinity();
  return {Vec3::Constant(inf), Vec3::Constant(-inf)};
}

void grow(std::array<Vec3, 2>& box, const Vectors3& points) {
  for (Index i = 0; i < points.cols(); ++i) {
    box[0] = box[0].cwiseMin(points.col(i));
    box[1] = box[1].cwiseMax(points.col(i));
  }
}

// Area-weighted vertex normals (smooth shading of the cloth).
Vectors3 vertex_normals(const DrawMesh& mesh) {
  Vectors3 n = Vectors3::Zero(3, mesh.vertices.cols());
  for (const auto& t : mesh.triangles) {
    const Vec3 a = mesh.vertices.col(t[0]), b = mesh.vertices.col(t[1]), c = mesh.vertices.col(t[2]);
    const Vec3 face = (b - a).cross(c - a);
    for (Index v : t) n.col(v) += face;
  }
  for (Index i = 0; i < n.cols(); ++i) {
    const double length = n.col(i).norm();
    n.col(i) = length > 0 ? Vec3(n.col(i) / length) : Vec3::UnitY();
  }
  return n;
}

void triangles(const DrawMesh& mesh, bool smooth) {
  if (smooth) {
    const Vectors3 normals = vertex_normals(mesh);
    glBegin(GL_TRIANGLES);
    for (const auto& t : mesh.triangles)
      for (Index v : t) {
        glNormal3dv(normals.col(v).data());
        glVertex3dv(mesh.vertices.col(v).data());
      }
    glEnd();
    return;
  }
  // Rigid shapes share vertices between faces at sharp edges: one normal per face keeps them crisp.
  glBegin(GL_TRIANGLES);
  for (const auto& t : mesh.triangles) {
    const Vec3 a = mesh.vertices.col(t[0]), b = mesh.vertices.col(t[1]), c = mesh.vertices.col(t[2]);
    const Vec3 face = (b - a).cross(c - a);
    const double length = face.norm();
    if (!(length > 0)) continue;
    glNormal3dv(Vec3(face / length).data());
    for (Index v : t) glVertex3dv(mesh.vertices.col(v).data());
  }
  glEnd();
}

void points(const std::vector<Vec3>& list, const float* color, float size) {
  if (list.empty()) return;
  glPointSize(size);
  glColor3fv(color);
  glBegin(GL_POINTS);
  for (const Vec3& p : list) glVertex3dv(p.data());
  glEnd();
}

// Projects onto the ground plane y = ground along the light direction (directional light).
Mat4 shadow_matrix(double ground) {
  const Eigen::Vector4d plane(0, 1, 0, -ground);
  const Eigen::Vector4d light(kLightDirection.x(), kLightDirection.y(), kLightDirection.z(), 0.0);
  return plane.dot(light) * Mat4::Identity() - light * plane.transpose();
}

void ground(const Picture& picture, const Camera& camera) {
  const double extent = 4.0 * std::max(camera.distance, 1.0);
  const double tile = std::pow(10.0, std::floor(std::log10(std::max(camera.distance, 0.1)))) * 0.25;
  const double y = picture.ground_y;
  const int n = std::min(200, static_cast<int>(std::ceil(extent / tile)));
  const double cx = std::floor(camera.target.x() / tile) * tile, cz = std::floor(camera.target.z() / tile) * tile;
  glNormal3d(0, 1, 0);
  glBegin(GL_QUADS);
  for (int i = -n; i < n; ++i)
    for (int k = -n; k < n; ++k) {
      glMaterialfv(GL_FRONT_AND_BACK, GL_AMBIENT_AND_DIFFUSE, ((i + k) & 1) ? kGroundA : kGroundB);
      const double x0 = cx + i * tile, z0 = cz + k * tile;
      glVertex3d(x0, y, z0);
      glVertex3d(x0, y, z0 + tile);
      glVertex3d(x0 + tile, y, z0 + tile);
      glVertex3d(x0 + tile, y, z0);
    }
  glEnd();
}

// BulletScene::surfaces() names rigid bodies' surfaces "body<index>"; anything else is a deformable.
Index body_index(const std::string& name, std::size_t bodies) {
  if (name.size() < 5 || name.compare(0, 4, "body") != 0) return -1;
  Index b = 0;
  for (std::size_t i = 4; i < name.size(); ++i) {
    if (name[i] < '0' || name[i] > '9') return -1;
    b = 10 * b + (name[i] - '0');
    if (b >= static_cast<Index>(bodies)) return -1;
  }
  return b;
}

Mat4 look_at(const Vec3& eye, const Vec3& target, const Vec3& up) {
  const Vec3 f = (target - eye).normalized();
  const Vec3 s = f.cross(up).normalized();
  const Vec3 u = s.cross(f);
  Mat4 m = Mat4::Identity();
  m.block<1, 3>(0, 0) = s.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -s.dot(eye);
  m(1, 3) = -u.dot(eye);
  m(2, 3) = f.dot(eye);
  return m;
}

}  // namespace

bool Picture::has_deformables() const {
  return std::any_of(meshes.begin(), meshes.end(), [](const DrawMesh& m) { return m.deformable; });
}

bool Picture::is_subject(const DrawMesh& mesh) const { return has_deformables() ? mesh.deformable : mesh.dynamic; }

std::array<Vec3, 2> Picture::subject_box() const {
  auto b = empty_box();
  const bool deformables = has_deformables();
  for (const DrawMesh& m : meshes)
    if (deformables ? m.deformable : m.dynamic) grow(b, m.vertices);
  return b;
}

std::array<Vec3, 2> Picture::box() const {
  auto b = empty_box();
  for (const DrawMesh& m : meshes) grow(b, m.vertices);
  return b;
}

Picture picture_of(scenes::BulletScene& scene, const Overlays& overlays) {
  Picture picture;
  // A static plane facing up is the ground itself: drawn as the checkered ground, not as a mesh.
  std::optional<double> plane_y;
  const auto& bullet_bodies = scene.bullet().bodies();
  for (auto& surface : scene.surfaces()) {
    const Index b = body_index(surface.name, bullet_bodies.size());
    if (b >= 0) {
      const btRigidBody* body = bullet_bodies[b];
      const btCollisionShape* shape = body->getCollisionShape();
      if (shape->getShapeType() == STATIC_PLANE_PROXYTYPE) {
        const auto* plane = static_cast<const btStaticPlaneShape*>(shape);
        const btVector3 normal = body->getWorldTransform().getBasis() * plane->getPlaneNormal();
        if (normal.y() > 0.999) {
          const btVector3 point = body->getWorldTransform() * (plane->getPlaneNormal() * plane->getPlaneConstant());
          plane_y = plane_y ? std::max(*plane_y, double(point.y())) : double(point.y());
          continue;
        }
      }
    }
    DrawMesh mesh;
    mesh.deformable = b < 0;
    mesh.dynamic = mesh.deformable || !bullet_bodies[b]->isStaticOrKinematicObject();
    mesh.name = std::move(surface.name);
    mesh.vertices = std::move(surface.vertices);
    mesh.triangles = std::move(surface.triangles);
    picture.meshes.push_back(std::move(mesh));
  }
  const System& s = scene.system();
  const Vectors3& x = s.particles().x;
  if (overlays.binding_springs) {
    const BindingSprings& springs = s.binding_springs();
    for (Index k = 0; k < springs.size(); ++k)
      if (springs.active(k)) picture.springs.push_back({Vec3(x.col(springs.a(k))), Vec3(x.col(springs.b(k)))});
  }
  const HardBindings& hard = s.hard_bindings();
  if (overlays.hard_bound) {
    for (const BindingKind* kind : hard.kinds())
      for (Index k = 0; k < kind->size(); ++k) picture.hard_bound.push_back(x.col(kind->particle(k)));
  }
  if (overlays.soft_bound) {
    const SoftBindings& soft = s.soft_bindings();
    for (Index k = 0; k < soft.size(); ++k) picture.soft_bound.push_back(x.col(soft.particle[k]));
  }
  if (overlays.parents) {
    std::vector<Index> parents;
    for (Index k = 0; k < hard.linear_count(); ++k)
      for (Index p : hard.linear_parents(k)) parents.push_back(p);
    std::sort(parents.begin(), parents.end());
    parents.erase(std::unique(parents.begin(), parents.end()), parents.end());
    for (Index p : parents) picture.parents.push_back(x.col(p));
    const RigidBodyParticles& bodies = s.rigid_bodies();
    for (Index b = 0; b < bodies.size(); ++b)
      if (!bodies.kinematic[b]) picture.parents.push_back(bodies.x.col(b));
  }
  const auto box = picture.box();
  const double size = std::isfinite(box[0].y()) ? (box[1] - box[0]).norm() : 1.0;
  // A little below everything, so that the shadows part from what casts them.
  picture.ground_y = plane_y ? *plane_y : std::isfinite(box[0].y()) ? box[0].y() - 0.08 * size : 0.0;
  return picture;
}

Vec3 Camera::eye() const {
  const Vec3 back(std::cos(pitch) * std::sin(yaw), std::sin(pitch), std::cos(pitch) * std::cos(yaw));
  return target + distance * back;
}

Mat4 Camera::view() const { return look_at(eye(), target, Vec3::UnitY()); }

Mat4 Camera::projection(double aspect) const {
  const double near = 0.02 * distance, far = 50.0 * distance;
  const double f = 1.0 / std::tan(0.5 * fov_y * kPi / 180.0);
  Mat4 p = Mat4::Zero();
  p(0, 0) = f / aspect;
  p(1, 1) = f;
  p(2, 2) = (far + near) / (near - far);
  p(2, 3) = 2.0 * far * near / (near - far);
  p(3, 2) = -1.0;
  return p;
}

Vec3 Camera::project(const Vec3& point, int width, int height) const {
  const Eigen::Vector4d clip = projection(double(width) / height) * view() * point.homogeneous();
  const Vec3 ndc = clip.head<3>() / clip.w();
  return Vec3(0.5 * (ndc.x() + 1.0) * width, 0.5 * (1.0 - ndc.y()) * height, ndc.z());
}

Vec3 Camera::unproject(double x, double y, double depth, int width, int height) const {
  const Mat4 inverse = (projection(double(width) / height) * view()).inverse();
  const Eigen::Vector4d world = inverse * Eigen::Vector4d(2.0 * x / width - 1.0, 1.0 - 2.0 * y / height, depth, 1.0);
  return world.head<3>() / world.w();
}

Index pick_particle(const System& system, const Camera& camera, double x, double y, double radius, int width,
                    int height, double* depth) {
  Index best = -1;
  double best_distance = radius, best_depth = 2.0;
  const Particles& p = system.particles();
  for (Index i = 0; i < p.size(); ++i) {
    if (p.kind[i] != ParticleKind::free) continue;
    const Vec3 q = camera.project(p.x.col(i), width, height);
    if (!(q.z() > -1.0 && q.z() < 1.0)) continue;  // behind the eye or beyond the far plane
    const double d = std::hypot(q.x() - x, q.y() - y);
    if (d > radius) continue;
    if (best < 0 || d < best_distance - 1e-9 || (std::abs(d - best_distance) <= 1e-9 && q.z() < best_depth)) {
      best = i;
      best_distance = d;
      best_depth = q.z();
    }
  }
  if (depth && best >= 0) *depth = best_depth;
  return best;
}

Camera framing_camera(const Picture& picture, double aspect) {
  auto box = picture.subject_box();
  if (!std::isfinite(box[0].x())) box = picture.box();
  Camera camera;
  if (!std::isfinite(box[0].x())) return camera;
  camera.target = 0.5 * (box[0] + box[1]);
  const double radius = std::max(0.5 * (box[1] - box[0]).norm(), 0.05);
  const double half_fov = 0.5 * camera.fov_y * kPi / 180.0;
  const double fit = std::min(std::tan(half_fov), std::tan(half_fov) * aspect);
  camera.distance = 1.15 * radius / std::sin(std::atan(fit));
  return camera;
}

void follow(Camera& camera, const Picture& picture) {
  const auto box = picture.subject_box();
  if (std::isfinite(box[0].x())) camera.target = 0.5 * (box[0] + box[1]);
}

void draw(const Picture& picture, const Camera& camera, int width, int height, Mode mode) {
  glViewport(0, 0, width, height);
  const bool mask = mode == Mode::subject_mask;
  if (mask) glClearColor(0, 0, 0, 1);
  else glClearColor(kBackground[0], kBackground[1], kBackground[2], kBackground[3]);
  glClearStencil(0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT | GL_STENCIL_BUFFER_BIT);
  glMatrixMode(GL_PROJECTION);
  const Mat4 projection = camera.projection(double(width) / height);
  glLoadMatrixd(projection.data());
  glMatrixMode(GL_MODELVIEW);
  const Mat4 view = camera.view();
  glLoadMatrixd(view.data());
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  glDisable(GL_STENCIL_TEST);

  if (mask) {
    glDisable(GL_LIGHTING);
    glColor3f(1, 1, 1);
    for (const DrawMesh& m : picture.meshes)
      if (picture.is_subject(m)) triangles(m, false);
    glFinish();
    return;
  }

  // A directional light from above and a soft ambient term; both faces of the cloth are lit.
  glEnable(GL_LIGHTING);
  glEnable(GL_LIGHT0);
  glEnable(GL_NORMALIZE);
  glShadeModel(GL_SMOOTH);
  const float position[4] = {float(kLightDirection.x()), float(kLightDirection.y()), float(kLightDirection.z()), 0.0f};
  const float diffuse[4] = {0.75f, 0.75f, 0.72f, 1.0f}, ambient[4] = {0.32f, 0.32f, 0.35f, 1.0f};
  const float specular[4] = {0.15f, 0.15f, 0.15f, 1.0f}, none[4] = {0, 0, 0, 1};
  glLightfv(GL_LIGHT0, GL_POSITION, position);
  glLightfv(GL_LIGHT0, GL_DIFFUSE, diffuse);
  glLightfv(GL_LIGHT0, GL_SPECULAR, specular);
  glLightModelfv(GL_LIGHT_MODEL_AMBIENT, ambient);
  glLightModeli(GL_LIGHT_MODEL_TWO_SIDE, GL_TRUE);
  glMaterialfv(GL_FRONT_AND_BACK, GL_SPECULAR, none);

  ground(picture, camera);

  // Planar shadows: every mesh flattened onto the ground along the light, each pixel darkened once
  // (the stencil counts), slightly above the ground to win the depth test.
  glDisable(GL_LIGHTING);
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glEnable(GL_STENCIL_TEST);
  glStencilFunc(GL_EQUAL, 0, 0xff);
  glStencilOp(GL_KEEP, GL_KEEP, GL_INCR);
  glEnable(GL_POLYGON_OFFSET_FILL);
  glPolygonOffset(-1.0f, -1.0f);
  glColor4f(0.0f, 0.0f, 0.05f, 0.28f);
  glPushMatrix();
  const Mat4 shadow = shadow_matrix(picture.ground_y);
  glMultMatrixd(shadow.data());
  for (const DrawMesh& m : picture.meshes) triangles(m, false);
  glPopMatrix();
  glDisable(GL_POLYGON_OFFSET_FILL);
  glDisable(GL_STENCIL_TEST);
  glDisable(GL_BLEND);

  // The solids, pushed back a little so that overlays on their surfaces stay visible.
  glEnable(GL_LIGHTING);
  glEnable(GL_POLYGON_OFFSET_FILL);
  glPolygonOffset(1.0f, 1.0f);
  for (const DrawMesh& m : picture.meshes) {
    if (m.deformable) {
      glMaterialfv(GL_FRONT, GL_AMBIENT_AND_DIFFUSE, kClothFront);
      glMaterialfv(GL_BACK, GL_AMBIENT_AND_DIFFUSE, kClothBack);
    } else {
      glMaterialfv(GL_FRONT_AND_BACK, GL_AMBIENT_AND_DIFFUSE, kRigid);
    }
    triangles(m, m.deformable);
  }
  glDisable(GL_POLYGON_OFFSET_FILL);

  glDisable(GL_LIGHTING);
  if (!picture.springs.empty()) {
    glLineWidth(2.0f);
    glColor3fv(kSpring);
    glBegin(GL_LINES);
    for (const auto& s : picture.springs) {
      glVertex3dv(s[0].data());
      glVertex3dv(s[1].data());
    }
    glEnd();
  }
  const float size = std::clamp(height / 120.0f, 3.0f, 9.0f);
  points(picture.parents, kParent, size + 1.0f);
  points(picture.hard_bound, kHard, size);
  points(picture.soft_bound, kSoft, size);
  glFinish();
}

std::vector<std::uint8_t> read_pixels(int width, int height) {
  std::vector<std::uint8_t> bottom_up(static_cast<std::size_t>(width) * height * 4);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, width, height, GL_RGBA, GL_UNSIGNED_BYTE, bottom_up.data());
  std::vector<std::uint8_t> top_down(bottom_up.size());
  const std::size_t row = static_cast<std::size_t>(width) * 4;
  for (int y = 0; y < height; ++y)
    std::copy_n(bottom_up.data() + row * (height - 1 - y), row, top_down.data() + row * y);
  return top_down;
}

void write_png(const std::string& path, int width, int height, const std::vector<std::uint8_t>& rgba) {
  if (rgba.size() != static_cast<std::size_t>(width) * height * 4)
    fail("write_png: ", rgba.size(), " bytes do not make a ", width, " x ", height, " RGBA image");
  const auto parent = std::filesystem::path(path).parent_path();
  std::error_code error;
  if (!parent.empty()) std::filesystem::create_directories(parent, error);
  if (error) fail("write_png: cannot create the folder of '", path, "': ", error.message());
  if (!stbi_write_png(path.c_str(), width, height, 4, rgba.data(), width * 4))
    fail("write_png: cannot write '", path, "'");
}

void encode_video(const std::string& frames_dir, int frames, double fps, const std::string& file) {
  if (std::system("command -v ffmpeg > /dev/null 2>&1") != 0)
    fail("--video: ffmpeg is not installed (apt-get install ffmpeg); the frames are in ", frames_dir);
  const std::string extension = std::filesystem::path(file).extension().string();
  // -frames:v: a folder used before may hold more frames than this run wrote.
  const std::string input = "-framerate " + std::to_string(fps) + " -i '" + frames_dir + "/frame_%04d.png' -frames:v " +
                            std::to_string(frames);
  std::string command;
  if (extension == ".gif")
    command =
        "ffmpeg -loglevel error -y " + input + " -vf 'split[a][b];[a]palettegen[p];[b][p]paletteuse' '" + file + "'";
  else
    command = "ffmpeg -loglevel error -y " + input +
              " -vf 'pad=ceil(iw/2)*2:ceil(ih/2)*2' -c:v libx264 -pix_fmt yuv420p -crf 20 '" + file + "'";
  if (std::system(command.c_str()) != 0) fail("--video: ffmpeg failed to write '", file, "'");
}

}  // namespace sinew::render
