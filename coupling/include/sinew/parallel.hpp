// Threads for sinew's step, deterministic by construction: 1 and N threads give bit-identical
// results. Loops are statically partitioned (OpenMP), no thread ever adds into memory another
// thread writes, and reductions combine fixed blocks of terms in a fixed order, so neither the
// partition nor the thread count changes a single rounding.
#pragma once

#include "sinew/types.hpp"

#include <algorithm>
#include <array>
#include <iterator>
#include <span>
#include <vector>

namespace sinew {

/// Threads sinew's loops use (1 by default; 0 means every hardware thread). Process-wide, set by
/// System::step from StepSettings::threads before it runs.
void set_thread_count(int threads);
int thread_count();

namespace parallel {

/// Loops shorter than this run on the calling thread: a parallel region costs microseconds. On the
/// benchmark curtain, two threads paid for a 40x40 cloth's 1600-node loops (its tick 2-4% faster
/// than with 2048) and lost on a 20x20 cloth's 1100-edge loops (7% slower with 1024).
inline constexpr Index kMinParallelItems = 1536;
/// Loops that do a handful of flops per particle (vector updates, dot products, block-Jacobi
/// preconditioning, clearing) run on the calling thread below this many particles. Such a loop costs
/// about 1 ns per particle, while a parallel region costs 1-5 us (measured: 4.5 us for two threads on
/// a 2-core KVM guest, AMD EPYC, where a serial pass over 1600 particles takes 1.1 us): below some
/// 9000 particles the region costs more than the second thread saves. With these loops on two threads
/// from 1536 particles, a 40x40 cloth's step ran slower on two threads than on one there (the benchmark
/// curtain's 1/240 s tick 0.87 against 0.84 ms); with them serial, two threads are 9-15% faster than
/// one (0.59 ms).
inline constexpr Index kMinParallelLightItems = 8192;
/// Element loops (ChunkedScatter) split into chunks from this many elements: below it, the split's
/// extra buffers or passes cost more than a second thread saves (a 20x20 cloth's 1100 edges: 11%
/// slower in two chunks). The chunks fix the order of the sums, so this is part of the results.
inline constexpr Index kMinChunkedElements = 2048;
/// Reductions add terms in blocks of this many, then the block sums in block order.
inline constexpr Index kReductionBlock = 1024;

/// Runs body(begin, end) over [0, n) split into contiguous static ranges, one per thread when
/// `parallel`, else once over all of it.
template <typename Body>
void for_ranges_when(bool parallel, Index n, Body&& body) {
  const int threads = parallel ? thread_count() : 1;
  if (threads <= 1) {
    body(Index(0), n);
    return;
  }
#pragma omp parallel for schedule(static) num_threads(threads)
  for (int t = 0; t < threads; ++t) body(n * t / threads, n * (t + 1) / threads);
}

/// for_ranges_when for loops of n items, parallel from kMinParallelItems on.
template <typename Body>
void for_ranges(Index n, Body&& body) {
  for_ranges_when(n >= kMinParallelItems, n, body);
}

/// for_ranges_when for loops of n particles that do a handful of flops each, parallel from
/// kMinParallelLightItems on.
template <typename Body>
void for_light_ranges(Index n, Body&& body) {
  for_ranges_when(n >= kMinParallelLightItems, n, body);
}

/// sum over i in [0, n) of term(i), in blocks of kReductionBlock whose sums are added in order:
/// the same bits for every thread count.
template <typename Term>
double sum(Index n, Term&& term) {
  const Index blocks = (n + kReductionBlock - 1) / kReductionBlock;
  thread_local std::vector<double> partial;
  partial.assign(static_cast<std::size_t>(blocks), 0.0);
  double* out = partial.data();
  for_ranges_when(n >= kMinParallelItems, blocks, [&](Index b0, Index b1) {
    for (Index b = b0; b < b1; ++b) {
      double s = 0.0;
      const Index end = std::min(n, (b + 1) * kReductionBlock);
      for (Index i = b * kReductionBlock; i < end; ++i) s += term(i);
      out[b] = s;
    }
  });
  double total = 0.0;
  for (Index b = 0; b < blocks; ++b) total += out[b];
  return total;
}

}  // namespace parallel

/// Elements whose node lists differ in length, in compressed rows (CSR): element e's nodes are
/// index[offset[e] .. offset[e + 1]). A meshfree particle's neighbourhood (30-60 nodes, varying per
/// particle) or a contact's 2-4 nodes, where std::array<Index, K> needs one K for every element.
struct Stencils {
  std::vector<Index> offset{0};  ///< size() + 1 entries, offset[0] = 0, non-decreasing
  std::vector<Index> index;      ///< node indices, offset.back() of them

  Index size() const { return static_cast<Index>(offset.size()) - 1; }
  /// Appends an element with the given nodes.
  template <typename Nodes>
  void push_back(const Nodes& nodes) {
    index.insert(index.end(), std::begin(nodes), std::end(nodes));
    offset.push_back(static_cast<Index>(index.size()));
  }
  /// Element e's nodes.
  std::span<const Index> operator[](Index e) const {
    const auto begin = static_cast<std::size_t>(offset[static_cast<std::size_t>(e)]);
    return {index.data() + begin, static_cast<std::size_t>(offset[static_cast<std::size_t>(e) + 1]) - begin};
  }
};

/// Element loops that add each element's terms straight into its nodes, sequentially within fixed
/// chunks of consecutive elements. The chunk count depends on the element count alone (never on the
/// thread count), which keeps the bits the same for any number of threads. With one chunk the terms
/// go into f. With four or more (so that each half still runs in parallel), and when every other
/// chunk's node range is disjoint from the others' of its parity (consecutive elements touch nearby
/// nodes, as a grid's rows of edges or hinges do), the even chunks add straight into f in parallel,
/// then the odd ones: each node receives its terms in element order, no two threads touch a node at
/// once, and there is no buffer to clear or add up.
/// Otherwise each chunk adds into its own buffer over the node range its elements touch, in
/// parallel, and the buffers are then added into f in chunk order. One pass over the elements and no
/// per-element storage (ScatterGather's alternative).
/// Elements of fixed size (std::array<Index, K>) and of varying size (Stencils) are chunked by the
/// same rule, by element count: only the node ranges of the chunks depend on the nodes, and run()
/// never sees an element's size, so a force's scatter reads its own stencils either way. (Chunks of
/// equal stencil entries would balance uneven stencils better, but would make the chunks of the
/// fixed-size forces, and with them their sums, depend on a second rule.)
class ChunkedScatter {
 public:
  struct Chunk {
    Index begin = 0, end = 0;            ///< elements
    Index node_begin = 0, node_end = 0;  ///< nodes touched by the chunk's elements
  };
  ChunkedScatter() = default;
  /// elements: node indices per element; nodes: one past the largest node index. One chunk below
  /// kMinChunkedElements elements, else up to 8 of at least kMinChunkedElements / 2 (so 2 or 4
  /// threads share them evenly).
  template <std::size_t K>
  ChunkedScatter(const std::vector<std::array<Index, K>>& elements, Index nodes)
      : ChunkedScatter(static_cast<Index>(elements.size()), nodes,
                       [&](Index e) -> const std::array<Index, K>& { return elements[static_cast<std::size_t>(e)]; }) {}
  /// The same for elements of varying size.
  ChunkedScatter(const Stencils& elements, Index nodes)
      : ChunkedScatter(elements.size(), nodes, [&](Index e) { return elements[e]; }) {}
  /// The chunks add straight into f, even chunks then odd ones (see above).
  bool direct() const { return m_direct; }
  const std::vector<Chunk>& chunks() const { return m_chunks; }
  /// f += the terms scatter(chunk, out) adds into `out`, a flat node-indexed array (3 per node).
  template <typename Scatter>
  void run(Vectors3& f, Scatter&& scatter) const {
    if (m_chunks.size() == 1) {
      scatter(m_chunks[0], f.data());
      return;
    }
    if (m_direct) {
      double* pf = f.data();
      const auto count = static_cast<Index>(m_chunks.size());
      for (Index parity = 0; parity < 2; ++parity)
        parallel::for_ranges_when(true, (count - parity + 1) / 2, [&](Index k0, Index k1) {
          for (Index k = k0; k < k1; ++k) scatter(m_chunks[static_cast<std::size_t>(2 * k + parity)], pf);
        });
      return;
    }
    parallel::for_ranges_when(true, static_cast<Index>(m_chunks.size()), [&](Index c0, Index c1) {
      for (Index c = c0; c < c1; ++c) {
        const Chunk& chunk = m_chunks[static_cast<std::size_t>(c)];
        Vectors3& buffer = m_buffers[static_cast<std::size_t>(c)];
        buffer.middleCols(chunk.node_begin, chunk.node_end - chunk.node_begin).setZero();
        scatter(chunk, buffer.data());
      }
    });
    double* pf = f.data();
    parallel::for_ranges(m_nodes, [&](Index i0, Index i1) {
      for (std::size_t c = 0; c < m_chunks.size(); ++c) {
        const double* pb = m_buffers[c].data();
        const Index begin = 3 * std::max(i0, m_chunks[c].node_begin), end = 3 * std::min(i1, m_chunks[c].node_end);
        for (Index k = begin; k < end; ++k) pf[k] += pb[k];
      }
    });
  }

 private:
  /// count elements, element e's nodes nodes_of(e) (any range of Index).
  template <typename NodesOf>
  ChunkedScatter(Index count, Index nodes, NodesOf&& nodes_of) : m_nodes(nodes) {
    const Index chunks = count < parallel::kMinChunkedElements
                             ? 1
                             : std::min<Index>(8, std::max<Index>(2, count / (parallel::kMinChunkedElements / 2)));
    for (Index c = 0; c < chunks; ++c) {
      Chunk chunk{count * c / chunks, count * (c + 1) / chunks, nodes, 0};
      for (Index e = chunk.begin; e < chunk.end; ++e)
        for (Index i : nodes_of(e)) {
          chunk.node_begin = std::min(chunk.node_begin, i);
          chunk.node_end = std::max(chunk.node_end, i + 1);
        }
      if (chunk.node_begin > chunk.node_end) chunk.node_begin = chunk.node_end;
      m_chunks.push_back(chunk);
    }
    m_direct = chunks >= 4;
    for (std::size_t a = 0; a < m_chunks.size(); ++a)
      for (std::size_t b = a + 2; b < m_chunks.size(); b += 2)
        if (m_chunks[a].node_begin < m_chunks[b].node_end && m_chunks[b].node_begin < m_chunks[a].node_end)
          m_direct = false;
    if (chunks > 1 && !m_direct) m_buffers.assign(static_cast<std::size_t>(chunks), Vectors3::Zero(3, nodes));
  }

  std::vector<Chunk> m_chunks;
  mutable std::vector<Vectors3> m_buffers;  // per chunk (more than one, not direct), 3 x nodes
  Index m_nodes = 0;
  bool m_direct = false;
};

/// Element forces add per-element contributions into nodes. To do that in parallel and
/// deterministically, each element writes its K node contributions into its own slots, and each
/// node then gathers its slots in a fixed order (the order of elements in the force).
template <std::size_t K>
class ScatterGather {
 public:
  ScatterGather() = default;
  /// elements: node indices per element; nodes: one past the largest node index.
  ScatterGather(const std::vector<std::array<Index, K>>& elements, Index nodes) {
    m_offset.assign(static_cast<std::size_t>(nodes) + 1, 0);
    for (const auto& e : elements)
      for (Index v : e) ++m_offset[static_cast<std::size_t>(v) + 1];
    for (std::size_t i = 1; i < m_offset.size(); ++i) m_offset[i] += m_offset[i - 1];
    m_slot.resize(static_cast<std::size_t>(m_offset.back()));
    std::vector<Index> fill(m_offset.begin(), m_offset.end() - 1);
    for (std::size_t e = 0; e < elements.size(); ++e)
      for (std::size_t a = 0; a < K; ++a)
        m_slot[static_cast<std::size_t>(fill[static_cast<std::size_t>(elements[e][a])]++)] =
            static_cast<Index>(K * e + a);
    m_values.setZero(3, static_cast<Index>(K * elements.size()));
    m_nodes = nodes;
  }
  /// The slot of element e's a-th node: write its contribution here.
  auto slot(Index e, std::size_t a) { return m_values.col(static_cast<Index>(K) * e + static_cast<Index>(a)); }
  Vectors3& values() { return m_values; }
  Index elements() const { return m_values.cols() / static_cast<Index>(K); }
  /// f.col(i) += the sum of node i's slots, in element order; parallel over nodes.
  void gather_add(Vectors3& f) const {
    parallel::for_ranges(m_nodes, [&](Index i0, Index i1) {
      for (Index i = i0; i < i1; ++i) {
        const Index begin = m_offset[static_cast<std::size_t>(i)], end = m_offset[static_cast<std::size_t>(i) + 1];
        if (begin == end) continue;
        Vec3 sum = Vec3::Zero();
        for (Index s = begin; s < end; ++s) sum += m_values.col(m_slot[static_cast<std::size_t>(s)]);
        f.col(i) += sum;
      }
    });
  }

 private:
  std::vector<Index> m_offset;  // CSR over nodes
  std::vector<Index> m_slot;    // slot column per entry
  Vectors3 m_values;
  Index m_nodes = 0;
};

}  // namespace sinew
