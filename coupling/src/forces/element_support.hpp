// Private helpers shared by the element forces: input checks that name the bad item, and the
// stable time step bound shared by the FEM-like forces.
#pragma once

#include "sinew/parallel.hpp"
#include "sinew/types.hpp"

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

namespace sinew::detail {

/// Fails unless value is finite and >= 0: "edge springs: stiffness is nan".
inline void check_non_negative(std::string_view force, std::string_view field, double value) {
  if (std::isnan(value)) fail(force, ": ", field, " is nan");
  if (std::isinf(value)) fail(force, ": ", field, " is ", value > 0 ? "inf" : "-inf");
  if (value < 0.0) fail(force, ": ", field, " is negative (", value, ")");
}

/// Fails unless every vertex index of element e is in [0, particle_count) and none repeats:
/// "triangle 12: vertex index 900 out of range [0, 400)".
template <std::size_t K>
void check_element_indices(std::string_view kind, std::size_t e, const std::array<Index, K>& v, Index particle_count) {
  for (std::size_t a = 0; a < K; ++a) {
    if (v[a] < 0 || v[a] >= particle_count) {
      fail(kind, " ", e, ": vertex index ", v[a], " out of range [0, ", particle_count, ")");
    }
    for (std::size_t b = 0; b < a; ++b) {
      if (v[a] == v[b]) fail(kind, " ", e, ": vertex index ", v[a], " is repeated");
    }
  }
}

/// Fails if a rest position used by element e is not finite (it would poison the rest data).
template <std::size_t K>
void check_rest_positions(std::string_view kind, std::size_t e, const std::array<Index, K>& v, const Vectors3& rest_x) {
  for (Index i : v) {
    if (!rest_x.col(i).allFinite()) fail(kind, " ", e, ": rest position of vertex ", i, " is not finite");
  }
}

/// One past the largest index used by the elements (the length m_eff must have).
template <std::size_t K>
Index index_span(const std::vector<std::array<Index, K>>& elements) {
  Index span = 0;
  for (const auto& v : elements) {
    for (Index i : v) span = std::max(span, i + 1);
  }
  return span;
}

/// 1/m for rows with dynamics; 0 for kinematic (m = inf) and massless (m = 0) rows, which the
/// integrator does not advance with this force, so they cannot limit the step.
inline double inverse_mass(double m) { return (m > 0.0 && std::isfinite(m)) ? 1.0 / m : 0.0; }

inline void check_mass_count(std::string_view force, const VectorXd& m_eff, Index span) {
  if (m_eff.size() < span) fail(force, ": stable_dt got ", m_eff.size(), " masses, elements use ", span);
}

/// Vertex -> element incidence in compressed rows, built once so that stable_dt can sum over a
/// particle's elements without allocating or mutating anything.
struct Incidence {
  std::vector<Index> offsets;   ///< particle i's elements are elements[offsets[i] .. offsets[i+1])
  std::vector<Index> elements;  ///< element ids, ascending within each particle

  template <std::size_t K>
  static Incidence build(const std::vector<std::array<Index, K>>& element_vertices, Index particle_count) {
    Incidence inc;
    inc.offsets.assign(static_cast<std::size_t>(particle_count) + 1, 0);
    for (const auto& v : element_vertices) {
      for (Index i : v) ++inc.offsets[static_cast<std::size_t>(i) + 1];
    }
    for (std::size_t i = 0; i + 1 < inc.offsets.size(); ++i) inc.offsets[i + 1] += inc.offsets[i];
    inc.elements.resize(static_cast<std::size_t>(inc.offsets.back()));
    std::vector<Index> next(inc.offsets.begin(), inc.offsets.end() - 1);  // next free slot per particle
    for (std::size_t e = 0; e < element_vertices.size(); ++e) {
      for (Index i : element_vertices[e]) {
        inc.elements[static_cast<std::size_t>(next[static_cast<std::size_t>(i)]++)] = static_cast<Index>(e);
      }
    }
    return inc;
  }
};

/// Stable step bound shared by the membrane, bending and tet forces.
///
/// Each element's rest stiffness K_e is bounded in the mass norm by
///   x_e^T K_e x_e <= lambda_e |x_e|_M^2,  lambda_e = sum_{a in e} w_{e,a} / m_a,
/// with w_{e,a} precomputed per force (see each force's comment). Summing over elements,
///   x^T K x <= sum_e lambda_e sum_{i in e} m_i |x_i|^2 <= (max_i sum_{e ni i} lambda_e) |x|_M^2,
/// so omega_max^2 = lambda_max(M^-1 K) <= max_i sum_{e ni i} lambda_e, and the step 2/omega_max of
/// the central-difference (explicit Newmark) update is bounded from below by 2/sqrt(that sum).
/// Rows with zero inverse mass drop out: they are eliminated, not advanced.
template <std::size_t K>
double element_bound_stable_dt(std::string_view force, const std::vector<std::array<Index, K>>& elements,
                               const std::vector<std::array<double, K>>& weights,
                               const std::vector<Index>& incidence_offsets, const std::vector<Index>& incidence,
                               const VectorXd& m_eff) {
  check_mass_count(force, m_eff, static_cast<Index>(incidence_offsets.size()) - 1);
  double omega_sq = 0.0;
  const Index n = static_cast<Index>(incidence_offsets.size()) - 1;
  for (Index i = 0; i < n; ++i) {
    if (inverse_mass(m_eff[i]) == 0.0) continue;
    double sum = 0.0;
    const auto begin = static_cast<std::size_t>(incidence_offsets[static_cast<std::size_t>(i)]);
    const auto end = static_cast<std::size_t>(incidence_offsets[static_cast<std::size_t>(i) + 1]);
    for (std::size_t k = begin; k < end; ++k) {
      const auto e = static_cast<std::size_t>(incidence[k]);
      for (std::size_t a = 0; a < K; ++a) sum += weights[e][a] * inverse_mass(m_eff[elements[e][a]]);
    }
    omega_sq = std::max(omega_sq, sum);
  }
  return omega_sq > 0.0 ? 2.0 / std::sqrt(omega_sq) : kInfinity;
}

/// Accumulates a fixed-size element stencil into a 3 x N array, in vertex order.
template <std::size_t K, typename Stencil>
inline void scatter(const std::array<Index, K>& v, const Stencil& f_e, Vectors3& f) {
  for (std::size_t a = 0; a < K; ++a) f.col(v[a]) += f_e.col(static_cast<Index>(a));
}

/// Gathers the element's columns of a 3 x N array into a fixed-size 3 x K stencil.
template <std::size_t K>
inline Eigen::Matrix<double, 3, static_cast<int>(K)> gather(const std::array<Index, K>& v, const Vectors3& x) {
  Eigen::Matrix<double, 3, static_cast<int>(K)> x_e;
  for (std::size_t a = 0; a < K; ++a) x_e.col(static_cast<Index>(a)) = x.col(v[a]);
  return x_e;
}

/// The elements with no node flagged in `removed` (one flag per particle; nodes past its end count as
/// kept), in their order.
template <std::size_t K>
std::vector<std::array<Index, K>> elements_without(const std::vector<std::array<Index, K>>& elements,
                                                   std::span<const std::uint8_t> removed) {
  auto gone = [&](Index i) {
    return i < static_cast<Index>(removed.size()) && removed[static_cast<std::size_t>(i)] != 0;
  };
  std::vector<std::array<Index, K>> kept;
  for (const auto& e : elements)
    if (std::none_of(e.begin(), e.end(), gone)) kept.push_back(e);
  return kept;
}
inline Stencils elements_without(const Stencils& elements, std::span<const std::uint8_t> removed) {
  auto gone = [&](Index i) {
    return i < static_cast<Index>(removed.size()) && removed[static_cast<std::size_t>(i)] != 0;
  };
  Stencils kept;
  for (Index e = 0; e < elements.size(); ++e)
    if (std::none_of(elements[e].begin(), elements[e].end(), gone)) kept.push_back(elements[e]);
  return kept;
}
inline Index element_count(const Stencils& elements) { return elements.size(); }
template <typename E>
Index element_count(const std::vector<E>& elements) {
  return static_cast<Index>(elements.size());
}

/// Force::remove_elements_touching for a force built as Force(elements, rest_x, settings): the force
/// is built again from the elements that remain, with the rest positions and settings it was built
/// with, so it is exactly the force those elements alone would have made.
template <typename ElementForce, typename Elements, typename Settings>
Index rebuild_without(ElementForce& force, const Elements& elements, std::span<const std::uint8_t> removed,
                      const Vectors3& rest_x, const Settings& settings) {
  Elements kept = elements_without(elements, removed);
  const Index dropped = element_count(elements) - element_count(kept);
  if (dropped > 0) force = ElementForce(std::move(kept), rest_x, settings);
  return dropped;
}

}  // namespace sinew::detail
