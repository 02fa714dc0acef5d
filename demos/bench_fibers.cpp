// sinew-bench-fibers: the fibered matrix (MeshfreeCorotated + embedded ElasticRods) against Table 1 of
// Liu et al. 2012, and speed against error beside an explicit step at the paper's step.
//
// Part 1, Table 1: the paper's short bar (588 material particles, 4 fibers, 52 structure particles,
// E 5e7) and long bar (375, 2 fibers, 28, E 3e8) as 7 x 7 x 12 and 5 x 5 x 15 lattices at its spacing
// s = 6 mm, h = 2.5 s (about 50 neighbours), 4e-4 kg per material particle. One thread; the state is
// the rest state turned, stretched by 5% and jittered, so every particle's rotation is a real one.
// "Elastic" is what the paper's "elastic calc." counts: the matrix's per-step pass (each particle's
// F, its rotation by SVD, the stress, the forces); "fibers" its "Bend & Stretch": the fibers' pass
// plus the binding's gather of structure positions and scatter of their forces (eq. 16-17). Printed
// per material particle and per structure particle per step, median of the runs, beside the paper's.
//
// Part 2, speed against error: the long bar as a cantilever (its first layer clamped, horizontal,
// sagging under gravity from rest, strain-rate damping 2e-4 s) for 20 ms. Error: the largest
// difference of the free end's mean height from a reference run (explicit at a quarter of the
// paper's step) over samples every 0.5 ms, relative to the largest sag. Rows: sinew's step with
// explicit elasticity at the paper's step 1e-5 s (a leap-frog in the elastic forces, section 3.3 of
// the first paper) and at sinew's own stable step, then implicit elasticity at longer steps.
// Columns: wall seconds per simulated second, error.
//
//   sinew-bench-fibers [--runs N] [--steps N]
#include "machine.hpp"
#include "sinew/fibers.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <thread>
#include <vector>

namespace {

using namespace sinew;
using bench::cpu_model;
using bench::median;
using Clock = std::chrono::steady_clock;

constexpr double kSpacing = 0.006, kSupport = 2.5 * kSpacing, kParticleMass = 4e-4;

struct BarSpec {
  const char* name;
  int nx, ny, nz;  // lattice counts across, across, along
  int fibers;
  double young;
  double paper_elastic_ms, paper_fiber_ms;  // Table 1
};

// A bar along x (nz layers), its fibers along the axis at the corners of a centred square (4) or on a
// centred line (2). `clamp`: the first layer kinematic.
struct Bar {
  System system;
  MeshfreeCorotated* matrix = nullptr;
  EmbeddedFibers fibers;
  std::vector<Index> material, end_layer;
  BarSpec spec;

  Bar(const BarSpec& b, bool clamp, bool implicit, double beta)
      : system(SystemSettings{.gravity = clamp ? Vec3(0, -9.81, 0) : Vec3::Zero()}), spec(b) {
    for (int k = 0; k < b.nz; ++k)
      for (int j = 0; j < b.ny; ++j)
        for (int i = 0; i < b.nx; ++i) {
          const Vec3 X = kSpacing * Vec3(k, j, i);
          const Index p =
              clamp && k == 0 ? system.add_kinematic_particle(X) : system.add_particle(X, Vec3::Zero(), kParticleMass);
          material.push_back(p);
          if (k == b.nz - 1) end_layer.push_back(p);
        }
    const double volume = kSpacing * kSpacing * kSpacing;
    matrix = &system.add_force(std::make_unique<MeshfreeCorotated>(material, system.particles().x,
                                                                   std::vector<double>(material.size(), volume),
                                                                   MeshfreeCorotatedSettings{.support_radius = kSupport,
                                                                                             .young_modulus = b.young,
                                                                                             .poisson_ratio = 0.33,
                                                                                             .beta = beta,
                                                                                             .hourglass = 0.1,
                                                                                             .implicit = implicit}));
    // Fibers along the bar from 4% to 96% of its length, 13 and 14 points (the paper's 52 / 4 and
    // 28 / 2: about the spacing apart).
    std::vector<Vectors3> lines;
    const double cy = 0.5 * (b.ny - 1) * kSpacing, cz = 0.5 * (b.nx - 1) * kSpacing, r = kSpacing;
    for (int f = 0; f < b.fibers; ++f) {
      const double oy = b.fibers == 4 ? (f % 2 ? r : -r) : 0.0;
      const double oz = b.fibers == 4 ? (f / 2 ? r : -r) : (f ? r : -r);
      const int points = b.fibers == 4 ? 13 : 14;
      Vectors3 line(3, points);
      const double span = (b.nz - 1) * kSpacing;
      for (int p = 0; p < points; ++p) line.col(p) = Vec3(span * (0.04 + 0.92 * p / (points - 1)), cy + oy, cz + oz);
      lines.push_back(line);
    }
    const double EA = b.young * (b.nx * kSpacing) * (b.ny * kSpacing) / b.fibers;
    fibers = embed_fibers(system, *matrix, kSupport, lines,
                          {.stretch_stiffness = EA,
                           .bending_stiffness = EA * kSpacing * kSpacing * 0.05,
                           .beta = beta,
                           .lambda = 0.5,
                           .implicit = implicit});
    system.step_settings().automatic = false;
    system.step_settings().implicit_elasticity = implicit;
    system.finalize();
  }
  Index structure_particles() const {
    Index n = 0;
    for (const auto& f : fibers.fibers) n += static_cast<Index>(f.size());
    return n;
  }
  double end_height() const {
    double y = 0.0;
    for (const Index p : end_layer) y += system.particles().x(1, p);
    return y / static_cast<double>(end_layer.size());
  }
};

const BarSpec kShort{"short bar", 7, 7, 12, 4, 5e7, 1.755, 0.072};
const BarSpec kLong{"long bar", 5, 5, 15, 2, 3e8, 1.067, 0.045};

void table_one(const BarSpec& spec, int runs, int steps) {
  Bar bar(spec, false, false, 0.0);
  // A turned, stretched, jittered state.
  Vectors3 x = bar.system.particles().x;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> jitter(-0.02 * kSpacing, 0.02 * kSpacing);
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  for (const Index p : bar.material) x.col(p) = turn * (1.05 * x.col(p)) + Vec3(jitter(rng), jitter(rng), jitter(rng));
  // Structure particles where their bindings put them.
  const auto gather = [&](Vectors3& state) {
    std::size_t sp = 0;
    for (const auto& fiber : bar.fibers.fibers)
      for (const Index p : fiber) {
        Vec3 at = Vec3::Zero();
        for (std::size_t a = 0; a < bar.fibers.parents[sp].size(); ++a)
          at += bar.fibers.weights[sp][a] * state.col(bar.fibers.parents[sp][a]);
        state.col(p) = at;
        ++sp;
      }
  };
  gather(x);
  Vectors3 f = Vectors3::Zero(3, x.cols());
  std::vector<double> elastic, fiber;
  double checksum = 0.0;
  for (int run = 0; run < runs; ++run) {
    auto start = Clock::now();
    for (int n = 0; n < steps; ++n) {
      bar.matrix->update_position_state(x);
      f.setZero();
      bar.matrix->add_elastic_forces(x, f);
    }
    elastic.push_back(std::chrono::duration<double, std::micro>(Clock::now() - start).count() / steps);
    checksum += f.norm();
    start = Clock::now();
    for (int n = 0; n < steps; ++n) {
      gather(x);
      bar.fibers.force->update_position_state(x);
      f.setZero();
      bar.fibers.force->add_elastic_forces(x, f);
      std::size_t sp = 0;
      for (const auto& fib : bar.fibers.fibers)
        for (const Index p : fib) {
          for (std::size_t a = 0; a < bar.fibers.parents[sp].size(); ++a)
            f.col(bar.fibers.parents[sp][a]) += bar.fibers.weights[sp][a] * f.col(p);
          ++sp;
        }
    }
    fiber.push_back(std::chrono::duration<double, std::micro>(Clock::now() - start).count() / steps);
    checksum += f.norm();
  }
  const double mp = static_cast<double>(bar.material.size()), sp = static_cast<double>(bar.structure_particles());
  const double e = median(elastic), b = median(fiber);
  double neighbours = 0.0;
  for (std::size_t k = 0; k < bar.material.size(); ++k) neighbours += bar.matrix->neighbours(k).size();
  const double paper_mp = spec.paper_elastic_ms * 1e3 / mp;
  std::printf("%-10s %5.0f %4.0f %5.1f %10.3f %8.3f %9.3f %8.3f %7.2f%% %7.2f%% %8.1fx\n", spec.name, mp, sp,
              neighbours / mp, e / mp, paper_mp, b / sp, spec.paper_fiber_ms * 1e3 / sp, 100.0 * b / e,
              100.0 * spec.paper_fiber_ms / spec.paper_elastic_ms, paper_mp / (e / mp));
  if (!std::isfinite(checksum)) std::printf("  (non-finite forces)\n");
}

struct Run {
  std::vector<double> heights;  // the free end's mean height every 0.5 ms
  double seconds = 0.0;         // wall time
  int cg = 0;                   // CG iterations
};

Run cantilever(double dt, bool implicit) {
  Bar bar(kLong, true, implicit, 2e-4);
  constexpr double kHorizon = 0.02, kSample = 5e-4;
  const int samples = static_cast<int>(std::lround(kHorizon / kSample));
  const int per_sample = std::max(1, static_cast<int>(std::lround(kSample / dt)));
  const double step = kSample / per_sample;
  Run run;
  const double y0 = bar.end_height();
  const auto start = Clock::now();
  for (int s = 0; s < samples; ++s) {
    for (int n = 0; n < per_sample; ++n) {
      const StepStats stats = bar.system.step(step);
      run.cg += stats.cg_iterations_step1 + stats.cg_iterations_step3 + stats.cg_iterations_step4;
    }
    run.heights.push_back(bar.end_height() - y0);
  }
  run.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return run;
}

}  // namespace

int main(int argc, char** argv) {
  int runs = 5, steps = 200;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--runs") && i + 1 < argc) runs = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--steps") && i + 1 < argc) steps = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: sinew-bench-fibers [--runs N] [--steps N]\n");
      return 2;
    }
  }
  std::printf("machine: %s, %u hardware threads; one sinew thread\n\n", cpu_model().c_str(),
              std::thread::hardware_concurrency());
  std::printf("Table 1 of the fibers paper (2012, 3.0 GHz, per step) against sinew (median of %d runs of %d passes)\n",
              runs, steps);
  std::printf("%-10s %5s %4s %5s %10s %8s %9s %8s %8s %8s %9s\n", "bar", "MP", "SP", "nbrs", "us/MP", "paper", "us/SP",
              "paper", "fibers", "paper", "speed-up");
  table_one(kShort, runs, steps);
  table_one(kLong, runs, steps);

  std::printf("\nLong-bar cantilever, 20 ms from rest: speed against error (reference: explicit at 2.5e-6 s)\n");
  const Run reference = cantilever(2.5e-6, false);
  double sag = 0.0;
  for (const double h : reference.heights) sag = std::max(sag, std::abs(h));
  std::printf("largest sag of the free end %.4g mm\n", sag * 1e3);
  std::printf("%-28s %9s %12s %10s %12s\n", "scheme", "dt [s]", "s per sim-s", "CG/step", "error");
  struct Row {
    const char* scheme;
    double dt;
    bool implicit;
  };
  Bar probe(kLong, true, false, 2e-4);
  const double stable = probe.system.stable_dt();
  const Row rows[] = {{"explicit, paper's step", 1e-5, false},
                      {"explicit, sinew's stable step", 0.9 * stable, false},
                      {"implicit", 1e-4, true},
                      {"implicit", 2.5e-4, true},
                      {"implicit", 5e-4, true}};
  for (const Row& row : rows) {
    std::vector<double> seconds;
    Run run;
    for (int r = 0; r < std::max(1, runs / 2); ++r) {
      run = cantilever(row.dt, row.implicit);
      seconds.push_back(run.seconds);
    }
    double error = 0.0;
    for (std::size_t s = 0; s < run.heights.size(); ++s)
      error = std::max(error, std::abs(run.heights[s] - reference.heights[s]));
    const int per_sample = std::max(1, static_cast<int>(std::lround(5e-4 / row.dt)));
    const double steps_taken = 40.0 * per_sample;
    std::printf("%-28s %9.2e %12.2f %10.1f %12.2e\n", row.scheme, 5e-4 / per_sample, median(seconds) / 0.02,
                run.cg / steps_taken, error / sag);
  }
  std::printf("s per sim-s: median wall seconds per simulated second; error: largest end-height difference / sag.\n");
  return 0;
}
