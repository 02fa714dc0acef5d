#include "multigrid.hpp"

#include "sinew/parallel.hpp"

#include <algorithm>
#include <cstdint>
#include <numeric>

namespace sinew {

namespace {

using Blocks = AggregationMultigrid::Blocks;

Eigen::Map<Mat3> block_at(Blocks& b, Index k) { return Eigen::Map<Mat3>(b.col(k).data()); }
Eigen::Map<const Mat3> block_at(const Blocks& b, Index k) { return Eigen::Map<const Mat3>(b.col(k).data()); }

/// One round of pairwise matching: each node in index order, if still unmatched, takes its strongest
/// unmatched neighbour (ties to the lowest index); a node without one stays alone.
Index match_pairs(Index n, const std::vector<std::array<Index, 2>>& pairs, const std::vector<double>& strength,
                  std::vector<Index>& agg) {
  // Adjacency (CSR, neighbours ascending because pairs are sorted by (i, j) and added both ways).
  std::vector<Index> offset(static_cast<std::size_t>(n) + 1, 0);
  for (const auto& p : pairs) {
    ++offset[static_cast<std::size_t>(p[0]) + 1];
    ++offset[static_cast<std::size_t>(p[1]) + 1];
  }
  for (std::size_t i = 1; i < offset.size(); ++i) offset[i] += offset[i - 1];
  std::vector<Index> nbr(static_cast<std::size_t>(offset.back()));
  std::vector<double> s(nbr.size());
  std::vector<Index> fill(offset.begin(), offset.end() - 1);
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const Index i = pairs[k][0], j = pairs[k][1];
    nbr[static_cast<std::size_t>(fill[static_cast<std::size_t>(i)])] = j;
    s[static_cast<std::size_t>(fill[static_cast<std::size_t>(i)]++)] = strength[k];
    nbr[static_cast<std::size_t>(fill[static_cast<std::size_t>(j)])] = i;
    s[static_cast<std::size_t>(fill[static_cast<std::size_t>(j)]++)] = strength[k];
  }
  agg.assign(static_cast<std::size_t>(n), -1);
  Index count = 0;
  for (Index i = 0; i < n; ++i) {
    if (agg[static_cast<std::size_t>(i)] >= 0) continue;
    Index best = -1;
    double best_s = 0.0;
    for (Index k = offset[static_cast<std::size_t>(i)]; k < offset[static_cast<std::size_t>(i) + 1]; ++k) {
      const Index j = nbr[static_cast<std::size_t>(k)];
      const double sj = s[static_cast<std::size_t>(k)];
      if (agg[static_cast<std::size_t>(j)] < 0 && (sj > best_s || (sj == best_s && best >= 0 && j < best))) {
        best = j;
        best_s = sj;
      }
    }
    agg[static_cast<std::size_t>(i)] = count;
    if (best >= 0) agg[static_cast<std::size_t>(best)] = count;
    ++count;
  }
  return count;
}

/// Orders items by their key (a, b), both in [0, n), ascending and stably: a counting sort by b, then
/// one by a (linear in the items and n, where a comparison sort of a fine cloth's pairs took most of
/// the hierarchy's build).
template <typename Item, typename KeyOf>
void sort_by_pair(std::vector<Item>& items, Index n, KeyOf&& key_of) {
  std::vector<Item> scratch(items.size());
  std::vector<Index> start(static_cast<std::size_t>(n) + 1);
  for (int pass = 1; pass >= 0; --pass) {
    std::fill(start.begin(), start.end(), 0);
    for (const Item& item : items) ++start[static_cast<std::size_t>(key_of(item)[pass]) + 1];
    for (std::size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
    for (const Item& item : items)
      scratch[static_cast<std::size_t>(start[static_cast<std::size_t>(key_of(item)[pass])]++)] = item;
    items.swap(scratch);
  }
}

/// One past the largest index in agg (0 if empty).
Index index_span(const std::vector<Index>& agg) {
  Index n = 0;
  for (Index a : agg) n = std::max(n, a + 1);
  return n;
}

/// The pairs between distinct aggregates, merged and sorted, with the summed strengths.
void merge_pairs(const std::vector<std::array<Index, 2>>& pairs, const std::vector<double>& strength,
                 const std::vector<Index>& agg, std::vector<std::array<Index, 2>>& out,
                 std::vector<double>& out_strength) {
  std::vector<std::pair<std::array<Index, 2>, double>> mapped;
  mapped.reserve(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    Index a = agg[static_cast<std::size_t>(pairs[k][0])], b = agg[static_cast<std::size_t>(pairs[k][1])];
    if (a == b) continue;
    if (a > b) std::swap(a, b);
    mapped.push_back({{a, b}, strength[k]});
  }
  sort_by_pair(mapped, index_span(agg), [](const auto& m) -> const std::array<Index, 2>& { return m.first; });
  out.clear();
  out_strength.clear();
  for (const auto& m : mapped) {
    if (!out.empty() && out.back() == m.first) {
      out_strength.back() += m.second;
    } else {
      out.push_back(m.first);
      out_strength.push_back(m.second);
    }
  }
}

/// coarse.col(a) = sum of fine.col(i) over the members i of aggregate a, ascending.
template <int Rows>
void restrict_to(const AggregationMultigrid::Members& members, const Eigen::Matrix<double, Rows, Eigen::Dynamic>& fine,
                 Eigen::Matrix<double, Rows, Eigen::Dynamic>& coarse) {
  const auto n = static_cast<Index>(members.offset.size()) - 1;
  parallel::for_ranges(n, [&](Index a0, Index a1) {
    for (Index a = a0; a < a1; ++a) {
      Eigen::Matrix<double, Rows, 1> sum = Eigen::Matrix<double, Rows, 1>::Zero();
      for (Index k = members.offset[static_cast<std::size_t>(a)]; k < members.offset[static_cast<std::size_t>(a) + 1];
           ++k)
        sum += fine.col(members.index[static_cast<std::size_t>(k)]);
      coarse.col(a) = sum;
    }
  });
}

/// fine.col(i) += coarse.col(agg[i]) where agg[i] >= 0.
void prolong_add(const std::vector<Index>& agg, const Vectors3& coarse, Vectors3& fine) {
  parallel::for_ranges(static_cast<Index>(agg.size()), [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      const Index a = agg[static_cast<std::size_t>(i)];
      if (a >= 0) fine.col(i) += coarse.col(a);
    }
  });
}

/// A fine pair block B as plan code `code` places it on the coarser level: B + B^T in an aggregate's
/// diagonal block, B^T in a pair block stored the other way round (odd code), else B.
Mat3 placed(Index code, const Mat3& block) {
  if (code < 0) return block + block.transpose();
  if (code & 1) return block.transpose();
  return block;
}

/// Every target block of `gather` (diagonal blocks into diag, then pair blocks into pairs) adds its
/// terms in order, term k being scale * placed(plan[k], block_of(k)): what a serial pass over k
/// adds, bit for bit, in parallel over targets.
template <typename BlockOf>
void gather_blocks(const AggregationMultigrid::Gather& gather, const std::vector<Index>& plan, double scale,
                   AggregationMultigrid::Blocks& diag, AggregationMultigrid::Blocks& pairs, BlockOf&& block_of) {
  auto add_terms = [&](Index t, Eigen::Map<Mat3> target) {
    Mat3 sum = target;
    for (Index e = gather.offset[static_cast<std::size_t>(t)]; e < gather.offset[static_cast<std::size_t>(t) + 1];
         ++e) {
      const Index k = gather.term[static_cast<std::size_t>(e)];
      sum += scale * placed(plan[static_cast<std::size_t>(k)], block_of(k));
    }
    target = sum;
  };
  const Index n = gather.diag_targets, pair_count = static_cast<Index>(gather.offset.size()) - 1 - n;
  parallel::for_ranges(n, [&](Index t0, Index t1) {
    for (Index t = t0; t < t1; ++t) add_terms(t, block_at(diag, t));
  });
  parallel::for_ranges(pair_count, [&](Index p0, Index p1) {
    for (Index p = p0; p < p1; ++p) add_terms(n + p, block_at(pairs, p));
  });
}

}  // namespace

void AggregationMultigrid::Gather::build(const std::vector<Index>& plan, Index diag_count, Index pair_count) {
  diag_targets = diag_count;
  auto target = [&](Index code) { return code < 0 ? -2 - code : diag_count + (code >> 1); };
  offset.assign(static_cast<std::size_t>(diag_count + pair_count) + 1, 0);
  for (Index code : plan)
    if (code != kSkip) ++offset[static_cast<std::size_t>(target(code)) + 1];
  for (std::size_t t = 1; t < offset.size(); ++t) offset[t] += offset[t - 1];
  term.resize(static_cast<std::size_t>(offset.back()));
  std::vector<Index> fill(offset.begin(), offset.end() - 1);
  for (std::size_t k = 0; k < plan.size(); ++k)
    if (plan[k] != kSkip)
      term[static_cast<std::size_t>(fill[static_cast<std::size_t>(target(plan[k]))]++)] = static_cast<Index>(k);
}

void AggregationMultigrid::Members::build(const std::vector<Index>& agg, Index aggregates) {
  offset.assign(static_cast<std::size_t>(aggregates) + 1, 0);
  for (Index a : agg)
    if (a >= 0) ++offset[static_cast<std::size_t>(a) + 1];
  for (std::size_t k = 1; k < offset.size(); ++k) offset[k] += offset[k - 1];
  index.resize(static_cast<std::size_t>(offset.back()));
  std::vector<Index> fill(offset.begin(), offset.end() - 1);
  for (std::size_t i = 0; i < agg.size(); ++i)
    if (agg[i] >= 0) index[static_cast<std::size_t>(fill[static_cast<std::size_t>(agg[i])]++)] = static_cast<Index>(i);
}

void AggregationMultigrid::reset() {
  m_built = false;
  m_omega_ready = false;
  m_recording = false;
  m_awaiting_level1 = false;
  m_levels.clear();
  m_agg0.clear();
  m_plan0.clear();
  m_gather0 = {};
  m_recorded_pairs.clear();
  m_recorded_strength.clear();
}

void AggregationMultigrid::reserve(std::size_t pairs) {
  if (!m_recording) return;
  m_recorded_pairs.reserve(pairs);
  m_recorded_strength.reserve(pairs);
}

Index AggregationMultigrid::level_size(int l) const {
  if (l == 0) return static_cast<Index>(std::count_if(m_agg0.begin(), m_agg0.end(), [](Index a) { return a >= 0; }));
  return m_levels[static_cast<std::size_t>(l - 1)].n;
}

Index AggregationMultigrid::aggregate(Index n, const std::vector<std::array<Index, 2>>& pairs,
                                      const std::vector<double>& strength, std::vector<Index>& agg) {
  std::vector<Index> first, second;
  const Index half = match_pairs(n, pairs, strength, first);
  std::vector<std::array<Index, 2>> mid_pairs;
  std::vector<double> mid_strength;
  merge_pairs(pairs, strength, first, mid_pairs, mid_strength);
  const Index count = match_pairs(half, mid_pairs, mid_strength, second);
  agg.resize(static_cast<std::size_t>(n));
  for (Index i = 0; i < n; ++i)
    agg[static_cast<std::size_t>(i)] = second[static_cast<std::size_t>(first[static_cast<std::size_t>(i)])];
  return count;
}

void AggregationMultigrid::coarse_pairs(const std::vector<std::array<Index, 2>>& pairs, const std::vector<Index>& agg,
                                        std::vector<std::array<Index, 2>>& coarse, std::vector<Index>& plan) {
  // The crossing pairs, each with the fine pair it came from, sorted by their coarse key: equal keys
  // are then adjacent, and each fine pair's plan code is its key's place among the distinct keys.
  struct Crossing {
    std::array<Index, 2> key;
    Index fine;
  };
  std::vector<Crossing> crossing;
  crossing.reserve(pairs.size());
  plan.resize(pairs.size());
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const Index a = agg[static_cast<std::size_t>(pairs[k][0])], b = agg[static_cast<std::size_t>(pairs[k][1])];
    if (a < 0 || b < 0) {  // an end without unknowns (level 0's bound or kinematic rows)
      plan[k] = kSkip;
    } else if (a == b) {
      plan[k] = encode_diag(a);
    } else {
      crossing.push_back({{std::min(a, b), std::max(a, b)}, static_cast<Index>(k)});
    }
  }
  sort_by_pair(crossing, index_span(agg), [](const Crossing& c) -> const std::array<Index, 2>& { return c.key; });
  coarse.clear();
  for (const Crossing& c : crossing) {
    if (coarse.empty() || coarse.back() != c.key) coarse.push_back(c.key);
    const auto& fine = pairs[static_cast<std::size_t>(c.fine)];
    const bool transposed = agg[static_cast<std::size_t>(fine[0])] > agg[static_cast<std::size_t>(fine[1])];
    plan[static_cast<std::size_t>(c.fine)] = encode_pair(static_cast<Index>(coarse.size()) - 1, transposed);
  }
}

// Each row lists its entries S_ij x_j with i < j (blocks as stored) before those with i > j
// (transposed), so the matvec runs two branch-free loops per row.
void AggregationMultigrid::build_rows(Level& level) {
  level.row_offset.assign(static_cast<std::size_t>(level.n) + 1, 0);
  std::vector<Index> upper(static_cast<std::size_t>(level.n), 0);
  for (const auto& p : level.pairs) {
    ++level.row_offset[static_cast<std::size_t>(p[0]) + 1];
    ++level.row_offset[static_cast<std::size_t>(p[1]) + 1];
    ++upper[static_cast<std::size_t>(p[0])];
  }
  for (std::size_t i = 1; i < level.row_offset.size(); ++i) level.row_offset[i] += level.row_offset[i - 1];
  const auto entries = static_cast<std::size_t>(level.row_offset.back());
  level.row_col.resize(entries);
  level.row_pair.resize(entries);
  level.row_mid.resize(static_cast<std::size_t>(level.n));
  std::vector<Index> fill_upper(level.row_offset.begin(), level.row_offset.end() - 1),
      fill_lower(static_cast<std::size_t>(level.n));
  for (Index i = 0; i < level.n; ++i) {
    level.row_mid[static_cast<std::size_t>(i)] =
        level.row_offset[static_cast<std::size_t>(i)] + upper[static_cast<std::size_t>(i)];
    fill_lower[static_cast<std::size_t>(i)] = level.row_mid[static_cast<std::size_t>(i)];
  }
  for (std::size_t k = 0; k < level.pairs.size(); ++k) {
    const Index i = level.pairs[k][0], j = level.pairs[k][1];
    const auto e = static_cast<std::size_t>(fill_upper[static_cast<std::size_t>(i)]++);  // row i: S_ij x_j
    level.row_col[e] = j;
    level.row_pair[e] = static_cast<Index>(k);
    const auto t = static_cast<std::size_t>(fill_lower[static_cast<std::size_t>(j)]++);  // row j: S_ij^T x_i
    level.row_col[t] = i;
    level.row_pair[t] = static_cast<Index>(k);
  }
}

void AggregationMultigrid::begin(const VectorXd& unknown, const Blocks& diag, double scale) {
  m_scale = scale;
  m_cursor = 0;
  if (!m_built) {
    m_particles = unknown.size();
    m_recording = true;
    m_unknown0 = unknown;
    m_recorded_pairs.clear();
    m_recorded_strength.clear();
    return;
  }
  if (unknown.size() != m_particles) fail("multigrid: ", unknown.size(), " particles, built for ", m_particles);
  Level& l1 = m_levels.front();
  restrict_to(m_members0, diag, l1.diag);
  l1.pair_block.setZero();
}

void AggregationMultigrid::add_to_level1(Index code, const Mat3& block) {
  if (code == kSkip) return;
  Level& l1 = m_levels.front();
  auto target = code < 0 ? block_at(l1.diag, -2 - code) : block_at(l1.pair_block, code >> 1);
  target += m_scale * placed(code, block);
}

void AggregationMultigrid::add(Index i, Index j, const Mat3& block) {
  if (m_recording) {
    m_recorded_pairs.push_back({i, j});
    m_recorded_strength.push_back(block.norm());
    return;
  }
  if (m_cursor >= m_plan0.size())
    fail("multigrid: the forces passed more pair blocks than when the hierarchy was built");
  add_to_level1(m_plan0[m_cursor++], block);
}

bool AggregationMultigrid::gather(const std::vector<PairBlockSource>& sources) {
  m_source_base.resize(sources.size() + 1);  // before the hierarchy exists too: no allocation later
  if (!m_built || m_recording || m_cursor != 0) return false;
  m_source_base[0] = 0;
  for (std::size_t f = 0; f < sources.size(); ++f) {
    const Index count = sources[f].blocks->pair_block_count();
    if (count == 0) return false;
    m_source_base[f + 1] = m_source_base[f] + count;
  }
  if (m_source_base.back() != static_cast<Index>(m_plan0.size())) return false;
  Level& l1 = m_levels.front();
  gather_blocks(m_gather0, m_plan0, m_scale, l1.diag, l1.pair_block, [&](Index k) {
    std::size_t f = 0;
    while (k >= m_source_base[f + 1]) ++f;
    return sources[f].blocks->pair_block(k - m_source_base[f], sources[f].b);
  });
  m_cursor = m_plan0.size();
  return true;
}

void AggregationMultigrid::allocate(Level& level) {
  level.diag.setZero(9, level.n);
  level.inverse.setZero(9, level.n);
  level.pair_block.setZero(9, static_cast<Index>(level.pairs.size()));
  level.x.setZero(3, level.n);
  level.b.setZero(3, level.n);
  level.t.setZero(3, level.n);
  build_rows(level);
}

void AggregationMultigrid::plan_level1(const VectorXd& unknown) {
  // Level 0: the unknown particles, their pairs (merged, with the summed block norms as strengths).
  const Index n = unknown.size();
  std::vector<Index> local(static_cast<std::size_t>(n), -1);
  Index n0 = 0;
  for (Index i = 0; i < n; ++i)
    if (unknown[i] > 0.0) local[static_cast<std::size_t>(i)] = n0++;
  std::vector<std::array<Index, 2>> raw;
  std::vector<double> raw_strength;
  raw.reserve(m_recorded_pairs.size());
  raw_strength.reserve(m_recorded_pairs.size());
  for (std::size_t k = 0; k < m_recorded_pairs.size(); ++k) {
    const Index a = local[static_cast<std::size_t>(m_recorded_pairs[k][0])],
                b = local[static_cast<std::size_t>(m_recorded_pairs[k][1])];
    if (a < 0 || b < 0 || a == b) continue;
    raw.push_back({std::min(a, b), std::max(a, b)});
    raw_strength.push_back(m_recorded_strength[k]);
  }
  std::vector<Index> identity(static_cast<std::size_t>(n0));
  std::iota(identity.begin(), identity.end(), Index(0));
  std::vector<std::array<Index, 2>> pairs0;
  std::vector<double> strength0;
  merge_pairs(raw, raw_strength, identity, pairs0, strength0);

  std::vector<Index> agg_local;
  Index n1 = aggregate(n0, pairs0, strength0, agg_local);
  m_agg0.assign(static_cast<std::size_t>(n), -1);
  for (Index i = 0; i < n; ++i)
    if (local[static_cast<std::size_t>(i)] >= 0)
      m_agg0[static_cast<std::size_t>(i)] = agg_local[static_cast<std::size_t>(local[static_cast<std::size_t>(i)])];
  m_members0.build(m_agg0, n1);

  // Level 1 and its plan from the recorded pairs (in particle numbering, -1 off the unknowns).
  m_levels.clear();
  m_levels.emplace_back();
  {
    Level& l1 = m_levels.back();
    l1.n = n1;
    coarse_pairs(m_recorded_pairs, m_agg0, l1.pairs, m_plan0);
    m_gather0.build(m_plan0, l1.n, static_cast<Index>(l1.pairs.size()));
  }
  allocate(m_levels.back());
  m_built = true;
  m_recording = false;
  m_awaiting_level1 = true;
  m_recorded_pairs = {};
  m_recorded_strength = {};
}

// Level 1's blocks are summed (the second pass): each coarser level is aggregated from the blocks of
// the one above.
void AggregationMultigrid::build_coarser_levels() {
  while (static_cast<int>(m_levels.size()) + 1 < kMaxLevels && m_levels.back().n > kCoarsestNodes) {
    const int l = static_cast<int>(m_levels.size()) - 1;
    Level& fine = m_levels[static_cast<std::size_t>(l)];
    std::vector<double> strength(fine.pairs.size());
    for (std::size_t k = 0; k < fine.pairs.size(); ++k)
      strength[k] = block_at(fine.pair_block, static_cast<Index>(k)).norm();
    std::vector<Index> agg;
    const Index coarse_n = aggregate(fine.n, fine.pairs, strength, agg);
    if (coarse_n * 5 > fine.n * 4) break;  // coarsening stalled (weakly coupled nodes): stop here
    Level next;
    next.n = coarse_n;
    coarse_pairs(fine.pairs, agg, next.pairs, fine.pair_plan);
    fine.gather.build(fine.pair_plan, coarse_n, static_cast<Index>(next.pairs.size()));
    fine.agg = std::move(agg);
    fine.members.build(fine.agg, coarse_n);
    m_levels.push_back(std::move(next));
    allocate(m_levels.back());
    assemble_next(l);
  }
  // A coarsest level that stayed large (coarsening stalled: forces without pair blocks, such as tets,
  // couple nothing here) is smoothed by block Jacobi instead of factored densely.
  m_dense_coarsest = m_levels.back().n <= kMaxDenseNodes;
  const Index dense = m_dense_coarsest ? 3 * m_levels.back().n : 0;
  m_dense.setZero(dense, dense);
  m_dense_rhs.setZero(dense);
  m_awaiting_level1 = false;
}

void AggregationMultigrid::assemble_next(int l) {
  const Level& fine = m_levels[static_cast<std::size_t>(l)];
  Level& coarse = m_levels[static_cast<std::size_t>(l) + 1];
  restrict_to(fine.members, fine.diag, coarse.diag);
  coarse.pair_block.setZero();
  gather_blocks(fine.gather, fine.pair_plan, 1.0, coarse.diag, coarse.pair_block,
                [&](Index k) -> Mat3 { return block_at(fine.pair_block, k); });
}

void AggregationMultigrid::invert_diagonals(Level& level) const {
  parallel::for_ranges(level.n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      const Mat3 d = block_at(level.diag, i);
      block_at(level.inverse, i) = d.inverse();
    }
  });
}

void AggregationMultigrid::end() {
  if (m_recording) {
    plan_level1(m_unknown0);  // chooses level 1's aggregates; the blocks come again
    m_unknown0.resize(0);
    return;
  }
  if (m_cursor != m_plan0.size())
    fail("multigrid: the forces passed ", m_cursor, " pair blocks, ", m_plan0.size(), " when the hierarchy was built");
  if (m_awaiting_level1) {
    build_coarser_levels();  // aggregates and assembles every coarser level from level 1
  } else {
    for (int l = 0; l + 1 < static_cast<int>(m_levels.size()); ++l) assemble_next(l);
  }
  for (std::size_t l = 0; l + 1 < m_levels.size(); ++l) invert_diagonals(m_levels[l]);
  if (!m_dense_coarsest) invert_diagonals(m_levels.back());
  if (!m_omega_ready) estimate_omegas();
  if (!m_dense_coarsest) return;
  // The coarsest level, dense: diagonal blocks and both triangles of every pair.
  const Level& last = m_levels.back();
  m_dense.setZero();
  for (Index i = 0; i < last.n; ++i) m_dense.block<3, 3>(3 * i, 3 * i) = block_at(last.diag, i);
  for (std::size_t k = 0; k < last.pairs.size(); ++k) {
    const Index i = last.pairs[k][0], j = last.pairs[k][1];
    const auto block = block_at(last.pair_block, static_cast<Index>(k));
    m_dense.block<3, 3>(3 * i, 3 * j) += block;
    m_dense.block<3, 3>(3 * j, 3 * i) += block.transpose();
  }
  m_coarsest.compute(m_dense);
  if (m_coarsest.info() != Eigen::Success)
    fail("multigrid: the coarsest operator (", last.n, " nodes) is not positive definite");
}

void AggregationMultigrid::matvec(const Level& level, const Vectors3& x, Vectors3& y) const {
  const double* px = x.data();
  double* py = y.data();
  const double* pd = level.diag.data();
  const double* pb = level.pair_block.data();
  parallel::for_ranges(level.n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      const double* d = pd + 9 * i;
      const double* xi = px + 3 * i;
      double y0 = (d[0] * xi[0] + d[3] * xi[1]) + d[6] * xi[2];
      double y1 = (d[1] * xi[0] + d[4] * xi[1]) + d[7] * xi[2];
      double y2 = (d[2] * xi[0] + d[5] * xi[1]) + d[8] * xi[2];
      const Index mid = level.row_mid[static_cast<std::size_t>(i)];
      for (Index e = level.row_offset[static_cast<std::size_t>(i)]; e < mid; ++e) {
        const double* B = pb + 9 * level.row_pair[static_cast<std::size_t>(e)];
        const double* xj = px + 3 * level.row_col[static_cast<std::size_t>(e)];
        y0 += (B[0] * xj[0] + B[3] * xj[1]) + B[6] * xj[2];
        y1 += (B[1] * xj[0] + B[4] * xj[1]) + B[7] * xj[2];
        y2 += (B[2] * xj[0] + B[5] * xj[1]) + B[8] * xj[2];
      }
      for (Index e = mid; e < level.row_offset[static_cast<std::size_t>(i) + 1];
           ++e) {  // S_ij^T x_j: rows of S_ij^T are B's columns
        const double* B = pb + 9 * level.row_pair[static_cast<std::size_t>(e)];
        const double* xj = px + 3 * level.row_col[static_cast<std::size_t>(e)];
        y0 += (B[0] * xj[0] + B[1] * xj[1]) + B[2] * xj[2];
        y1 += (B[3] * xj[0] + B[4] * xj[1]) + B[5] * xj[2];
        y2 += (B[6] * xj[0] + B[7] * xj[1]) + B[8] * xj[2];
      }
      py[3 * i] = y0;
      py[3 * i + 1] = y1;
      py[3 * i + 2] = y2;
    }
  });
}

namespace {

/// x (+)= omega D^-1 b per node, D^-1 given as 9 x n column-major blocks.
void jacobi(Index n, double omega, const Blocks& inverse, const Vectors3& b, Vectors3& x, bool accumulate) {
  const double* pi = inverse.data();
  const double* pb = b.data();
  double* px = x.data();
  parallel::for_ranges(n, [&](Index i0, Index i1) {
    for (Index i = i0; i < i1; ++i) {
      const double* B = pi + 9 * i;
      const double b0 = pb[3 * i], b1 = pb[3 * i + 1], b2 = pb[3 * i + 2];
      const double z0 = omega * ((B[0] * b0 + B[3] * b1) + B[6] * b2);
      const double z1 = omega * ((B[1] * b0 + B[4] * b1) + B[7] * b2);
      const double z2 = omega * ((B[2] * b0 + B[5] * b1) + B[8] * b2);
      if (accumulate) {
        px[3 * i] += z0;
        px[3 * i + 1] += z1;
        px[3 * i + 2] += z2;
      } else {
        px[3 * i] = z0;
        px[3 * i + 1] = z1;
        px[3 * i + 2] = z2;
      }
    }
  });
}

/// t = b - t, over n nodes.
void residual_in_place(Index n, const Vectors3& b, Vectors3& t) {
  parallel::for_ranges(n, [&](Index i0, Index i1) {
    t.middleCols(i0, i1 - i0) = b.middleCols(i0, i1 - i0) - t.middleCols(i0, i1 - i0);
  });
}

}  // namespace

namespace {

/// A fixed pseudo-random start vector in [-1, 1) for the power iterations (the same every run).
void start_vector(Vectors3& v) {
  std::uint64_t state = 0x9E3779B97F4A7C15ull;
  for (Index i = 0; i < v.cols(); ++i)
    for (Index c = 0; c < 3; ++c) {
      state = state * 6364136223846793005ull + 1442695040888963407ull;
      v(c, i) = static_cast<double>(state >> 11) * 0x1.0p-53 * 2.0 - 1.0;
    }
}

constexpr int kPowerIterations = 15;
/// omega = kSmoothing / lambda_max(D^-1 S): the smoothing sweep scales the stiffest mode's error by
/// 1 - kSmoothing, safely inside the (0, 2) that keeps the V-cycle positive definite even when the
/// power iterations underestimate lambda_max or the operator stiffens later.
constexpr double kSmoothing = 1.1;

}  // namespace

// lambda_max(D^-1 S) of every smoothed level by power iterations, once, from the first operator
// (like the aggregates): the damping that makes block Jacobi a smoother there.
void AggregationMultigrid::estimate_omegas() {
  for (std::size_t l = 0; l < m_levels.size(); ++l) {
    if (l + 1 == m_levels.size() && m_dense_coarsest) break;  // solved exactly, not smoothed
    Level& level = m_levels[l];
    Vectors3& v = level.x;
    start_vector(v);
    double lambda = 0.0;
    for (int k = 0; k < kPowerIterations; ++k) {
      const double norm = v.norm();
      if (!(norm > 0.0)) break;
      v /= norm;
      matvec(level, v, level.t);
      jacobi(level.n, 1.0, level.inverse, level.t, v, false);
      lambda = v.norm();
    }
    level.omega = lambda > 0.0 ? kSmoothing / lambda : 0.5;
  }
  m_omega_ready = true;
}

void AggregationMultigrid::cycle(int k) {
  Level& level = m_levels[static_cast<std::size_t>(k)];
  if (k + 1 == static_cast<int>(m_levels.size())) {
    if (!m_dense_coarsest) {
      jacobi(level.n, level.omega, level.inverse, level.b, level.x, false);
      return;
    }
    m_dense_rhs = Eigen::Map<const VectorXd>(level.b.data(), 3 * level.n);
    m_coarsest.solveInPlace(m_dense_rhs);
    Eigen::Map<VectorXd>(level.x.data(), 3 * level.n) = m_dense_rhs;
    return;
  }
  Level& next = m_levels[static_cast<std::size_t>(k) + 1];
  jacobi(level.n, level.omega, level.inverse, level.b, level.x, false);  // pre-smoothing from zero
  matvec(level, level.x, level.t);
  residual_in_place(level.n, level.b, level.t);
  restrict_to(level.members, level.t, next.b);
  cycle(k + 1);
  prolong_add(level.agg, next.x, level.x);
  matvec(level, level.x, level.t);  // post-smoothing
  residual_in_place(level.n, level.b, level.t);
  jacobi(level.n, level.omega, level.inverse, level.t, level.x, true);
}

void AggregationMultigrid::apply(const Vectors3& r, Vectors3& z, const Blocks& inverse0) {
  if (!built()) fail("multigrid: apply before the first update has finished (both of its passes)");
  const Index n = m_particles;
  Level& l1 = m_levels.front();
  jacobi(n, kOmega0, inverse0, r, z, false);  // z is zero off the unknowns (inverse0 is)
  restrict_to(m_members0, r, l1.b);
  cycle(0);
  prolong_add(m_agg0, l1.x, z);
}

}  // namespace sinew
