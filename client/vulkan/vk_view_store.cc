#include "client/vulkan/vk_view_store.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <functional>

#include "common/lumigraph/cpu_renderer.h"

namespace exo::vk {
namespace {

// Colour layers: the stored sRGB8 texels decoded to LINEAR once at upload and kept as UNORM16
// (quantisation 1.5e-5 in linear, far below the golden tolerance), so the texture unit filters
// linear values directly: the decode-before-filter convention of blend_math.h without the
// per-texel sRGB decode of an _SRGB format in every fetch (measured: docs/vulkan.md).
constexpr VkFormat kColorFormat = VK_FORMAT_R16G16B16A16_UNORM;
constexpr uint32_t kColorTexelBytes = 8;
constexpr uint32_t kDepthTexelBytes = 4;  // R32F

const std::array<uint16_t, 256>& Linear16Lut() {
  static const std::array<uint16_t, 256> lut = [] {
    std::array<uint16_t, 256> t{};
    for (int i = 0; i < 256; ++i)
      t[i] = uint16_t(std::lround(blend::SrgbToLinear(blend::U8ToUnit(uint8_t(i))) * 65535.0));
    return t;
  }();
  return lut;
}

}  // namespace

void ViewStore::RecordRegrowth(VkCommandBuffer cmd, Image* nc, Image* nd, bool had) const {
  const VkImageAspectFlags a = VK_IMAGE_ASPECT_COLOR_BIT;
  for (Image* img : {nc, nd}) {
    TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_UNDEFINED,
                    VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
    // Clear so unused texels are defined (depth 0 = invalid).
    VkClearColorValue zero{};
    VkImageSubresourceRange range{a, 0, 1, 0, VK_REMAINING_ARRAY_LAYERS};
    vkCmdClearColorImage(cmd, img->image.get(), VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &zero, 1,
                         &range);
  }
  if (had) {
    for (auto [src, dst] : {std::pair{&colors_, nc}, std::pair{&depths_, nd}}) {
      TransitionImage(cmd, src->image.get(), a, src == &depths_ ? kDepthLayout : kColorLayout,
                      VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL);
      VkImageCopy region{};
      region.srcSubresource = {a, 0, 0, slot_capacity_};
      region.dstSubresource = {a, 0, 0, slot_capacity_};
      region.extent = {layer_w_, layer_h_, 1};
      vkCmdCopyImage(cmd, src->image.get(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, dst->image.get(),
                     VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
    }
  }
  for (Image* img : {nc, nd})
    TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                    img == nd ? kDepthLayout : kColorLayout);
}

absl::Status ViewStore::Grow(uint32_t w, uint32_t h, uint32_t slots) {
  const uint32_t nw = std::max(w, layer_w_), nh = std::max(h, layer_h_);
  uint32_t ns = std::max<uint32_t>(slot_capacity_, 1);
  while (ns < slots) ns *= 2;
  if (colors_.image && nw == layer_w_ && nh == layer_h_ && ns == slot_capacity_)
    return absl::OkStatus();
  const VkImageUsageFlags usage = VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT |
                                  VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
  EXO_ASSIGN_OR_RETURN(Image nc, Image::Create(ctx_, nw, nh, ns, kColorFormat,
                                               usage | VK_IMAGE_USAGE_STORAGE_BIT,
                                               VK_IMAGE_ASPECT_COLOR_BIT, true));
  EXO_ASSIGN_OR_RETURN(Image nd, Image::Create(ctx_, nw, nh, ns, VK_FORMAT_R32_SFLOAT,
                                               usage | VK_IMAGE_USAGE_STORAGE_BIT,
                                               VK_IMAGE_ASPECT_COLOR_BIT, true));
  EXO_ASSIGN_OR_RETURN(Buffer nrec, Buffer::Create(ctx_, ns * sizeof(GpuView),
                                                   VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT));
  std::memset(nrec.mapped, 0, ns * sizeof(GpuView));
  const bool had = static_cast<bool>(colors_.image);
  if (had) std::memcpy(nrec.mapped, records_.mapped, slot_capacity_ * sizeof(GpuView));
  EXO_RETURN_IF_ERROR(
      ctx_.Submit([&](VkCommandBuffer cmd) { RecordRegrowth(cmd, &nc, &nd, had); }));
  for (uint32_t s = slot_capacity_; s < ns; ++s) free_slots_.push_back(s);
  std::sort(free_slots_.begin(), free_slots_.end(), std::greater<>());  // pop lowest first
  if (had) ++stats_.array_regrowths;
  colors_ = std::move(nc);
  depths_ = std::move(nd);
  records_ = std::move(nrec);
  layer_w_ = nw;
  layer_h_ = nh;
  slot_capacity_ = ns;
  storage_changed_ = true;
  return absl::OkStatus();
}

absl::Status ViewStore::Validate(const StoredView& v) const {
  EXO_RETURN_IF_ERROR(v.camera.Validate());
  const int w = v.camera.width, h = v.camera.height;
  if (w > 16384 || h > 16384)  // the ranked record packs width | height << 16
    return absl::InvalidArgumentError(
        absl::StrCat("view ", v.id, ": size ", w, "x", h, " above 16384"));
  if (v.color.width() != w || v.color.height() != h || v.color.channels() != 3)
    return absl::InvalidArgumentError(absl::StrCat("view ", v.id, ": colour must be RGB8 ", w, "x",
                                                   h, ", got ", v.color.width(), "x",
                                                   v.color.height(), "x", v.color.channels()));
  if (v.depth_m.width() != w || v.depth_m.height() != h || v.depth_m.channels() != 1)
    return absl::InvalidArgumentError(
        absl::StrCat("view ", v.id, ": depth must be 1 channel ", w, "x", h));
  if (!std::isfinite(v.exposure) || v.exposure <= 0.0f)
    return absl::InvalidArgumentError(
        absl::StrCat("view ", v.id, ": exposure must be finite and > 0, got ", v.exposure));
  EXO_RETURN_IF_ERROR(ValidateQuaternion(v.local_from_cam.rotation));
  if (v.inpainted && (v.labels.width() != w || v.labels.height() != h || v.labels.channels() != 1))
    return absl::InvalidArgumentError(
        absl::StrCat("view ", v.id, ": labels of an inpainted view must be 1 channel ", w, "x", h));
  const glm::dvec3& t = v.local_from_cam.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError(absl::StrCat("view ", v.id, ": non-finite position"));
  return absl::OkStatus();
}

absl::StatusOr<uint32_t> ViewStore::AcquireSlot(ViewId id, int w, int h, bool is_new) {
  const uint32_t needed = static_cast<uint32_t>(views_.size() + (is_new ? 1 : 0));
  EXO_RETURN_IF_ERROR(Grow(w, h, needed));
  if (!is_new) return views_.at(id).slot;
  const uint32_t slot = free_slots_.back();
  free_slots_.pop_back();
  return slot;
}

bool ViewStore::BackgroundMaskAny(const Entry& e, int x0, int y0, int x1, int y1) {
  const glm::ivec4& b = e.bg_box;
  x0 = std::max(x0, b.x);
  y0 = std::max(y0, b.y);
  x1 = std::min(x1, b.z);
  y1 = std::min(y1, b.w);
  if (x0 > x1 || y0 > y1) return false;
  if (e.bg_block_sat.empty()) return true;
  const int stride = (e.params.size.x + kBgBlockPx - 1) / kBgBlockPx + 1;
  const int bx0 = x0 / kBgBlockPx, by0 = y0 / kBgBlockPx;
  const int bx1 = x1 / kBgBlockPx + 1, by1 = y1 / kBgBlockPx + 1;
  const auto at = [&](int x, int y) { return int(e.bg_block_sat[size_t(y) * stride + x]); };
  return at(bx1, by1) - at(bx0, by1) - at(bx1, by0) + at(bx0, by0) > 0;
}

absl::StatusOr<bool> ViewStore::Stage(const StoredView& v, glm::ivec4* bg_box,
                                      std::vector<uint16_t>* bg_block_sat) {
  // Staging: linear UNORM16 RGBA colour then R32F baked depth.
  const size_t n = v.color.width() * size_t(v.color.height());
  const VkDeviceSize color_bytes = n * kColorTexelBytes, depth_bytes = n * kDepthTexelBytes;
  if (!staging_.buffer || staging_.size < color_bytes + depth_bytes) {
    EXO_ASSIGN_OR_RETURN(staging_, Buffer::Create(ctx_, color_bytes + depth_bytes,
                                                  VK_BUFFER_USAGE_TRANSFER_SRC_BIT));
  }
  uint8_t* dst = static_cast<uint8_t*>(staging_.mapped);
  const uint8_t* src = v.color.data();
  // sRGB8 -> linear UNORM16 (the texel decode of blend_math.h, done once at upload).
  const auto& lut = Linear16Lut();
  uint16_t* d16 = reinterpret_cast<uint16_t*>(dst);
  // Alpha: 1 for an observed view; an inpainted keyframe's labels (1 = inside its ROI, SPEC §7).
  const uint8_t* labels = v.inpainted ? v.labels.data() : nullptr;
  for (size_t i = 0; i < n; ++i) {
    d16[4 * i + 0] = lut[src[3 * i + 0]];
    d16[4 * i + 1] = lut[src[3 * i + 1]];
    d16[4 * i + 2] = lut[src[3 * i + 2]];
    d16[4 * i + 3] = labels == nullptr || labels[i] ? 65535 : 0;
  }
  ImageF baked =
      BakeDiscontinuities(v.depth_m, opt_.bake_discontinuity_radius_px,
                          opt_.bake_discontinuity_delta_z_m, opt_.bake_discontinuity_delta_z_rel);
  // Background at infinity: -1 marks the guarded background mask (invalid for surfaces too).
  const ImageU8 bg_mask = BackgroundMask(v.depth_m, opt_.bake_background_guard_radius_px);
  bool has_background = false;
  const int bw = baked.width();
  *bg_box = glm::ivec4(bw, baked.height(), -1, -1);
  for (size_t i = 0, m = baked.size(); i < m; ++i)
    if (bg_mask.data()[i]) {
      baked.data()[i] = -1.0f;
      has_background = true;
      const int x = int(i % size_t(bw)), y = int(i / size_t(bw));
      *bg_box = glm::ivec4(std::min(bg_box->x, x), std::min(bg_box->y, y),
                           std::max(bg_box->z, x), std::max(bg_box->w, y));
    }
  // Blocks of kBgBlockPx pixels holding a mask pixel, as a summed-area table.
  bg_block_sat->clear();
  const int nbx = (bw + kBgBlockPx - 1) / kBgBlockPx;
  const int nby = (baked.height() + kBgBlockPx - 1) / kBgBlockPx;
  if (has_background && nbx * nby <= 65535) {
    std::vector<uint8_t> block(size_t(nbx) * nby, 0);
    for (size_t i = 0, m = baked.size(); i < m; ++i)
      if (bg_mask.data()[i])
        block[size_t(i / size_t(bw)) / kBgBlockPx * nbx + (i % size_t(bw)) / kBgBlockPx] = 1;
    bg_block_sat->assign(size_t(nbx + 1) * (nby + 1), 0);
    for (int y = 0; y < nby; ++y)
      for (int x = 0; x < nbx; ++x)
        (*bg_block_sat)[size_t(y + 1) * (nbx + 1) + x + 1] = uint16_t(
            block[size_t(y) * nbx + x] + (*bg_block_sat)[size_t(y) * (nbx + 1) + x + 1] +
            (*bg_block_sat)[size_t(y + 1) * (nbx + 1) + x] -
            (*bg_block_sat)[size_t(y) * (nbx + 1) + x]);
  }
  std::memcpy(dst + color_bytes, baked.data(), depth_bytes);
  return has_background;
}

absl::Status ViewStore::CopyStagingToLayer(uint32_t slot, uint32_t w, uint32_t h) {
  const VkDeviceSize color_bytes = VkDeviceSize(w) * h * kColorTexelBytes;
  return ctx_.Submit([&](VkCommandBuffer cmd) {
    const VkImageAspectFlags a = VK_IMAGE_ASPECT_COLOR_BIT;
    VkDeviceSize offset = 0;
    for (Image* img : {&colors_, &depths_}) {
      const VkImageLayout resident = img == &depths_ ? kDepthLayout : kColorLayout;
      TransitionImage(cmd, img->image.get(), a, resident, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                      slot, 1);
      VkBufferImageCopy region{};
      region.bufferOffset = offset;
      region.imageSubresource = {a, 0, slot, 1};
      region.imageExtent = {w, h, 1};
      vkCmdCopyBufferToImage(cmd, staging_.buffer.get(), img->image.get(),
                             VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
      TransitionImage(cmd, img->image.get(), a, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, resident,
                      slot, 1);
      offset += color_bytes;
    }
  });
}

void ViewStore::WriteRecord(const StoredView& v, uint32_t slot) {
  // The record (mirrors blend::BlendView as the CPU reference builds it).
  // P = K [R^T | -R^T c] in double, rounded once to float.
  const glm::dmat3 cam_from_local = glm::transpose(v.local_from_cam.RotationMatrix());
  const glm::dvec3 c = v.local_from_cam.translation;
  const glm::dvec3 tr = -(cam_from_local * c);
  GpuView rec;
  // Row r of R^T (glm is column-major: element (r, k) is [k][r]), with its translation.
  auto row_of = [&](int r) {
    return glm::dvec4(cam_from_local[0][r], cam_from_local[1][r], cam_from_local[2][r], tr[r]);
  };
  rec.p0 = glm::vec4(v.camera.fx * row_of(0) + v.camera.cx * row_of(2));
  rec.p1 = glm::vec4(v.camera.fy * row_of(1) + v.camera.cy * row_of(2));
  rec.p2 = glm::vec4(row_of(2));
  rec.centre_exposure = glm::vec4(glm::vec3(c), v.exposure);
  rec.size_layer = glm::vec4(float(v.camera.width), float(v.camera.height), float(slot), 1.0f);
  std::memcpy(static_cast<GpuView*>(records_.mapped) + slot, &rec, sizeof(rec));
  stats_.bytes += sizeof(GpuView);
}

absl::StatusOr<bool> ViewStore::Upsert(const StoredView& v, uint64_t fingerprint) {
  EXO_RETURN_IF_ERROR(Validate(v));
  const bool is_new = !views_.contains(v.id);
  const int w = v.camera.width, h = v.camera.height;
  EXO_ASSIGN_OR_RETURN(const uint32_t slot, AcquireSlot(v.id, w, h, is_new));
  glm::ivec4 bg_box;
  std::vector<uint16_t> bg_block_sat;
  EXO_ASSIGN_OR_RETURN(const bool has_background, Stage(v, &bg_box, &bg_block_sat));
  EXO_RETURN_IF_ERROR(CopyStagingToLayer(slot, uint32_t(w), uint32_t(h)));
  WriteRecord(v, slot);
  stats_.bytes += VkDeviceSize(w) * h * (kColorTexelBytes + kDepthTexelBytes);
  ++stats_.view_uploads;
  views_[v.id] =
      Entry{slot,   fingerprint,           MakeBlendView(v), has_background,
            bg_box, std::move(bg_block_sat), v.inpainted};
  return is_new;
}

absl::Status ViewStore::Remove(ViewId id) {
  auto it = views_.find(id);
  if (it == views_.end()) return absl::NotFoundError(absl::StrCat("view ", id, " not resident"));
  const uint32_t slot = it->second.slot;
  GpuView* rec = static_cast<GpuView*>(records_.mapped) + slot;
  rec->size_layer.w = 0.0f;
  stats_.bytes += sizeof(GpuView);
  views_.erase(it);
  free_slots_.push_back(slot);
  return absl::OkStatus();
}

uint64_t ViewStore::ResidentBytes() const {
  return uint64_t(layer_w_) * layer_h_ * slot_capacity_ * (kColorTexelBytes + kDepthTexelBytes) +
         records_.size + staging_.size;
}

}  // namespace exo::vk
