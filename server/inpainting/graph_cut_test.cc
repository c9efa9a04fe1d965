#include "server/inpainting/graph_cut.h"

#include <cstdint>
#include <limits>
#include <random>

#include <gtest/gtest.h>

namespace exo::inpainting {
namespace {

// Minimum cut of a small graph by enumerating every source/sink split.
struct SmallGraph {
  int n;
  std::vector<double> ts, tt;
  struct E {
    int a, b;
    double ab, ba;
  };
  std::vector<E> edges;
  double CutOf(uint32_t sink_set) const {
    double c = 0;
    for (int i = 0; i < n; ++i) c += (sink_set >> i & 1) ? ts[i] : tt[i];
    for (const E& e : edges) {
      const bool as = !(sink_set >> e.a & 1), bs = !(sink_set >> e.b & 1);
      if (as && !bs) c += e.ab;
      if (bs && !as) c += e.ba;
    }
    return c;
  }
};

TEST(GraphCutTest, MaxFlowEqualsBruteForceMinCut) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 300; ++trial) {
    SmallGraph g;
    g.n = 2 + trial % 9;  // 2..10 nodes
    g.ts.resize(g.n);
    g.tt.resize(g.n);
    MaxFlow mf(g.n);
    for (int i = 0; i < g.n; ++i) {
      g.ts[i] = u(rng) < 0.5 ? 0.0 : u(rng) * 3.0;
      g.tt[i] = u(rng) < 0.5 ? 0.0 : u(rng) * 3.0;
      mf.AddTerminalWeights(i, g.ts[i], g.tt[i]);
    }
    const int m = g.n * 2;
    for (int k = 0; k < m; ++k) {
      const int a = static_cast<int>(u(rng) * g.n), b = static_cast<int>(u(rng) * g.n);
      if (a == b) continue;
      const double ab = u(rng) * 2.0, ba = u(rng) < 0.3 ? 0.0 : u(rng) * 2.0;
      g.edges.push_back({a, b, ab, ba});
      mf.AddEdge(a, b, ab, ba);
    }
    double best = std::numeric_limits<double>::infinity();
    for (uint32_t s = 0; s < (1u << g.n); ++s) best = std::min(best, g.CutOf(s));
    const double flow = mf.Solve();
    EXPECT_NEAR(flow, best, 1e-9) << "trial " << trial;
    // The reported partition is a minimum cut.
    uint32_t sink_set = 0;
    for (int i = 0; i < g.n; ++i)
      if (!mf.OnSourceSide(i)) sink_set |= 1u << i;
    EXPECT_NEAR(g.CutOf(sink_set), best, 1e-9) << "trial " << trial;
  }
}

TEST(GraphCutTest, LongChainNeedsNoRecursion) {
  // A 200k-node path: the search trees grow iteratively (a recursive search would need a
  // 200k-deep stack).
  const int n = 200000;
  MaxFlow mf(n);
  mf.AddTerminalWeights(0, 5.0, 0.0);
  mf.AddTerminalWeights(n - 1, 0.0, 5.0);
  for (int i = 0; i + 1 < n; ++i) mf.AddEdge(i, i + 1, i == n / 2 ? 1.5 : 2.0, 0.0);
  EXPECT_NEAR(mf.Solve(), 1.5, 1e-12);
  EXPECT_TRUE(mf.OnSourceSide(n / 2));
  EXPECT_FALSE(mf.OnSourceSide(n / 2 + 1));
}

// Brute-force Potts minimum over all labellings of a small graph.
double BrutePotts(int n, int k, const std::vector<float>& unary, const std::vector<PottsEdge>& edges) {
  std::vector<int> lab(n, 0);
  double best = std::numeric_limits<double>::infinity();
  for (;;) {
    best = std::min(best, PottsEnergy(k, unary, edges, lab));
    int i = 0;
    while (i < n && ++lab[i] == k) lab[i++] = 0;
    if (i == n) break;
  }
  return best;
}

TEST(GraphCutTest, AlphaExpansionIsExactForTwoLabelsAndWithinBoundForThree) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 120; ++trial) {
    const int gw = 3, gh = 3 + trial % 2, n = gw * gh;  // 9 or 12 nodes, 4-connected grid
    for (int k : {2, 3}) {
      if (k == 3 && n > 9) continue;
      std::vector<float> unary(static_cast<size_t>(n) * k);
      for (float& v : unary) v = static_cast<float>(u(rng) * 2.0);
      std::vector<PottsEdge> edges;
      for (int y = 0; y < gh; ++y)
        for (int x = 0; x < gw; ++x) {
          if (x + 1 < gw) edges.push_back({y * gw + x, y * gw + x + 1, static_cast<float>(u(rng) * 1.5)});
          if (y + 1 < gh) edges.push_back({y * gw + x, (y + 1) * gw + x, static_cast<float>(u(rng) * 1.5)});
        }
      std::vector<int> lab(n, 0);
      const double e = PottsAlphaExpansion(n, k, unary, edges, &lab, k == 2 ? 1 : 5);
      EXPECT_NEAR(e, PottsEnergy(k, unary, edges, lab), 1e-5);
      const double best = BrutePotts(n, k, unary, edges);
      if (k == 2) {
        EXPECT_NEAR(e, best, 1e-5) << "trial " << trial;
      } else {
        EXPECT_LE(e, 2.0 * best + 1e-5) << "trial " << trial;  // the expansion bound for Potts
        EXPECT_GE(e, best - 1e-5);
      }
    }
  }
}

}  // namespace
}  // namespace exo::inpainting
