#include "server/inpainting/graph_cut.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <boost/graph/adjacency_list.hpp>
#include <boost/graph/boykov_kolmogorov_max_flow.hpp>

namespace exo::inpainting {

MaxFlow::MaxFlow(int num_nodes)
    : n_(num_nodes), ts_(num_nodes, 0.0), tt_(num_nodes, 0.0), source_side_(num_nodes, 0) {}

MaxFlow::~MaxFlow() = default;

void MaxFlow::AddTerminalWeights(int node, double cap_source, double cap_sink) {
  ts_[node] += std::max(0.0, cap_source);
  tt_[node] += std::max(0.0, cap_sink);
}

void MaxFlow::AddEdge(int a, int b, double cap_ab, double cap_ba) {
  if (a == b) return;
  edges_.push_back({a, b, std::max(0.0, cap_ab), std::max(0.0, cap_ba)});
}

double MaxFlow::Solve() {
  using Traits = boost::adjacency_list_traits<boost::vecS, boost::vecS, boost::directedS>;
  struct EdgeProps {
    double capacity = 0.0, residual = 0.0;
    Traits::edge_descriptor reverse;
  };
  using Graph =
      boost::adjacency_list<boost::vecS, boost::vecS, boost::directedS, boost::no_property, EdgeProps>;
  const int s = n_, t = n_ + 1;
  Graph g(n_ + 2);
  auto add = [&g](int a, int b, double cap_ab, double cap_ba) {
    const auto ab = boost::add_edge(a, b, g).first;
    const auto ba = boost::add_edge(b, a, g).first;
    g[ab].capacity = cap_ab;
    g[ab].reverse = ba;
    g[ba].capacity = cap_ba;
    g[ba].reverse = ab;
  };
  // Flow straight through source -> node -> sink needs no search.
  double through = 0.0;
  for (int i = 0; i < n_; ++i) {
    const double m = std::min(ts_[i], tt_[i]);
    through += m;
    if (ts_[i] - m > 0.0) add(s, i, ts_[i] - m, 0.0);
    if (tt_[i] - m > 0.0) add(i, t, tt_[i] - m, 0.0);
  }
  for (const Edge& e : edges_) add(e.a, e.b, e.cap_ab, e.cap_ba);
  const size_t nv = boost::num_vertices(g);
  std::vector<boost::default_color_type> color(nv);
  std::vector<Traits::edge_descriptor> pred(nv);
  std::vector<long> dist(nv);
  const auto index = boost::get(boost::vertex_index, g);
  const double flow = boost::boykov_kolmogorov_max_flow(
      g, boost::get(&EdgeProps::capacity, g), boost::get(&EdgeProps::residual, g),
      boost::get(&EdgeProps::reverse, g), boost::make_iterator_property_map(pred.begin(), index),
      boost::make_iterator_property_map(color.begin(), index),
      boost::make_iterator_property_map(dist.begin(), index), index, s, t);
  // Source side: the source tree (black), i.e. the nodes reachable from s in the residual graph.
  for (int i = 0; i < n_; ++i)
    source_side_[i] = color[i] == boost::color_traits<boost::default_color_type>::black();
  return through + flow;
}

double PottsEnergy(int num_labels, const std::vector<float>& unary,
                   const std::vector<PottsEdge>& edges, const std::vector<int>& labels) {
  double e = 0.0;
  for (size_t p = 0; p < labels.size(); ++p) e += unary[p * num_labels + labels[p]];
  for (const PottsEdge& pe : edges) e += labels[pe.a] != labels[pe.b] ? pe.w : 0.0;
  return e;
}

double PottsAlphaExpansion(int num_nodes, int num_labels, const std::vector<float>& unary,
                           const std::vector<PottsEdge>& edges, std::vector<int>* labels,
                           int max_cycles) {
  std::vector<int>& lab = *labels;
  double energy = PottsEnergy(num_labels, unary, edges, lab);
  if (num_labels < 2 || num_nodes == 0) return energy;
  std::vector<double> c0(num_nodes), c1(num_nodes);  // cost of keeping / of taking alpha
  for (int cycle = 0; cycle < max_cycles; ++cycle) {
    bool improved = false;
    for (int alpha = 0; alpha < num_labels; ++alpha) {
      // Binary move: x_p = 1 takes alpha (sink side), x_p = 0 keeps l_p (source side).
      MaxFlow g(num_nodes);
      for (int p = 0; p < num_nodes; ++p) {
        c0[p] = unary[static_cast<size_t>(p) * num_labels + lab[p]];
        c1[p] = unary[static_cast<size_t>(p) * num_labels + alpha];
      }
      for (const PottsEdge& pe : edges) {
        // E(x_a, x_b): A = E(0,0), B = E(0,1), C = E(1,0), D = E(1,1) = 0 (Potts, alpha-alpha)
        // = A + (C - A) x_a + (D - C) x_b + (B + C - A - D) (1 - x_a) x_b, B + C - A - D >= 0.
        const double A = lab[pe.a] != lab[pe.b] ? pe.w : 0.0;
        const double B = lab[pe.a] != alpha ? pe.w : 0.0;
        const double C = lab[pe.b] != alpha ? pe.w : 0.0;
        c0[pe.a] += A;  // the constant A, carried by a's both choices
        c1[pe.a] += C;
        c1[pe.b] += -C;
        c0[pe.b] += 0.0;
        // (1 - x_a) x_b: a on the source side, b on the sink side -> arc a -> b.
        const double pair = B + C - A;
        if (pair > 0.0) g.AddEdge(pe.a, pe.b, pair, 0.0);
      }
      for (int p = 0; p < num_nodes; ++p) {
        // Sink side (x = 1) pays cap_source = c1, source side pays cap_sink = c0; shift so that
        // both are >= 0.
        const double m = std::min(c0[p], c1[p]);
        g.AddTerminalWeights(p, c1[p] - m, c0[p] - m);
      }
      g.Solve();
      std::vector<int> cand = lab;
      for (int p = 0; p < num_nodes; ++p)
        if (!g.OnSourceSide(p)) cand[p] = alpha;
      const double e = PottsEnergy(num_labels, unary, edges, cand);
      if (e < energy - 1e-9 * (1.0 + std::fabs(energy))) {
        energy = e;
        lab.swap(cand);
        improved = true;
      }
    }
    if (!improved) break;
  }
  return energy;
}

}  // namespace exo::inpainting
