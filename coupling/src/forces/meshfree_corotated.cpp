// Corotated meshfree elasticity: see the header for the model, the correction and the forces.
#include "sinew/forces/meshfree_corotated.hpp"

#include "corotated_stress.hpp"
#include "element_support.hpp"
#include "signed_svd.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <numeric>
#include <utility>

namespace sinew {

namespace {

constexpr std::string_view kName = "meshfree corotated";
// M_i's smallest singular value below this fraction of its largest: the neighbours do not span space.
constexpr double kSingularMoment = 1.0e-8;

// Lucy's quartic, normalised in 3D: W(r) = 105 / (16 pi h^3) (1 + 3q)(1 - q)^3, and dW/dr.
double kernel(double r, double h) {
  const double q = r / h;
  if (q >= 1.0) return 0.0;
  return 105.0 / (16.0 * std::numbers::pi * h * h * h) * (1.0 + 3.0 * q) * std::pow(1.0 - q, 3);
}
double kernel_slope(double r, double h) {
  const double q = r / h;
  if (q >= 1.0) return 0.0;
  // d/dq [(1 + 3q)(1 - q)^3] = 3(1 - q)^3 - 3(1 + 3q)(1 - q)^2 = -12 q (1 - q)^2
  return 105.0 / (16.0 * std::numbers::pi * h * h * h) * (-12.0 * q * (1.0 - q) * (1.0 - q)) / h;
}

using detail::corotated_diagonal_stress;

}  // namespace

MeshfreeCorotated::MeshfreeCorotated(std::vector<Index> particles, const Vectors3& rest_x, std::vector<double> volumes,
                                     const MeshfreeCorotatedSettings& settings)
    : m_particles(std::move(particles)), m_volume(std::move(volumes)), m_settings(settings) {
  const double h = m_settings.support_radius;
  if (!(std::isfinite(h) && h > 0.0)) fail(kName, ": support_radius ", h, " must be positive and finite");
  detail::check_non_negative(kName, "young_modulus", m_settings.young_modulus);
  if (m_settings.young_modulus == 0.0) fail(kName, ": young_modulus is 0, expected > 0");
  const double nu = m_settings.poisson_ratio;
  if (!(nu > -1.0 && nu < 0.5)) fail(kName, ": poisson_ratio ", nu, " is outside (-1, 0.5)");
  detail::check_non_negative(kName, "beta", m_settings.beta);
  detail::check_non_negative(kName, "hourglass", m_settings.hourglass);
  m_mu = m_settings.young_modulus / (2.0 * (1.0 + nu));
  m_lambda = m_settings.young_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));

  const std::size_t count = m_particles.size();
  if (count == 0) fail(kName, ": no particles");
  if (m_volume.size() != count) fail(kName, ": ", m_volume.size(), " volumes for ", count, " particles");
  std::vector<Index> sorted = m_particles;
  std::sort(sorted.begin(), sorted.end());
  for (std::size_t k = 0; k < count; ++k) {
    if (sorted[k] < 0 || sorted[k] >= rest_x.cols())
      fail(kName, ": particle ", sorted[k], " is outside the ", rest_x.cols(), " rest positions");
    if (k > 0 && sorted[k] == sorted[k - 1]) fail(kName, ": particle ", sorted[k], " appears twice");
  }
  m_rest.resize(3, static_cast<Index>(count));
  for (std::size_t k = 0; k < count; ++k) {
    if (!(std::isfinite(m_volume[k]) && m_volume[k] > 0.0))
      fail(kName, ": particle ", m_particles[k], " has volume ", m_volume[k], ", expected > 0");
    m_rest.col(static_cast<Index>(k)) = rest_x.col(m_particles[k]);
    if (!m_rest.col(static_cast<Index>(k)).allFinite())
      fail(kName, ": particle ", m_particles[k], " has a non-finite rest position");
  }

  // Rest neighbourhoods: a sweep along x over the particles sorted by their rest x.
  std::vector<std::size_t> order(count);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return m_rest(0, static_cast<Index>(a)) < m_rest(0, static_cast<Index>(b)) ||
           (m_rest(0, static_cast<Index>(a)) == m_rest(0, static_cast<Index>(b)) && a < b);
  });
  std::vector<std::vector<Index>> near(count);
  for (std::size_t a = 0; a < count; ++a) {
    const Index i = static_cast<Index>(order[a]);
    for (std::size_t b = a + 1; b < count; ++b) {
      const Index j = static_cast<Index>(order[b]);
      if (m_rest(0, j) - m_rest(0, i) >= h) break;
      const double r = (m_rest.col(j) - m_rest.col(i)).norm();
      if (r <= 1e-12 * h)
        fail(kName, ": particles ", m_particles[static_cast<std::size_t>(i)], " and ",
             m_particles[static_cast<std::size_t>(j)], " share a rest position");
      if (r < h) {
        near[static_cast<std::size_t>(i)].push_back(j);
        near[static_cast<std::size_t>(j)].push_back(i);
      }
    }
  }
  m_offset.assign(count + 1, 0);
  for (std::size_t k = 0; k < count; ++k) {
    std::sort(near[k].begin(), near[k].end());
    m_offset[k + 1] = m_offset[k] + near[k].size();
  }
  m_neighbours.reserve(m_offset.back());
  for (const auto& list : near) m_neighbours.insert(m_neighbours.end(), list.begin(), list.end());

  // Corrected gradients and the penalty's weights.
  m_g.resize(m_neighbours.size());
  m_hg_weight.resize(m_neighbours.size());
  for (std::size_t k = 0; k < count; ++k) {
    Mat3 M = Mat3::Zero();
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
      const auto j = static_cast<std::size_t>(m_neighbours[e]);
      const Vec3 d = m_rest.col(static_cast<Index>(j)) - m_rest.col(static_cast<Index>(k));
      const double r = d.norm();
      const Vec3 grad = kernel_slope(r, h) / r * d;
      m_g[e] = grad;
      M += m_volume[j] * d * grad.transpose();
      m_hg_weight[e] = m_volume[k] * m_volume[j] * kernel(r, h) / (r * r);
    }
    const Eigen::JacobiSVD<Mat3> svd(M);
    const Vec3 s = svd.singularValues();
    if (!M.allFinite() || svd.info() != Eigen::Success || !(s(0) > 0.0) || s(2) < kSingularMoment * s(0))
      fail(kName, ": particle ", m_particles[k], " has ", m_offset[k + 1] - m_offset[k], " neighbours within h = ", h,
           " that do not span space (moment matrix singular values ", s.transpose(),
           "): a larger support radius or more particles around it");
    const Mat3 correction = M.inverse().transpose();
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) m_g[e] = correction * m_g[e];
  }
  // What every pass reads per neighbour entry: V_j g_kj and X_kj.
  m_vg.resize(m_neighbours.size());
  m_X.resize(m_neighbours.size());
  m_neighbour_particle.resize(m_neighbours.size());
  for (std::size_t k = 0; k < count; ++k)
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
      const auto j = static_cast<std::size_t>(m_neighbours[e]);
      m_vg[e] = m_volume[j] * m_g[e];
      m_neighbour_particle[e] = m_particles[j];
      m_X[e] = m_rest.col(static_cast<Index>(j)) - m_rest.col(static_cast<Index>(k));
    }
  m_fraction.assign(count, 1.0);
  m_state.resize(count);
  for (State& s : m_state) s.F.setConstant(std::numeric_limits<double>::quiet_NaN());
}

void MeshfreeCorotated::set_volume_fraction(Index particle, double fraction) {
  if (!(fraction > 0.0 && fraction <= 1.0))
    fail(kName, ": particle ", particle, ": volume fraction ", fraction, ", expected in (0, 1]");
  const auto at = std::find(m_particles.begin(), m_particles.end(), particle);
  if (at == m_particles.end()) fail(kName, ": particle ", particle, " is not one of its material particles");
  m_fraction[static_cast<std::size_t>(at - m_particles.begin())] = fraction;
}

void MeshfreeCorotated::validate(Index particle_count) const {
  for (const Index p : m_particles)
    if (p < 0 || p >= particle_count)
      fail(kName, ": particle ", p, " is outside the system's ", particle_count, " particles");
}

// Plain loops over raw columns: the passes' hot spots (the neighbour lists are long, the terms small).
Mat3 MeshfreeCorotated::gradient_of(const Vectors3& x, std::size_t k) const {
  const double* xk = x.col(m_particles[k]).data();
  double F[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};  // column-major
  for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
    const double* xj = x.col(m_neighbour_particle[e]).data();
    const double* g = m_vg[e].data();
    const double d0 = xj[0] - xk[0], d1 = xj[1] - xk[1], d2 = xj[2] - xk[2];
    for (int c = 0; c < 3; ++c) {
      F[3 * c + 0] += d0 * g[c];
      F[3 * c + 1] += d1 * g[c];
      F[3 * c + 2] += d2 * g[c];
    }
  }
  return Eigen::Map<const Mat3>(F);
}

void MeshfreeCorotated::update_position_state(const Vectors3& x) {
  m_state_x.resize(3, static_cast<Index>(m_particles.size()));
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    m_state_x.col(static_cast<Index>(k)) = x.col(m_particles[k]);
    State& s = m_state[k];
    s.F = gradient_of(x, k);
    const detail::SignedSvd svd = detail::signed_svd_from_eigen(s.F);
    s.U = svd.U;
    s.V = svd.V;
    s.R = svd.U * svd.V.transpose();
    s.sigma = svd.sigma;
    s.phat = corotated_diagonal_stress(svd.sigma, m_mu, m_lambda);
  }
}

double MeshfreeCorotated::potential_energy(const Vectors3& x) const {
  double energy = 0.0;
  for (std::size_t k = 0; k < m_particles.size(); ++k)
    energy += m_volume[k] * m_fraction[k] *
              detail::corotated_energy_density(detail::signed_svd_from_eigen(gradient_of(x, k)).sigma, m_mu, m_lambda);
  return energy + hourglass_energy(x);
}

// One pass over the stencils, three sweeps of each particle's neighbours (its F, the penalty's B, the
// scatter). For particle k: F_k of y (with `cached`, the state's, y being where it was cached); h_k = stress(k, F_k),
// V_k times a first Piola-Kirchhoff stress (or its differential, or a damping stress); with c = hourglass_scale alpha
// mu, the penalty's b_kj = c phi_k w_kj (y_j - y_k - F_k X_kj) and B_k = sum_j b_kj X_kj^T (the penalty.s gradient,
// derived above hourglass_energy). Then, with V_j g_kj stored per neighbour entry,
//   f_j += -b_kj + (B_k - h_k) V_j g_kj   (each neighbour j of k),   f_k -= the sum of those.
template <typename Stress>
void MeshfreeCorotated::stencil_pass(const Vectors3& y, double hourglass_scale, Vectors3& f, bool cached,
                                     Stress&& stress) const {
  const double c = hourglass_scale * m_settings.hourglass * m_mu;
  // The penalty's b_kj of a stencil, kept between its two sweeps (recomputed for a stencil this large).
  constexpr std::size_t kKept = 160;
  std::array<Vec3, kKept> kept;
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    const std::size_t begin = m_offset[k], end = m_offset[k + 1];
    const Vec3 yk = y.col(m_particles[k]);
    const Mat3 F = cached ? m_state[k].F : gradient_of(y, k);
    Mat3 H = -stress(k, F);
    const double ck = c * m_fraction[k];
    const bool keep = end - begin <= kKept;
    const auto b = [&](std::size_t e) {
      return Vec3((ck * m_hg_weight[e]) * (Vec3(y.col(m_neighbour_particle[e])) - yk - F * m_X[e]));
    };
    if (ck != 0.0)
      for (std::size_t e = begin; e < end; ++e) {
        const Vec3 be = b(e);
        if (keep) kept[e - begin] = be;
        H += be * m_X[e].transpose();
      }
    Vec3 sum = Vec3::Zero();
    for (std::size_t e = begin; e < end; ++e) {
      Vec3 t = H * m_vg[e];
      if (ck != 0.0) t -= keep ? kept[e - begin] : b(e);
      f.col(m_neighbour_particle[e]) += t;
      sum += t;
    }
    f.col(m_particles[k]) -= sum;
  }
}

// A step asks for the forces at the positions it just cached the state at: the cached F and SVD are
// then those of x to the bit (the same operations on the same numbers), and the pass skips its first
// sweep and the SVDs.
bool MeshfreeCorotated::state_is_at(const Vectors3& x) const {
  if (m_state_x.cols() != static_cast<Index>(m_particles.size())) return false;
  for (std::size_t k = 0; k < m_particles.size(); ++k)
    if (x.col(m_particles[k]) != m_state_x.col(static_cast<Index>(k))) return false;
  return true;
}

void MeshfreeCorotated::add_elastic_forces(const Vectors3& x, Vectors3& f) const {
  if (state_is_at(x)) {
    stencil_pass(x, 1.0, f, true, [&](std::size_t k, const Mat3&) {
      const State& s = m_state[k];
      return Mat3(m_volume[k] * m_fraction[k] * s.U * s.phat.asDiagonal() * s.V.transpose());
    });
    return;
  }
  stencil_pass(x, 1.0, f, false, [&](std::size_t k, const Mat3& F) {
    const detail::SignedSvd s = detail::signed_svd_from_eigen(F);
    return Mat3(m_volume[k] * m_fraction[k] * s.U * corotated_diagonal_stress(s.sigma, m_mu, m_lambda).asDiagonal() *
                s.V.transpose());
  });
}

// The corotated differential in the SVD frame (corotated_stress.hpp), per particle; the penalty is
// linear in the positions: its own differential.
void MeshfreeCorotated::add_elastic_differentials(const Vectors3& dx, Vectors3& df) const {
  stencil_pass(dx, 1.0, df, false, [&](std::size_t k, const Mat3& dF) {
    const State& s = m_state[k];
    const Mat3 dF_hat = s.U.transpose() * dF * s.V;
    const Mat3 dP_hat = detail::corotated_stress_differential(dF_hat, s.sigma, s.phat, m_mu, m_lambda);
    return Mat3(m_volume[k] * m_fraction[k] * s.U * dP_hat * s.V.transpose());
  });
}

void MeshfreeCorotated::add_damping_forces(const Vectors3& v, Vectors3& f) const { add_implicit_products(v, 0.0, f); }

// -(beta + b) V_k R (2 mu Edot + lambda tr(Edot) I) scattered by g, Edot = sym(R^T Fdot); plus b times
// the penalty's (exact, constant) differential.
void MeshfreeCorotated::add_implicit_products(const Vectors3& v, double b, Vectors3& f) const {
  const double hg = m_settings.implicit ? b : 0.0;
  const double scale = m_settings.beta + hg;
  if (scale == 0.0 && hg == 0.0) return;
  stencil_pass(v, hg, f, false, [&](std::size_t k, const Mat3& Fdot) {
    if (scale == 0.0) return Mat3(Mat3::Zero());
    const Mat3& R = m_state[k].R;
    const Mat3 RtFdot = R.transpose() * Fdot;
    const Mat3 Edot = 0.5 * (RtFdot + RtFdot.transpose());
    const Mat3 Sdot = 2.0 * m_mu * Edot + (m_lambda * Edot.trace()) * Mat3::Identity();
    return Mat3((m_volume[k] * m_fraction[k] * scale) * R * Sdot);  // applied as -h g, as a stress
  });
}

// E_hg = alpha mu / 2 sum_k phi_k sum_j w_kj |r_kj|^2, r_kj = x_j - x_k - F_k X_kj (linear in x, zero
// for affine x). With b_kj = alpha mu phi_k w_kj r_kj and B_k = sum_j b_kj X_kj^T, since
// F_k X_kj = sum_l V_l (x_l - x_k) (g_kl . X_kj):
//   -dE/dx_j = -b_kj + V_j B_k g_kj   (j a neighbour of k),   -dE/dx_k = -(sum over j of that);
// stencil_pass adds these with the stresses' terms.

double MeshfreeCorotated::largest_non_affine_residual(const Vectors3& x) const {
  double largest = 0.0;
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    const Mat3 F = gradient_of(x, k);
    const Vec3 xk = x.col(m_particles[k]);
    double departure = 0.0, size = 0.0;
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
      const double w = m_hg_weight[e] * m_X[e].squaredNorm() / m_volume[k];  // V_j W_kj
      departure += w * (Vec3(x.col(m_neighbour_particle[e])) - xk - F * m_X[e]).squaredNorm();
      size += w * m_X[e].squaredNorm();
    }
    if (size > 0.0) largest = std::max(largest, departure / size);
  }
  return largest;
}

double MeshfreeCorotated::hourglass_energy(const Vectors3& x) const {
  const double c = m_settings.hourglass * m_mu;
  if (c == 0.0) return 0.0;
  double energy = 0.0;
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    const Mat3 F = gradient_of(x, k);
    const Vec3 xk = x.col(m_particles[k]);
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
      const auto j = static_cast<std::size_t>(m_neighbours[e]);
      energy +=
          0.5 * c * m_fraction[k] * m_hg_weight[e] * (Vec3(x.col(m_particles[j])) - xk - F * m_X[e]).squaredNorm();
    }
  }
  return energy;
}

// What the step's linearisation misses (Force::turn_work_rate), as EdgeSprings counts it for a
// spring (tension times length, T l w^2 / 2 per squared step): particle k's stress, V_k phi_k times
// its largest principal stress |phat|, times half its material's squared turning rate w_k, the axial
// vector of skew(Fdot_k R_k^T) (Fdot_k the velocity's gradient through the same stencil as F_k). An
// explicit matrix linearises nothing: 0 (and for turn_stretch_rate below).
double MeshfreeCorotated::turn_work_rate(const Vectors3& x, const Vectors3& v) const {
  if (!m_settings.implicit) return 0.0;  // explicit: nothing linearised
  double sum = 0.0;
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    const detail::SignedSvd svd = detail::signed_svd_from_eigen(gradient_of(x, k));
    const double stress = corotated_diagonal_stress(svd.sigma, m_mu, m_lambda).cwiseAbs().maxCoeff();
    if (!(stress > 0.0)) continue;
    const Mat3 spin = gradient_of(v, k) * (svd.U * svd.V.transpose()).transpose();
    const Vec3 w(0.5 * (spin(2, 1) - spin(1, 2)), 0.5 * (spin(0, 2) - spin(2, 0)), 0.5 * (spin(1, 0) - spin(0, 1)));
    sum += 0.5 * m_volume[k] * m_fraction[k] * stress * w.squaredNorm();
  }
  return sum;
}

// Force::turn_stretch_rate: particle k's material turning at w_k (as above) and moved along tangents
// is stretched by (w_k dt)^2 / 2 across w_k, a strain eps (I - n n^T) with eps = (w_k dt)^2 / 2, whose
// energy V_k phi_k (mu |strain|^2 + lambda / 2 tr^2) is V_k phi_k (mu + lambda) / 2 |w_k|^4 dt^4
// (lambda taken at least 0).
double MeshfreeCorotated::turn_stretch_rate(const Vectors3& x, const Vectors3& v) const {
  if (!m_settings.implicit) return 0.0;
  const double modulus = 0.5 * (m_mu + std::max(m_lambda, 0.0));
  double sum = 0.0;
  for (std::size_t k = 0; k < m_particles.size(); ++k) {
    const detail::SignedSvd svd = detail::signed_svd_from_eigen(gradient_of(x, k));
    const Mat3 spin = gradient_of(v, k) * (svd.U * svd.V.transpose()).transpose();
    const Vec3 w(0.5 * (spin(2, 1) - spin(1, 2)), 0.5 * (spin(0, 2) - spin(2, 0)), 0.5 * (spin(1, 0) - spin(0, 1)));
    sum += m_volume[k] * m_fraction[k] * modulus * w.squaredNorm() * w.squaredNorm();
  }
  return sum;
}

// Per stencil k (the particle and its neighbours), as element_bound_stable_dt: at rest
//   dx^T K_k dx <= V_k (2 mu + 3 lambda+) |dF_k|^2 + alpha mu sum_j w_kj |dr_kj|^2
// (2 mu |sym dF|^2 + lambda tr(dF)^2, and tr(dF)^2 <= 3 |dF|^2),
// and |sum_a c_a dx_a|^2 <= (sum_a c_a^2 / m_a) |dx|_M^2 (Cauchy-Schwarz) for each linear map (dF_k's
// columns and each r_kj). omega^2 is at most the largest sum over the stencils a particle is in.
double MeshfreeCorotated::stable_dt(const VectorXd& m_eff) const {
  detail::check_mass_count(kName, m_eff, *std::max_element(m_particles.begin(), m_particles.end()) + 1);
  const std::size_t count = m_particles.size();
  std::vector<double> lambda_k(count, 0.0);
  const auto inv = [&](std::size_t a) { return detail::inverse_mass(m_eff[m_particles[a]]); };
  const double modulus = 2.0 * m_mu + 3.0 * std::max(m_lambda, 0.0);
  const double c = m_settings.hourglass * m_mu;
  for (std::size_t k = 0; k < count; ++k) {
    Vec3 self = Vec3::Zero();
    double sum = 0.0;
    for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
      const auto j = static_cast<std::size_t>(m_neighbours[e]);
      const Vec3 cj = m_volume[j] * m_g[e];
      self -= cj;
      sum += cj.squaredNorm() * inv(j);
    }
    sum += self.squaredNorm() * inv(k);
    double total = m_volume[k] * m_fraction[k] * modulus * sum;
    if (c > 0.0) {
      for (std::size_t e = m_offset[k]; e < m_offset[k + 1]; ++e) {
        const auto j = static_cast<std::size_t>(m_neighbours[e]);
        const Vec3 X = m_rest.col(static_cast<Index>(j)) - m_rest.col(static_cast<Index>(k));
        // r_kj's coefficients: on x_l, delta_lj - V_l g_kl . X; on x_k, -1 + sum_l V_l g_kl . X.
        double coefficients = 0.0, on_k = -1.0;
        for (std::size_t f = m_offset[k]; f < m_offset[k + 1]; ++f) {
          const auto l = static_cast<std::size_t>(m_neighbours[f]);
          const double w = m_volume[l] * m_g[f].dot(X);
          const double on_l = (l == j ? 1.0 : 0.0) - w;
          on_k += w;
          coefficients += on_l * on_l * inv(l);
        }
        coefficients += on_k * on_k * inv(k);
        total += c * m_fraction[k] * m_hg_weight[e] * coefficients;
      }
    }
    lambda_k[k] = total;
  }
  // Each particle's sum over the stencils it is in: its own and its neighbours'.
  double omega_sq = 0.0;
  for (std::size_t a = 0; a < count; ++a) {
    if (inv(a) == 0.0) continue;
    double sum = lambda_k[a];
    for (std::size_t e = m_offset[a]; e < m_offset[a + 1]; ++e)
      sum += lambda_k[static_cast<std::size_t>(m_neighbours[e])];
    omega_sq = std::max(omega_sq, sum);
  }
  return omega_sq > 0.0 ? 2.0 / std::sqrt(omega_sq) : kInfinity;
}

}  // namespace sinew
