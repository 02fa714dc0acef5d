// sinew-view SCENE: a registered Bullet scene in a window, drawn by the same renderer as sinew-demo
// --render; `sinew-view --list` names the scenes. The flags are the shared command line's
// (common/cli.hpp): --size, --dt/--fps, --substeps, the overlay flags, --frames N --screenshot FILE.
//
// Mouse: left-drag on the cloth grabs the nearest point (a binding spring to the cursor, released on
// mouse-up), left-drag elsewhere orbits, right-drag pans, the wheel zooms. Keys: space pauses, S steps
// one frame, R resets. The HUD shows the step's timings, CG iterations and the bindings' drift.
// --screenshot runs N frames, writes the window's picture as a PNG and exits (CI runs it under Xvfb).
//
// Drawing fibers (Liu et al. 2012, section 5): the "draw a fiber" window shows the scene's particles
// from the front (x, y) and from the side (z, y); drag one stroke in each, then "make fiber" turns the
// pair into a 3D fiber at the spacing set there (sinew::fiber_from_strokes; what it refuses, it says
// why), drawn back in both views; "save" writes every fiber made to fibers.txt in the working
// directory (sinew::write_fibers; sinew::read_fibers reads it, and embed_fibers draws it into a
// meshfree matrix).
#include "cli.hpp"
#include "renderer.hpp"
#include "runner.hpp"
#include "sinew/fibers.hpp"

#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl2.h>
#include <imgui.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

namespace {

using namespace sinew;

// The scene and the viewer's mouse spring: a kinematic cursor particle tied to whatever point is
// grabbed by an implicit binding spring, switched off while nothing is held.
struct Session {
  std::unique_ptr<scenes::BulletScene> scene;
  Index cursor = -1, spring = -1, grabbed = -1;
  double grab_depth = 0.0;  // the grabbed point's depth in normalised device coordinates

  explicit Session(const std::string& name) : scene(scenes::make_bullet_scene(name)) {
    System& s = scene->system();
    Index any = -1;
    for (Index i = 0; i < s.particles().size() && any < 0; ++i)
      if (s.particles().kind[i] == ParticleKind::free) any = i;
    if (any < 0) return;  // nothing to grab
    cursor = s.add_kinematic_particle(s.particles().x.col(any));
    // Stiff enough to lift a cloth by a corner, soft enough not to tear its elements: about 50 g per cm.
    spring = s.add_binding_spring({any, cursor, 50.0, 1.0});
    s.set_binding_spring_active(spring, false);
  }
};

// The drawing panel: two strokes, front (x, y) and side (z, y), over the box the scene's particles
// span, and the fibers made from them.
struct FiberPanel {
  Vec3 low = Vec3::Zero(), high = Vec3::Ones();  // the views' box
  std::vector<Eigen::Vector2d> strokes[2];       // front: (x, y); side: (z, y)
  std::vector<Vectors3> fibers;
  float spacing = 0.01f;
  std::string status = "drag a stroke in each view";

  explicit FiberPanel(const System& s) {
    const Vectors3& x = s.particles().x;
    if (x.cols() == 0) return;
    low = x.rowwise().minCoeff();
    high = x.rowwise().maxCoeff();
    const double size = std::max((high - low).maxCoeff(), 1e-3);
    low -= Vec3::Constant(0.1 * size);
    high += Vec3::Constant(0.1 * size);
    spacing = static_cast<float>(size / 20.0);
  }

  // One view: a square canvas mapping (across, y) of the box; a left-drag inside records the stroke.
  void view(int which, float side, const System& s) {
    const int across = which == 0 ? 0 : 2;
    ImGui::BeginGroup();
    ImGui::Text(which == 0 ? "front (x, y)" : "side (z, y)");
    const ImVec2 corner = ImGui::GetCursorScreenPos();
    ImGui::InvisibleButton(which == 0 ? "front" : "side", ImVec2(side, side));
    ImDrawList* draw = ImGui::GetWindowDrawList();
    draw->AddRectFilled(corner, ImVec2(corner.x + side, corner.y + side), IM_COL32(40, 40, 48, 255));
    const double extent = (high - low).maxCoeff();  // one scale for both views: a height sits alike in each
    const auto to_screen = [&](double a, double y) {
      return ImVec2(corner.x + float((a - low(across)) / extent * side),
                    corner.y + float((high(1) - y) / extent * side));
    };
    const auto to_world = [&](ImVec2 p) {
      return Eigen::Vector2d(low(across) + (p.x - corner.x) / side * extent,
                             high(1) - (p.y - corner.y) / side * extent);
    };
    if (ImGui::IsItemActive() && ImGui::IsMouseDown(0) && ImGui::IsMousePosValid()) {
      if (ImGui::IsItemActivated()) strokes[which].clear();
      const Eigen::Vector2d p = to_world(ImGui::GetIO().MousePos);
      std::vector<Eigen::Vector2d>& stroke = strokes[which];
      // A hand turns back by a pixel now and then: a point that reverses the stroke's direction in y
      // is dropped (fiber_from_strokes needs strokes that run one way along y).
      const bool reverses = stroke.size() >= 2 && (p.y() - stroke.back().y()) * (stroke[1].y() - stroke[0].y()) < 0.0;
      if ((stroke.empty() || (p - stroke.back()).norm() > 1e-3 * extent) && !reverses) stroke.push_back(p);
    }
    draw->PushClipRect(corner, ImVec2(corner.x + side, corner.y + side), true);
    const Vectors3& x = s.particles().x;  // the deformables where they are now, to draw over
    for (Index i = 0; i < x.cols(); ++i)
      if (s.particles().kind[i] != ParticleKind::kinematic && s.particles().kind[i] != ParticleKind::removed)
        draw->AddCircleFilled(to_screen(x(across, i), x(1, i)), 1.5f, IM_COL32(170, 150, 120, 255));
    for (const Vectors3& fiber : fibers)
      for (Index i = 1; i < fiber.cols(); ++i)
        draw->AddLine(to_screen(fiber(across, i - 1), fiber(1, i - 1)), to_screen(fiber(across, i), fiber(1, i)),
                      IM_COL32(120, 200, 255, 255), 2.0f);
    for (std::size_t i = 1; i < strokes[which].size(); ++i)
      draw->AddLine(to_screen(strokes[which][i - 1].x(), strokes[which][i - 1].y()),
                    to_screen(strokes[which][i].x(), strokes[which][i].y()), IM_COL32(255, 200, 80, 255), 2.0f);
    draw->PopClipRect();
    ImGui::EndGroup();
  }

  void show(const System& s) {
    ImGui::SetNextWindowPos(ImVec2(10, 330), ImGuiCond_FirstUseEver);
    ImGui::Begin("draw a fiber");
    view(0, 220.0f, s);
    ImGui::SameLine();
    view(1, 220.0f, s);
    ImGui::SetNextItemWidth(120.0f);
    ImGui::InputFloat("spacing [m]", &spacing, 0.0f, 0.0f, "%.4f");
    if (ImGui::Button("make fiber")) {
      try {
        Eigen::Matrix2Xd front(2, strokes[0].size()), side(2, strokes[1].size());
        for (std::size_t i = 0; i < strokes[0].size(); ++i) front.col(static_cast<Index>(i)) = strokes[0][i];
        for (std::size_t i = 0; i < strokes[1].size(); ++i) side.col(static_cast<Index>(i)) = strokes[1][i];
        fibers.push_back(fiber_from_strokes(front, side, spacing));
        status = "fiber " + std::to_string(fibers.size()) + ": " + std::to_string(fibers.back().cols()) + " points";
        strokes[0].clear();
        strokes[1].clear();
      } catch (const Error& e) {
        status = e.what();
      }
    }
    ImGui::SameLine();
    if (ImGui::Button("clear strokes")) strokes[0].clear(), strokes[1].clear();
    ImGui::SameLine();
    if (ImGui::Button("save fibers.txt")) {
      try {
        write_fibers("fibers.txt", fibers);
        status = "saved " + std::to_string(fibers.size()) + " fibers to fibers.txt";
      } catch (const Error& e) {
        status = e.what();
      }
    }
    ImGui::TextWrapped("%s", status.c_str());
    ImGui::End();
  }
};

}  // namespace

int main(int argc, char** argv) {
  const demos::Program program{
      .name = "sinew-view",
      .flags = demos::kFrames | demos::kDt | demos::kSubsteps | demos::kSize | demos::kScreenshot | demos::kOverlays,
      .kinds = {scenes::SceneKind::bullet},
      .default_frames = 0,
      .default_width = 1280,
      .default_height = 720};
  const demos::Options options = demos::parse_command_line(program, argc, argv);
  const std::string& scene_name = options.scene;
  const std::string& screenshot = options.screenshot;
  const int width = options.width, height = options.height, frames = options.frames;

  try {
    auto session = std::make_unique<Session>(scene_name);
    const demos::Timing timing = demos::timing(options, *session->scene);
    const int substeps = timing.substeps;

    if (!glfwInit()) fail("sinew-view: GLFW could not start (no display? run it under xvfb-run)");
    if (!screenshot.empty()) glfwWindowHint(GLFW_VISIBLE, GLFW_FALSE);
    GLFWwindow* window = glfwCreateWindow(width, height, ("sinew-view: " + scene_name).c_str(), nullptr, nullptr);
    if (!window) {
      glfwTerminate();
      fail("sinew-view: no OpenGL window could be created");
    }
    glfwMakeContextCurrent(window);
    glfwSwapInterval(1);
    IMGUI_CHECKVERSION();
    ImGui::CreateContext();
    ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini next to the user's files
    ImGui_ImplGlfw_InitForOpenGL(window, true);
    ImGui_ImplOpenGL2_Init();

    render::Overlays overlays;
    overlays.binding_springs = options.springs;
    overlays.hard_bound = options.hard_bound;
    overlays.soft_bound = options.soft_bound;
    overlays.parents = options.parents;
    render::Camera camera =
        render::framing_camera(render::picture_of(*session->scene, overlays), double(width) / height);
    FiberPanel panel(session->scene->system());
    bool paused = false, step_once = false, follow = true;
    const double frame_dt = timing.frame_dt;
    int frame = 0;
    double frame_ms = 0.0;

    while (!glfwWindowShouldClose(window)) {
      glfwPollEvents();
      int fb_width, fb_height;
      glfwGetFramebufferSize(window, &fb_width, &fb_height);
      if (fb_width < 1 || fb_height < 1) {  // minimised: wait instead of spinning
        glfwWaitEvents();
        continue;
      }
      System& s = session->scene->system();
      ImGui_ImplOpenGL2_NewFrame();
      ImGui_ImplGlfw_NewFrame();
      ImGui::NewFrame();
      const ImGuiIO& io = ImGui::GetIO();

      // ---- mouse: grab, orbit, pan, zoom (window coordinates scaled to the framebuffer) -----------
      int win_width, win_height;
      glfwGetWindowSize(window, &win_width, &win_height);
      const double scale = win_width > 0 ? double(fb_width) / win_width : 1.0;
      const double mx = io.MousePos.x * scale, my = io.MousePos.y * scale;
      if (!io.WantCaptureMouse) {
        if (io.MouseClicked[0] && session->spring >= 0) {
          session->grabbed =
              render::pick_particle(s, camera, mx, my, 15.0 * scale, fb_width, fb_height, &session->grab_depth);
          if (session->grabbed >= 0) {
            s.particles().x.col(session->cursor) = s.particles().x.col(session->grabbed);
            s.particles().v.col(session->cursor).setZero();
            s.set_binding_spring_ends(session->spring, session->grabbed, session->cursor);
            s.set_binding_spring_active(session->spring, true);
          }
        }
        if (io.MouseDown[0] && session->grabbed < 0) {
          camera.yaw -= 0.008 * io.MouseDelta.x;
          camera.pitch = std::clamp(camera.pitch + 0.008 * io.MouseDelta.y, -1.5, 1.5);
        }
        if (io.MouseDown[1] || io.MouseDown[2]) {
          const render::Mat4 view = camera.view();
          const Vec3 right = view.block<1, 3>(0, 0).transpose(), up = view.block<1, 3>(1, 0).transpose();
          camera.target += camera.distance * 0.0015 * (-io.MouseDelta.x * right + io.MouseDelta.y * up);
          follow = false;
        }
        if (io.MouseWheel != 0.0f) camera.distance *= std::pow(0.9, io.MouseWheel);
      }
      if (io.MouseReleased[0] && session->grabbed >= 0) {
        s.set_binding_spring_active(session->spring, false);
        s.particles().v.col(session->cursor).setZero();  // the cursor particle stays where it was let go
        session->grabbed = -1;
      }
      if (session->grabbed >= 0) {
        // The cursor particle moves to the mouse at the grabbed depth, with the velocity that gets it there.
        const Vec3 target = camera.unproject(mx, my, session->grab_depth, fb_width, fb_height);
        s.particles().v.col(session->cursor) = (target - s.particles().x.col(session->cursor)) / frame_dt;
      }

      // ---- keys and the HUD -----------------------------------------------------------------------
      if (!io.WantCaptureKeyboard) {
        if (ImGui::IsKeyPressed(GLFW_KEY_SPACE)) paused = !paused;
        if (ImGui::IsKeyPressed(GLFW_KEY_S)) step_once = true;
      }
      bool reset = !io.WantCaptureKeyboard && ImGui::IsKeyPressed(GLFW_KEY_R);
      ImGui::SetNextWindowPos(ImVec2(10, 10), ImGuiCond_FirstUseEver);
      ImGui::Begin("sinew");
      ImGui::Text("%s, t = %.2f s, frame %d", scene_name.c_str(), session->scene->time(), frame);
      ImGui::Checkbox("paused (space)", &paused);
      ImGui::SameLine();
      if (ImGui::Button("step (S)")) step_once = true;
      ImGui::SameLine();
      if (ImGui::Button("reset (R)")) reset = true;
      ImGui::Checkbox("binding springs", &overlays.binding_springs);
      ImGui::Checkbox("hard-bound points", &overlays.hard_bound);
      ImGui::Checkbox("soft-bound points", &overlays.soft_bound);
      ImGui::Checkbox("parents", &overlays.parents);
      ImGui::Checkbox("camera follows the cloth", &follow);
      const StepStats& st = session->scene->coupling().last_stats();
      ImGui::Separator();
      ImGui::Text("frame: %.2f ms (%d ticks), last tick %.3f ms", frame_ms, substeps, st.ms.total);
      ImGui::Text("  step 1 %.3f  2 %.3f  3 %.3f  4 %.3f  5 %.3f ms", st.ms.implicit_half_velocity,
                  st.ms.advance_positions, st.ms.process_collisions, st.ms.backward_euler_velocity,
                  st.ms.extrapolate_velocity);
      ImGui::Text("  forces %.3f ms, CG %.3f ms", st.ms.forces, st.ms.cg);
      ImGui::Text("CG iterations: %d + %d + %d (steps 1, 3, 4), residual %.1e%s", st.cg_iterations_step1,
                  st.cg_iterations_step3, st.cg_iterations_step4, st.cg_residual,
                  st.cg_converged ? "" : " (not converged)");
      ImGui::Text("hard-binding drift: %.2e m", session->scene->hard_binding_drift());
      double stretch = 0.0;  // the scene's springs, not the mouse spring
      for (Index k = 0; k < s.binding_springs().size(); ++k)
        if (k != session->spring && s.binding_springs().active(k))
          stretch = std::max(
              stretch,
              (s.particles().x.col(s.binding_springs().a(k)) - s.particles().x.col(s.binding_springs().b(k))).norm());
      ImGui::Text("binding-spring stretch: %.2e m", stretch);
      ImGui::Text(session->grabbed >= 0 ? "holding particle %lld" : "left-drag the cloth to grab it",
                  static_cast<long long>(session->grabbed));
      ImGui::End();
      panel.show(s);

      if (reset) {
        session = std::make_unique<Session>(scene_name);
        frame = 0;
      }

      // ---- simulate, draw -----------------------------------------------------------------------
      if (!paused || step_once) {
        const auto start = std::chrono::steady_clock::now();
        session->scene->advance(frame_dt, substeps);
        frame_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        ++frame;
        step_once = false;
      }
      const render::Picture picture = render::picture_of(*session->scene, overlays);
      if (follow && session->grabbed < 0) render::follow(camera, picture);
      render::draw(picture, camera, fb_width, fb_height);
      ImGui::Render();
      ImGui_ImplOpenGL2_RenderDrawData(ImGui::GetDrawData());
      if (!screenshot.empty() && frame >= frames) {
        glFinish();
        render::write_png(screenshot, fb_width, fb_height, render::read_pixels(fb_width, fb_height));
        std::printf("{\"scene\": \"%s\", \"frames\": %d, \"screenshot\": \"%s\", \"width\": %d, \"height\": %d}\n",
                    scene_name.c_str(), frame, screenshot.c_str(), fb_width, fb_height);
        break;
      }
      glfwSwapBuffers(window);
    }
    ImGui_ImplOpenGL2_Shutdown();
    ImGui_ImplGlfw_Shutdown();
    ImGui::DestroyContext();
    glfwDestroyWindow(window);
    glfwTerminate();
  } catch (const std::exception& e) {  // sinew::Error and file errors alike
    std::fprintf(stderr, "sinew-view: %s\n", e.what());
    return 1;
  }
  return 0;
}
