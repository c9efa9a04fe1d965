#include "server/inpainting/dr_compositor.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>

#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "common/image_fill.h"
#include "common/image_fill_impl.h"
#include "server/inpainting/poisson.h"

namespace exo::inpainting {

absl::Status DrOptions::Validate() const {
  EXO_RETURN_IF_ERROR(inpaint.Validate());
  EXO_RETURN_IF_ERROR(policy.Validate());
  if (obs_stride < 1) return absl::InvalidArgumentError("obs_stride must be >= 1");
  if (obs_views < 0) return absl::InvalidArgumentError("obs_views must be >= 0");
  if (!(ring_sigma >= 0.0 && ring_sigma <= 100.0))
    return absl::InvalidArgumentError("ring_sigma must be in [0, 100]");
  if (!(temporal >= 0.0 && temporal < 1.0))
    return absl::InvalidArgumentError("temporal must be in [0, 1)");
  if (kf_crop_margin_px < 0 || !(kf_crop_margin_rel >= 0.0 && kf_crop_margin_rel <= 100.0))
    return absl::InvalidArgumentError("kf_crop_margin_px must be >= 0, kf_crop_margin_rel in [0, 100]");
  return absl::OkStatus();
}

namespace {

double WallMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

cv::Mat Wrap(ImageU8& im) {
  return cv::Mat(im.height(), im.width(), im.channels() == 3 ? CV_8UC3 : CV_8UC1, im.data());
}

int Count(const ImageU8& m) {
  int n = 0;
  for (size_t i = 0; i < m.size(); ++i) n += m.data()[i] != 0;
  return n;
}

// The keyframe's crop (DrOptions::kf_crop_margin_*): the ROI's bounding box grown by the margin,
// clamped to the frame; the whole frame when both margins are 0 or the ROI is empty.
cv::Rect KeyframeCrop(const ImageU8& roi, const DrOptions& o) {
  const int w = roi.width(), h = roi.height();
  const cv::Rect whole(0, 0, w, h);
  if (o.kf_crop_margin_px <= 0 && o.kf_crop_margin_rel <= 0.0) return whole;
  int x0 = w, y0 = h, x1 = -1, y1 = -1;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (roi.data()[static_cast<size_t>(y) * w + x]) {
        x0 = std::min(x0, x);
        x1 = std::max(x1, x);
        y0 = std::min(y0, y);
        y1 = std::max(y1, y);
      }
  if (x1 < 0) return whole;
  const int side = std::max(x1 - x0 + 1, y1 - y0 + 1);
  const int m = std::max(o.kf_crop_margin_px,
                         static_cast<int>(std::ceil(o.kf_crop_margin_rel * side)));
  const int ax = std::max(0, x0 - m), ay = std::max(0, y0 - m);
  const int bx = std::min(w, x1 + 1 + m), by = std::min(h, y1 + 1 + m);
  return cv::Rect(ax, ay, bx - ax, by - ay);
}

template <typename T>
Image<T> CropImage(const Image<T>& im, const cv::Rect& r) {
  const int c = im.channels();
  Image<T> out(r.width, r.height, c);
  for (int y = 0; y < r.height; ++y)
    std::memcpy(out.data() + static_cast<size_t>(y) * r.width * c,
                im.data() + (static_cast<size_t>(y + r.y) * im.width() + r.x) * c,
                sizeof(T) * r.width * c);
  return out;
}

template <typename T>
void PasteImage(const Image<T>& part, const cv::Rect& r, Image<T>* im) {
  const int c = im->channels();
  for (int y = 0; y < r.height; ++y)
    std::memcpy(im->data() + (static_cast<size_t>(y + r.y) * im->width() + r.x) * c,
                part.data() + static_cast<size_t>(y) * r.width * c, sizeof(T) * r.width * c);
}

absl::Status CheckFrame(const RgbdKeyframe& f, const ImageU8& roi) {
  const int w = f.camera.width, h = f.camera.height;
  if (w <= 0 || h <= 0 || f.color.width() != w || f.color.height() != h ||
      f.color.channels() != 3 || f.depth_m.width() != w || f.depth_m.height() != h ||
      f.depth_m.channels() != 1 || roi.width() != w || roi.height() != h || roi.channels() != 1)
    return absl::InvalidArgumentError(
        "diminished reality: colour (RGB8), depth and ROI must have the camera's size");
  return absl::OkStatus();
}

}  // namespace

std::shared_ptr<DrView> MakeKeyframeView(const RgbdKeyframe& frame, const ImageU8& roi,
                                         const ImageU8& hallucinated) {
  auto v = std::make_shared<DrView>();
  v->color = frame.color;
  v->depth = frame.depth_m;
  v->cam = frame.camera;
  v->world_from_cam = frame.world_from_cam;
  v->cam_from_world = frame.world_from_cam.Inverse();
  v->roi = roi;
  v->hallucinated = hallucinated.empty() ? roi : hallucinated;
  return v;
}

KeyframeDecision DiminishedReality::Decide(const ImageU8& roi, const PinholeCamera& camera,
                                           const Rigid3d& pose) const {
  std::vector<KeyframeView> kviews;
  kviews.reserve(keyframes_.size());
  for (const auto& k : keyframes_) kviews.push_back({&k->roi, &k->depth, k->cam, k->world_from_cam});
  return DecideKeyframe(roi, camera, pose, kviews, options_.policy);
}

std::vector<std::shared_ptr<const DrView>> DiminishedReality::ViewsNearest(
    const Rigid3d& pose, int nearest) const {
  // Every keyframe and observation view, nearest pose first, or (without prefer_observed) only
  // the rule's nearest keyframe.
  std::vector<std::shared_ptr<const DrView>> views;
  if (options_.prefer_observed) {
    views.assign(keyframes_.begin(), keyframes_.end());
    views.insert(views.end(), obs_.begin(), obs_.end());
    std::stable_sort(views.begin(), views.end(), [&](const auto& a, const auto& b) {
      return PoseDistance(a->world_from_cam, pose) < PoseDistance(b->world_from_cam, pose);
    });
  } else if (nearest >= 0 && nearest < static_cast<int>(keyframes_.size())) {
    views.push_back(keyframes_[nearest]);
  }
  return views;
}

DrKeyframeJob DiminishedReality::MakeJob(RgbdKeyframe frame, ImageU8 roi,
                                         const KeyframeDecision& d) const {
  DrKeyframeJob job;
  const Rigid3d pose = frame.world_from_cam;
  // Propagation source: the nearest keyframe (pose distance) that the library inpainted.
  double best = 1e300;
  for (const auto& k : keyframes_)
    if (k->result && PoseDistance(k->world_from_cam, pose) < best) {
      best = PoseDistance(k->world_from_cam, pose);
      job.previous = k->result;
    }
  if (d.nearest >= 0 && d.nearest < static_cast<int>(keyframes_.size()))
    job.nearest = keyframes_[d.nearest];
  job.views = ViewsNearest(pose, d.nearest);
  job.frame = std::move(frame);
  job.roi = std::move(roi);
  return job;
}

absl::StatusOr<DrKeyframe> DiminishedReality::ComputeKeyframe(const DrKeyframeJob& job,
                                                              const DrOptions& options) {
  const RgbdKeyframe& f = job.frame;
  const ImageU8& roi = job.roi;
  EXO_RETURN_IF_ERROR(CheckFrame(f, roi));
  const int width = f.camera.width, height = f.camera.height;
  const PinholeCamera& cam = f.camera;
  const Rigid3d& pose = f.world_from_cam;
  ImageU8 region(width, height, 1, 0);
  {
    ImageU8 r = roi;
    cv::Mat g = Wrap(region);
    cv::dilate(Wrap(r), g, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  }
  std::vector<const DrView*> views;
  for (const auto& v : job.views) views.push_back(v.get());
  DrKeyframe out;
  out.guide = f.color;
  out.observed = ImageU8(width, height, 1, 0);
  out.filled = ImageU8(width, height, 1, 0);
  out.depth = f.depth_m;
  auto v = std::make_shared<DrView>();
  v->cam = cam;
  v->world_from_cam = pose;
  v->cam_from_world = pose.Inverse();
  v->roi = roi;
  RgbdKeyframe kf = f;
  ImageU8 t_mask = roi;
  if (options.kf_context && job.nearest) {
    // Observed colour (and the warped depth) first; the library fills only the rest, with the
    // observed pixels as its context.
    out.depth = WarpBackgroundDepth(*job.nearest, cam, pose, roi, f.depth_m);
    LookUpInViews(views, cam, pose, region, out.depth, &out.guide, &out.observed, &out.filled,
                  options.bicubic);
    for (size_t i = 0; i < roi.size(); ++i)
      if (roi.data()[i] && out.observed.data()[i]) {
        for (int c = 0; c < 3; ++c) kf.color.data()[3 * i + c] = out.guide.data()[3 * i + c];
        kf.depth_m.data()[i] = out.depth.data()[i];
        t_mask.data()[i] = 0;
      }
  }
  out.hallucinated_px = Count(t_mask);
  if (out.hallucinated_px > 0) {
    const double i0 = WallMs();
    const cv::Rect crop = KeyframeCrop(roi, options);
    if (crop.width == width && crop.height == height) {
      EXO_ASSIGN_OR_RETURN(InpaintResult r,
                           InpaintKeyframe(kf, t_mask, options.inpaint, job.previous.get()));
      v->result = std::make_shared<InpaintResult>(std::move(r));
      v->color = v->result->color;
      v->depth = v->result->depth_m;
    } else {
      // The crop is a frame of its own (principal point shifted); its result carries the crop's
      // camera, so a later keyframe propagates from it through 3D as from a whole frame.
      RgbdKeyframe kc;
      kc.color = CropImage(kf.color, crop);
      kc.depth_m = CropImage(kf.depth_m, crop);
      kc.camera = cam;
      kc.camera.cx -= crop.x;
      kc.camera.cy -= crop.y;
      kc.camera.width = crop.width;
      kc.camera.height = crop.height;
      kc.world_from_cam = pose;
      EXO_ASSIGN_OR_RETURN(InpaintResult r, InpaintKeyframe(kc, CropImage(t_mask, crop),
                                                            options.inpaint, job.previous.get()));
      v->color = kf.color;
      v->depth = kf.depth_m;
      PasteImage(r.color, crop, &v->color);
      PasteImage(r.depth_m, crop, &v->depth);
      v->result = std::make_shared<InpaintResult>(std::move(r));
    }
    out.ms = WallMs() - i0;
    out.inpainted = true;
    out.propagated = job.previous != nullptr;
    out.stats = v->result->stats;
  } else {
    v->color = kf.color;
    v->depth = kf.depth_m;
  }
  v->hallucinated = t_mask;
  out.depth = v->depth;
  if (!options.kf_context && !views.empty()) {
    // Inpainted whole; where a view observed the surface its colour replaces PatchMatch's.
    LookUpInViews(views, cam, pose, region, out.depth, &out.guide, &out.observed, &out.filled,
                  options.bicubic);
    for (size_t i = 0; i < roi.size(); ++i)
      if (roi.data()[i] && out.observed.data()[i]) {
        for (int c = 0; c < 3; ++c) v->color.data()[3 * i + c] = out.guide.data()[3 * i + c];
        v->hallucinated.data()[i] = 0;
      }
  }
  for (size_t i = 0; i < roi.size(); ++i) {
    if (!roi.data()[i]) continue;
    for (int c = 0; c < 3; ++c) out.guide.data()[3 * i + c] = v->color.data()[3 * i + c];
    out.filled.data()[i] = 255;
    out.observed_px += out.observed.data()[i] != 0;
  }
  out.view = std::move(v);
  return out;
}

void DiminishedReality::AddKeyframe(std::shared_ptr<const DrView> view, const DrKeyframe* computed) {
  if (computed && computed->inpainted) {
    ++stats_.keyframes_inpainted;
    if (computed->propagated) {
      ++stats_.keyframes_propagated;
      stats_.propagated_keyframe_ms += computed->ms;
    } else {
      stats_.first_keyframe_ms = computed->ms;
    }
  }
  keyframes_.push_back(std::move(view));
  if (options_.max_keyframes > 0 && keyframes_.size() > options_.max_keyframes)
    keyframes_.erase(keyframes_.begin());
}

void DiminishedReality::AddObservation(const RgbdKeyframe& frame, const ImageU8& roi,
                                       int64_t index) {
  if (options_.obs_views <= 0 || index % options_.obs_stride != 0) return;
  auto o = std::make_shared<DrView>();
  o->color = frame.color;
  o->depth = frame.depth_m;
  for (size_t i = 0; i < roi.size() && i < o->depth.size(); ++i)
    if (roi.data()[i]) o->depth.data()[i] = 0.f;
  o->cam = frame.camera;
  o->world_from_cam = frame.world_from_cam;
  o->cam_from_world = frame.world_from_cam.Inverse();
  obs_.push_back(std::move(o));
  if (static_cast<int>(obs_.size()) > options_.obs_views) obs_.pop_front();
}

std::vector<std::shared_ptr<const DrView>> DiminishedReality::ViewsAround(const DrView& kf) const {
  std::vector<std::shared_ptr<const DrView>> views;
  for (const auto& k : keyframes_)
    if (k.get() != &kf) views.push_back(k);
  for (const auto& o : obs_) views.push_back(o);
  std::stable_sort(views.begin(), views.end(), [&](const auto& a, const auto& b) {
    return PoseDistance(a->world_from_cam, kf.world_from_cam) <
           PoseDistance(b->world_from_cam, kf.world_from_cam);
  });
  return views;
}

DiminishedReality::Refresh DiminishedReality::RefreshKeyframe(
    const DrView& kf, const std::vector<std::shared_ptr<const DrView>>& views) {
  Refresh out;
  if (kf.hallucinated.empty()) return out;
  out.hallucinated_before = Count(kf.hallucinated);
  if (out.hallucinated_before == 0 || views.empty()) return out;
  std::vector<const DrView*> raw;
  for (const auto& v : views)
    if (v.get() != &kf) raw.push_back(v.get());
  const int w = kf.cam.width, h = kf.cam.height;
  ImageU8 color = kf.color, observed(w, h, 1, 0), filled(w, h, 1, 0);
  LookUpInViews(raw, kf.cam, kf.world_from_cam, kf.hallucinated, kf.depth, &color, &observed,
                &filled);
  for (size_t i = 0; i < observed.size(); ++i) out.replaced += kf.hallucinated.data()[i] && observed.data()[i];
  if (out.replaced == 0) return out;
  auto v = std::make_shared<DrView>(kf);
  for (size_t i = 0; i < observed.size(); ++i)
    if (kf.hallucinated.data()[i] && observed.data()[i]) {
      for (int c = 0; c < 3; ++c) v->color.data()[3 * i + c] = color.data()[3 * i + c];
      v->hallucinated.data()[i] = 0;
    }
  out.view = std::move(v);
  return out;
}

bool DiminishedReality::ReplaceKeyframe(const DrView* old, std::shared_ptr<const DrView> now) {
  for (auto& k : keyframes_)
    if (k.get() == old) {
      k = std::move(now);
      return true;
    }
  return false;
}

void DiminishedReality::Clear() {
  keyframes_.clear();
  obs_.clear();
  prev_color_ = ImageU8();
  prev_pose_ = Rigid3d();
}

absl::StatusOr<DrFrameResult> DiminishedReality::ProcessFrame(const RgbdKeyframe& f,
                                                              const ImageU8& roi, int64_t index) {
  EXO_RETURN_IF_ERROR(CheckFrame(f, roi));
  const int width = f.camera.width, height = f.camera.height;
  const PinholeCamera& cam = f.camera;
  const Rigid3d& pose = f.world_from_cam;
  DrFrameResult out{f.color, f.depth_m, false, Count(roi), 0};
  if (out.roi_px == 0) return out;  // nothing to remove in this frame
  const KeyframeDecision d = Decide(roi, cam, pose);
  // The ROI and a one-pixel ring (the guide of the gradient-domain blend).
  ImageU8 region(width, height, 1, 0);
  {
    ImageU8 r = roi;
    cv::Mat g = Wrap(region);
    cv::dilate(Wrap(r), g, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  }
  ImageU8 guide, observed, filled;
  ImageF depth, warped;
  if (d.insert) {
    EXO_ASSIGN_OR_RETURN(DrKeyframe kf, ComputeKeyframe(MakeJob(f, roi, d), options_));
    guide = std::move(kf.guide);
    observed = std::move(kf.observed);
    filled = std::move(kf.filled);
    depth = std::move(kf.depth);
    AddKeyframe(kf.view, &kf);
    out.keyframe = true;
  } else {
    guide = f.color;
    observed = ImageU8(width, height, 1, 0);
    filled = ImageU8(width, height, 1, 0);
    std::vector<const DrView*> views;
    for (const auto& v : ViewsNearest(pose, d.nearest)) views.push_back(v.get());
    // Warped over the ROI and its ring (the ring's warped values give the depth blend its
    // gradients across the border); the look-up uses the frame's own depth on the ring.
    warped = WarpBackgroundDepth(*keyframes_[d.nearest], cam, pose, region, f.depth_m);
    depth = warped;
    for (size_t i = 0; i < roi.size(); ++i)
      if (!roi.data()[i]) depth.data()[i] = f.depth_m.data()[i];
    LookUpInViews(views, cam, pose, region, depth, &guide, &observed, &filled, options_.bicubic);
  }
  // Pixels no view reached (outside every view): Telea from what is there.
  ImageU8 holes(width, height, 1, 0);
  int n_holes = 0;
  for (size_t i = 0; i < holes.size(); ++i)
    if (roi.data()[i] && !filled.data()[i]) {
      holes.data()[i] = 255;
      ++n_holes;
    }
  if (n_holes > 0) {
    cv::Mat rgb = Wrap(guide), dst;
    cv::inpaint(rgb, Wrap(holes), dst, 3.0, cv::INPAINT_TELEA);
    std::memcpy(guide.data(), dst.data, guide.size());
  }
  // Ring pixels that no other view observed take the frame's own colour (the frame observes
  // them; a hallucinated sample there is 20-45 grey levels off in the village and the blend
  // would spread that mismatch into the ROI, differently every frame).
  for (size_t i = 0; i < region.size(); ++i)
    if (region.data()[i] && !roi.data()[i] &&
        (options_.ring == DrRing::kFrame ||
         (options_.ring == DrRing::kObserved && !observed.data()[i]) || !filled.data()[i]))
      for (int c = 0; c < 3; ++c) guide.data()[3 * i + c] = f.color.data()[3 * i + c];
  for (size_t i = 0; i < roi.size(); ++i)
    if (roi.data()[i]) {
      for (int c = 0; c < 3; ++c) out.color.data()[3 * i + c] = guide.data()[3 * i + c];
      out.depth.data()[i] = depth.data()[i];
    }
  if (options_.blend == DrBlend::kPoisson && options_.ring_sigma > 0) {
    // Only the low frequencies of the mismatch on the ring are blended in: the ring's guide
    // becomes frame - smooth(frame - guide) (normalised Gaussian over the ring).
    cv::Mat ring(height, width, CV_32FC1, cv::Scalar(0)),
        diff(height, width, CV_32FC3, cv::Scalar(0, 0, 0));
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x)
        if (region.at(x, y) && !roi.at(x, y)) {
          ring.at<float>(y, x) = 1.f;
          for (int c = 0; c < 3; ++c)
            diff.at<cv::Vec3f>(y, x)[c] = float(f.color.at(x, y, c)) - float(guide.at(x, y, c));
        }
    cv::Mat sd, sr;
    cv::GaussianBlur(diff, sd, cv::Size(0, 0), options_.ring_sigma);
    cv::GaussianBlur(ring, sr, cv::Size(0, 0), options_.ring_sigma);
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x)
        if (region.at(x, y) && !roi.at(x, y))
          for (int c = 0; c < 3; ++c)
            guide.at(x, y, c) = static_cast<uint8_t>(std::clamp(
                std::lround(f.color.at(x, y, c) -
                            sd.at<cv::Vec3f>(y, x)[c] / std::max(1e-6f, sr.at<float>(y, x))),
                0L, 255L));
  }
  ImageU8 blend_region = roi;
  if (options_.blend == DrBlend::kPoissonHallucinated)
    for (size_t i = 0; i < roi.size(); ++i)
      if (observed.data()[i]) blend_region.data()[i] = 0;
  if (options_.blend != DrBlend::kPaste)
    EXO_RETURN_IF_ERROR(PoissonBlendColor(guide, blend_region, &out.color));
  if (options_.depth_poisson && !d.insert) {
    // The warped depth's gradients, anchored on the frame's own depth around the ROI (the
    // library's gradient-domain depth, eqs. 4.13-4.16): removes the offset a chain of warps
    // leaves.
    const float nan = std::numeric_limits<float>::quiet_NaN();
    ImageF values(width, height, 1, nan), gx(width, height, 1, nan), gy(width, height, 1, nan);
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        if (!roi.at(x, y) && f.depth_m.at(x, y) > 0.f) values.at(x, y) = f.depth_m.at(x, y);
        if (x + 1 < width && (roi.at(x, y) || roi.at(x + 1, y)))
          gx.at(x, y) = warped.at(x, y) - warped.at(x + 1, y);
        if (y + 1 < height && (roi.at(x, y) || roi.at(x, y + 1)))
          gy.at(x, y) = warped.at(x, y) - warped.at(x, y + 1);
      }
    PoissonProblem pb;
    pb.region = &roi;
    pb.values = &values;
    pb.gx = &gx;
    pb.gy = &gy;
    pb.gauge = &warped;
    PoissonOptions po;
    po.tolerance = 1e-6;
    auto r = SolvePoisson(pb, po);
    if (!r.ok())
      return absl::Status(r.status().code(),
                          "diminished reality: depth Poisson: " + std::string(r.status().message()));
    for (size_t i = 0; i < roi.size(); ++i)
      if (roi.data()[i]) out.depth.data()[i] = r->data()[i];
  }
  if (options_.temporal > 0 && !prev_color_.empty()) {
    // Exponential smoothing along the camera motion: the previous output, looked up through this
    // frame's background depth and the previous pose.
    const double temporal = options_.temporal;
    const Rigid3d prev_from_cur = prev_pose_.Inverse() * pose;
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        if (!roi.at(x, y) || !(out.depth.at(x, y) > 0.f)) continue;
        if (options_.temporal_hallucinated_only && observed.at(x, y)) continue;
        glm::dvec2 uv;
        if (!cam.Project(prev_from_cur * cam.Unproject({x, y}, out.depth.at(x, y)), &uv) ||
            !cam.InImage(uv, 1.0))
          continue;
        const int x0 = static_cast<int>(uv.x), y0 = static_cast<int>(uv.y);
        const double ax = uv.x - x0, ay = uv.y - y0;
        for (int c = 0; c < 3; ++c) {
          auto P = [&](int u, int v) { return double(prev_color_.at(u, v, c)); };
          const double prev = (1 - ay) * ((1 - ax) * P(x0, y0) + ax * P(x0 + 1, y0)) +
                              ay * ((1 - ax) * P(x0, y0 + 1) + ax * P(x0 + 1, y0 + 1));
          out.color.at(x, y, c) = static_cast<uint8_t>(
              std::clamp(std::lround(temporal * prev + (1 - temporal) * out.color.at(x, y, c)),
                         0L, 255L));
        }
      }
  }
  prev_color_ = out.color;
  prev_pose_ = pose;
  // This frame as an observation view for later frames (its ROI unusable).
  AddObservation(f, roi, index);
  for (size_t i = 0; i < roi.size(); ++i) out.observed_px += roi.data()[i] && observed.data()[i];
  return out;
}

}  // namespace exo::inpainting

namespace exo::inpainting {

absl::Status DrLiveOptions::Validate() const {
  if (max_views < 1 || max_views > 64)
    return absl::InvalidArgumentError("live max_views must be in [1, 64]");
  if (!(temporal >= 0.0 && temporal < 1.0))
    return absl::InvalidArgumentError("live temporal must be in [0, 1)");
  return absl::OkStatus();
}

DrLiveSnapshot DiminishedReality::LiveSnapshot(const Rigid3d& pose, int max_views) const {
  DrLiveSnapshot s;
  double best = 1e300;
  for (const auto& k : keyframes_)
    if (const double d = PoseDistance(k->world_from_cam, pose); d < best) {
      best = d;
      s.nearest = k;
    }
  if (!s.nearest) return s;
  std::vector<std::pair<double, std::shared_ptr<const DrView>>> all;
  for (const auto& k : keyframes_) all.emplace_back(PoseDistance(k->world_from_cam, pose), k);
  for (const auto& o : obs_) all.emplace_back(PoseDistance(o->world_from_cam, pose), o);
  std::stable_sort(all.begin(), all.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  bool has_nearest = false;
  for (size_t i = 0; i < all.size() && static_cast<int>(i) < std::max(1, max_views); ++i) {
    has_nearest |= all[i].second == s.nearest;
    s.views.push_back(all[i].second);
  }
  // The nearest keyframe always: its inpainted samples are the fallback of the look-up.
  if (!has_nearest) s.views.push_back(s.nearest);
  return s;
}

absl::StatusOr<DrLiveResult> ComposeLiveFrame(const RgbdKeyframe& f, const ImageU8& roi,
                                              const DrLiveSnapshot& snap,
                                              const DrLiveOptions& o, DrLiveState* state) {
  EXO_RETURN_IF_ERROR(CheckFrame(f, roi));
  EXO_RETURN_IF_ERROR(o.Validate());
  DrLiveResult out;
  out.color = f.color;
  out.depth = f.depth_m;
  out.roi_px = Count(roi);
  if (out.roi_px == 0 || !snap.nearest) {
    // Nothing removed in this frame: the next one is not smoothed against it.
    if (state) state->Reset();
    return out;
  }
  const int width = f.camera.width, height = f.camera.height;
  const PinholeCamera& cam = f.camera;
  const Rigid3d& pose = f.world_from_cam;
  // The ROI and its one-pixel ring; every per-pixel pass below stays in their bounding box.
  ImageU8 region(width, height, 1, 0);
  {
    ImageU8 r = roi;
    cv::Mat g = Wrap(region);
    cv::dilate(Wrap(r), g, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  }
  int bx0 = width, by0 = height, bx1 = -1, by1 = -1;
  for (int y = 0; y < height; ++y) {
    const uint8_t* r = region.row(y);
    for (int x = 0; x < width; ++x)
      if (r[x]) {
        bx0 = std::min(bx0, x);
        bx1 = std::max(bx1, x);
        by0 = std::min(by0, y);
        by1 = std::max(by1, y);
      }
  }
  const int bw = bx1 - bx0 + 1, bh = by1 - by0 + 1;
  ImageF depth = WarpBackgroundDepth(*snap.nearest, cam, pose, region, f.depth_m);
  // The ring: the frame's own depth (only the region's pixels of `depth` are read below).
  for (int y = by0; y <= by1; ++y)
    for (int x = bx0; x <= bx1; ++x)
      if (!roi.at(x, y)) depth.at(x, y) = f.depth_m.at(x, y);
  ImageU8 guide = f.color, observed(width, height, 1, 0), filled(width, height, 1, 0);
  std::vector<const DrView*> views;
  for (const auto& v : snap.views) views.push_back(v.get());
  LookUpInViews(views, cam, pose, region, depth, &guide, &observed, &filled);
  // Colour in the box: looked up inside the ROI (unreached pixels push-pull filled from their
  // neighbours), the frame outside. The ring's mismatch (frame - looked up) is spread over the
  // ROI by push-pull: a smooth correction that meets the frame at the border.
  const size_t bn = static_cast<size_t>(bw) * bh;
  std::vector<float> col(bn * 3), diff(bn * 3, 0.f);
  std::vector<uint8_t> known(bn, 0), ring(bn, 0);
  for (int y = 0; y < bh; ++y)
    for (int x = 0; x < bw; ++x) {
      const int gx = bx0 + x, gy = by0 + y;
      const size_t j = static_cast<size_t>(y) * bw + x;
      if (!roi.at(gx, gy)) {
        known[j] = 1;
        for (int c = 0; c < 3; ++c) col[3 * j + c] = f.color.at(gx, gy, c);
        if (region.at(gx, gy)) {
          ring[j] = 1;
          if (filled.at(gx, gy))
            for (int c = 0; c < 3; ++c)
              diff[3 * j + c] = float(f.color.at(gx, gy, c)) - float(guide.at(gx, gy, c));
        }
      } else if (filled.at(gx, gy)) {
        known[j] = 1;
        for (int c = 0; c < 3; ++c) col[3 * j + c] = guide.at(gx, gy, c);
        out.observed_px += observed.at(gx, gy) != 0;
      } else {
        ++out.unreached_px;
      }
    }
  if (out.unreached_px > 0 && static_cast<size_t>(out.unreached_px) > bn / 16) {
    PushPullFill(col, 3, known, bw, bh, PullFilter::kBilinear);
  } else if (out.unreached_px > 0) {
    // Few pixels (4-5 per frame in dr_bench): the sparse evaluation of the same bilinear
    // push-pull over the box, bit for bit (image_fill_impl.h), instead of its whole pyramid.
    std::vector<size_t> unknown;
    unknown.reserve(out.unreached_px);
    for (size_t j = 0; j < bn; ++j)
      if (!known[j]) unknown.push_back(j);
    float* cd = col.data();
    const uint8_t* kn = known.data();
    image_fill_internal::PushPullSparseBilinear<3>(
        bw, bh, 3, [kn](size_t j) { return kn[j] != 0; },
        [cd](size_t j, int c) { return cd[3 * j + c]; },
        [cd](size_t j, int c, float v) { cd[3 * j + c] = v; }, unknown);
  }
  if (o.blend) PushPullFill(diff, 3, ring, bw, bh, PullFilter::kBilinear);
  for (int y = 0; y < bh; ++y)
    for (int x = 0; x < bw; ++x) {
      const int gx = bx0 + x, gy = by0 + y;
      if (!roi.at(gx, gy)) continue;
      const size_t j = static_cast<size_t>(y) * bw + x;
      for (int c = 0; c < 3; ++c)
        out.color.at(gx, gy, c) = static_cast<uint8_t>(
            std::clamp(RoundHalfAway(col[3 * j + c] + (o.blend ? diff[3 * j + c] : 0.f)), 0L, 255L));
      out.depth.at(gx, gy) = depth.at(gx, gy);
    }
  if (state && o.temporal > 0 && state->prev_color.SameShape(out.color)) {
    // Exponential smoothing along the camera motion (as ProcessFrame).
    const Rigid3d prev_from_cur = state->prev_pose.Inverse() * pose;
    const ImageU8& prev = state->prev_color;
    for (int y = by0; y <= by1; ++y)
      for (int x = bx0; x <= bx1; ++x) {
        if (!roi.at(x, y) || !(out.depth.at(x, y) > 0.f)) continue;
        glm::dvec2 uv;
        if (!cam.Project(prev_from_cur * cam.Unproject({x, y}, out.depth.at(x, y)), &uv) ||
            !cam.InImage(uv, 1.0))
          continue;
        const int x0 = static_cast<int>(uv.x), y0 = static_cast<int>(uv.y);
        const double ax = uv.x - x0, ay = uv.y - y0;
        for (int c = 0; c < 3; ++c) {
          const double p = (1 - ay) * ((1 - ax) * prev.at(x0, y0, c) + ax * prev.at(x0 + 1, y0, c)) +
                           ay * ((1 - ax) * prev.at(x0, y0 + 1, c) + ax * prev.at(x0 + 1, y0 + 1, c));
          out.color.at(x, y, c) = static_cast<uint8_t>(std::clamp(
              RoundHalfAway(o.temporal * p + (1 - o.temporal) * out.color.at(x, y, c)), 0L, 255L));
        }
      }
  }
  if (state) {
    state->prev_color = out.color;
    state->prev_pose = pose;
  }
  out.composited = true;
  return out;
}

}  // namespace exo::inpainting
