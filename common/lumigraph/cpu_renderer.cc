#include "common/lumigraph/cpu_renderer.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <thread>

#include "common/image_fill.h"
#include "common/image_fill_impl.h"
#include "common/raster/rasterizer.h"

namespace exo {
namespace {

// sRGB8 -> linear lookup table (the texel decode of an _SRGB texture).
const std::array<float, 256>& SrgbLut() {
  static const std::array<float, 256> lut = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[i] = blend::SrgbToLinear(blend::U8ToUnit(uint8_t(i)));
    return t;
  }();
  return lut;
}

// Bilinear sample of an RGB8 sRGB image at continuous pixel uv (centres at integers), texels
// decoded to linear first, edges clamped.
glm::vec3 SampleLinear(const ImageU8& img, const glm::vec2& uv) {
  const auto& lut = SrgbLut();
  const float fx = std::floor(uv.x), fy = std::floor(uv.y);
  const float ax = uv.x - fx, ay = uv.y - fy;
  const int w = img.width(), h = img.height();
  const int x0 = std::clamp(int(fx), 0, w - 1), x1 = std::clamp(int(fx) + 1, 0, w - 1);
  const int y0 = std::clamp(int(fy), 0, h - 1), y1 = std::clamp(int(fy) + 1, 0, h - 1);
  const uint8_t* p00 = &img.at(x0, y0);
  const uint8_t* p10 = &img.at(x1, y0);
  const uint8_t* p01 = &img.at(x0, y1);
  const uint8_t* p11 = &img.at(x1, y1);
  glm::vec3 out;
  for (int c = 0; c < 3; ++c) {
    const float top = lut[p00[c]] + ax * (lut[p10[c]] - lut[p00[c]]);
    const float bot = lut[p01[c]] + ax * (lut[p11[c]] - lut[p01[c]]);
    out[c] = top + ay * (bot - top);
  }
  return out;
}

double MsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

absl::Status CpuRenderOptions::Validate() const {
  EXO_RETURN_IF_ERROR(blend.Validate());
  if (num_threads < 1 || num_threads > 64)
    return absl::InvalidArgumentError("cpu renderer num_threads must be in [1,64]");
  return absl::OkStatus();
}

ImageU8 BackgroundMask(const ImageF& depth_m, int guard_radius_px) {
  const int w = depth_m.width(), h = depth_m.height(), r = std::max(0, guard_radius_px);
  ImageU8 out(w, h, 1, 0);
  if (w == 0 || h == 0) return out;
  // Horizontal pass: near_valid(x, y) = some valid depth in row y within [x - r, x + r]; then
  // vertical: background(x, y) = no near_valid in column x within [y - r, y + r]. Prefix sums.
  std::vector<int> row(w + 1), near_valid(size_t(w) * h), col(h + 1);
  for (int y = 0; y < h; ++y) {
    row[0] = 0;
    for (int x = 0; x < w; ++x) row[x + 1] = row[x] + (blend::ValidDepth(depth_m.at(x, y)) ? 1 : 0);
    for (int x = 0; x < w; ++x)
      near_valid[size_t(y) * w + x] = row[std::min(w, x + r + 1)] - row[std::max(0, x - r)] > 0;
  }
  for (int x = 0; x < w; ++x) {
    col[0] = 0;
    for (int y = 0; y < h; ++y) col[y + 1] = col[y] + near_valid[size_t(y) * w + x];
    for (int y = 0; y < h; ++y)
      out.at(x, y) = col[std::min(h, y + r + 1)] - col[std::max(0, y - r)] == 0 ? 1 : 0;
  }
  return out;
}

glm::mat3 LocalFromPixel(const PinholeCamera& camera, const Rigid3d& local_from_cam) {
  // K^-1 maps (x, y, 1) to ((x - cx) / fx, (y - cy) / fy, 1); column-major glm.
  glm::dmat3 k_inv(1.0);
  k_inv[0][0] = 1.0 / camera.fx;
  k_inv[1][1] = 1.0 / camera.fy;
  k_inv[2][0] = -camera.cx / camera.fx;
  k_inv[2][1] = -camera.cy / camera.fy;
  return glm::mat3(local_from_cam.RotationMatrix() * k_inv);
}

double HalfDiagonalFov(const glm::vec4& intr, const glm::ivec2& size) {
  double best = 0.0;
  for (double u : {-0.5, double(size.x) - 0.5})
    for (double v : {-0.5, double(size.y) - 0.5}) {
      const double rx = (u - intr.z) / intr.x, ry = (v - intr.w) / intr.y;
      best = std::max(best, std::atan(std::sqrt(rx * rx + ry * ry)));
    }
  return best;
}

std::vector<int> SelectBackgroundViews(const PinholeCamera& camera, const Rigid3d& local_from_cam,
                                       std::span<const blend::BlendView> views,
                                       std::span<const ViewId> ids, int max_views,
                                       const std::function<bool(int)>& has_background) {
  std::vector<int> out;
  if (max_views <= 0 || views.size() != ids.size()) return out;
  const glm::dvec3 axis_o = local_from_cam.RotationMatrix()[2];
  const double fov_o = HalfDiagonalFov(
      glm::vec4(camera.fx, camera.fy, camera.cx, camera.cy), {camera.width, camera.height});
  std::vector<std::pair<double, int>> ranked;
  for (size_t i = 0; i < views.size(); ++i) {
    const glm::mat3& m = views[i].cam_from_local;
    // Optical axis of view i in the local frame: row 2 of cam_from_local (glm: m[col][row]).
    const glm::dvec3 axis_i(m[0][2], m[1][2], m[2][2]);
    const double cos_a =
        std::clamp(glm::dot(axis_o, axis_i) / std::max(1e-12, glm::length(axis_i)), -1.0, 1.0);
    const double angle = std::acos(cos_a);
    if (angle >= fov_o + HalfDiagonalFov(views[i].intrinsics, views[i].size)) continue;
    ranked.emplace_back(angle, int(i));
  }
  std::sort(ranked.begin(), ranked.end(), [&](const auto& a, const auto& b) {
    return a.first != b.first ? a.first < b.first : ids[a.second] < ids[b.second];
  });
  for (const auto& [angle, i] : ranked) {
    if (int(out.size()) >= max_views) break;
    if (has_background(i)) out.push_back(i);
  }
  return out;
}

std::vector<int> SelectInpaintedViews(const Rigid3d& local_from_cam,
                                      std::span<const glm::vec3> centres,
                                      std::span<const ViewId> ids) {
  const glm::vec3 c_o(local_from_cam.translation);
  std::vector<std::pair<float, int>> ranked;
  for (size_t i = 0; i < centres.size(); ++i) ranked.emplace_back(glm::length(centres[i] - c_o), int(i));
  std::sort(ranked.begin(), ranked.end(), [&](const auto& a, const auto& b) {
    return a.first != b.first ? a.first < b.first : ids[a.second] < ids[b.second];
  });
  std::vector<int> out;
  for (const auto& [d, i] : ranked) {
    if (int(out.size()) >= kMaxInpaintedViews) break;
    out.push_back(i);
  }
  return out;
}

blend::BlendView MakeBlendView(const StoredView& view) {
  blend::BlendView b;
  b.cam_from_local = glm::mat3(glm::transpose(view.local_from_cam.RotationMatrix()));
  b.centre_local = glm::vec3(view.local_from_cam.translation);
  b.intrinsics = glm::vec4(view.camera.fx, view.camera.fy, view.camera.cx, view.camera.cy);
  b.size = {view.camera.width, view.camera.height};
  b.exposure = view.exposure;
  return b;
}

absl::StatusOr<std::unique_ptr<CpuLumigraphRenderer>> CpuLumigraphRenderer::Create(
    const LumigraphModel& model, const CpuRenderOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::unique_ptr<CpuLumigraphRenderer> r(new CpuLumigraphRenderer());
  r->options_ = options;
  r->grid_ = model.grid;
  r->mesh_ = model.ProxyMesh();
  EXO_RETURN_IF_ERROR(ValidateMesh(r->mesh_));
  std::unordered_map<ViewId, int> index;
  for (const auto& [id, v] : model.views) {
    EXO_RETURN_IF_ERROR(v.camera.Validate());
    if (v.color.width() != v.camera.width || v.color.height() != v.camera.height ||
        v.color.channels() != 3)
      return absl::InvalidArgumentError(absl::StrCat("view ", id, ": colour is not RGB8 of the camera size"));
    if (v.depth_m.width() != v.camera.width || v.depth_m.height() != v.camera.height ||
        v.depth_m.channels() != 1)
      return absl::InvalidArgumentError(absl::StrCat("view ", id, ": depth is not of the camera size"));
    if (!std::isfinite(v.exposure) || v.exposure < 0.0f)
      return absl::InvalidArgumentError(absl::StrCat("view ", id, ": exposure must be finite, >= 0"));
    EXO_RETURN_IF_ERROR(ValidateQuaternion(v.local_from_cam.rotation));
    if (v.inpainted && (v.labels.width() != v.camera.width ||
                        v.labels.height() != v.camera.height || v.labels.channels() != 1))
      return absl::InvalidArgumentError(absl::StrCat("view ", id, ": labels are not 1 channel of the camera size"));
    index[id] = static_cast<int>(r->views_.size());
    if (v.inpainted) r->inpainted_.push_back(static_cast<int>(r->views_.size()));
    r->views_.push_back({MakeBlendView(v), id, &v.color, &v.depth_m,
                         v.inpainted ? &v.labels : nullptr});
    r->masks_.push_back(std::make_unique<BackgroundMaskEntry>());
  }
  for (const auto& [cell, refs] : model.cell_refs) {
    std::vector<int> idx;
    for (ViewId v : refs)
      if (auto it = index.find(v); it != index.end()) idx.push_back(it->second);  // skip stale
    if (!idx.empty()) r->refs_.emplace(cell, std::move(idx));
  }
  return r;
}

const CpuLumigraphRenderer::BackgroundMaskEntry& CpuLumigraphRenderer::MaskOf(int vi) const {
  std::lock_guard<std::mutex> lock(mask_mutex_);
  BackgroundMaskEntry& e = *masks_[vi];
  if (!e.computed) {
    e.mask = BackgroundMask(*views_[vi].depth, options_.blend.background_guard_radius_px);
    e.any = std::any_of(e.mask.span().begin(), e.mask.span().end(), [](uint8_t b) { return b != 0; });
    e.computed = true;
  }
  return e;
}

absl::StatusOr<CpuRenderOutput> CpuLumigraphRenderer::Render(const PinholeCamera& camera,
                                                             const Rigid3d& local_from_cam) const {
  EXO_RETURN_IF_ERROR(camera.Validate());
  EXO_RETURN_IF_ERROR(ValidateQuaternion(local_from_cam.rotation));
  const int w = camera.width, h = camera.height;
  CpuRenderOutput out;
  out.color = ImageU8(w, h, 3);
  out.coverage = ImageU8(w, h, 1, 0);
  out.inpainted = ImageU8(w, h, 1, 0);
  if (options_.debug_weights) {
    out.weight_sum = ImageF(w, h, 1, 0.0f);
    out.num_views = ImageU8(w, h, 1, 0);
  }
  const blend::BlendOptions& bo = options_.blend;
  const std::array<uint8_t, 3> bg = {blend::UnitToU8(bo.background_srgb.x),
                                     blend::UnitToU8(bo.background_srgb.y),
                                     blend::UnitToU8(bo.background_srgb.z)};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) out.color.at(x, y, c) = bg[c];
  out.background = ImageU8(w, h, 1, 0);
  const bool background_on = bo.background_views > 0;
  if (mesh_.empty() && !background_on) return out;

  auto t0 = std::chrono::steady_clock::now();
  RasterOutput raster;
  RasterOptions ro;
  ro.position = true;
  ro.cell_id = true;
  ro.cell_grid = grid_;
  ro.cull_backfaces = options_.cull_backfaces;
  ro.num_threads = options_.num_threads;
  if (!mesh_.empty()) {
    EXO_ASSIGN_OR_RETURN(raster, Rasterize(mesh_, camera, local_from_cam, ro));
  } else {
    raster.cell_id = Image<uint64_t>(w, h, 1, kNoCell);  // no proxy: every ray is background
  }
  out.raster_ms = MsSince(t0);
  t0 = std::chrono::steady_clock::now();

  // Background at infinity: the per-frame view list (only when some ray misses the proxy, so a
  // fully covered frame, e.g. indoors, pays one scan of the cell-id buffer).
  struct BackgroundView {
    const ViewData* view;
    const ImageU8* mask;
  };
  std::vector<BackgroundView> bg_views;
  const glm::mat3 local_from_pixel = LocalFromPixel(camera, local_from_cam);
  if (background_on) {
    const auto ids_span = raster.cell_id.span();
    if (std::find(ids_span.begin(), ids_span.end(), kNoCell) != ids_span.end()) {
      std::vector<blend::BlendView> params;
      std::vector<ViewId> ids;
      params.reserve(views_.size());
      ids.reserve(views_.size());
      for (const ViewData& v : views_) {
        params.push_back(v.params);
        ids.push_back(v.id);
      }
      const std::vector<int> chosen = SelectBackgroundViews(
          camera, local_from_cam, params, ids, bo.background_views,
          [&](int i) { return views_[i].labels == nullptr && MaskOf(i).any; });
      for (int i : chosen) {
        bg_views.push_back({&views_[i], &MaskOf(i).mask});
        out.background_views.push_back(views_[i].id);
      }
    }
  }
  out.background_ms = MsSince(t0);

  const glm::vec3 c_o(local_from_cam.translation);
  const int n = bo.n_best;
  // The inpainted keyframes of this frame (SelectInpaintedViews), nearest first.
  std::vector<int> inpainted;
  if (!inpainted_.empty()) {
    std::vector<glm::vec3> centres;
    std::vector<ViewId> ids;
    for (int vi : inpainted_) {
      centres.push_back(views_[vi].params.centre_local);
      ids.push_back(views_[vi].id);
    }
    for (int k : SelectInpaintedViews(local_from_cam, centres, ids)) inpainted.push_back(inpainted_[k]);
  }
  std::vector<size_t> covered(options_.num_threads, 0), surface(options_.num_threads, 0),
      background(options_.num_threads, 0);
  const int num_bg = static_cast<int>(bg_views.size());
  auto work = [&](int t) {
    CellId last_cell = kNoCell;
    const std::vector<int>* refs = nullptr;
    for (int y = t; y < h; y += options_.num_threads) {
      for (int x = 0; x < w; ++x) {
        const CellId cell = raster.cell_id.at(x, y);
        if (cell == kNoCell) {
          if (num_bg == 0) continue;
          // Background at infinity (blend_math.h BackgroundWeight), best n, normalised blend.
          const glm::vec3 d = local_from_pixel * glm::vec3(float(x), float(y), 1.0f);
          blend::BestN best = blend::EmptyBestN();
          glm::vec2 uvs[blend::kMaxBackgroundViews];
          for (int j = 0; j < num_bg; ++j) {
            const ImageU8& mask = *bg_views[j].mask;
            const float wgt = blend::BackgroundWeight(
                d, bg_views[j].view->params, [&](glm::ivec2 q) { return mask.at(q.x, q.y) != 0; },
                &uvs[j]);
            blend::InsertBest(best, n, wgt, j);
          }
          blend::BlendAccumulator acc;
          for (int s = 0; s < n && best.index[s] >= 0; ++s) {
            const ViewData& vd = *bg_views[best.index[s]].view;
            blend::Accumulate(acc, SampleLinear(*vd.color, uvs[best.index[s]]),
                              vd.params.exposure, best.weight[s]);
          }
          glm::vec3 srgb;
          if (blend::Resolve(acc, bo.background_srgb, &srgb)) {
            for (int c = 0; c < 3; ++c) out.color.at(x, y, c) = blend::UnitToU8(srgb[c]);
            out.background.at(x, y) = 255;
            ++background[t];
          }
          continue;
        }
        ++surface[t];
        if (cell != last_cell) {
          last_cell = cell;
          auto it = refs_.find(cell);
          refs = it == refs_.end() ? nullptr : &it->second;
        }
        const glm::vec3 p(raster.position_local.at(x, y, 0), raster.position_local.at(x, y, 1),
                          raster.position_local.at(x, y, 2));
        // InpaintFusion (SPEC §7, 4.17-4.18): a surface point inside an inpainted keyframe's ROI
        // (its label at the point's projection is L_IP and the point is not hidden behind the
        // keyframe's surface: blend::InpaintedLabelHolds) is blended from the inpainted keyframes
        // whose ROI holds it only; everywhere else only the cell's observed references count.
        bool in_roi = false;
        blend::BestN best = blend::EmptyBestN();
        // (3.4)-(3.5) for one stored view, kept if among the best n.
        const auto consider = [&](int vi) {
          const ViewData& vd = views_[vi];
          const ImageF& depth = *vd.depth;
          const float v = blend::Validity(p, vd.params, bo, [&](glm::ivec2 q) {
            return depth.at(q.x, q.y);
          });
          if (v == 0.0f) return;
          const float wd = blend::DirectionalWeight(p, c_o, vd.params.centre_local);
          const float wp = blend::PositionalWeight(p, c_o, vd.params.centre_local,
                                                   bo.positional_mode);
          blend::InsertBest(best, n, blend::CombinedWeight(v, wd, wp, bo.lambda, bo.min_weight), vi);
        };
        for (int vi : inpainted) {
          const ViewData& vd = views_[vi];
          const ImageU8& labels = *vd.labels;
          const ImageF& depth = *vd.depth;
          if (!blend::InpaintedLabelHolds(
                  p, vd.params, bo, [&](glm::ivec2 q) { return labels.at(q.x, q.y) != 0; },
                  [&](glm::ivec2 q) { return depth.at(q.x, q.y); }))
            continue;
          in_roi = true;
          consider(vi);
        }
        if (!in_roi && refs == nullptr) continue;  // empty reference set: background, uncovered
        for (int vi : in_roi ? std::span<const int>() : std::span<const int>(*refs)) consider(vi);
        blend::BlendAccumulator acc;
        int used = 0;
        for (int s = 0; s < n; ++s) {
          if (best.index[s] < 0) break;
          const ViewData& vd = views_[best.index[s]];
          const blend::Projection proj = blend::ProjectToView(p, vd.params);
          blend::Accumulate(acc, SampleLinear(*vd.color, proj.uv), vd.params.exposure,
                            best.weight[s]);
          ++used;
        }
        glm::vec3 srgb;
        if (blend::Resolve(acc, bo.background_srgb, &srgb)) {
          for (int c = 0; c < 3; ++c) out.color.at(x, y, c) = blend::UnitToU8(srgb[c]);
          out.coverage.at(x, y) = 255;
          if (in_roi) out.inpainted.at(x, y) = 255;
          ++covered[t];
        }
        if (options_.debug_weights) {
          out.weight_sum.at(x, y) = acc.sum_weight;
          out.num_views.at(x, y) = static_cast<uint8_t>(used);
        }
      }
    }
  };
  std::vector<std::thread> threads;
  for (int t = 1; t < options_.num_threads; ++t) threads.emplace_back(work, t);
  work(0);
  for (auto& th : threads) th.join();
  for (int t = 0; t < options_.num_threads; ++t) {
    out.covered_pixels += covered[t];
    out.surface_pixels += surface[t];
    out.background_pixels += background[t];
  }
  out.blend_ms = MsSince(t0);
  if (bo.fill_holes && out.covered_pixels + out.background_pixels < size_t(w) * h) {
    const auto tf = std::chrono::steady_clock::now();
    ImageU8 known(w, h, 1, 0);
    for (size_t i = 0; i < known.size(); ++i)
      known.data()[i] = out.coverage.data()[i] | out.background.data()[i];
    out.filled_pixels = FillHoles(out.color, known);
    out.fill_ms = MsSince(tf);
  }
  return out;
}

size_t FillHoles(ImageU8& rgb, const ImageU8& known) {
  EXO_CHECK(rgb.channels() == 3 && known.channels() == 1 && known.width() == rgb.width() &&
            known.height() == rgb.height());
  const size_t n = static_cast<size_t>(rgb.width()) * rgb.height();
  const uint8_t* k = known.data();
  size_t unknown = 0;
  for (size_t i = 0; i < n; ++i) unknown += k[i] == 0;
  if (unknown == 0 || unknown == n) return 0;
  // Reads the frame's sRGB8 texels as linear intensity on the fly (no float copy of the frame)
  // and encodes a filled value exactly as UnitToU8(LinearToSrgb(v)) up to ties, without a pow:
  // a guess from a 4096-entry table, corrected against the linear values halfway between
  // consecutive sRGB8 codes.
  const std::array<float, 256>& lin = SrgbLut();
  struct Encoder {
    std::array<float, 255> mid;       // mid[i]: linear value between codes i and i + 1
    std::array<uint8_t, 4097> guess;  // code of linear i / 4096
  };
  static const Encoder enc = [] {
    Encoder e{};
    for (int i = 0; i < 255; ++i) e.mid[i] = blend::SrgbToLinear((i + 0.5f) / 255.0f);
    for (int i = 0; i <= 4096; ++i) e.guess[i] = blend::UnitToU8(blend::LinearToSrgb(i / 4096.0f));
    return e;
  }();
  auto encode = [](float v) {
    v = std::clamp(v, 0.0f, 1.0f);
    int c = enc.guess[static_cast<int>(v * 4096.0f)];
    while (c < 255 && v >= enc.mid[c]) ++c;
    while (c > 0 && v < enc.mid[c - 1]) --c;
    return static_cast<uint8_t>(c);
  };
  uint8_t* px = rgb.data();
  auto is_known = [&](size_t i) { return k[i] != 0; };
  auto value = [&](size_t i, int c) { return lin[px[i * 3 + c]]; };
  auto write = [&](size_t i, int c, float v) { px[i * 3 + c] = encode(v); };
  // Few holes (the usual frame: 0.3 % of the pixels in vulkan_bench's village): the sparse
  // evaluation of the same push-pull, bit for bit, whose cost follows the holes (measured 3.2 ->
  // <0.5 ms at 720p, docs/vulkan.md); many holes: the dense pass over the frame.
  if (unknown <= n / 16) {
    std::vector<size_t> holes;
    holes.reserve(unknown);
    for (size_t i = 0; i < n; ++i)
      if (k[i] == 0) holes.push_back(i);
    image_fill_internal::PushPullSparseBilinear<3>(rgb.width(), rgb.height(), 3, is_known, value,
                                                   write, holes);
  } else {
    image_fill_internal::PushPull<3>(rgb.width(), rgb.height(), 3, PullFilter::kBilinear,
                                     is_known, value, write);
  }
  return unknown;
}

}  // namespace exo
