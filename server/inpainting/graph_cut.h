// Minimum s-t cut / maximum flow and Potts labelling by alpha-expansion, for the layered depth
// solve (InpaintOptions::layered_depth): which pixels of T belong to which depth layer.
//
// MaxFlow wraps Boost.Graph's boykov_kolmogorov_max_flow (header-only; the standard max-flow for
// vision grid graphs); see docs/inpainting.md for its measurement against the former Dinic.
#pragma once

#include <vector>

namespace exo::inpainting {

class MaxFlow {
 public:
  explicit MaxFlow(int num_nodes);
  ~MaxFlow();
  MaxFlow(const MaxFlow&) = delete;
  MaxFlow& operator=(const MaxFlow&) = delete;
  // Accumulates capacities of source -> node and node -> sink (both >= 0). A node on the sink
  // side after the cut pays cap_source, one on the source side pays cap_sink.
  void AddTerminalWeights(int node, double cap_source, double cap_sink);
  // Edge a -> b with capacity cap_ab (cut when a is on the source side and b on the sink side)
  // and b -> a with cap_ba; both >= 0.
  void AddEdge(int a, int b, double cap_ab, double cap_ba);
  // Returns the maximum flow = the minimum cut's capacity. Call once.
  double Solve();
  // After Solve: true if the node is on the source side of the minimum cut (reachable from the
  // source in the residual graph).
  bool OnSourceSide(int node) const { return source_side_[node] != 0; }
  int num_nodes() const { return n_; }

 private:
  struct Edge {
    int a, b;
    double cap_ab, cap_ba;
  };
  int n_;
  std::vector<double> ts_, tt_;  // terminal capacities per node
  std::vector<Edge> edges_;
  std::vector<char> source_side_;
};

struct PottsEdge {
  int a, b;
  float w;  // cost when a and b take different labels (>= 0)
};

// Minimises sum_p unary[p * num_labels + l_p] + sum_e e.w * [l_a != l_b] over labellings by
// alpha-expansion moves (each one an s-t min cut), starting from `labels` (size num_nodes,
// values in [0, num_labels)); a move is kept only if it lowers the energy. For two labels and
// a constant start the first expansion is the global minimum. Returns the final energy.
double PottsAlphaExpansion(int num_nodes, int num_labels, const std::vector<float>& unary,
                           const std::vector<PottsEdge>& edges, std::vector<int>* labels,
                           int max_cycles = 3);

// Energy of a labelling (same terms as PottsAlphaExpansion).
double PottsEnergy(int num_labels, const std::vector<float>& unary,
                   const std::vector<PottsEdge>& edges, const std::vector<int>& labels);

}  // namespace exo::inpainting
