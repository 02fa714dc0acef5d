// sinew-bench: speed against error on the benchmark curtain, sinew beside Bullet 3.24's two
// cloth-to-rigid couplings (classic appendAnchor, deformable world), plus the stability suite.
//
// For every system, resolution and setting (Bullet ticks per 1/60 s frame, CG tolerance) it prints the
// wall time per simulated second (median of --runs timed runs) beside the error at t = 1 s and 2 s: the
// RMS and largest node position error against that system's own converged reference (the same scene at
// a far smaller step and a tight tolerance, whose own convergence is shown by comparing it with a run at
// twice its step). It also prints how far the systems' references disagree (the bottom edge's path),
// the attachment figures (bound-node error, ring joint error, momentum along the rod), sinew's
// per-phase timings, and the stability table. Everything also goes to CSV files in --out, and
// plot_bench.py draws the work-precision plot from them.
//
//   sinew-bench [--sizes 20,40,100] [--runs 5] [--threads N] [--seconds 2] [--out DIR] [--deformable-max N]
//               [--big 150] [--quick] [--no-stability] [--no-plot]
#include "bullet_peers.hpp"
#include "machine.hpp"
#include "sinew_curtain.hpp"
#include "stability.hpp"

#include <LinearMath/btScalar.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace sinew;
using namespace sinew::bench;
using Clock = std::chrono::steady_clock;

constexpr double kFrame = 1.0 / 60.0;

struct Options {
  std::vector<int> sizes{20, 40, 100};  // the range of cloth resolutions
  int runs = 5;
  int threads = 1;
  double seconds = 2.0;     // horizon of the error runs
  int timing_frames = 30;   // frames per timed run
  int deformable_max = 40;  // above it the deformable world costs minutes (100 x 100: 0.1 s a tick, ~16 min in all)
  std::string out = "bench-results";
  bool stability = true;
  bool plot = true;
  int big = 150;  // the half-real-time check's resolution (0: skip)
};

/// One way of running one system: Bullet ticks per 1/60 s frame, and sinew's CG tolerance and CFL.
struct Setting {
  std::string system;
  int ticks = 4;
  double cg_tolerance = 1e-9;
  double cfl = 0.9;
  std::string label() const {
    std::ostringstream out;
    out << ticks << " ticks";
    if (system.rfind("sinew", 0) == 0)
      out << ", tol " << cg_tolerance << (cfl != 0.9 ? ", cfl " + std::to_string(cfl).substr(0, 5) : "");
    return out.str();
  }
};

bool is_sinew(const std::string& system) { return system.rfind("sinew", 0) == 0; }

std::unique_ptr<CurtainRun> make_run(const Setting& s, const CurtainSpec& spec, int threads) {
  if (is_sinew(s.system)) {
    // sinew-implicit: implicit springs, explicit bending (whose stable step then sets the substep),
    // block Jacobi; sinew-implicit-bending: springs and bending implicit, block Jacobi;
    // sinew-multigrid: springs and bending implicit, the multigrid preconditioner.
    SinewSettings settings;
    settings.implicit_elasticity = s.system != "sinew";
    settings.multigrid = s.system == "sinew-multigrid";
    settings.cg_tolerance = s.cg_tolerance;
    settings.cfl = s.cfl;
    settings.threads = threads;
    CurtainSpec sinew_spec = spec;
    sinew_spec.bending_implicit = settings.multigrid || s.system == "sinew-implicit-bending";
    return make_sinew_curtain(sinew_spec, settings);
  }
  if (s.system == "bullet-classic") return make_classic_curtain(spec);
  if (s.system == "bullet-deformable") return make_deformable_curtain(spec);
  fail("sinew-bench: unknown system '", s.system, "'");
}

/// What one run to the horizon recorded.
struct Run {
  bool survived = true;
  int failed_frame = -1;
  std::string reason;
  std::map<int, Vectors3> snapshots;  // node positions at the frames asked for
  std::vector<Vectors3> bottom;       // bottom edge after every frame
  AttachmentError worst;              // largest of each figure over the run
  double momentum_change = 0.0;       // largest |p_x - p_x(0)| [kg m/s]
  double energy_start = 0.0, energy_end = 0.0;
  double wall_ms = 0.0;
  StepStats stats;  // sinew only
};

Run simulate(const Setting& s, const CurtainSpec& spec, int threads, int frames,
             const std::vector<int>& snapshot_frames) {
  Run run;
  auto system = make_run(s, spec, threads);
  const double p0 = system->momentum_along_rod();
  run.energy_start = system->energy();
  const int n = spec.n;
  const auto start = Clock::now();
  for (int f = 1; f <= frames; ++f) {
    try {
      system->advance(kFrame, s.ticks);
    } catch (const Error& e) {
      run.survived = false;
      run.failed_frame = f;
      run.reason = e.what();
      break;
    }
    if (!system->healthy()) {
      run.survived = false;
      run.failed_frame = f;
      run.reason = "non-finite or beyond 1 km";
      break;
    }
    const Vectors3 x = system->nodes();
    run.bottom.push_back(x.rightCols(n));
    for (int k : snapshot_frames)
      if (k == f) run.snapshots[k] = x;
    const AttachmentError a = system->attachment();
    run.worst.bound_node = std::max(run.worst.bound_node, a.bound_node);
    run.worst.bound_node_before_overwrite =
        std::max(run.worst.bound_node_before_overwrite, a.bound_node_before_overwrite);
    run.worst.ring_joint = std::max(run.worst.ring_joint, a.ring_joint);
    run.momentum_change = std::max(run.momentum_change, std::abs(system->momentum_along_rod() - p0));
  }
  run.wall_ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  run.energy_end = system->energy();
  if (auto* sinew_run = dynamic_cast<SinewCurtainRun*>(system.get())) run.stats = sinew_run->total_stats();
  return run;
}

/// Median wall time per simulated second over `runs` runs of `frames` frames [ms], each run timed
/// after one untimed frame: the step's cost, without the one-time set-up of the first step (storage,
/// the multigrid's hierarchy, Bullet's broadphase pairs), for every system alike.
double timed(const Setting& s, const CurtainSpec& spec, int threads, int runs, int frames) {
  std::vector<double> per_second;
  for (int r = 0; r < runs; ++r) {
    auto system = make_run(s, spec, threads);
    system->advance(kFrame, s.ticks);
    const auto start = Clock::now();
    for (int f = 0; f < frames; ++f) system->advance(kFrame, s.ticks);
    per_second.push_back(std::chrono::duration<double, std::milli>(Clock::now() - start).count() / (frames * kFrame));
  }
  return median(per_second);
}

struct Error2 {
  double rms = kInfinity, max = kInfinity;
};
Error2 difference(const Vectors3& a, const Vectors3& b) {
  const Eigen::RowVectorXd d = (a - b).colwise().norm();
  return {std::sqrt(d.squaredNorm() / static_cast<double>(d.size())), d.maxCoeff()};
}

struct Reference {
  Setting setting, half;  // the reference, and the run at twice its step that shows its convergence
  Run run, half_run;
};

/// The converged reference of each system: far smaller steps (and, for sinew, a tight tolerance).
Reference reference_for(const std::string& system) {
  Reference ref;
  if (system == "sinew") {
    // A ninth of the default substep (the explicit elastic forces' stable step): both sinew settings are
    // measured against it, since implicit elasticity converges to the same solution as the step shrinks.
    ref.setting = {system, 4, 1e-12, 0.1};
    ref.half = {system, 4, 1e-12, 0.2};
  } else if (system == "bullet-classic") {
    ref.setting = {system, 128};
    ref.half = {system, 64};
  } else {
    ref.setting = {system, 32};
    ref.half = {system, 16};
  }
  return ref;
}

std::vector<Setting> sweep(const std::string& system, int n) {
  std::vector<Setting> out;
  if (system == "sinew") {
    // Explicit elasticity at its stable substep: the tolerance (of the damping and binding solves)
    // hardly moves its error (at 40 x 40 the three give 4.8e-5 to 4.9e-5 m at t = 1 s), and above
    // 40 x 40 a run costs tens of seconds per simulated second (bending's stable step shrinks as
    // dx^2; 27 s at 100 x 100), so the finer cloths take the first only.
    for (double tol : {1e-5, 1e-7, 1e-9})
      if (n <= 40 || tol == 1e-5) out.push_back({system, 4, tol});
  } else if (system == "sinew-implicit") {
    // The tolerance barely moves the error here (1e-5 and 1e-7 m/s give the same figures): the
    // linearised implicit elasticity's own first-order error dominates, so the sweep is over ticks.
    for (int ticks : {1, 2, 4, 8, 16}) out.push_back({system, ticks, 1e-5});
    out.push_back({system, 4, 1e-7});
    // Looser tolerances: fewer iterations per solve where the step's own error dominates anyway. The
    // loosest, 0.3 m/s, is the cheap end at one tick per frame (at 1 m/s the solves lose the motion
    // over longer runs: measured over 15 s at 20x20 and 40x40, the iterations rise tenfold).
    for (int ticks : {1, 4}) out.push_back({system, ticks, 1e-3});
    for (int ticks : {1, 4}) out.push_back({system, ticks, 1e-2});
    for (int ticks : {1, 4}) out.push_back({system, ticks, 1e-1});
    out.push_back({system, 1, 0.3});
  } else if (system == "sinew-implicit-bending") {
    // Nothing limits the step either, and on a small cloth block Jacobi's solves are cheaper than the
    // multigrid's set-up and V-cycles: the cheap settings at one and two ticks per frame.
    for (int ticks : {1, 2}) out.push_back({system, ticks, 1e-3});
    for (double tol : {1e-2, 1e-1, 0.3}) out.push_back({system, 1, tol});
  } else if (system == "sinew-multigrid") {
    // Nothing limits the step: one tick per frame is the cheapest; looser tolerances trade the CG's
    // error against the step's own.
    for (int ticks : {1, 2, 4}) out.push_back({system, ticks, 1e-5});
    for (double tol : {1e-4, 1e-3, 1e-2, 1e-1}) out.push_back({system, 1, tol});
  } else if (system == "bullet-classic") {
    for (int ticks : {1, 2, 4, 8, 16, 32}) out.push_back({system, ticks});
  } else {
    for (int ticks : {2, 4, 8}) out.push_back({system, ticks});
  }
  return out;
}

/// One line of the work-precision sweep, kept for the goals.
struct Row {
  std::string system;
  int n = 0, ticks = 0;
  double ms_per_sim_s = kInfinity, rms_t2 = kInfinity;
  bool ok = false;
  bool timed_only = false;  ///< no error measured (not an equal-error comparison)
  std::string setting;      ///< Setting::label()
};

/// The speed goals, each judged from the sweep: the coupled tick at 40 x 40 and 1/240 s against
/// each peer's, and at equal error the time per simulated second of sinew's cheapest setting that is
/// at least as accurate as each peer setting.
void print_goals(std::vector<Row> rows, const Options& o) {
  std::printf("\n## goals\n");
  // When the deformable world at 40 x 40 lies outside the sweep (--deformable-max below 40), its
  // 1/240 s tick is timed here alone, without an error, for the 20x goal.
  const bool sinew_40 = std::any_of(rows.begin(), rows.end(),
                                    [](const Row& r) { return r.n == 40 && r.ticks == 4 && is_sinew(r.system); });
  const bool deformable_40 =
      std::any_of(rows.begin(), rows.end(), [](const Row& r) { return r.n == 40 && r.system == "bullet-deformable"; });
  if (sinew_40 && !deformable_40) {
    CurtainSpec spec;
    spec.n = 40;
    Row r{"bullet-deformable", 40,    4,    timed({"bullet-deformable", 4}, spec, o.threads, 3, 30),
          kInfinity,           false, true, "4 ticks"};
    r.ok = std::isfinite(r.ms_per_sim_s);
    rows.push_back(r);
    std::printf("(bullet-deformable at 40x40, 4 ticks: timed alone, median of 3 runs of 30 frames)\n");
  }
  for (const Row& r : rows) {
    if (r.n != 40 || r.ticks != 4 || is_sinew(r.system) || !r.ok) continue;
    // sinew's fastest setting at that tick, with its error beside the peer's (every sinew setting in
    // the sweep is far more exact than the peers' at 1/240 s).
    const Row* fastest = nullptr;
    for (const Row& s : rows)
      if (s.n == 40 && s.ticks == 4 && is_sinew(s.system) && s.ok &&
          (!fastest || s.ms_per_sim_s < fastest->ms_per_sim_s))
        fastest = &s;
    if (!fastest) continue;
    const double best = fastest->ms_per_sim_s;
    const double factor = r.ms_per_sim_s / best;
    char peer_error[64] = "no error measured";
    if (!r.timed_only) std::snprintf(peer_error, sizeof peer_error, "rms %.2e m at 2 s", r.rms_t2);
    std::printf(
        "40x40, 1/240 s tick: %s %.3f ms per tick (%s), %s %s (fastest setting, rms %.2e m at 2 s) %.3f ms: %.2fx "
        "(%s)\n",
        r.system.c_str(), r.ms_per_sim_s / 240.0, peer_error, fastest->system.c_str(), fastest->setting.c_str(),
        fastest->rms_t2, best / 240.0, factor,
        r.system == "bullet-classic" ? (factor > 1 ? "goal met: faster" : "goal missed: slower")
                                     : (factor >= 20 ? "goal met: at least 20x" : "goal missed: below 20x"));
  }
  int met = 0, total = 0;
  for (const Row& peer : rows) {
    if (is_sinew(peer.system) || !peer.ok || peer.timed_only) continue;
    double best = kInfinity;
    std::string which;
    int ticks = 0;
    for (const Row& s : rows)
      if (s.n == peer.n && is_sinew(s.system) && s.ok && s.rms_t2 <= peer.rms_t2 && s.ms_per_sim_s < best)
        best = s.ms_per_sim_s, which = s.system, ticks = s.ticks;
    ++total;
    const bool win = best < peer.ms_per_sim_s;
    met += win;
    std::printf("equal error, %dx%d: %s at %d ticks (rms %.2e m) %.1f ms/sim-s; sinew at that error or better: %s\n",
                peer.n, peer.n, peer.system.c_str(), peer.ticks, peer.rms_t2, peer.ms_per_sim_s,
                std::isfinite(best)
                    ? (which + " " + std::to_string(ticks) + " ticks, " + std::to_string(best).substr(0, 7) +
                       " ms/sim-s" + (win ? " (faster)" : " (slower)"))
                          .c_str()
                    : "no setting in the sweep is that accurate (slower)");
  }
  std::printf("equal error: sinew faster in %d of %d peer settings (sizes", met, total);
  for (int n : o.sizes) std::printf(" %d", n);
  std::printf(")\n");
}

/// One simulated second (60 frames) of an n x n curtain in sinew with implicit elasticity: block
/// Jacobi at 4 ticks per frame (explicit bending sets the substep), and the multigrid at 1 tick
/// (bending implicit too) at a tight CG tolerance and at two loose ones, each loose run's solver
/// error measured against the tight run (same step, same scene) at t = 1 s. The goal is at most two
/// wall seconds at 150 x 150.
void print_big(const Options& o) {
  struct BigSetting {
    bool multigrid;
    double tolerance;
  };
  Vectors3 tight;  // the multigrid run at 1e-6: the loose runs' solver reference
  for (const BigSetting setting :
       {BigSetting{false, 1e-7}, BigSetting{true, 1e-6}, BigSetting{true, 1e-2}, BigSetting{true, 1e-1}}) {
    const bool multigrid = setting.multigrid;
    CurtainSpec spec;
    spec.n = o.big;
    spec.bending_implicit = multigrid;
    SinewSettings settings;
    settings.implicit_elasticity = true;
    settings.multigrid = multigrid;
    settings.cg_tolerance = setting.tolerance;
    settings.threads = o.threads;
    const int ticks = multigrid ? 1 : 4;
    auto run = make_sinew_curtain(spec, settings);
    const auto start = Clock::now();
    for (int f = 0; f < 60; ++f) run->advance(kFrame, ticks);
    const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
    const StepStats& st = run->total_stats();
    std::string solver_error;
    if (multigrid && tight.size() == 0) {
      tight = run->nodes();
      solver_error = "; the loose runs' solver reference";
    } else if (multigrid) {
      const Vectors3 d = run->nodes() - tight;
      char text[160];
      std::snprintf(text, sizeof text, "; solver error against tol 1e-06 at t = 1 s: rms %.2e m, max %.2e m",
                    std::sqrt(d.colwise().squaredNorm().mean()), d.colwise().norm().maxCoeff());
      solver_error = text;
    }
    std::printf(
        "%dx%d curtain, %s, %d ticks per frame (%.1f substeps per tick), tol %g, %d threads: one simulated second in "
        "%.2f wall s "
        "(%.1f CG iterations per solve, attachment %.1e m, %s%s): %s\n",
        o.big, o.big, multigrid ? "sinew-multigrid" : "sinew-implicit", ticks, double(st.substeps) / (60.0 * ticks),
        settings.cg_tolerance, o.threads, seconds,
        0.5 * (st.cg_iterations_step1 + st.cg_iterations_step4) / std::max(1, st.substeps),
        run->attachment().bound_node, run->healthy() ? "healthy" : "NOT healthy", solver_error.c_str(),
        seconds <= 2.0 ? "goal met (half real time or better)" : "goal missed (slower than half real time)");
  }
}

std::FILE* open_csv(const Options& o, const char* name, const char* header) {
  const std::string path = o.out + "/" + name;
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) fail("sinew-bench: cannot write ", path);
  std::fprintf(f, "%s\n", header);
  return f;
}

void usage() {
  std::fprintf(
      stderr,
      "usage: sinew-bench [--sizes 20,40,100] [--runs 5] [--threads N] [--seconds 2] [--out DIR] [--deformable-max N]\n"
      "                   [--big 150] [--quick] [--no-stability] [--no-plot]\n");
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    auto next = [&]() -> const char* {
      if (i + 1 >= argc) {
        usage();
        std::exit(2);
      }
      return argv[++i];
    };
    if (!std::strcmp(argv[i], "--sizes")) {
      o.sizes.clear();
      std::stringstream list(next());
      std::string item;
      while (std::getline(list, item, ',')) o.sizes.push_back(std::atoi(item.c_str()));
    } else if (!std::strcmp(argv[i], "--runs")) o.runs = std::atoi(next());
    else if (!std::strcmp(argv[i], "--threads")) o.threads = std::atoi(next());
    else if (!std::strcmp(argv[i], "--seconds")) o.seconds = std::atof(next());
    else if (!std::strcmp(argv[i], "--out")) o.out = next();
    else if (!std::strcmp(argv[i], "--deformable-max")) o.deformable_max = std::atoi(next());
    else if (!std::strcmp(argv[i], "--big")) o.big = std::atoi(next());
    else if (!std::strcmp(argv[i], "--quick")) {
      // A smoke run of every code path (CTest runs it): tiny cloth, short horizon, one timed run.
      o.sizes = {8};
      o.runs = 1;
      o.seconds = 0.25;
      o.timing_frames = 3;
      o.deformable_max = 8;
      o.big = 0;
    } else if (!std::strcmp(argv[i], "--no-stability")) o.stability = false;
    else if (!std::strcmp(argv[i], "--no-plot")) o.plot = false;
    else {
      usage();
      std::exit(2);
    }
  }
  for (int n : o.sizes)
    if (n < 10 && o.sizes.size() > 1) fail("sinew-bench: size ", n, " is below the 10 rings' minimum");
  if (o.runs < 1) fail("sinew-bench: --runs ", o.runs, ", needs at least 1");
  if (!(o.seconds > 0)) fail("sinew-bench: --seconds ", o.seconds, ", must be positive");
  return o;
}

}  // namespace

int main(int argc, char** argv) try {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // progress shows line by line when piped to a file
  const Options o = parse(argc, argv);
  std::filesystem::create_directories(o.out);
  const int frames = static_cast<int>(std::lround(o.seconds / kFrame));
  const int mid = frames / 2;  // t = 1 s at the default horizon
  const std::vector<std::string> systems{"sinew",           "sinew-implicit", "sinew-implicit-bending",
                                         "sinew-multigrid", "bullet-classic", "bullet-deformable"};

  std::printf("# sinew-bench\nmachine: %s, %u hardware threads; sinew threads: %d; Bullet: 1 thread (%s precision)\n",
              cpu_model().c_str(), std::thread::hardware_concurrency(), o.threads,
              sizeof(btScalar) == 8 ? "double" : "single");
  std::printf(
      "scene: n x n cloth, 2 m x 2 m, 0.5 kg, edge springs 200 N/m (damping 0.05 N s/m), bending 1e-4 N m, ten 0.05 kg "
      "rings\n"
      "sliding on a static rod, one top-row node bound per ring, every body starting at (0.2, 0, 1) m/s; 1/60 s "
      "frames,\n"
      "errors at t = %.3g s and %.3g s against each system's own converged reference;\ntimes are medians of %d runs of "
      "%d frames, each after one untimed frame.\n",
      mid * kFrame, frames * kFrame, o.runs, o.timing_frames);

  std::FILE* wp = open_csv(o, "work_precision.csv",
                           "system,n,ticks,cg_tolerance,cfl,ms_per_sim_s,ms_per_tick,rms_t1,max_t1,rms_t2,max_t2,bound_"
                           "node,bound_node_before_overwrite,"
                           "ring_joint,momentum_change,energy_start,energy_end,survived,failed_frame");
  std::FILE* refs = open_csv(o, "references.csv", "system,n,ticks,cfl,rms_vs_half_t2,max_vs_half_t2");
  std::FILE* agree = open_csv(o, "agreement.csv", "system,n,bottom_edge_rms_max_over_time,bottom_edge_rms_t2");
  std::FILE* phases = open_csv(
      o, "phases.csv",
      "system,n,ticks,substeps_per_tick,cg_iterations_per_substep,ms_per_tick,step1,step2,step3,step4,step5,forces,cg");

  std::vector<Row> rows;
  for (int n : o.sizes) {
    CurtainSpec spec;
    spec.n = n;
    if (n < spec.rings) spec.rings = n;
    std::printf("\n## %d x %d cloth (%d nodes)\n", n, n, n * n);
    std::printf("models: where they cannot match the spec\n");
    for (const std::string& system : systems)
      std::printf("  %-22s %s\n", system.c_str(), make_run({system}, spec, 1)->mismatch().c_str());

    // ---- references ------------------------------------------------------------------------------
    std::map<std::string, Reference> ref;
    std::printf("converged references (difference from a run at twice the step, at t = %.3g s):\n", frames * kFrame);
    for (const std::string& system : systems) {
      if (system == "bullet-deformable" && n > o.deformable_max) continue;
      if (is_sinew(system) && system != "sinew") continue;  // measured against sinew's reference
      Reference r = reference_for(system);
      r.run = simulate(r.setting, spec, o.threads, frames, {mid, frames});
      r.half_run = simulate(r.half, spec, o.threads, frames, {mid, frames});
      Error2 e;
      if (r.run.survived && r.half_run.survived) e = difference(r.run.snapshots[frames], r.half_run.snapshots[frames]);
      std::printf("  %-22s %-24s vs %-24s rms %.2e m, max %.2e m%s\n", system.c_str(), r.setting.label().c_str(),
                  r.half.label().c_str(), e.rms, e.max, r.run.survived ? "" : "  (reference failed)");
      std::fprintf(refs, "%s,%d,%d,%g,%.6e,%.6e\n", system.c_str(), n, r.setting.ticks, r.setting.cfl, e.rms, e.max);
      ref[system] = std::move(r);
    }
    // How far the models disagree: the bottom edge's path in each reference against sinew's.
    const Run& sinew_ref = ref["sinew"].run;
    std::printf(
        "agreement: bottom edge of each reference against sinew's (RMS over the edge; worst frame, and at the end)\n");
    for (const auto& [system, r] : ref) {
      if (system == "sinew" || !r.run.survived || !sinew_ref.survived) continue;
      double worst = 0.0;
      for (std::size_t f = 0; f < r.run.bottom.size() && f < sinew_ref.bottom.size(); ++f)
        worst = std::max(worst, difference(r.run.bottom[f], sinew_ref.bottom[f]).rms);
      const double end = difference(r.run.bottom.back(), sinew_ref.bottom.back()).rms;
      std::printf("  %-22s %.3e m worst, %.3e m at the end\n", system.c_str(), worst, end);
      std::fprintf(agree, "%s,%d,%.6e,%.6e\n", system.c_str(), n, worst, end);
    }

    // ---- work-precision --------------------------------------------------------------------------
    std::printf("work-precision:\n  %-22s %-22s %10s %9s %9s %9s %9s %9s %9s %9s %9s %s\n", "system", "setting",
                "ms/sim-s", "ms/tick", "rms@1s", "max@1s", "rms@2s", "max@2s", "bound[m]", "joint[m]", "dp_x", "");
    for (const std::string& system : systems) {
      const std::string own = is_sinew(system) ? "sinew" : system;
      if (!ref.count(own)) continue;
      const Reference& r = ref[own];
      for (const Setting& s : sweep(system, n)) {
        const Run run = simulate(s, spec, o.threads, frames, {mid, frames});
        Error2 e1, e2;
        double ms = kInfinity;
        if (run.survived) {
          if (r.run.survived) {
            e1 = difference(run.snapshots.at(mid), r.run.snapshots.at(mid));
            e2 = difference(run.snapshots.at(frames), r.run.snapshots.at(frames));
          }
          ms = timed(s, spec, o.threads, o.runs, o.timing_frames);
        }
        const double per_tick = ms * kFrame / s.ticks;
        char status[96] = "";
        if (!run.survived) std::snprintf(status, sizeof status, "FAILED at frame %d", run.failed_frame);
        const double bound =
            system == "bullet-deformable" ? run.worst.bound_node_before_overwrite : run.worst.bound_node;
        std::printf("  %-22s %-22s %10.1f %9.3f %9.2e %9.2e %9.2e %9.2e %9.2e %9.2e %9.1e %s\n", system.c_str(),
                    s.label().c_str(), ms, per_tick, e1.rms, e1.max, e2.rms, e2.max, bound, run.worst.ring_joint,
                    run.momentum_change, status);
        std::fprintf(wp, "%s,%d,%d,%g,%g,%.6g,%.6g,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.9g,%.9g,%d,%d\n",
                     system.c_str(), n, s.ticks, s.cg_tolerance, s.cfl, ms, per_tick, e1.rms, e1.max, e2.rms, e2.max,
                     run.worst.bound_node, run.worst.bound_node_before_overwrite, run.worst.ring_joint,
                     run.momentum_change, run.energy_start, run.energy_end, run.survived ? 1 : 0, run.failed_frame);
        std::fflush(wp);
        rows.push_back({system, n, s.ticks, ms, e2.rms, run.survived && std::isfinite(e2.rms), false, s.label()});
        if (is_sinew(system) && (s.ticks == 4 || (system != "sinew" && system != "sinew-implicit" && s.ticks == 1)) &&
            run.survived) {
          const StepStats& st = run.stats;
          const double ticks = frames * s.ticks, per = 1.0 / ticks;
          const double cg_per_substep =
              double(st.cg_iterations_step1 + st.cg_iterations_step3 + st.cg_iterations_step4) /
              std::max(1, st.substeps);
          std::fprintf(phases, "%s,%d,%d,%.3f,%.2f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f\n", system.c_str(), n,
                       s.ticks, st.substeps * per, cg_per_substep, st.ms.total * per,
                       st.ms.implicit_half_velocity * per, st.ms.advance_positions * per,
                       st.ms.process_collisions * per, st.ms.backward_euler_velocity * per,
                       st.ms.extrapolate_velocity * per, st.ms.forces * per, st.ms.cg * per);
        }
      }
    }
    std::printf(
        "  (bound: largest distance of a bound node from its pivot over the run; for bullet-deformable measured before "
        "it\n"
        "   overwrites anchored nodes, which leaves 0 after; joint: ring centre from the rod axis; dp_x: momentum "
        "along the rod)\n");
  }
  print_goals(rows, o);
  if (o.big > 0) print_big(o);
  std::fclose(wp);
  std::fclose(refs);
  std::fclose(agree);
  std::fclose(phases);

  // sinew's per-phase timings, read back from what the sweep recorded.
  std::printf(
      "\n## sinew's step, per Bullet tick (1/60 s over the ticks column; phases of section 3.3 in ms; error runs, not "
      "the timed ones)\n");
  {
    std::FILE* f = std::fopen((o.out + "/phases.csv").c_str(), "r");
    char line[512];
    while (f && std::fgets(line, sizeof line, f)) std::printf("  %s", line);
    if (f) std::fclose(f);
  }

  if (o.stability) {
    std::printf("\n## stability suite\n");
    const std::vector<StabilityResult> results = run_stability_suite(stability_systems());
    print_stability_table(stdout, results);
    const std::string path = o.out + "/stability.csv";
    std::FILE* csv = std::fopen(path.c_str(), "w");
    if (!csv) fail("sinew-bench: cannot write ", path);
    write_stability_csv(csv, results);
    std::fclose(csv);
  }

  if (o.plot) {
    const std::string command = "/usr/bin/python3 \"" SINEW_BENCH_PLOT "\" \"" + o.out + "\"";
    if (std::system(command.c_str()) != 0)
      std::printf("\n(no plot: %s failed; needs Debian's python3-matplotlib)\n", command.c_str());
  }
  std::printf("\nCSV files and the plot are in %s/\n", o.out.c_str());
  return 0;
} catch (const sinew::Error& e) {
  std::fprintf(stderr, "sinew-bench: %s\n", e.what());
  return 1;
}
