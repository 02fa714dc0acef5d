// sinew-schemes: the scheme StepSettings::automatic chooses, against every hand-chosen setting of a
// sweep, on every demo scene and the benchmark's curtain.
//
// For each scene it runs, at the scene's own frame and Bullet ticks:
// - a reference: explicit elasticity at a quarter of the default stable step (cfl 0.225), CG to 1e-12
//   m/s, and the same at half that step, whose difference says how far the reference has converged;
// - "auto": StepSettings at their defaults with `automatic` on (what a user who sets nothing gets);
// - the sweep: explicit elasticity at three CG tolerances; implicit springs (bending explicit), implicit
//   springs and bending with block Jacobi, and with the multigrid, each at several tolerances; one
//   Newton iteration; every one with `automatic` off, so it runs exactly as named.
// Each run prints the wall time per frame (median of --runs runs), the RMS position error of every
// particle and rigid body against the reference at the middle and end frames, and whether it held:
// no error thrown, and its energy never above max(its first frame's, the reference's at that frame)
// by more than 1% of the reference's energy range (a passive scene never gains; a driven one gains
// what the reference gains). The best hand-chosen setting is the fastest that held with an end error
// within 10% (or 0.1 mm) of auto's; the goal is auto at most 10% slower than it.
//
//   sinew-schemes [--frames 120] [--runs 3] [--scenes hello,plates,...] [--out DIR] [--auto-only]
#include "machine.hpp"
#include "scene.hpp"

#include "sinew/types.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace sinew;
using Clock = std::chrono::steady_clock;

struct Options {
  int frames = 120;
  int runs = 3;
  std::vector<std::string> scenes{"hello",        "plates",        "net",          "curtain",
                                  "spinning-box", "bench-curtain", "hanging-cloth"};
  std::string out = "bench-results";
  bool auto_only = false;  // the automatic scheme alone (no sweep, no comparison)
};

/// One way of setting the step. `automatic` runs the defaults with the choice on; the others run as named.
struct Scheme {
  std::string name;
  bool automatic = false;
  bool implicit = false;          // StepSettings::implicit_elasticity
  bool implicit_bending = false;  // forces offer their definite differentials (dihedral bending implicit)
  bool multigrid = false;
  double tolerance = 1e-9;
  int newton = 0;
  double cfl = 0.9;
};

std::vector<Scheme> sweep() {
  std::vector<Scheme> s;
  for (double tol : {1e-9, 1e-6, 1e-3}) s.push_back({.name = "explicit", .tolerance = tol});
  for (double tol : {1e-6, 1e-4, 1e-2}) s.push_back({.name = "implicit springs", .implicit = true, .tolerance = tol});
  for (double tol : {1e-6, 1e-4, 1e-2})
    s.push_back({.name = "implicit springs+bending", .implicit = true, .implicit_bending = true, .tolerance = tol});
  for (double tol : {1e-4, 1e-2})
    s.push_back({.name = "implicit s+b, multigrid",
                 .implicit = true,
                 .implicit_bending = true,
                 .multigrid = true,
                 .tolerance = tol});
  s.push_back(
      {.name = "implicit s+b, 1 Newton", .implicit = true, .implicit_bending = true, .tolerance = 1e-4, .newton = 1});
  return s;
}

std::string label(const Scheme& s) {
  if (s.automatic) return "auto (defaults, StepSettings::automatic)";
  std::ostringstream out;
  out << s.name << ", tol " << s.tolerance;
  if (s.cfl != 0.9) out << ", cfl " << s.cfl;
  return out.str();
}

void apply(const Scheme& scheme, System& system) {
  StepSettings& step = system.step_settings();
  const StepSettings defaults;
  step.automatic = scheme.automatic;
  step.implicit_elasticity = scheme.automatic ? defaults.implicit_elasticity : scheme.implicit;
  step.multigrid = scheme.automatic ? defaults.multigrid : scheme.multigrid;
  step.cg_tolerance = scheme.automatic ? defaults.cg_tolerance : scheme.tolerance;
  step.newton_iterations = scheme.automatic ? defaults.newton_iterations : scheme.newton;
  step.cfl = scheme.automatic ? defaults.cfl : scheme.cfl;
  for (const auto& force : system.forces()) force->offer_definite_differentials(scheme.implicit_bending);
}

/// Every particle's and rigid body's position, one column each.
Vectors3 positions(const System& system) {
  const Vectors3& x = system.particles().x;
  const Vectors3& b = system.rigid_bodies().x;
  Vectors3 out(3, x.cols() + b.cols());
  out << x, b;
  return out;
}

double rms(const Vectors3& a, const Vectors3& b) {
  if (a.cols() != b.cols() || a.cols() == 0) return std::numeric_limits<double>::quiet_NaN();
  return std::sqrt((a - b).colwise().squaredNorm().mean());
}

struct Run {
  std::string failure;  // empty when every frame ran
  std::vector<double> energy;
  Vectors3 middle, end;
  double ms_per_frame = 0.0;
  double substeps_per_frame = 0.0;
  double cg_per_substep = 0.0;  // CG iterations of steps 1 and 4 per substep
};

Run run(const std::string& name, const Scheme& scheme, int frames) {
  Run r;
  auto scene = scenes::make_scene(name);
  System* system = scene->deformable_system();
  if (!system) fail(name, ": the scene has no deformable system to set");
  apply(scheme, *system);
  const double dt = scene->default_frame_dt();
  const int ticks = scene->default_substeps();
  double seconds = 0.0;
  try {
    for (int f = 1; f <= frames; ++f) {
      const auto start = Clock::now();
      scene->advance(dt, ticks);
      seconds += std::chrono::duration<double>(Clock::now() - start).count();
      r.energy.push_back(scene->measure().energy);
      if (!std::isfinite(r.energy.back())) fail("frame ", f, ": the energy is not finite");
      if (f == frames / 2) r.middle = positions(*system);
    }
    r.end = positions(*system);
  } catch (const std::exception& e) {
    r.failure = e.what();
  }
  r.ms_per_frame = 1e3 * seconds / std::max<std::size_t>(1, r.energy.size());
  if (const StepStats* s = scene->total_stats(); s && !r.energy.empty()) {
    r.substeps_per_frame = double(s->substeps) / double(r.energy.size());
    r.cg_per_substep = double(s->cg_iterations_step1 + s->cg_iterations_step3 + s->cg_iterations_step4) /
                       double(std::max(1, s->substeps));
  }
  return r;
}

struct Row {
  Scheme scheme;
  bool held = false;
  std::string why;  // when it did not hold
  double ms = 0.0, error_middle = 0.0, error_end = 0.0, gain = 0.0, substeps = 0.0, cg = 0.0;
};

Row measure(const std::string& name, const Scheme& scheme, const Options& o, const Run& reference) {
  Row row;
  row.scheme = scheme;
  std::vector<double> times;
  Run first;
  for (int k = 0; k < o.runs; ++k) {
    Run r = run(name, scheme, o.frames);
    times.push_back(r.ms_per_frame);
    if (k == 0) first = std::move(r);
    if (!first.failure.empty()) break;  // a failing setting is not timed again
  }
  row.ms = bench::median(times);
  row.substeps = first.substeps_per_frame;
  row.cg = first.cg_per_substep;
  if (!first.failure.empty()) {
    row.why = "stopped at frame " + std::to_string(first.energy.size() + 1) + ": " + first.failure;
    return row;
  }
  const std::vector<double>& e_ref = reference.energy;
  const auto [lo, hi] = std::minmax_element(e_ref.begin(), e_ref.end());
  const double range = std::max(*hi - *lo, 1e-12);
  for (std::size_t f = 0; f < first.energy.size(); ++f)
    row.gain = std::max(row.gain, (first.energy[f] - std::max(first.energy[0], e_ref[f])) / range);
  row.error_middle = rms(first.middle, reference.middle);
  row.error_end = rms(first.end, reference.end);
  row.held = row.gain <= 0.01;
  if (!row.held) {
    char text[96];
    std::snprintf(text, sizeof text, "gains %.1f%% of the energy range", 100.0 * row.gain);
    row.why = text;
  }
  return row;
}

void print_row(std::FILE* out, const Row& r) {
  std::fprintf(out, "| %s | %.2f | %.1f | %.1f | %.2e m | %.2e m | %.2f%% | %s |\n", label(r.scheme).c_str(), r.ms,
               r.substeps, r.cg, r.error_middle, r.error_end, 100.0 * r.gain, r.held ? "yes" : r.why.c_str());
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) fail("sinew-schemes: ", arg, " needs a value");
      return argv[++i];
    };
    if (arg == "--frames") o.frames = std::stoi(value());
    else if (arg == "--runs") o.runs = std::stoi(value());
    else if (arg == "--out") o.out = value();
    else if (arg == "--auto-only") o.auto_only = true;
    else if (arg == "--scenes") {
      o.scenes.clear();
      std::stringstream list(value());
      for (std::string name; std::getline(list, name, ',');) o.scenes.push_back(name);
    } else {
      std::fprintf(stderr,
                   "usage: sinew-schemes [--frames 120] [--runs 3] [--scenes a,b,...] [--out DIR] [--auto-only]\n");
      std::exit(2);
    }
  }
  if (o.frames < 2 || o.runs < 1) fail("sinew-schemes: --frames needs at least 2 and --runs at least 1");
  return o;
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  std::filesystem::create_directories(o.out);
  std::FILE* csv = std::fopen((o.out + "/schemes.csv").c_str(), "w");
  if (!csv) fail("sinew-schemes: cannot write ", o.out, "/schemes.csv");
  std::fprintf(csv, "scene,scheme,ms_per_frame,substeps_per_frame,error_middle_m,error_end_m,gain,held\n");
  std::printf("# sinew-schemes\nmachine: %s, %u hardware threads; one sinew thread; %d frames, median of %d runs\n",
              bench::cpu_model().c_str(), std::thread::hardware_concurrency(), o.frames, o.runs);
  std::vector<std::string> summary;
  for (const std::string& name : o.scenes) {
    const Scheme reference_scheme{.name = "reference (explicit)", .tolerance = 1e-12, .cfl = 0.225};
    Scheme check = reference_scheme;
    check.cfl = 0.45;
    const Run reference = run(name, reference_scheme, o.frames);
    if (!reference.failure.empty()) fail(name, ": the reference run failed: ", reference.failure);
    const Run coarser = run(name, check, o.frames);
    std::printf(
        "\n## %s (%d frames; reference: explicit, cfl 0.225, tol 1e-12, %.1f substeps a frame; "
        "its RMS change at twice the step: %.1e m at the middle, %.1e m at the end)\n\n",
        name.c_str(), o.frames, reference.substeps_per_frame, rms(coarser.middle, reference.middle),
        rms(coarser.end, reference.end));
    std::printf(
        "| scheme | ms / frame | substeps / frame | CG iterations / substep | RMS error, middle | at the end | energy "
        "gain | held |\n");
    std::printf("|---|---|---|---|---|---|---|---|\n");
    std::vector<Row> rows;
    rows.push_back(measure(name, Scheme{.name = "auto", .automatic = true}, o, reference));
    if (!o.auto_only)
      for (const Scheme& s : sweep()) rows.push_back(measure(name, s, o, reference));
    for (const Row& r : rows) {
      print_row(stdout, r);
      std::fprintf(csv, "%s,\"%s\",%.4f,%.2f,%.4e,%.4e,%.4e,%d\n", name.c_str(), label(r.scheme).c_str(), r.ms,
                   r.substeps, r.error_middle, r.error_end, r.gain, r.held ? 1 : 0);
    }
    std::fflush(stdout);
    const Row& a = rows.front();
    const Row* best = nullptr;
    const Row* fastest = nullptr;
    for (std::size_t k = 1; k < rows.size(); ++k) {
      const Row& r = rows[k];
      if (!r.held) continue;
      if (!fastest || r.ms < fastest->ms) fastest = &r;
      if (r.error_end <= std::max(1.1 * a.error_end, a.error_end + 1e-4) && (!best || r.ms < best->ms)) best = &r;
    }
    char line[512];
    if (!a.held) std::snprintf(line, sizeof line, "%s: auto did NOT hold (%s)", name.c_str(), a.why.c_str());
    else if (!best)
      std::snprintf(line, sizeof line, "%s: auto %.2f ms/frame, error %.1e m; no hand-chosen setting held at its error",
                    name.c_str(), a.ms, a.error_end);
    else
      std::snprintf(line, sizeof line,
                    "%s: auto %.2f ms/frame (error %.1e m) against the best hand-chosen at that error, %s: %.2f ms "
                    "(%.1e m): %.2fx%s; fastest that held: %s, %.2f ms (%.1e m)",
                    name.c_str(), a.ms, a.error_end, label(best->scheme).c_str(), best->ms, best->error_end,
                    a.ms / best->ms, a.ms <= 1.1 * best->ms ? "" : " (above the 1.1x goal)",
                    label(fastest->scheme).c_str(), fastest->ms, fastest->error_end);
    std::printf("\n%s\n", line);
    summary.push_back(line);
  }
  std::fclose(csv);
  std::printf("\n## Summary\n\n");
  for (const std::string& s : summary) std::printf("- %s\n", s.c_str());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "sinew-schemes: %s\n", e.what());
  return 1;
}
