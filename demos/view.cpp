// sinew-view SCENE: a registered Bullet scene in a window, drawn by the same renderer as sinew-demo
// --render; `sinew-view --list` names the scenes. The flags are the shared command line's
// (common/cli.hpp): --size, --dt/--fps, --substeps, the overlay flags, --frames N --screenshot FILE.
//
// Mouse: left-drag on the cloth grabs the nearest point (a binding spring to the cursor, released on
// mouse-up), left-drag elsewhere orbits, right-drag pans, the wheel zooms. Keys: space pauses, S steps
// one frame, R resets. The HUD shows the step's timings, CG iterations and the bindings' drift.
// --screenshot runs N frames, writes the window's picture as a PNG and exits (CI runs it under Xvfb).
#include "cli.hpp"
#include "renderer.hpp"
#include "runner.hpp"

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
      ImGui::Text("CG iterations: %d + %d, residual %.1e%s", st.cg_iterations_step1, st.cg_iterations_step4,
                  st.cg_residual, st.cg_converged ? "" : " (not converged)");
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
