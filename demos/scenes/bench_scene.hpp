// A scene that runs one of the benchmark's systems (bench::CurtainRun: the benchmark curtain or a
// stability case, built by demos/bench/ as sinew-bench builds it), so the programs and the smoke
// tests reach the benchmark's scenes through the scene library.
#pragma once

#include "curtain_bench.hpp"
#include "fnv_hash.hpp"
#include "scene.hpp"
#include "sinew_curtain.hpp"

#include <memory>

namespace sinew::scenes {

class BenchScene final : public Scene {
 public:
  BenchScene(std::unique_ptr<bench::CurtainRun> run, double frame_dt, int ticks, Index rigid_bodies)
      : m_run(std::move(run)), m_frame_dt(frame_dt), m_ticks(ticks), m_rigid_bodies(rigid_bodies) {}
  double default_frame_dt() const override { return m_frame_dt; }
  int default_substeps() const override { return m_ticks; }
  void advance(double frame_dt, int substeps) override {
    m_run->advance(frame_dt, substeps);
    if (!m_run->healthy()) fail(m_run->system(), ": the state is not finite or left 1 km");
  }
  SceneMeasures measure() override {
    SceneMeasures m;
    m.particles = m_run->nodes().cols();
    m.rigid_bodies = m_rigid_bodies;
    m.hard_binding_drift = m_run->attachment().bound_node;
    m.energy = m_run->energy();
    return m;
  }
  const StepStats* total_stats() const override {
    auto* sinew_run = dynamic_cast<const bench::SinewCurtainRun*>(m_run.get());
    return sinew_run ? &sinew_run->total_stats() : nullptr;
  }
  System* deformable_system() override {
    auto* sinew_run = dynamic_cast<bench::SinewCurtainRun*>(m_run.get());
    return sinew_run ? &sinew_run->deformable_system() : nullptr;
  }
  /// FNV-1a over the node positions, the energy and the momentum along the rod (sinew-hashes'
  /// record of the benchmark's settings).
  std::uint64_t state_hash() override { return hash(*m_run); }
  static std::uint64_t hash(const bench::CurtainRun& run) {
    FnvHash h;
    const Vectors3 x = run.nodes();
    h.mix(x.data(), sizeof(double) * static_cast<std::size_t>(x.size()));
    h.mix(run.energy());
    h.mix(run.momentum_along_rod());
    return h.h;
  }

 private:
  std::unique_ptr<bench::CurtainRun> m_run;
  double m_frame_dt;
  int m_ticks;
  Index m_rigid_bodies;
};

}  // namespace sinew::scenes
