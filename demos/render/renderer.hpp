// Pictures of a coupled scene: smooth-shaded two-sided cloth with per-vertex normals, rigid bodies from
// their Bullet collision shapes, a ground with planar shadows, and the binding overlays of figure 1 of
// the hybrid-simulation paper (binding springs orange, hard-bound points red, soft-bound points yellow,
// parent particles blue). The same fixed-function OpenGL drawing serves the offscreen OSMesa context
// (sinew-demo --render, the rendering tests) and the GLFW window of sinew-view.
#pragma once

#include "bullet_scenes.hpp"

#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace sinew::render {

using Mat4 = Eigen::Matrix4d;
using Vec2 = Eigen::Vector2d;

/// Which overlays to draw (all but the parents by default, as in figure 1's close-ups).
struct Overlays {
  bool binding_springs = true;
  bool hard_bound = true;
  bool soft_bound = true;
  bool parents = false;
};

/// A triangle mesh to draw: deformables are shaded two-sided (front and back colours differ).
struct DrawMesh {
  std::string name;
  Vectors3 vertices;
  std::vector<std::array<Index, 3>> triangles;
  bool deformable = false;
  bool dynamic = false;  ///< a deformable or a dynamic rigid body (not static or kinematic)
};

/// Everything one picture shows, in world coordinates.
struct Picture {
  std::vector<DrawMesh> meshes;
  std::vector<std::array<Vec3, 2>> springs;  ///< binding springs (both ends)
  std::vector<Vec3> hard_bound, soft_bound, parents;
  double ground_y = 0.0;  ///< the ground plane y = ground_y, below everything
  bool has_deformables() const;
  /// What the picture is of: its deformables, or (a scene of rigid bodies only, like the net of rods)
  /// its dynamic bodies. Cameras frame and follow it; the mask mode draws it.
  bool is_subject(const DrawMesh& mesh) const;
  /// Bounding box of the subject's meshes (min, max).
  std::array<Vec3, 2> subject_box() const;
  /// Bounding box of every mesh.
  std::array<Vec3, 2> box() const;
};

/// The scene's current state as a picture.
Picture picture_of(scenes::BulletScene& scene, const Overlays& overlays);

/// An orbit camera: looks at `target` from `distance`, turned by yaw about +y and pitched by pitch.
struct Camera {
  Vec3 target = Vec3::Zero();
  double yaw = 0.5;       ///< [rad]
  double pitch = 0.35;    ///< [rad], positive looks down
  double distance = 4.0;  ///< [m]
  double fov_y = 40.0;    ///< [degrees]

  Vec3 eye() const;
  Mat4 view() const;
  Mat4 projection(double aspect) const;
  /// Pixel coordinates (x right, y down from the top-left corner) of a world point in a width x height
  /// image; z of the result is the depth in [-1, 1].
  Vec3 project(const Vec3& point, int width, int height) const;
  /// The world point at pixel (x, y) and depth z in [-1, 1]: project's inverse.
  Vec3 unproject(double x, double y, double depth, int width, int height) const;
};

/// The free particle drawn nearest to pixel (x, y), within `radius` pixels, or -1; among equally near
/// ones the one in front. Its depth (as project gives it) goes to *depth.
Index pick_particle(const System& system, const Camera& camera, double x, double y, double radius, int width,
                    int height, double* depth = nullptr);

/// A camera that frames the picture's subject (Picture::is_subject) from above and aside.
Camera framing_camera(const Picture& picture, double aspect);
/// Moves the camera's target to the centre of the picture's subject (a camera that follows it keeps
/// its distance and direction).
void follow(Camera& camera, const Picture& picture);

/// What to draw: the full picture, or only its subject in flat white on black (a mask for tests).
enum class Mode { shaded, subject_mask };

/// Draws into the current OpenGL context's framebuffer of width x height pixels.
void draw(const Picture& picture, const Camera& camera, int width, int height, Mode mode = Mode::shaded);

/// An offscreen OpenGL context (Mesa's OSMesa: no display, no GPU) with an RGBA colour, depth and
/// stencil buffer. One per thread; make it current before drawing.
class Offscreen {
 public:
  Offscreen(int width, int height);
  ~Offscreen();
  Offscreen(const Offscreen&) = delete;
  Offscreen& operator=(const Offscreen&) = delete;
  void make_current();
  int width() const { return m_width; }
  int height() const { return m_height; }
  /// The image, RGBA, rows from the top.
  std::vector<std::uint8_t> pixels() const;

 private:
  void* m_context = nullptr;
  int m_width, m_height;
  std::vector<std::uint8_t> m_buffer;  // OSMesa's, rows from the bottom
};

/// Reads the current context's framebuffer (RGBA, rows from the top).
std::vector<std::uint8_t> read_pixels(int width, int height);

/// Writes RGBA pixels (rows from the top) as a PNG; throws sinew::Error naming the file on failure.
void write_png(const std::string& path, int width, int height, const std::vector<std::uint8_t>& rgba);

/// Assembles DIR/frame_0001.png to frame_<frames>.png into an MP4 (or a GIF, by the file's extension)
/// with ffmpeg; throws sinew::Error when ffmpeg is missing or fails.
void encode_video(const std::string& frames_dir, int frames, double fps, const std::string& file);

}  // namespace sinew::render
