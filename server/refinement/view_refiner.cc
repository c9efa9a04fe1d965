#include "server/refinement/view_refiner.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <ctime>
#include <cmath>
#include <cstring>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <tuple>
#include <vector>

#include <Eigen/Eigenvalues>

#include "server/refinement/cost_functors.h"
#include "server/refinement/pose_batch.h"

namespace exo {
namespace {

using refinement::LogExposureResidual;
using refinement::LevelIntrinsics;
using refinement::LumaGrid;
using refinement::LumaInterpolator;
using refinement::DepthDeltaAnalytic;
using refinement::PoseDeltaAnalytic;

constexpr int kMaxLevels = 5;

struct LinearLut {
  std::array<float, 256> v;
  LinearLut() {
    for (int i = 0; i < 256; ++i) v[i] = static_cast<float>(SrgbToLinear(static_cast<uint8_t>(i)));
  }
};
const LinearLut& Lut() {
  static const LinearLut lut;  // immutable after construction (thread-safe init)
  return lut;
}

// One pyramid level of an image: linear luma, a "bad" mask (saturated/black pixels, dilated by
// the sampling support) and the level's intrinsics. The interpolator points into `luma`.
struct Level {
  int w = 0, h = 0;
  std::vector<float> luma;
  std::vector<uint8_t> bad;
  LevelIntrinsics k;
  std::unique_ptr<LumaGrid> grid;
  std::unique_ptr<LumaInterpolator> interp;
  refinement::FastBicubic fast;  // same spline as interp, used on the hot paths
  // Reference views, level 0 only: per kPickCell x kPickCell cell (from border_px), the most
  // textured and the flattest pixel with valid depth (see BuildPicks).
  struct Pick {
    int32_t best = -1, flat = -1;  // pixel index, -1: none
    float best_g = -1.f, flat_g = 1e30f;
  };
  std::vector<Pick> picks;
  int picks_w = 0, picks_h = 0;

  bool Bad(double u, double v) const {
    const int x = static_cast<int>(std::lround(u)), y = static_cast<int>(std::lround(v));
    if (x < 0 || y < 0 || x >= w || y >= h) return true;
    return bad[static_cast<size_t>(y) * w + x] != 0;
  }
  bool Inside(double u, double v, double border) const {
    return u >= border && v >= border && u <= w - 1 - border && v <= h - 1 - border;
  }
  bool BadBilinear(double u, double v) const {
    const int x0 = std::clamp(static_cast<int>(std::floor(u)), 0, w - 2);
    const int y0 = std::clamp(static_cast<int>(std::floor(v)), 0, h - 2);
    const uint8_t* b0 = &bad[static_cast<size_t>(y0) * w + x0];
    return b0[0] | b0[1] | b0[w] | b0[w + 1];
  }
  double Bilinear(double u, double v) const {
    const int x0 = std::clamp(static_cast<int>(std::floor(u)), 0, w - 2);
    const int y0 = std::clamp(static_cast<int>(std::floor(v)), 0, h - 2);
    const double fx = std::clamp(u - x0, 0.0, 1.0), fy = std::clamp(v - y0, 0.0, 1.0);
    const float* r0 = &luma[static_cast<size_t>(y0) * w + x0];
    const float* r1 = r0 + w;
    return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  }
};

// Box dilation (square of side 2*radius+1) with running counts: O(pixels) per pass.
void Dilate(std::vector<uint8_t>& m, int w, int h, int radius) {
  if (radius <= 0) return;
  std::vector<uint8_t> tmp(m.size(), 0);
  for (int y = 0; y < h; ++y) {
    const uint8_t* in = &m[static_cast<size_t>(y) * w];
    uint8_t* out = &tmp[static_cast<size_t>(y) * w];
    int count = 0;
    for (int x = 0; x < std::min(radius, w); ++x) count += in[x] != 0;
    for (int x = 0; x < w; ++x) {
      if (x + radius < w) count += in[x + radius] != 0;
      if (x - radius - 1 >= 0) count -= in[x - radius - 1] != 0;
      out[x] = count > 0;
    }
  }
  std::vector<int> count(w, 0);
  for (int y = 0; y < std::min(radius, h); ++y)
    for (int x = 0; x < w; ++x) count[x] += tmp[static_cast<size_t>(y) * w + x];
  for (int y = 0; y < h; ++y) {
    if (y + radius < h)
      for (int x = 0; x < w; ++x) count[x] += tmp[static_cast<size_t>(y + radius) * w + x];
    if (y - radius - 1 >= 0)
      for (int x = 0; x < w; ++x) count[x] -= tmp[static_cast<size_t>(y - radius - 1) * w + x];
    uint8_t* out = &m[static_cast<size_t>(y) * w];
    for (int x = 0; x < w; ++x) out[x] = count[x] > 0;
  }
}

// `dilate_px`: the candidate's mask is dilated by the bicubic support; references are sampled
// bilinearly and check their 2x2 support directly (no dilation, no interpolator).
std::vector<Level> BuildPyramid(const ImageU8& color, const PinholeCamera& cam, int levels,
                                const RefinementOptions& o, int dilate_px, bool interpolator) {
  const auto& lut = Lut().v;
  std::vector<Level> pyr(levels);
  Level& l0 = pyr[0];
  l0.w = color.width();
  l0.h = color.height();
  l0.k = {cam.fx, cam.fy, cam.cx, cam.cy};
  l0.luma.resize(static_cast<size_t>(l0.w) * l0.h);
  l0.bad.resize(l0.luma.size());
  const uint8_t* px = color.data();
  for (size_t i = 0; i < l0.luma.size(); ++i, px += 3) {
    l0.luma[i] = 0.2126f * lut[px[0]] + 0.7152f * lut[px[1]] + 0.0722f * lut[px[2]];
    const int mx = std::max({px[0], px[1], px[2]});
    l0.bad[i] = (mx >= o.saturated_u8 || mx <= o.black_u8) ? 1 : 0;
  }
  for (int l = 1; l < levels; ++l) {
    const Level& p = pyr[l - 1];
    Level& c = pyr[l];
    c.w = p.w / 2;
    c.h = p.h / 2;
    c.k = {p.k.fx * 0.5, p.k.fy * 0.5, (p.k.cx + 0.5) * 0.5 - 0.5, (p.k.cy + 0.5) * 0.5 - 0.5};
    c.luma.resize(static_cast<size_t>(c.w) * c.h);
    c.bad.resize(c.luma.size());
    // Binomial [1 3 3 1]/8 per axis (same phase as the 2x2 box, but low-pass: a box lets the
    // fine texture alias into the coarse levels, which then have no smooth basin).
    std::vector<float> rows(static_cast<size_t>(c.w) * p.h);
    for (int y = 0; y < p.h; ++y) {
      const float* in = &p.luma[static_cast<size_t>(y) * p.w];
      for (int x = 0; x < c.w; ++x) {
        const int x0 = std::max(0, 2 * x - 1), x3 = std::min(p.w - 1, 2 * x + 2);
        rows[static_cast<size_t>(y) * c.w + x] =
            0.125f * (in[x0] + 3.f * in[2 * x] + 3.f * in[2 * x + 1] + in[x3]);
      }
    }
    for (int y = 0; y < c.h; ++y) {
      const int y0 = std::max(0, 2 * y - 1), y3 = std::min(p.h - 1, 2 * y + 2);
      for (int x = 0; x < c.w; ++x) {
        const auto r = [&](int yy) { return rows[static_cast<size_t>(yy) * c.w + x]; };
        c.luma[static_cast<size_t>(y) * c.w + x] =
            0.125f * (r(y0) + 3.f * r(2 * y) + 3.f * r(2 * y + 1) + r(y3));
        const size_t a = static_cast<size_t>(2 * y) * p.w + 2 * x, b = a + p.w;
        c.bad[static_cast<size_t>(y) * c.w + x] = p.bad[a] | p.bad[a + 1] | p.bad[b] | p.bad[b + 1];
      }
    }
  }
  for (Level& l : pyr) {
    Dilate(l.bad, l.w, l.h, dilate_px);
    if (!interpolator) continue;
    l.grid = std::make_unique<LumaGrid>(l.luma.data(), 0, l.h, 0, l.w);
    l.interp = std::make_unique<LumaInterpolator>(*l.grid);
    l.fast = refinement::FastBicubic(l.luma.data(), l.h, l.w);
  }
  return pyr;
}

constexpr int kPickCell = 4;

// Sample selection, precomputed once per reference view (and cached with its pyramid): for
// every 4x4 cell of level 0 starting at border_px, the pixel with the largest gradient
// |dI/dx| + |dI/dy| (central differences) and the one with the smallest relative gradient
// g / (I + 0.01), among pixels with valid depth and not saturated/black. BuildSamples then picks
// per block of 4k x 4k pixels from k x k cells instead of scanning every pixel of every
// reference for every candidate (measured: ~15 ms of a 640x480 call with 8 references).
void BuildPicks(Level& l0, const ImageF& depth, int border) {
  const int w = l0.w, h = l0.h;
  l0.picks_w = std::max(0, (w - 2 * border + kPickCell - 1) / kPickCell);
  l0.picks_h = std::max(0, (h - 2 * border + kPickCell - 1) / kPickCell);
  l0.picks.assign(static_cast<size_t>(l0.picks_w) * l0.picks_h, Level::Pick{});
  for (int y = border; y < h - border; ++y) {
    const float* zr = &depth.at(0, y);
    Level::Pick* prow = &l0.picks[static_cast<size_t>((y - border) / kPickCell) * l0.picks_w];
    for (int x = border; x < w - border; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float z = zr[x];
      if (!(z > 0.f) || !std::isfinite(z) || l0.bad[i]) continue;
      const double g = std::abs(l0.luma[i + 1] - l0.luma[i - 1]) +
                       std::abs(l0.luma[i + w] - l0.luma[i - w]);
      const double gr = g / (l0.luma[i] + 0.01);
      Level::Pick& pk = prow[(x - border) / kPickCell];
      if (g > pk.best_g) {
        pk.best_g = static_cast<float>(g);
        pk.best = static_cast<int32_t>(i);
      }
      if (gr < pk.flat_g) {
        pk.flat_g = static_cast<float>(gr);
        pk.flat = static_cast<int32_t>(i);
      }
    }
  }
}

struct Pose {  // cam_from_local
  Eigen::Quaterniond q{1, 0, 0, 0};
  Eigen::Vector3d t{0, 0, 0};
  Eigen::Vector3d Apply(const Eigen::Vector3d& p) const { return q * p + t; }
};

Pose CamFromLocal(const Rigid3d& local_from_cam) {
  const Rigid3d c = local_from_cam.Inverse();
  Pose p;
  p.q = Eigen::Quaterniond(c.rotation.w, c.rotation.x, c.rotation.y, c.rotation.z).normalized();
  p.t = {c.translation.x, c.translation.y, c.translation.z};
  return p;
}
Rigid3d LocalFromCam(const Pose& p) {
  const Eigen::Quaterniond q = p.q.normalized();
  Rigid3d c;
  c.rotation = glm::dquat(q.w(), q.x(), q.y(), q.z());
  c.translation = {p.t.x(), p.t.y(), p.t.z()};
  return c.Inverse();
}

struct Sample {
  Eigen::Vector3d p_in_local;
  std::array<float, kMaxLevels> m{};     // median of E_i * C_i per level
  std::array<bool, kMaxLevels> has{};
  // Flat samples (the least textured pixel of a block) estimate the exposure: their values do
  // not depend on sub-pixel alignment or on the views' different texture blur, so the ratio
  // is unbiased; textured samples (the most textured pixel) drive the pose.
  bool flat = false;
  // How much the references disagree here: median |E_i C_i - m| over the references (level 0;
  // 0 with one reference). Calibrates the outlier threshold per scene.
  float spread = 0.f;
  int num_refs = 0;
};

// Depth edge test of SPEC §6: within 2 px of a discontinuity larger than dz, or of a hole.
bool NearDepthEdge(const ImageF& d, int x, int y, float z, double dz) {
  static constexpr int kOff[8][2] = {{-2, 0}, {2, 0}, {0, -2}, {0, 2},
                                     {-2, -2}, {2, 2}, {-2, 2}, {2, -2}};
  for (const auto& o : kOff) {
    const int xx = x + o[0], yy = y + o[1];
    if (!d.Contains(xx, yy)) continue;  // image border is handled by the FOV border
    const float n = d.at(xx, yy);
    if (!(n > 0.f) || !std::isfinite(n) || std::abs(n - z) > dz) return true;
  }
  return false;
}

double Median(std::vector<double>& v) {
  if (v.empty()) return 0.0;
  const size_t n = v.size(), mid = n / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  double m = v[mid];
  if (n % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + mid));
  return m;
}

double TukeyRho(double r, double c) {
  const double c2 = c * c, s = r * r;
  if (s >= c2) return c2 / 6.0;
  const double a = 1.0 - s / c2;
  return c2 / 6.0 * (1.0 - a * a * a);
}

}  // namespace

struct RefinementCache::Impl {
  // id, width, height, levels, saturated_u8, black_u8, border_px, fingerprint
  using Key = std::tuple<ViewId, int, int, int, int, int, int, uint64_t>;
  struct Entry {
    std::shared_ptr<const std::vector<Level>> pyramid;
    std::list<Key>::iterator lru;
  };
  size_t max_views;
  std::mutex mu;
  std::map<Key, Entry> entries;
  std::list<Key> lru;  // front: most recently used
  int64_t hits = 0, misses = 0;
};

RefinementCache::RefinementCache(size_t max_views) : impl_(std::make_unique<Impl>()) {
  impl_->max_views = std::max<size_t>(1, max_views);
}
RefinementCache::~RefinementCache() = default;
int64_t RefinementCache::hits() const {
  std::lock_guard<std::mutex> l(impl_->mu);
  return impl_->hits;
}
int64_t RefinementCache::misses() const {
  std::lock_guard<std::mutex> l(impl_->mu);
  return impl_->misses;
}

class RefinementCacheAccess {
 public:
  // The reference's pyramid (no interpolator, mask not dilated), from the cache when present.
  static std::shared_ptr<const std::vector<Level>> Pyramid(RefinementCache* cache,
                                                           const StoredView& v, int levels,
                                                           const RefinementOptions& o) {
    const auto build = [&] {
      std::vector<Level> pyr = BuildPyramid(v.color, v.camera, levels, o, 0, false);
      BuildPicks(pyr[0], v.depth_m, o.border_px);
      return std::make_shared<const std::vector<Level>>(std::move(pyr));
    };
    if (cache == nullptr) return build();
    // FNV-1a over 256 pixels on a 16x16 grid (cheap; catches a view replaced under its id).
    uint64_t fp = 1469598103934665603ull;
    const int w = v.color.width(), h = v.color.height();
    for (int gy = 0; gy < 16; ++gy)
      for (int gx = 0; gx < 16; ++gx) {
        const uint8_t* px = v.color.data() + 3 * (static_cast<size_t>((2 * gy + 1) * h / 32) * w +
                                                  (2 * gx + 1) * w / 32);
        for (int c = 0; c < 3; ++c) fp = (fp ^ px[c]) * 1099511628211ull;
        // The depth too: the cached sample picks depend on where it is valid.
        uint32_t zb;
        const float z = v.depth_m.at((2 * gx + 1) * w / 32, (2 * gy + 1) * h / 32);
        std::memcpy(&zb, &z, sizeof(zb));
        fp = (fp ^ zb) * 1099511628211ull;
      }
    const RefinementCache::Impl::Key key{v.id, w, h, levels, o.saturated_u8, o.black_u8, o.border_px, fp};
    RefinementCache::Impl& c = *cache->impl_;
    {
      std::lock_guard<std::mutex> l(c.mu);
      auto it = c.entries.find(key);
      if (it != c.entries.end()) {
        c.lru.splice(c.lru.begin(), c.lru, it->second.lru);
        ++c.hits;
        return it->second.pyramid;
      }
      ++c.misses;
    }
    auto pyr = build();  // outside the lock
    std::lock_guard<std::mutex> l(c.mu);
    if (c.entries.count(key) == 0) {
      c.lru.push_front(key);
      c.entries[key] = {pyr, c.lru.begin()};
      while (c.entries.size() > c.max_views) {
        c.entries.erase(c.lru.back());
        c.lru.pop_back();
      }
    }
    return pyr;
  }
};

namespace {

class Refiner {
 public:
  Refiner(const StoredView& cand, std::vector<const StoredView*> refs, std::vector<double> overlap,
          const RefinementOptions& o, RefinementCache* cache)
      : cand_(cand), refs_(std::move(refs)), overlap_(std::move(overlap)), o_(o), cache_(cache) {}

  absl::StatusOr<RefinementResult> Run();

 private:
  // The steps of Run, in order.
  void BuildPyramids();          // candidate and reference pyramids (the latter from cache_)
  void PrepareCandidateDepth();  // depth-term grid and its invalid (hole / edge) mask
  struct Active {
    std::vector<int> idx;
    std::vector<double> c;  // candidate value at the current pose
  };
  void BuildSamples(int budget);
  // BuildSamples' steps: block culling, the textured and flat picks of a block, and one sample
  // (valid in the candidate at its input pose, medians over the references per level).
  bool BlockReachesCandidate(const StoredView& ref, const Level& rl, const Rigid3d& cand_from_ref,
                             int bx, int by, int block, double margin_px) const;
  struct BlockPicks {
    int best_x = -1, best_y = -1, flat_x = -1, flat_y = -1;
  };
  BlockPicks PickInBlock(const StoredView& ref, const Level& rl, int bx, int by, int block,
                         bool use_picks) const;
  bool MakeSample(const glm::dvec3& p_in_local, bool flat, const Pose& cand0,
                  const std::vector<Rigid3d>& ref_from_local, Sample* s,
                  double* depth_in_cand) const;
  enum class Kind { kAll, kTextured, kFlat };
  Active ActiveSet(int level, const Pose& pose, Kind kind = Kind::kAll) const;
  bool ValidInCandidate(int level, const Pose& pose, const Sample& s, double* u,
                        double* v) const;
  // J of (e0, p0) and (e1, p1) over the samples valid at both (a fair comparison when the
  // valid set changes); `raised` also when most of the samples valid before are lost.
  struct EnergyPair {
    double before = 0, after = 0;
    int common = 0, valid_before = 0;
    bool Raised() const { return after > before || common < valid_before / 2; }
  };
  EnergyPair CompareEnergy(int level, double e0, const Pose& p0, double e1, const Pose& p1,
                           double scale) const;
  double ScaleFromResiduals(std::vector<double> r, double fixed) const;
  double SolveExposure(int level, const Pose& pose, double e, bool warm_start);
  void LogValues(int level, const Active& a, std::vector<double>* lc, std::vector<double>* lm) const;
  Pose SolvePose(int level, double e, const Pose& pose);
  void RankCheck(const Pose& pose, double e);
  // Depth term (RGB-D candidates): relative depth residual of sample j at `pose`, false when
  // the candidate has no usable depth there (hole, depth edge, outside).
  bool DepthResidual(const Sample& s, const Pose& pose, double* r) const;
  // Weight that maps the depth residuals' robust scale onto the photometric scale `scale`.
  double DepthWeight(const std::vector<int>& idx, const Pose& pose, double scale) const;
  // Tukey energy of the depth term before/after, on samples valid at both poses.
  void AddDepthEnergy(const std::vector<int>& idx, const Pose& p0, const Pose& p1, double w,
                      double scale, double* before, double* after) const;
  Eigen::Matrix<double, 6, 6> Information(int level, const Pose& pose, double e) const;
  // Pose/exposure alternation over the pyramid from `start_level` (-1: the coarsest). The first
  // pass refines rotation only on the coarse levels; a multi-start pass is 6-DoF everywhere.
  void CoarseToFine(bool multistart, Pose* pose, double* e, int start_level = -1);
  // Relative residual at `pose` and the outlier threshold for it (references' disagreement).
  void OutlierTest(const Pose& pose, double e, double* relative, double* threshold,
                   double* disagreement = nullptr, int* num_valid = nullptr) const;
  struct ResidualSummary {
    double relative = 1.0;  // median |E c_j - m_j| / median(m_j)
    double median_m = 0.0;  // median(m_j)
  };
  ResidualSummary SummarizeResiduals(const Active& a, double e) const;
  // Surface samples valid at the input pose (densified for saturated/black candidates); an
  // error when fewer than 3 are valid.
  absl::StatusOr<Active> SampleSurface(const Pose& pose0);
  double InitialExposure(const Pose& pose0, const Active& a0) const;
  // Restarts around a first pass that would be rejected as an outlier (multistart_step_m).
  void MultiStart(Pose* pose, double* e);
  // Undo pose / exposure changes that raised the energy of the whole call.
  void GuardEnergy(const Pose& pose0, double e0, double e_exposure_only, const Active& a0,
                   double report_scale, Pose* pose, double* e);
  // Significance gates: keep the input pose / prior exposure when an update explains less than
  // the references' own disagreement.
  void GateInsignificantUpdates(const Pose& pose0, double e_exposure_only, Pose* pose, double* e);
  bool multistart_pass_ = false;  // set by CoarseToFine

  const StoredView& cand_;
  std::vector<const StoredView*> refs_;
  std::vector<double> overlap_;  // fraction of each reference seen by the candidate
  const RefinementOptions& o_;
  int levels_ = 1;
  std::vector<Level> cand_pyr_;
  RefinementCache* cache_ = nullptr;
  std::vector<std::shared_ptr<const std::vector<Level>>> ref_pyr_;
  std::vector<Sample> samples_;
  double median_depth_m_ = 1.0;
  std::vector<float> cand_depth_;        // candidate z-depth (holes 0), for the depth term
  std::vector<uint8_t> cand_depth_bad_;  // hole or within 2 px of a depth step
  std::unique_ptr<refinement::DepthGrid> depth_grid_;
  std::unique_ptr<refinement::DepthInterpolator> depth_interp_;
  refinement::FastBicubic depth_fast_;  // same spline as depth_interp_
  // Pose directions updated (orthonormal columns in the PoseDeltaResidual chart): all
  // well-conditioned ones at fine levels, the rotation ones at coarse levels.
  Eigen::Matrix<double, 6, Eigen::Dynamic> free_basis_ = Eigen::Matrix<double, 6, 6>::Identity();
  Eigen::Matrix<double, 6, Eigen::Dynamic> rot_basis_ = Eigen::Matrix<double, 6, 6>::Identity().leftCols(3);
  RefinementResult res_;
};

bool Refiner::BlockReachesCandidate(const StoredView& ref, const Level& rl,
                                    const Rigid3d& cand_from_ref, int bx, int by, int block,
                                    double margin_px) const {
  // The block centre (with its depth) must not project farther than `margin_px` outside the
  // candidate image (scanning every pixel of every reference was ~15 ms of a 640x480 call with 8
  // references). A centre without depth or behind the candidate keeps the block.
  const Level& c0 = cand_pyr_[0];
  const int w = rl.w, h = rl.h;
  const int cx = std::min(bx + block / 2, w - 1 - o_.border_px);
  const int cy = std::min(by + block / 2, h - 1 - o_.border_px);
  const float zc = ref.depth_m.at(cx, cy);
  if (!(zc > 0.f && std::isfinite(zc))) return true;
  const glm::dvec3 q = cand_from_ref * ref.camera.Unproject({double(cx), double(cy)}, zc);
  if (!(q.z > 0.05 * zc)) return true;
  const double u = c0.k.fx * q.x / q.z + c0.k.cx, v = c0.k.fy * q.y / q.z + c0.k.cy;
  return !(u < -margin_px || v < -margin_px || u > c0.w - 1 + margin_px ||
           v > c0.h - 1 + margin_px);
}

Refiner::BlockPicks Refiner::PickInBlock(const StoredView& ref, const Level& rl, int bx, int by,
                                         int block, bool use_picks) const {
  // The most textured pixel of the block with valid depth (DSO-style candidates) and the
  // flattest one (relative gradient): from the cached per-cell picks, or by a scan.
  const int w = rl.w, h = rl.h;
  BlockPicks out;
  if (use_picks) {
    const int c0x = (bx - o_.border_px) / kPickCell, c0y = (by - o_.border_px) / kPickCell;
    const int nc = block / kPickCell;
    int best = -1, flat = -1;
    float bg = -1.f, fg = 1e30f;
    for (int cy = c0y; cy < std::min(c0y + nc, rl.picks_h); ++cy)
      for (int cx = c0x; cx < std::min(c0x + nc, rl.picks_w); ++cx) {
        const Level::Pick& pk = rl.picks[static_cast<size_t>(cy) * rl.picks_w + cx];
        if (pk.best < 0) continue;
        if (pk.best_g > bg) {
          bg = pk.best_g;
          best = pk.best;
        }
        if (pk.flat_g < fg) {
          fg = pk.flat_g;
          flat = pk.flat;
        }
      }
    if (best >= 0) {
      out.best_x = best % w;
      out.best_y = best / w;
      out.flat_x = flat % w;
      out.flat_y = flat / w;
    }
    return out;
  }
  double best_g = -1.0, flat_g = 1e30;
  for (int y = by; y < std::min(by + block, h - o_.border_px); ++y)
    for (int x = bx; x < std::min(bx + block, w - o_.border_px); ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float z = ref.depth_m.at(x, y);
      if (!(z > 0.f) || !std::isfinite(z) || rl.bad[i]) continue;
      const double g =
          std::abs(rl.luma[i + 1] - rl.luma[i - 1]) + std::abs(rl.luma[i + w] - rl.luma[i - w]);
      if (g > best_g) {
        best_g = g;
        out.best_x = x;
        out.best_y = y;
      }
      const double gr = g / (rl.luma[i] + 0.01);
      if (gr < flat_g) {
        flat_g = gr;
        out.flat_x = x;
        out.flat_y = y;
      }
    }
  return out;
}

bool Refiner::MakeSample(const glm::dvec3& pl, bool flat, const Pose& cand0,
                         const std::vector<Rigid3d>& ref_from_local, Sample* s,
                         double* depth_in_cand) const {
  const Level& c0 = cand_pyr_[0];
  s->flat = flat;
  s->p_in_local = {pl.x, pl.y, pl.z};
  // Valid in the candidate at its initial pose (SPEC §6, looser occlusion tolerance).
  const Eigen::Vector3d q = cand0.Apply(s->p_in_local);
  if (!(q.z() > 1e-6)) return false;
  const double u = c0.k.fx * q.x() / q.z() + c0.k.cx, v = c0.k.fy * q.y() / q.z() + c0.k.cy;
  if (!c0.Inside(u, v, o_.border_px)) return false;
  const bool cand_depth = !cand_.depth_m.empty() && cand_.depth_m.width() == c0.w &&
                          cand_.depth_m.height() == c0.h;
  if (cand_depth) {
    const float dc =
        cand_.depth_m.at(static_cast<int>(std::lround(u)), static_cast<int>(std::lround(v)));
    if (dc > 0.f && std::isfinite(dc) &&
        std::abs(q.z() - dc) > o_.cand_occlusion_abs_m + o_.cand_occlusion_rel * dc)
      return false;
  }
  // Median over the references in which the point is valid, per level.
  std::vector<double> vals[kMaxLevels];
  for (size_t i = 0; i < refs_.size(); ++i) {
    const StoredView& ri = *refs_[i];
    const glm::dvec3 pi = ref_from_local[i] * pl;
    glm::dvec2 uv;
    if (!ri.camera.Project(pi, &uv)) continue;
    const Level& L0 = (*ref_pyr_[i])[0];
    if (!L0.Inside(uv.x, uv.y, 1.0)) continue;
    const int xi = static_cast<int>(std::lround(uv.x)), yi = static_cast<int>(std::lround(uv.y));
    const float di = ri.depth_m.at(xi, yi);
    if (!(di > 0.f) || !std::isfinite(di)) continue;
    if (std::abs(pi.z - di) > o_.ref_occlusion_abs_m + o_.ref_occlusion_rel * di) continue;
    if (NearDepthEdge(ri.depth_m, xi, yi, di, o_.depth_discontinuity_m)) continue;
    for (int l = 0; l < levels_; ++l) {
      const Level& L = (*ref_pyr_[i])[l];
      const double s_l = 1.0 / (1 << l);
      const double ul = (uv.x + 0.5) * s_l - 0.5, vl = (uv.y + 0.5) * s_l - 0.5;
      if (!L.Inside(ul, vl, 0.0) || L.BadBilinear(ul, vl)) continue;
      vals[l].push_back(ri.exposure * L.Bilinear(ul, vl));
    }
  }
  for (int l = 0; l < levels_; ++l) {
    s->has[l] = !vals[l].empty();
    if (s->has[l]) s->m[l] = static_cast<float>(Median(vals[l]));
  }
  s->num_refs = static_cast<int>(vals[0].size());
  if (s->num_refs >= 2) {
    for (double& x : vals[0]) x = std::abs(x - s->m[0]);
    s->spread = static_cast<float>(Median(vals[0]));
  }
  if (!s->has[0]) return false;
  *depth_in_cand = q.z();
  return true;
}

void Refiner::BuildSamples(int budget) {
  const Pose cand0 = CamFromLocal(cand_.local_from_cam);
  const Level& c0 = cand_pyr_[0];
  // One block size for all references: each contributes in proportion to its overlap.
  double overlap_sum = 0;
  for (double f : overlap_) overlap_sum += f;
  std::vector<double> depths;
  std::vector<Rigid3d> ref_from_local;
  for (const StoredView* r : refs_) ref_from_local.push_back(r->local_from_cam.Inverse());
  for (size_t r = 0; r < refs_.size(); ++r) {
    const StoredView& ref = *refs_[r];
    const Level& rl = (*ref_pyr_[r])[0];
    const int w = rl.w, h = rl.h;
    int block =
        std::max(2, static_cast<int>(std::ceil(std::sqrt(double(w) * h * overlap_sum / budget))));
    // Blocks of >= 2 cells pick from the cached per-cell picks (block rounded to whole cells);
    // smaller blocks (small images, densified sampling) scan their pixels.
    const bool use_picks = block >= 2 * kPickCell && !rl.picks.empty();
    if (use_picks) block = kPickCell * (block / kPickCell);
    const Rigid3d cand_from_ref = cand_.local_from_cam.Inverse() * ref.local_from_cam;
    const double margin_px = 3.0 * block * c0.k.fx / ref.camera.fx + o_.border_px;
    for (int by = o_.border_px; by < h - o_.border_px; by += block)
      for (int bx = o_.border_px; bx < w - o_.border_px; bx += block) {
        if (!BlockReachesCandidate(ref, rl, cand_from_ref, bx, by, block, margin_px)) continue;
        const BlockPicks picks = PickInBlock(ref, rl, bx, by, block, use_picks);
        if (picks.best_x < 0) continue;
        for (int pass = 0; pass < 2; ++pass) {
          const int sx = pass == 0 ? picks.best_x : picks.flat_x;
          const int sy = pass == 0 ? picks.best_y : picks.flat_y;
          const float z = ref.depth_m.at(sx, sy);
          if (NearDepthEdge(ref.depth_m, sx, sy, z, o_.depth_discontinuity_m)) continue;
          const glm::dvec3 pl = ref.local_from_cam * ref.camera.Unproject({double(sx), double(sy)}, z);
          Sample s;
          double depth = 0;
          if (!MakeSample(pl, pass == 1, cand0, ref_from_local, &s, &depth)) continue;
          samples_.push_back(s);
          depths.push_back(depth);
        }
      }
  }
  if (!depths.empty()) median_depth_m_ = Median(depths);
}

bool Refiner::ValidInCandidate(int level, const Pose& pose, const Sample& s, double* u,
                               double* v) const {
  if (!s.has[level]) return false;
  const Level& L = cand_pyr_[level];
  const Eigen::Vector3d q = pose.Apply(s.p_in_local);
  if (!(q.z() > 1e-6)) return false;
  *u = L.k.fx * q.x() / q.z() + L.k.cx;
  *v = L.k.fy * q.y() / q.z() + L.k.cy;
  return L.Inside(*u, *v, o_.border_px) && !L.Bad(*u, *v);
}

Refiner::Active Refiner::ActiveSet(int level, const Pose& pose, Kind kind) const {
  Active a;
  const Level& L = cand_pyr_[level];
  // Coarse levels use a subset (every stride-th sample, at least ~400): they only need to bring
  // the pose into the basin of the finer levels.
  const size_t stride = std::max<size_t>(1, std::min<size_t>(size_t{1} << level, samples_.size() / 400));
  size_t counter = 0;
  for (size_t j = 0; j < samples_.size(); ++j) {
    if ((kind == Kind::kFlat && !samples_[j].flat) || (kind == Kind::kTextured && samples_[j].flat))
      continue;
    if (counter++ % stride != 0) continue;
    double u, v;
    if (!ValidInCandidate(level, pose, samples_[j], &u, &v)) continue;
    double val;
    L.fast.Evaluate(v, u, &val);
    a.idx.push_back(static_cast<int>(j));
    a.c.push_back(val);
  }
  return a;
}

// J (3.17) at one level with a fixed Tukey scale, before and after a step, on common samples.
Refiner::EnergyPair Refiner::CompareEnergy(int level, double e0, const Pose& p0, double e1,
                                           const Pose& p1, double scale) const {
  const Level& L = cand_pyr_[level];
  EnergyPair ep;
  for (const Sample& s : samples_) {
    if (s.flat) continue;  // the pose energy: textured samples
    double u0, v0, u1, v1;
    const bool ok0 = ValidInCandidate(level, p0, s, &u0, &v0);
    if (!ok0) continue;
    ++ep.valid_before;
    if (!ValidInCandidate(level, p1, s, &u1, &v1)) continue;
    double c0, c1;
    L.fast.Evaluate(v0, u0, &c0);
    L.fast.Evaluate(v1, u1, &c1);
    ep.before += TukeyRho(e0 * c0 - s.m[level], scale);
    ep.after += TukeyRho(e1 * c1 - s.m[level], scale);
    ++ep.common;
  }
  return ep;
}

// Tukey scale from the median absolute residual (MAD about zero, not about the median: an
// all-offset start, e.g. a wrong exposure, then gets a scale as large as the offset and is not
// "converged" at once on Tukey's flat tails).
double Refiner::ScaleFromResiduals(std::vector<double> r, double fixed) const {
  if (!o_.scale_from_mad || r.empty()) return fixed;
  for (double& x : r) x = std::abs(x);
  const double mad = Median(r);
  return std::max(o_.min_scale, o_.tukey_k * 1.4826 * mad);
}

ceres::Solver::Options SolverOptions(const RefinementOptions& o) {
  ceres::Solver::Options s;
  s.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  s.max_num_iterations = o.max_solver_iterations;
  s.num_threads = 1;
  s.use_nonmonotonic_steps = false;  // every accepted LM step lowers the cost
  s.minimizer_progress_to_stdout = false;
  s.logging_type = ceres::SILENT;
  s.function_tolerance = o.function_tolerance;
  s.parameter_tolerance = 1e-8;
  return s;
}

// Log-domain Tukey energy of the exposure stage over the active samples.
double LogExposureEnergy(const std::vector<double>& lc, const std::vector<double>& lm, double e,
                         double scale) {
  double sum = 0;
  const double le = std::log(e);
  for (size_t k = 0; k < lc.size(); ++k) sum += TukeyRho(le + lc[k] - lm[k], scale);
  return sum;
}

void Refiner::LogValues(int level, const Active& a, std::vector<double>* lc,
                        std::vector<double>* lm) const {
  constexpr double kMinIntensity = 1e-4;
  lc->clear();
  lm->clear();
  for (size_t k = 0; k < a.idx.size(); ++k) {
    const double m = samples_[a.idx[k]].m[level];
    if (a.c[k] < kMinIntensity || m < kMinIntensity) continue;
    lc->push_back(std::log(a.c[k]));
    lm->push_back(std::log(m));
  }
}

double Refiner::SolveExposure(int level, const Pose& pose, double e, bool warm_start) {
  Active a = ActiveSet(level, pose, Kind::kFlat);
  if (a.idx.size() < 30) a = ActiveSet(level, pose, Kind::kAll);
  std::vector<double> lc, lm;
  LogValues(level, a, &lc, &lm);
  if (lc.size() < 3) return e;
  std::vector<double> r(lc.size());
  for (size_t k = 0; k < lc.size(); ++k) r[k] = std::log(e) + lc[k] - lm[k];
  const double scale = ScaleFromResiduals(r, o_.fixed_scale);
  double x = std::log(e);  // log-exposure parameter (LogExposureResidual)
  const ceres::Solver::Options so = SolverOptions(o_);
  for (int stage = warm_start ? 0 : 1; stage < 2; ++stage) {
    ceres::Problem::Options po;
    po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    std::unique_ptr<ceres::LossFunction> loss;
    if (stage == 0)
      loss = std::make_unique<ceres::CauchyLoss>(scale);
    else
      loss = std::make_unique<ceres::TukeyLoss>(scale);
    for (size_t k = 0; k < lc.size(); ++k)
      problem.AddResidualBlock(new LogExposureResidual(lc[k], lm[k]), loss.get(), &x);
    ceres::Solver::Summary sum;
    ceres::Solve(so, &problem, &sum);
    res_.iterations += static_cast<int>(sum.iterations.size());
  }
  x = std::exp(x);
  RefinementStage st{level, false, LogExposureEnergy(lc, lm, e, scale), 0.0, true, LocalFromCam(pose), e};
  st.after = std::isfinite(x) && x > 0 ? LogExposureEnergy(lc, lm, x, scale) : st.before + 1.0;
  if (st.after > st.before) {
    st.accepted = false;
    res_.step_reverted = true;  // guard: never accept a stage that raises its energy
  }
  if (st.accepted) st.exposure = x;
  res_.stages.push_back(st);
  return st.accepted ? x : e;
}

Pose Refiner::SolvePose(int level, double e, const Pose& pose) {
  // Coarse levels cannot separate a small camera translation from a rotation (1-2 cm at metres
  // is sub-pixel there): rotation only (about the camera centre), the translation waits for the
  // fine levels. Weak directions (eigen-analysis of the level-0 information) stay frozen.
  const bool rot_only = !multistart_pass_ && level >= o_.rotation_only_from_level;
  const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis = rot_only ? rot_basis_ : free_basis_;
  if (basis.cols() == 0) return pose;
  const Active a = ActiveSet(level, pose, Kind::kTextured);
  if (static_cast<int>(a.idx.size()) < o_.min_pose_samples) return pose;
  const Level& L = cand_pyr_[level];
  std::vector<double> r(a.idx.size());
  for (size_t k = 0; k < a.idx.size(); ++k) r[k] = e * a.c[k] - samples_[a.idx[k]].m[level];
  const double scale = ScaleFromResiduals(r, o_.fixed_scale);
  double xi[6] = {0, 0, 0, 0, 0, 0};
  ceres::Solver::Options so = SolverOptions(o_);
  if (level > 0) so.max_num_iterations = std::max(3, o_.max_solver_iterations / 2);
  const double dw = depth_interp_ ? DepthWeight(a.idx, pose, scale) : 0.0;
  // ceres::Solve on ONE residual block holding all residuals (pose_batch.h), the robust loss
  // folded into the residuals per residual: the same residuals and robust energy as a
  // ceres::Problem with one block per residual, without its per-block overhead.
  refinement::PoseBatchCost batch(&L.fast, L.k, e, &depth_fast_, cand_pyr_[0].k, dw,
                                  median_depth_m_);
  for (size_t k = 0; k < a.idx.size(); ++k) {
    const Sample& s = samples_[a.idx[k]];
    batch.AddPhotometric(pose.Apply(s.p_in_local), s.m[level]);
  }
  if (dw > 0)
    for (size_t k = 0; k < a.idx.size(); ++k) {
      const Sample& s = samples_[a.idx[k]];
      double rd;
      if (DepthResidual(s, pose, &rd)) batch.AddDepth(pose.Apply(s.p_in_local));
    }
  // Tukey at the finest level; Cauchy (same influence scale) on the coarse levels, whose job is
  // to bring the pose into the basin: Tukey gives misaligned samples zero weight, which there
  // are the very samples that carry the alignment signal.
  refinement::RobustLoss rl;
  rl.kind = level == 0 ? refinement::RobustLoss::Kind::kTukey : refinement::RobustLoss::Kind::kCauchy;
  rl.scale = level == 0 ? scale : scale / o_.tukey_k;
  refinement::PoseSolveOptions lo;
  lo.max_iterations = so.max_num_iterations;
  lo.function_tolerance = so.function_tolerance;
  lo.parameter_tolerance = so.parameter_tolerance;
  lo.gradient_tolerance = so.gradient_tolerance;
  res_.iterations += refinement::SolvePoseCeres(batch, rl, basis, lo, xi).iterations;
  const Eigen::Vector3d w(xi[0], xi[1], xi[2]);
  const Eigen::Vector3d dt = median_depth_m_ * Eigen::Vector3d(xi[3], xi[4], xi[5]);
  const double angle = w.norm();
  const Eigen::Quaterniond dq =
      angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, w / angle)) : Eigen::Quaterniond::Identity();
  Pose out;
  out.q = (dq * pose.q).normalized();
  out.t = dq * pose.t + dt;
  const bool finite = out.t.allFinite() && out.q.coeffs().allFinite();
  EnergyPair ep = finite ? CompareEnergy(level, e, pose, e, out, scale) : EnergyPair{};
  if (finite && dw > 0) AddDepthEnergy(a.idx, pose, out, dw, scale, &ep.before, &ep.after);
  RefinementStage st{level, true, ep.before, ep.after, finite && !ep.Raised(), {}, e};
  st.local_from_cam = LocalFromCam(st.accepted ? out : pose);
  res_.stages.push_back(st);
  if (!st.accepted) {
    res_.step_reverted = true;  // guard: never accept a stage that raises J
    return pose;
  }
  return out;
}

bool Refiner::DepthResidual(const Sample& s, const Pose& pose, double* r) const {
  const Level& L = cand_pyr_[0];
  const Eigen::Vector3d q = pose.Apply(s.p_in_local);
  if (!(q.z() > 1e-6)) return false;
  const double u = L.k.fx * q.x() / q.z() + L.k.cx, v = L.k.fy * q.y() / q.z() + L.k.cy;
  if (!L.Inside(u, v, o_.border_px)) return false;
  const int x = static_cast<int>(std::lround(u)), y = static_cast<int>(std::lround(v));
  if (cand_depth_bad_[static_cast<size_t>(y) * L.w + x]) return false;
  double d;
  depth_fast_.Evaluate(v, u, &d);
  *r = (d - q.z()) / q.z();
  return std::isfinite(*r);
}

double Refiner::DepthWeight(const std::vector<int>& idx, const Pose& pose, double scale) const {
  std::vector<double> r;
  for (int j : idx) {
    double rd;
    if (DepthResidual(samples_[j], pose, &rd)) r.push_back(std::abs(rd));
  }
  if (r.size() < 10) return 0.0;
  const double scale_d = std::max(o_.min_depth_scale_rel, o_.tukey_k * 1.4826 * Median(r));
  return o_.depth_weight * scale / scale_d;
}

void Refiner::AddDepthEnergy(const std::vector<int>& idx, const Pose& p0, const Pose& p1, double w,
                             double scale, double* before, double* after) const {
  for (int j : idx) {
    double r0, r1;
    if (!DepthResidual(samples_[j], p0, &r0) || !DepthResidual(samples_[j], p1, &r1)) continue;
    *before += TukeyRho(w * r0, scale);
    *after += TukeyRho(w * r1, scale);
  }
}

Eigen::Matrix<double, 6, 6> Refiner::Information(int level, const Pose& pose, double e) const {
  const Active a = ActiveSet(level, pose, Kind::kTextured);
  const Level& L = cand_pyr_[level];
  const int n = static_cast<int>(a.idx.size());
  Eigen::Matrix<double, 6, 6> h = Eigen::Matrix<double, 6, 6>::Zero();
  if (n < 6) return h;
  std::vector<double> r(n), ms(n);
  for (int k = 0; k < n; ++k) {
    r[k] = e * a.c[k] - samples_[a.idx[k]].m[level];
    ms[k] = samples_[a.idx[k]].m[level];
  }
  const double scale = ScaleFromResiduals(r, o_.fixed_scale);
  double xi[6] = {0, 0, 0, 0, 0, 0};
  const double* params[1] = {xi};
  for (int k = 0; k < n; ++k) {
    const Sample& s = samples_[a.idx[k]];
    const PoseDeltaAnalytic cf(L.interp.get(), L.k, pose.Apply(s.p_in_local), median_depth_m_, e,
                               s.m[level]);
    double res;
    Eigen::Matrix<double, 6, 1> j;
    double* jac[1] = {j.data()};
    if (!cf.Evaluate(params, &res, jac)) continue;
    const double s2 = res * res / (scale * scale);
    const double w = s2 < 1.0 ? (1.0 - s2) * (1.0 - s2) : 0.0;
    h += w * j * j.transpose();
  }
  // The depth term (as weighted in SolvePose) adds its own information; it is what separates
  // a rotation from a translation in front of a wall.
  const double dw = depth_interp_ ? DepthWeight(a.idx, pose, scale) : 0.0;
  if (dw > 0)
    for (int k = 0; k < n; ++k) {
      const Sample& s = samples_[a.idx[k]];
      double rd;
      if (!DepthResidual(s, pose, &rd)) continue;
      const DepthDeltaAnalytic cf(depth_interp_.get(), cand_pyr_[0].k, pose.Apply(s.p_in_local),
                                  median_depth_m_, dw);
      double res;
      Eigen::Matrix<double, 6, 1> j;
      double* jac[1] = {j.data()};
      if (!cf.Evaluate(params, &res, jac)) continue;
      const double s2 = res * res / (scale * scale);
      const double w = s2 < 1.0 ? (1.0 - s2) * (1.0 - s2) : 0.0;
      h += w * j * j.transpose();
    }
  const double med_m = std::max(1e-4, Median(ms));
  return h / (n * med_m * med_m);
}

// Gauss-Newton information of the 6-DoF pose correction at level 1 (chart of PoseDeltaResidual:
// radians about the camera centre, translation in median-depth units), robust-weighted, per
// sample and relative to the squared median intensity: (relative contrast / radian)^2. Image
// gradients per pixel shrink with resolution while radians per pixel grow, so the figure does
// not depend on the resolution. Directions with little information (or a large condition
// number) are frozen; the pose is refused when none is left or there are too few samples.
void Refiner::RankCheck(const Pose& pose, double e) {
  free_basis_.resize(6, 0);
  rot_basis_.resize(6, 0);
  // Level 1 (the first low-passed level) when there is one: uncorrelated pixel noise carries
  // spurious "information" at level 0 (a uniform room with sensor noise scores like a weakly
  // textured one) and is suppressed ~30x by one binomial level, texture is not.
  const int rank_level = std::min(1, levels_ - 1);
  const int n = static_cast<int>(ActiveSet(rank_level, pose, Kind::kTextured).idx.size());
  if (n < o_.min_pose_samples) {
    res_.pose_refused_rank_deficient = true;
    return;
  }
  const Eigen::Matrix<double, 6, 6> h = Information(rank_level, pose, e);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(h);
  const double lmin = std::max(0.0, es.eigenvalues()(0)), lmax = es.eigenvalues()(5);
  res_.pose_min_eigenvalue = lmin;
  res_.pose_condition = lmin > 0 ? lmax / lmin : std::numeric_limits<double>::infinity();
  const double floor = std::max(o_.min_pose_information, lmax / o_.max_pose_condition);
  // Translation in metres: information of the translation given the rotation (Schur
  // complement), per m^2. At altitude (village: 20-60 m) a centimetre of camera motion is far
  // below a pixel and its directions are frozen, instead of letting them wander along the
  // energy's flat valley (measured: hundreds of mm).
  Eigen::Matrix<double, 6, Eigen::Dynamic> allowed = Eigen::Matrix<double, 6, 6>::Identity();
  {
    const Eigen::Matrix3d hrr = h.topLeftCorner<3, 3>(), htt = h.bottomRightCorner<3, 3>();
    const Eigen::Matrix3d hrt = h.topRightCorner<3, 3>();
    const Eigen::Matrix3d schur =
        (htt - hrt.transpose() * hrr.ldlt().solve(hrt)) / (median_depth_m_ * median_depth_m_);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> et(schur);
    res_.pose_translation_information = std::max(0.0, et.eigenvalues()(0));
    std::vector<int> keep_t;
    for (int i = 0; i < 3; ++i)
      if (et.eigenvalues()(i) >= o_.min_translation_information) keep_t.push_back(i);
    if (!o_.freeze_weak_directions && keep_t.size() < 3) keep_t.clear();
    allowed = Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, 3 + static_cast<int>(keep_t.size()));
    allowed.topLeftCorner<3, 3>().setIdentity();
    for (size_t i = 0; i < keep_t.size(); ++i)
      allowed.block<3, 1>(3, 3 + i) = et.eigenvectors().col(keep_t[i]);
  }
  // Weak directions of the information restricted to the allowed subspace.
  const Eigen::MatrixXd ha = allowed.transpose() * h * allowed;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> ea(ha);
  std::vector<int> keep;
  for (int i = 0; i < ha.rows(); ++i)
    if (ea.eigenvalues()(i) >= floor) keep.push_back(i);
  if (!o_.freeze_weak_directions && static_cast<int>(keep.size()) < 6) keep.clear();
  res_.pose_free_directions = static_cast<int>(keep.size());
  if (keep.empty()) {
    res_.pose_refused_rank_deficient = true;
    return;
  }
  free_basis_.resize(6, static_cast<int>(keep.size()));
  for (size_t i = 0; i < keep.size(); ++i) free_basis_.col(i) = allowed * ea.eigenvectors().col(keep[i]);
  // Coarse levels: rotation only, its own well-conditioned directions.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> er(h.topLeftCorner<3, 3>());
  std::vector<int> keep_r;
  for (int i = 0; i < 3; ++i)
    if (er.eigenvalues()(i) >= floor) keep_r.push_back(i);
  if (!o_.freeze_weak_directions && static_cast<int>(keep_r.size()) < 3) keep_r.clear();
  rot_basis_ = Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, static_cast<int>(keep_r.size()));
  for (size_t i = 0; i < keep_r.size(); ++i) rot_basis_.block<3, 1>(0, i) = er.eigenvectors().col(keep_r[i]);
}

void Refiner::CoarseToFine(bool multistart, Pose* pose_io, double* e_io, int start_level) {
  Pose pose = *pose_io;
  double e = *e_io;
  multistart_pass_ = multistart;
  const int first = start_level < 0 ? levels_ - 1 : std::min(start_level, levels_ - 1);
  for (int l = first; l >= 0; --l) {
    for (int it = 0; it < o_.max_outer_iterations; ++it) {
      const Pose p1 = SolvePose(l, e, pose);
      const double e1 = SolveExposure(l, p1, e, false);
      const double drot = p1.q.angularDistance(pose.q);
      const double dt = (p1.q.conjugate() * p1.t - pose.q.conjugate() * pose.t).norm();
      const double de = std::abs(e1 - e) / std::max(e, 1e-9);
      pose = p1;
      e = e1;
      const double motion_px = cand_pyr_[l].k.fx * (drot + dt / median_depth_m_);
      // Coarse levels: the exposure of each level differs by its blur (0.2-0.5 %), so only the
      // pose decides; the final exposure is solved at level 0 anyway.
      if (motion_px < o_.convergence_px && (l > 0 || de < o_.convergence_exposure_rel)) break;
    }
  }
  *pose_io = pose;
  *e_io = SolveExposure(0, pose, e, false);
}

Refiner::ResidualSummary Refiner::SummarizeResiduals(const Active& a, double e) const {
  std::vector<double> absr, ms;
  for (size_t k = 0; k < a.idx.size(); ++k) {
    const double m = samples_[a.idx[k]].m[0];
    absr.push_back(std::abs(e * a.c[k] - m));
    ms.push_back(m);
  }
  ResidualSummary out;
  out.median_m = Median(ms);
  out.relative = out.median_m > 0 ? Median(absr) / out.median_m : 1.0;
  return out;
}

void Refiner::OutlierTest(const Pose& pose, double e, double* relative, double* threshold,
                          double* disagreement, int* num_valid) const {
  const Active af = ActiveSet(0, pose);
  const ResidualSummary sum = SummarizeResiduals(af, e);
  *relative = sum.relative;
  // Threshold relative to what the references themselves disagree about (texture blur,
  // resampling, their own residual pose errors), so it adapts per scene: factor x the median
  // relative spread of the references at the same samples, within [min, max].
  std::vector<double> spreads;
  for (int j : af.idx)
    if (samples_[j].num_refs >= 2) spreads.push_back(samples_[j].spread);
  const double dis = spreads.size() >= 30 && sum.median_m > 0 ? Median(spreads) / sum.median_m : -1.0;
  *threshold = dis < 0 ? o_.outlier_max_relative_residual
                       : std::clamp(o_.outlier_disagreement_factor * dis,
                                    o_.outlier_min_relative_residual, o_.outlier_max_relative_residual);
  if (disagreement != nullptr) *disagreement = dis;
  if (num_valid != nullptr) *num_valid = static_cast<int>(af.idx.size());
}

double ThreadCpuMs() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

void Refiner::BuildPyramids() {
  levels_ = 1;
  while (levels_ < std::min(o_.pyramid_levels, kMaxLevels) &&
         (cand_.color.width() >> levels_) >= 40 && (cand_.color.height() >> levels_) >= 30)
    ++levels_;
  cand_pyr_ = BuildPyramid(cand_.color, cand_.camera, levels_, o_, o_.border_px, true);
  ref_pyr_.reserve(refs_.size());
  for (const StoredView* r : refs_) ref_pyr_.push_back(RefinementCacheAccess::Pyramid(cache_, *r, levels_, o_));
}

void Refiner::PrepareCandidateDepth() {
  if (!(o_.depth_weight > 0) || cand_.depth_m.empty()) return;
  const int w = cand_pyr_[0].w, h = cand_pyr_[0].h;
  cand_depth_.assign(static_cast<size_t>(w) * h, 0.f);
  cand_depth_bad_.assign(cand_depth_.size(), 0);
  // Bad: a hole or a step > depth_discontinuity_m to a 4-neighbour, dilated by 2 px (the
  // bicubic support plus the SPEC §6 edge margin). O(pixels), no per-pixel 8-probe test.
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float z = cand_.depth_m.at(x, y);
      const bool ok = z > 0.f && std::isfinite(z);
      cand_depth_[static_cast<size_t>(y) * w + x] = ok ? z : 0.f;
    }
  const float dz = static_cast<float>(o_.depth_discontinuity_m);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float z = cand_depth_[i];
      bool bad = !(z > 0.f);
      if (!bad && x + 1 < w) bad = !(std::abs(cand_depth_[i + 1] - z) <= dz);
      if (!bad && y + 1 < h) bad = !(std::abs(cand_depth_[i + w] - z) <= dz);
      if (bad) cand_depth_bad_[i] = 1;
    }
  Dilate(cand_depth_bad_, w, h, 2);
  depth_grid_ = std::make_unique<refinement::DepthGrid>(cand_depth_.data(), 0, h, 0, w);
  depth_interp_ = std::make_unique<refinement::DepthInterpolator>(*depth_grid_);
  depth_fast_ = refinement::FastBicubic(cand_depth_.data(), h, w);
}

absl::StatusOr<Refiner::Active> Refiner::SampleSurface(const Pose& pose0) {
  // Saturated or black candidates leave few usable samples: densify the sampling (up to 16x).
  Active a0;
  for (int budget = o_.max_samples;; budget *= 4) {
    samples_.clear();
    BuildSamples(budget);
    a0 = ActiveSet(0, pose0);
    if (static_cast<int>(a0.idx.size()) >= 4 * o_.min_pose_samples ||
        budget >= 16 * o_.max_samples || a0.idx.size() * 2 >= samples_.size())
      break;
  }
  res_.num_samples = static_cast<int>(samples_.size());
  if (a0.idx.size() < 3)
    return absl::FailedPreconditionError(absl::StrCat(
        "refinement: only ", a0.idx.size(),
        " surface samples are valid in the candidate and the reference views (no overlap, or "
        "all saturated/black)"));
  return a0;
}

double Refiner::InitialExposure(const Pose& pose0, const Active& a0) const {
  // Robust ratio of medians to candidate values, or the given value.
  double e0 = o_.initial_exposure;
  if (o_.init_exposure_from_ratio) {
    std::vector<double> lc, lm;
    const Active a0f = ActiveSet(0, pose0, Kind::kFlat);
    LogValues(0, a0f.idx.size() >= 30 ? a0f : a0, &lc, &lm);
    for (size_t k = 0; k < lc.size(); ++k) lm[k] -= lc[k];
    if (!lm.empty()) e0 = std::exp(Median(lm));
  }
  return e0;
}

void Refiner::MultiStart(Pose* pose_io, double* e_io) {
  // Close-range views: the first pass can end with the rotation right and the camera centre in
  // a side basin 2-3 cm away (sideways motion along a wall changes neither its depth nor, with
  // repetitive texture, the photometric energy much), where the view would be rejected as an
  // outlier. Restart the fine levels from that pose shifted by +-1 and +-2 x multistart_step_m
  // along the camera's x and y axes; the first start that passes the outlier test (or else the
  // lowest relative residual) wins. Only runs when the view would otherwise be rejected, so it
  // cannot change a kept view; the cost guard still compares the winner with the input pose.
  const Pose pose = *pose_io;
  const double e = *e_io;
  double rel1 = 0, thr1 = 0;
  OutlierTest(pose, e, &rel1, &thr1);
  if (!(rel1 > thr1)) return;
  Pose best = pose;
  double best_e = e, best_rel = rel1;
  bool passed = false;
  std::vector<Pose> starts;
  const Eigen::Vector3d axes[2] = {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY()};
  for (int mult : {1, -1, 2, -2})
    for (const Eigen::Vector3d& axis : axes) {
      Pose start = pose;
      start.t += mult * o_.multistart_step_m * axis;  // camera-frame shift of the centre
      starts.push_back(start);
    }
  for (Pose start : starts) {
    double e_s = e;
    CoarseToFine(/*multistart=*/true, &start, &e_s, o_.multistart_from_level);
    ++res_.attempts;
    double rel_s = 0, thr_s = 0;
    OutlierTest(start, e_s, &rel_s, &thr_s);
    if (rel_s < best_rel) {
      best = start;
      best_e = e_s;
      best_rel = rel_s;
      passed = rel_s <= thr_s;
    }
    if (passed) break;
  }
  *pose_io = best;
  *e_io = best_e;
}

void Refiner::GuardEnergy(const Pose& pose0, double e0, double e_exposure_only, const Active& a0,
                          double report_scale, Pose* pose, double* e) {
  // The pose stages must lower J relative to the exposure-only result at the input pose, and
  // that must not be worse than the initial exposure.
  if (!(pose->q.coeffs() == pose0.q.coeffs() && pose->t == pose0.t) &&
      CompareEnergy(0, e_exposure_only, pose0, *e, *pose, report_scale).Raised()) {
    res_.step_reverted = true;
    *pose = pose0;
    *e = e_exposure_only;
  }
  if (pose->t == pose0.t && pose->q.coeffs() == pose0.q.coeffs()) {
    std::vector<double> lc, lm;
    const Active a0f = ActiveSet(0, pose0, Kind::kFlat);
    LogValues(0, a0f.idx.size() >= 30 ? a0f : a0, &lc, &lm);
    std::vector<double> r(lc.size());
    for (size_t k = 0; k < lc.size(); ++k) r[k] = std::log(e0) + lc[k] - lm[k];
    const double s = ScaleFromResiduals(r, o_.fixed_scale);
    if (LogExposureEnergy(lc, lm, *e, s) > LogExposureEnergy(lc, lm, e0, s)) {
      res_.step_reverted = true;
      *e = e0;
    }
  }
}

void Refiner::GateInsignificantUpdates(const Pose& pose0, double e_exposure_only, Pose* pose,
                                       double* e) {
  // Trust region (RefinerOptions::max_pose_correction_*).
  if (!(pose->t == pose0.t && pose->q.coeffs() == pose0.q.coeffs())) {
    const Eigen::Vector3d c0 = -(pose0.q.conjugate() * pose0.t);
    const Eigen::Vector3d c1 = -(pose->q.conjugate() * pose->t);
    const double moved_m = (c1 - c0).norm();
    const double turned_deg = pose0.q.angularDistance(pose->q) * 180.0 / M_PI;
    if ((o_.max_pose_correction_m > 0 && moved_m > o_.max_pose_correction_m) ||
        (o_.max_pose_correction_deg > 0 && turned_deg > o_.max_pose_correction_deg)) {
      res_.pose_update_too_large = true;
      *pose = pose0;
      *e = e_exposure_only;
    }
  }
  // A pose update that explains less than the references' own disagreement is not evidence
  // against the input pose.
  if (o_.min_pose_gain_over_disagreement > 0 &&
      !(pose->t == pose0.t && pose->q.coeffs() == pose0.q.coeffs())) {
    double rel0 = 0, thr0 = 0, rel1 = 0, thr1 = 0, dis1 = -1;
    OutlierTest(pose0, e_exposure_only, &rel0, &thr0);
    OutlierTest(*pose, *e, &rel1, &thr1, &dis1);
    if (dis1 >= 0 && rel0 - rel1 < o_.min_pose_gain_over_disagreement * dis1) {
      res_.pose_update_insignificant = true;
      *pose = pose0;
      *e = e_exposure_only;
    }
  }
  if (o_.max_exposure_ratio > 1.0 &&
      std::abs(std::log(*e / o_.prior_exposure)) > std::log(o_.max_exposure_ratio)) {
    res_.exposure_update_too_large = true;
    *e = o_.prior_exposure;
  }
  // An exposure that explains less than the references' own disagreement (relative to the
  // prior) is not evidence of an exposure change (real cameras with stable exposure: otherwise
  // small misfits accumulate along the chain of references).
  if (o_.min_exposure_gain_over_disagreement > 0 && *e != o_.prior_exposure) {
    double rel_e = 0, thr_e = 0, dis_e = -1, rel_p = 0, thr_p = 0;
    OutlierTest(*pose, *e, &rel_e, &thr_e, &dis_e);
    OutlierTest(*pose, o_.prior_exposure, &rel_p, &thr_p);
    if (dis_e >= 0 && rel_p - rel_e < o_.min_exposure_gain_over_disagreement * dis_e) {
      res_.exposure_update_insignificant = true;
      *e = o_.prior_exposure;
    }
  }
}

absl::StatusOr<RefinementResult> Refiner::Run() {
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu0 = ThreadCpuMs();
  BuildPyramids();
  PrepareCandidateDepth();
  const double cpu_pyr = ThreadCpuMs();
  res_.cpu_ms_pyramids = cpu_pyr - cpu0;
  const Pose pose0 = CamFromLocal(cand_.local_from_cam);
  absl::StatusOr<Active> sampled = SampleSurface(pose0);
  const double cpu_samples = ThreadCpuMs();
  res_.cpu_ms_samples = cpu_samples - cpu_pyr;
  if (!sampled.ok()) return sampled.status();
  const Active& a0 = *sampled;

  const double e0 = InitialExposure(pose0, a0);
  // Reporting/guard scale, fixed for the whole call.
  std::vector<double> r0(a0.idx.size());
  for (size_t k = 0; k < a0.idx.size(); ++k) r0[k] = e0 * a0.c[k] - samples_[a0.idx[k]].m[0];
  const double report_scale = ScaleFromResiduals(r0, o_.fixed_scale);

  double e = SolveExposure(0, pose0, e0, o_.warm_start);
  const double e_exposure_only = e;
  Pose pose = pose0;
  if (o_.refine_pose) {
    if (o_.check_rank) RankCheck(pose0, e);
    if (!res_.pose_refused_rank_deficient) {
      CoarseToFine(/*multistart=*/false, &pose, &e);
      if (o_.multistart_step_m > 0) MultiStart(&pose, &e);
    }
  }
  GuardEnergy(pose0, e0, e_exposure_only, a0, report_scale, &pose, &e);
  GateInsignificantUpdates(pose0, e_exposure_only, &pose, &e);
  const EnergyPair final_pair = CompareEnergy(0, e_exposure_only, pose0, e, pose, report_scale);
  res_.cost_before = final_pair.before;
  res_.cost_after = final_pair.after;

  // Pose-outlier decision on the final residuals.
  OutlierTest(pose, e, &res_.relative_residual, &res_.outlier_threshold,
              &res_.reference_disagreement, &res_.num_valid_final);
  // Fraction of the samples valid at the input pose that are still valid at the result.
  const double valid_fraction = double(res_.num_valid_final) / std::max<size_t>(1, a0.idx.size());
  res_.rejected_outlier = res_.relative_residual > res_.outlier_threshold ||
                          valid_fraction < o_.outlier_min_valid_fraction;
  res_.exposure = e;
  // An unchanged pose is returned bit-exact (no inverse round trip).
  const bool pose_unchanged = pose.q.coeffs() == pose0.q.coeffs() && pose.t == pose0.t;
  res_.local_from_cam = pose_unchanged ? cand_.local_from_cam : LocalFromCam(pose);
  res_.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const double cpu1 = ThreadCpuMs();
  res_.cpu_ms = cpu1 - cpu0;
  res_.cpu_ms_solve = cpu1 - cpu_samples;
  return res_;
}

double OverlapFraction(const StoredView& ref, const StoredView& cand, const RefinementOptions& o) {
  const Rigid3d cam_from_local = cand.local_from_cam.Inverse();
  const bool cand_depth = !cand.depth_m.empty();
  int valid = 0, seen = 0;
  constexpr int kGx = 24, kGy = 18;
  for (int gy = 0; gy < kGy; ++gy)
    for (int gx = 0; gx < kGx; ++gx) {
      const int x = (2 * gx + 1) * ref.color.width() / (2 * kGx);
      const int y = (2 * gy + 1) * ref.color.height() / (2 * kGy);
      const float z = ref.depth_m.at(x, y);
      if (!(z > 0.f) || !std::isfinite(z)) continue;
      ++valid;
      const glm::dvec3 pc = cam_from_local * (ref.local_from_cam * ref.camera.Unproject({double(x), double(y)}, z));
      glm::dvec2 uv;
      if (!cand.camera.Project(pc, &uv) || !cand.camera.InImage(uv, o.border_px)) continue;
      if (cand_depth) {
        const float d = cand.depth_m.at(static_cast<int>(std::lround(uv.x)), static_cast<int>(std::lround(uv.y)));
        if (d > 0.f && std::abs(pc.z - d) > o.cand_occlusion_abs_m + o.cand_occlusion_rel * d) continue;
      }
      ++seen;
    }
  return valid > 0 ? double(seen) / valid : 0.0;
}

absl::Status ValidateViewImages(const StoredView& v, const char* what) {
  EXO_RETURN_IF_ERROR(v.camera.Validate());
  if (v.color.channels() != 3 || v.color.width() != v.camera.width ||
      v.color.height() != v.camera.height)
    return absl::InvalidArgumentError(absl::StrCat("refinement: ", what, " colour must be RGB8 of ",
                                                   v.camera.width, "x", v.camera.height));
  if (v.color.width() < 8 || v.color.height() < 8)
    return absl::InvalidArgumentError(absl::StrCat("refinement: ", what, " image too small"));
  const glm::dquat& q = v.local_from_cam.rotation;
  EXO_RETURN_IF_ERROR(ValidateQuaternion(q));
  const glm::dvec3& t = v.local_from_cam.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError(absl::StrCat("refinement: ", what, " translation not finite"));
  return absl::OkStatus();
}

}  // namespace

double SrgbToLinear(uint8_t v) {
  const double c = v / 255.0;
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

absl::Status RefinementOptions::Validate() const {
  if (max_samples < 10) return absl::InvalidArgumentError("refinement: max_samples must be >= 10");
  if (max_reference_views < 1)
    return absl::InvalidArgumentError("refinement: max_reference_views must be >= 1");
  if (saturated_u8 <= black_u8 || saturated_u8 > 256 || black_u8 < -1)
    return absl::InvalidArgumentError("refinement: need -1 <= black_u8 < saturated_u8 <= 256");
  if (!(ref_occlusion_abs_m >= 0) || !(ref_occlusion_rel >= 0) || !(cand_occlusion_abs_m >= 0) ||
      !(cand_occlusion_rel >= 0) || !(depth_discontinuity_m > 0))
    return absl::InvalidArgumentError("refinement: occlusion/discontinuity tolerances must be >= 0");
  if (border_px < 1 || border_px > 8)
    return absl::InvalidArgumentError("refinement: border_px must be in [1, 8]");
  if (pyramid_levels < 1 || pyramid_levels > kMaxLevels)
    return absl::InvalidArgumentError(absl::StrCat("refinement: pyramid_levels in [1, ", kMaxLevels, "]"));
  if (max_outer_iterations < 1 || max_solver_iterations < 1)
    return absl::InvalidArgumentError("refinement: iteration limits must be >= 1");
  if (!(max_exposure_ratio == 0.0 || (max_exposure_ratio > 1.0 && std::isfinite(max_exposure_ratio))))
    return absl::InvalidArgumentError("refinement: max_exposure_ratio must be 0 (off) or > 1");
  if (!(max_pose_correction_m >= 0) || !std::isfinite(max_pose_correction_m) ||
      !(max_pose_correction_deg >= 0) || !std::isfinite(max_pose_correction_deg))
    return absl::InvalidArgumentError("refinement: max_pose_correction_m/deg must be >= 0");
  if (!(initial_exposure > 0) || !std::isfinite(initial_exposure))
    return absl::InvalidArgumentError("refinement: initial_exposure must be > 0");
  if (!(function_tolerance > 0) || !(function_tolerance < 1))
    return absl::InvalidArgumentError("refinement: function_tolerance must be in (0, 1)");
  if (!(min_exposure_gain_over_disagreement >= 0) || !(prior_exposure > 0) ||
      !std::isfinite(prior_exposure))
    return absl::InvalidArgumentError(
        "refinement: min_exposure_gain_over_disagreement must be >= 0, prior_exposure > 0");
  if (!(min_pose_gain_over_disagreement >= 0))
    return absl::InvalidArgumentError("refinement: min_pose_gain_over_disagreement must be >= 0");
  if (!(multistart_step_m >= 0) || multistart_from_level < 0)
    return absl::InvalidArgumentError("refinement: multistart options invalid");
  if (!(convergence_px > 0) || !(convergence_exposure_rel > 0))
    return absl::InvalidArgumentError("refinement: convergence thresholds must be > 0");
  if (!(tukey_k > 0) || !(fixed_scale > 0) || !(min_scale > 0))
    return absl::InvalidArgumentError("refinement: Tukey scales must be > 0");
  if (min_pose_samples < 6) return absl::InvalidArgumentError("refinement: min_pose_samples >= 6");
  if (!(min_pose_information >= 0) || !(max_pose_condition > 1))
    return absl::InvalidArgumentError("refinement: rank thresholds invalid");
  if (!(outlier_min_relative_residual > 0) ||
      !(outlier_max_relative_residual >= outlier_min_relative_residual) ||
      !(outlier_disagreement_factor > 0) || !(min_translation_information >= 0) ||
      !(depth_weight >= 0) || !(min_depth_scale_rel > 0) || rotation_only_from_level < 0)
    return absl::InvalidArgumentError("refinement: outlier/depth/translation options invalid");
  if (!(outlier_max_relative_residual > 0) || !(outlier_min_valid_fraction >= 0) ||
      outlier_min_valid_fraction > 1)
    return absl::InvalidArgumentError("refinement: outlier thresholds invalid");
  return absl::OkStatus();
}

absl::StatusOr<RefinementResult> RefineView(const StoredView& candidate,
                                            std::span<const StoredView* const> refs,
                                            const RefinementOptions& options,
                                            RefinementCache* cache) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(ValidateViewImages(candidate, "candidate"));
  if (!candidate.depth_m.empty() && (candidate.depth_m.width() != candidate.color.width() ||
                                     candidate.depth_m.height() != candidate.color.height()))
    return absl::InvalidArgumentError("refinement: candidate depth must be empty or colour-sized");
  std::vector<const StoredView*> use;
  for (const StoredView* r : refs) {
    if (r == nullptr) return absl::InvalidArgumentError("refinement: null reference view");
    EXO_RETURN_IF_ERROR(ValidateViewImages(*r, "reference"));
    if (r->depth_m.width() != r->color.width() || r->depth_m.height() != r->color.height())
      return absl::InvalidArgumentError("refinement: reference depth must be colour-sized");
    if (!(r->exposure > 0.f) || !std::isfinite(r->exposure))
      return absl::InvalidArgumentError("refinement: reference exposure must be > 0");
    use.push_back(r);
  }
  if (use.empty()) return absl::InvalidArgumentError("refinement: no reference views");
  // Keep the references that share the most surface with the candidate (a coarse grid of each
  // reference's depth projected into the candidate at its input pose).
  std::vector<std::pair<double, const StoredView*>> scored;
  for (const StoredView* r : use) scored.push_back({OverlapFraction(*r, candidate, options), r});
  std::stable_sort(scored.begin(), scored.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  use.clear();
  std::vector<double> overlap;
  for (const auto& [f, r] : scored) {
    if (static_cast<int>(use.size()) >= options.max_reference_views) break;
    if (f < 0.02 && !use.empty()) break;
    use.push_back(r);
    overlap.push_back(std::max(f, 1e-3));
  }
  Refiner refiner(candidate, std::move(use), std::move(overlap), options, cache);
  return refiner.Run();
}

}  // namespace exo
