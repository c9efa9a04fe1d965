#include "server/inpainting/layers.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <utility>

#include "server/inpainting/graph_cut.h"

namespace exo::inpainting {
namespace {

using ImageI32 = Image<int32_t>;

// A layer's robust inverse-depth plane (1/z is affine in pixel coordinates on a plane).
struct LayerPlane {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();  // v = c0 * x / 640 + c1 * y / 640 + c2
  double vlo = 0, vhi = 0;                      // range of the cluster's values
  double At(double x, double y) const { return c[0] * x / 640.0 + c[1] * y / 640.0 + c[2]; }
};

LayerPlane FitLayerPlane(const std::vector<Eigen::Vector3d>& pts) {  // (x, y, v), frame px
  LayerPlane pl;
  std::vector<double> vs;
  for (const auto& p : pts) vs.push_back(p[2]);
  std::nth_element(vs.begin(), vs.begin() + vs.size() / 2, vs.end());
  const double med = vs[vs.size() / 2];
  pl.vlo = *std::min_element(vs.begin(), vs.end());
  pl.vhi = *std::max_element(vs.begin(), vs.end());
  pl.c = Eigen::Vector3d(0, 0, med);  // fallback: fronto-parallel at the median
  // Iteratively reweighted least squares, Huber weights on the relative residual (2 %).
  std::vector<double> wt(pts.size(), 1.0);
  for (int iter = 0; iter < 4; ++iter) {
    Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
    Eigen::Vector3d atb = Eigen::Vector3d::Zero();
    double sw = 0;
    for (size_t k = 0; k < pts.size(); ++k) {
      const Eigen::Vector3d a(pts[k][0] / 640.0, pts[k][1] / 640.0, 1.0);
      ata += wt[k] * a * a.transpose();
      atb += wt[k] * a * pts[k][2];
      sw += wt[k];
    }
    ata /= sw;
    atb /= sw;
    if (!(std::fabs(ata.determinant()) > 1e-12)) break;  // collinear border: keep the fallback
    const Eigen::Vector3d c = ata.ldlt().solve(atb);
    if (!c.allFinite()) break;
    pl.c = c;
    for (size_t k = 0; k < pts.size(); ++k) {
      const double r =
          std::fabs(pl.At(pts[k][0], pts[k][1]) - pts[k][2]) / std::max(1e-9, std::fabs(pts[k][2]));
      wt[k] = r <= 0.02 ? 1.0 : 0.02 / r;
    }
  }
  return pl;
}

// One SetupLayers call; each step below is one member function, run in order by Run().
class LayerBuilder {
 public:
  LayerBuilder(const std::vector<uint8_t>& measured, const ImageU8& color, const InpaintOptions& o,
               DepthCrop* crop)
      : measured_(measured),
        color_(color),
        o_(o),
        c_(*crop),
        cw_(crop->width()),
        ch_(crop->height()) {}

  LayerResult Run();

 private:
  static constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
  bool InT(int cx, int cy) const {
    return cx >= 0 && cy >= 0 && cx < cw_ && cy < ch_ && c_.region.at(cx, cy) != 0;
  }
  bool NextToT(int cx, int cy) const {
    return InT(cx - 1, cy) || InT(cx + 1, cy) || InT(cx, cy - 1) || InT(cx, cy + 1);
  }
  bool Measured(int cx, int cy) const {
    return measured_[static_cast<size_t>(c_.oy + cy) * c_.frame_w + c_.ox + cx] != 0;
  }
  // 1. The measured ring of T clustered in inverse depth; false when fewer than two layers.
  bool ClusterRing();
  // 2. A robust plane per layer; border labels of the clustered ring.
  void FitPlanes();
  // Other border values (push-pull-filled, measured in no kept cluster): the layer whose plane
  // they match; none -> no boundary value at all.
  void LabelOtherBorderValues();
  // Seeds of the labelling (distances, fixed-label border pairs): with layer_seed_measured_only
  // only the measured ring, else every labelled border pixel.
  void ChooseSeeds();
  // Distance of every crop pixel to each layer's seeds (and continued border seeds).
  void SeedDistances();
  // layer_edge_seeds: T's free border pixels continue the seeds' labels along T's border.
  void ContinueSeedsAlongBorder();
  float FarthestFromSeeds() const;
  // 3. Labels of T: Potts labelling on blocks of layer_label_block^2 px.
  struct Labelling {
    int num_nodes = 0;
    std::vector<float> unary;
    std::vector<PottsEdge> edges;
  };
  Labelling BuildLabelling();
  void ApplyLabels(const std::vector<int>& labels, LayerResult* out);
  // 4. Pairs between layers, and from a T pixel to a border pixel of another layer, are free.
  void FreePairsBetweenLayers();
  // 5. The surface prior per layer region, from that layer's border values only.
  void BuildLayerPriors(LayerResult* out) const;

  const std::vector<uint8_t>& measured_;
  const ImageU8& color_;
  const InpaintOptions& o_;
  DepthCrop& c_;
  const int cw_, ch_;

  struct RingPx {
    int cx, cy;
    float v;
  };
  std::vector<RingPx> ring_;
  std::vector<int> order_;                 // ring_ sorted by value
  std::vector<std::pair<int, int>> kept_;  // clusters, [begin, end) in order_
  int k_ = 0;                              // number of layers
  std::vector<LayerPlane> planes_;
  ImageI32 blabel_, slabel_, elabel_, tlabel_;  // border, seed, continued-seed, T labels (-1)
  std::vector<cv::Mat> dist_;                   // per layer: distance to its seeds (px)
  int block_ = 1, nbw_ = 0, nbh_ = 0;           // labelling blocks
  std::vector<int> bnode_;                      // block -> node (-1: no T pixel)
  int NodeOf(int cx, int cy) const {
    return c_.region.at(cx, cy) ? bnode_[static_cast<size_t>(cy / block_) * nbw_ + cx / block_]
                                : -1;
  }
};

bool LayerBuilder::ClusterRing() {
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      const float v = c_.q.at(cx, cy);
      if (c_.region.at(cx, cy) || !std::isfinite(v) || !(v > 0.f)) continue;
      if (!Measured(cx, cy) || !NextToT(cx, cy)) continue;
      ring_.push_back({cx, cy, v});
    }
  if (ring_.size() < 16) return false;
  order_.resize(ring_.size());
  for (size_t k = 0; k < order_.size(); ++k) order_[k] = static_cast<int>(k);
  std::stable_sort(order_.begin(), order_.end(),
                   [&](int a, int b) { return ring_[a].v < ring_[b].v; });
  // Split where neighbouring values differ by more than layer_gap_rel of their value.
  std::vector<std::pair<int, int>> runs;
  int start = 0;
  for (size_t k = 1; k <= order_.size(); ++k) {
    if (k == order_.size() ||
        ring_[order_[k]].v - ring_[order_[k - 1]].v > o_.layer_gap_rel * ring_[order_[k]].v) {
      runs.push_back({start, static_cast<int>(k)});
      start = static_cast<int>(k);
    }
  }
  const int min_size = std::max(8, static_cast<int>(std::ceil(o_.layer_min_share * ring_.size())));
  for (const auto& r : runs)
    if (r.second - r.first >= min_size) kept_.push_back(r);
  if (kept_.size() < 2) return false;
  if (static_cast<int>(kept_.size()) > o_.max_layers) {  // the largest clusters
    std::stable_sort(kept_.begin(), kept_.end(), [](const auto& a, const auto& b) {
      return a.second - a.first > b.second - b.first;
    });
    kept_.resize(o_.max_layers);
    std::sort(kept_.begin(), kept_.end());
  }
  k_ = static_cast<int>(kept_.size());
  return true;
}

void LayerBuilder::FitPlanes() {
  planes_.resize(k_);
  blabel_ = ImageI32(cw_, ch_, 1, -1);
  for (int l = 0; l < k_; ++l) {
    std::vector<Eigen::Vector3d> pts;
    for (int k = kept_[l].first; k < kept_[l].second; ++k) {
      const RingPx& r = ring_[order_[k]];
      pts.emplace_back(c_.ox + r.cx, c_.oy + r.cy, r.v);
      blabel_.at(r.cx, r.cy) = l;
    }
    planes_[l] = FitLayerPlane(pts);
  }
}

void LayerBuilder::LabelOtherBorderValues() {
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      if (c_.region.at(cx, cy) || !std::isfinite(c_.q.at(cx, cy)) || !NextToT(cx, cy)) continue;
      if (blabel_.at(cx, cy) >= 0) continue;
      const double v = c_.q.at(cx, cy);
      int best = -1;
      double best_r = o_.layer_agree_rel;
      for (int l = 0; l < k_; ++l) {
        const double p = std::clamp(planes_[l].At(c_.ox + cx, c_.oy + cy), 0.5 * planes_[l].vlo,
                                    2.0 * planes_[l].vhi);
        const double r = std::fabs(v - p) / std::max(1e-9, std::fabs(p));
        if (r <= best_r) {
          best_r = r;
          best = l;
        }
      }
      blabel_.at(cx, cy) = best;
      if (best < 0) c_.q.at(cx, cy) = kNan;
    }
}

void LayerBuilder::ChooseSeeds() {
  slabel_ = blabel_;
  if (o_.layer_seed_measured_only) {
    for (int cy = 0; cy < ch_; ++cy)
      for (int cx = 0; cx < cw_; ++cx)
        if (!Measured(cx, cy)) slabel_.at(cx, cy) = -1;
  }
  elabel_ = ImageI32(cw_, ch_, 1, -1);
}

void LayerBuilder::SeedDistances() {
  dist_.resize(k_);
  for (int l = 0; l < k_; ++l) {
    cv::Mat seeds(ch_, cw_, CV_8U, cv::Scalar(1));
    for (int cy = 0; cy < ch_; ++cy)
      for (int cx = 0; cx < cw_; ++cx)
        if (slabel_.at(cx, cy) == l || elabel_.at(cx, cy) == l) seeds.at<uint8_t>(cy, cx) = 0;
    cv::distanceTransform(seeds, dist_[l], cv::DIST_L2, cv::DIST_MASK_5);
  }
}

// T's free border pixels (on the frame's edge, or next to pixels that seed no layer: holes,
// push-pull-filled depth) continue the labels of the seeds along T's border: breadth-first over
// T's 8-connected border pixels from those next to a seed, so a free stretch between two seeds of
// one layer belongs to that layer (an occlusion edge that enters T must leave it again), and
// they become seeds themselves.
void LayerBuilder::ContinueSeedsAlongBorder() {
  ImageI32 glabel(cw_, ch_, 1, -1);
  std::vector<int> queue;
  auto on_border = [&](int cx, int cy) {
    const int x = c_.ox + cx, y = c_.oy + cy;
    if (!c_.region.at(cx, cy)) return false;
    if (x == 0 || y == 0 || x == c_.frame_w - 1 || y == c_.frame_h - 1) return true;
    return !InT(cx - 1, cy) || !InT(cx + 1, cy) || !InT(cx, cy - 1) || !InT(cx, cy + 1);
  };
  ImageU8 free_px(cw_, ch_, 1, 0);
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      if (!on_border(cx, cy)) continue;
      int seed = -1;
      const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
      for (int k = 0; k < 4; ++k) {
        if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw_ || ny[k] >= ch_ || c_.region.at(nx[k], ny[k]))
          continue;
        const int sl = slabel_.at(nx[k], ny[k]);
        if (sl >= 0 && (seed < 0 || sl < seed)) seed = sl;
      }
      if (seed >= 0) {
        glabel.at(cx, cy) = seed;
        queue.push_back(cy * cw_ + cx);
      } else {
        free_px.at(cx, cy) = 1;
      }
    }
  for (size_t qi = 0; qi < queue.size(); ++qi) {
    const int cx = queue[qi] % cw_, cy = queue[qi] / cw_;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const int nx = cx + dx, ny = cy + dy;
        if (nx < 0 || ny < 0 || nx >= cw_ || ny >= ch_ || !free_px.at(nx, ny) ||
            glabel.at(nx, ny) >= 0)
          continue;
        glabel.at(nx, ny) = glabel.at(cx, cy);
        queue.push_back(ny * cw_ + nx);
      }
  }
  bool any = false;
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx)
      if (free_px.at(cx, cy) && glabel.at(cx, cy) >= 0) {
        elabel_.at(cx, cy) = glabel.at(cx, cy);
        any = true;
      }
  if (any) SeedDistances();
}

float LayerBuilder::FarthestFromSeeds() const {
  float far_px = 0.f;
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      if (!c_.region.at(cx, cy)) continue;
      float dm = std::numeric_limits<float>::infinity();
      for (int l = 0; l < k_; ++l) dm = std::min(dm, dist_[l].at<float>(cy, cx));
      far_px = std::max(far_px, dm);
    }
  return far_px;
}

// One label per block of layer_label_block^2 pixels; the block energy is the exact sum of its
// pixels' terms, pairs inside a block drop out: the cut is a long smooth curve, and a 4x coarser
// graph makes the max-flow ~20x cheaper. Data term: layer_distance_weight * d_l / (d_l + d_other)
// plus layer_smooth for leaving a continued seed's label; pair weight layer_smooth *
// exp(-|c_p - c_q|^2 / 2 layer_color_sigma^2), times layer_jump_factor where the fused copied
// gradient is a jump; a pair with a fixed-label seed adds its weight to the other labels.
LayerBuilder::Labelling LayerBuilder::BuildLabelling() {
  const int bs = o_.layer_label_block;
  block_ = bs;
  nbw_ = (cw_ + bs - 1) / bs;
  nbh_ = (ch_ + bs - 1) / bs;
  bnode_.assign(static_cast<size_t>(nbw_) * nbh_, -1);
  int nn = 0;
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      int& b = bnode_[static_cast<size_t>(cy / bs) * nbw_ + cx / bs];
      if (c_.region.at(cx, cy) && b < 0) b = nn++;
    }
  const int K = k_;
  std::vector<float> unary(static_cast<size_t>(nn) * K, 0.f);
  const double inv2s2 = 1.0 / (2.0 * o_.layer_color_sigma * o_.layer_color_sigma);
  auto colour_w = [&](int x0, int y0, int x1, int y1) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double d = static_cast<double>(color_.at(x0, y0, k)) - color_.at(x1, y1, k);
      d2 += d * d;
    }
    return std::exp(-d2 * inv2s2);
  };
  std::vector<double> ew_r(bnode_.size(), 0.0), ew_d(bnode_.size(), 0.0);  // block pair weights
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      const int p = NodeOf(cx, cy);
      if (p < 0) continue;
      const int x = c_.ox + cx, y = c_.oy + cy;
      for (int l = 0; l < K; ++l) {
        double u = 0.0;
        double dmin = std::numeric_limits<double>::infinity();
        for (int m = 0; m < K; ++m)
          if (m != l) dmin = std::min<double>(dmin, dist_[m].at<float>(cy, cx));
        const double dl = dist_[l].at<float>(cy, cx);
        u += o_.layer_distance_weight * dl / std::max(1e-6, dl + dmin);
        unary[static_cast<size_t>(p) * K + l] += static_cast<float>(u);
      }
      if (elabel_.at(cx, cy) >= 0) {
        for (int l = 0; l < K; ++l)
          if (l != elabel_.at(cx, cy))
            unary[static_cast<size_t>(p) * K + l] += static_cast<float>(o_.layer_smooth);
      }
      const int nx[4] = {cx - 1, cx + 1, cx, cx}, ny[4] = {cy, cy, cy - 1, cy + 1};
      for (int k = 0; k < 4; ++k) {
        if (nx[k] < 0 || ny[k] < 0 || nx[k] >= cw_ || ny[k] >= ch_) continue;
        // Pair weight; the pair's fused gradient weight marks copied jumps.
        const bool fwd = k == 1 || k == 3;
        const int pcx = fwd ? cx : nx[k], pcy = fwd ? cy : ny[k];
        const float pw = (k < 2 ? c_.wx : c_.wy).at(pcx, pcy);
        const double jf = std::isfinite(pw) && pw < 1.f ? o_.layer_jump_factor : 1.0;
        const double cwgt = o_.layer_color_sigma > 0.0 && o_.layer_color_sigma < 1e6
                                ? colour_w(x, y, c_.ox + nx[k], c_.oy + ny[k])
                                : 1.0;
        const double wgt = o_.layer_smooth * jf * cwgt;
        const int qn = NodeOf(nx[k], ny[k]);
        if (qn >= 0) {
          if (fwd && qn != p)
            (k == 1 ? ew_r : ew_d)[static_cast<size_t>(cy / bs) * nbw_ + cx / bs] += wgt;
        } else if (slabel_.at(nx[k], ny[k]) >= 0) {
          // A fixed-label border pixel: a T pixel of another layer pays the pair weight.
          for (int l = 0; l < K; ++l)
            if (l != slabel_.at(nx[k], ny[k]))
              unary[static_cast<size_t>(p) * K + l] += static_cast<float>(wgt);
        }
      }
    }
  Labelling problem;
  problem.num_nodes = nn;
  problem.unary = std::move(unary);
  for (int by = 0; by < nbh_; ++by)
    for (int bx = 0; bx < nbw_; ++bx) {
      const size_t b = static_cast<size_t>(by) * nbw_ + bx;
      if (ew_r[b] > 0.0)
        problem.edges.push_back({bnode_[b], bnode_[b + 1], static_cast<float>(ew_r[b])});
      if (ew_d[b] > 0.0)
        problem.edges.push_back({bnode_[b], bnode_[b + nbw_], static_cast<float>(ew_d[b])});
    }
  return problem;
}

void LayerBuilder::ApplyLabels(const std::vector<int>& labels, LayerResult* out) {
  tlabel_ = ImageI32(cw_, ch_, 1, -1);
  out->layer_pixels.assign(k_, 0);
  out->layer_map = ImageU8(c_.frame_w, c_.frame_h, 1, 0);
  for (int cy = 0; cy < ch_; ++cy)  // outside T: the labelling's seeds
    for (int cx = 0; cx < cw_; ++cx)
      if (!c_.region.at(cx, cy) && slabel_.at(cx, cy) >= 0)
        out->layer_map.at(c_.ox + cx, c_.oy + cy) = static_cast<uint8_t>(1 + slabel_.at(cx, cy));
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx) {
      const int p = NodeOf(cx, cy);
      if (p < 0) continue;
      tlabel_.at(cx, cy) = labels[p];
      ++out->layer_pixels[labels[p]];
      out->layer_map.at(c_.ox + cx, c_.oy + cy) = static_cast<uint8_t>(1 + labels[p]);
    }
}

void LayerBuilder::FreePairsBetweenLayers() {
  for (int cy = 0; cy < ch_; ++cy)
    for (int cx = 0; cx < cw_; ++cx)
      for (int dir = 0; dir < 2; ++dir) {
        const int qx = cx + (dir == 0), qy = cy + (dir == 1);
        if (qx >= cw_ || qy >= ch_) continue;
        const bool tp = c_.region.at(cx, cy), tq = c_.region.at(qx, qy);
        if (!tp && !tq) continue;
        const int lp = tp ? tlabel_.at(cx, cy) : blabel_.at(cx, cy);
        const int lq = tq ? tlabel_.at(qx, qy) : blabel_.at(qx, qy);
        const bool other_known =
            (!tp && std::isfinite(c_.q.at(cx, cy))) || (!tq && std::isfinite(c_.q.at(qx, qy)));
        if (tp && tq ? lp != lq : (other_known && lp != lq))
          (dir == 0 ? c_.gx : c_.gy).at(cx, cy) = kNan;
      }
}

void LayerBuilder::BuildLayerPriors(LayerResult* out) const {
  ImageF& prior = out->prior;
  ImageF& prior_w = out->prior_weight;
  prior = ImageF(cw_, ch_, 1, kNan);
  prior_w = ImageF(cw_, ch_, 1, kNan);
  int count = 0;
  for (int l = 0; l < k_; ++l) {
    ImageU8 rl(cw_, ch_, 1, 0);
    ImageF ql(cw_, ch_, 1, kNan);
    for (int cy = 0; cy < ch_; ++cy)
      for (int cx = 0; cx < cw_; ++cx) {
        if (c_.region.at(cx, cy))
          rl.at(cx, cy) = tlabel_.at(cx, cy) == l;
        else if (blabel_.at(cx, cy) == l)
          ql.at(cx, cy) = c_.q.at(cx, cy);
      }
    ImageF pl, pw;
    if (BuildSurfacePrior(rl, ql, c_.ox, c_.oy, c_.frame_w, c_.frame_h, o_, &pl, &pw) > 0) {
      for (int cy = 0; cy < ch_; ++cy)
        for (int cx = 0; cx < cw_; ++cx)
          if (rl.at(cx, cy) && std::isfinite(pw.at(cx, cy))) {
            prior.at(cx, cy) = pl.at(cx, cy);
            prior_w.at(cx, cy) = pw.at(cx, cy);
            ++count;
          }
    } else if (o_.neumann_prior_weight > 0.0) {
      // Too few border samples of its own: the layer's plane anchors the region.
      for (int cy = 0; cy < ch_; ++cy)
        for (int cx = 0; cx < cw_; ++cx)
          if (rl.at(cx, cy)) {
            prior.at(cx, cy) = static_cast<float>(
                std::clamp(planes_[l].At(c_.ox + cx, c_.oy + cy), planes_[l].vlo, planes_[l].vhi));
            prior_w.at(cx, cy) = static_cast<float>(o_.neumann_prior_weight);
            ++count;
          }
    }
  }
  if (count == 0) {
    prior = ImageF();
    prior_w = ImageF();
  }
}

LayerResult LayerBuilder::Run() {
  LayerResult out;
  if (!ClusterRing()) return out;
  FitPlanes();
  LabelOtherBorderValues();
  ChooseSeeds();
  SeedDistances();
  if (o_.layer_edge_seeds) ContinueSeedsAlongBorder();
  out.seed_dist_px = FarthestFromSeeds();
  const Labelling problem = BuildLabelling();
  std::vector<int> labels(problem.num_nodes, 0);
  PottsAlphaExpansion(problem.num_nodes, k_, problem.unary, problem.edges, &labels,
                      k_ == 2 ? 1 : 3);
  ApplyLabels(labels, &out);
  FreePairsBetweenLayers();
  BuildLayerPriors(&out);
  out.layers = k_;
  return out;
}

}  // namespace

LayerResult SetupLayers(const std::vector<uint8_t>& measured, const ImageU8& color,
                        const InpaintOptions& options, DepthCrop* crop) {
  return LayerBuilder(measured, color, options, crop).Run();
}

}  // namespace exo::inpainting
