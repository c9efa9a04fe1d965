#include "server/inpainting/completion.h"

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "common/lumigraph/blend_math.h"
#include "common/raster/rasterizer.h"

namespace exo::inpainting {
namespace {

double WallMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
double CpuMs() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}

bool FinitePose(const Rigid3d& p) {
  const glm::dquat& q = p.rotation;
  return std::isfinite(q.w) && std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z) &&
         std::isfinite(p.translation.x) && std::isfinite(p.translation.y) &&
         std::isfinite(p.translation.z) && ValidateQuaternion(q).ok();
}

// Separable Gaussian blur of an RGB8 image into floats (borders clamped), radius 3 sigma.
std::vector<float> GaussianBlur3(const ImageU8& img, double sigma) {
  const int w = img.width(), h = img.height(), r = std::max(1, int(std::ceil(3.0 * sigma)));
  std::vector<float> k(2 * r + 1);
  float sum = 0.0f;
  for (int i = -r; i <= r; ++i) sum += k[i + r] = float(std::exp(-0.5 * i * i / (sigma * sigma)));
  for (float& v : k) v /= sum;
  std::vector<float> tmp(size_t(w) * h * 3), out(size_t(w) * h * 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        float a = 0.0f;
        for (int i = -r; i <= r; ++i) a += k[i + r] * img.at(std::clamp(x + i, 0, w - 1), y, c);
        tmp[(size_t(y) * w + x) * 3 + c] = a;
      }
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        float a = 0.0f;
        for (int i = -r; i <= r; ++i)
          a += k[i + r] * tmp[(size_t(std::clamp(y + i, 0, h - 1)) * w + x) * 3 + c];
        out[(size_t(y) * w + x) * 3 + c] = a;
      }
  return out;
}

}  // namespace

absl::Status CompletionOptions::Validate() const {
  EXO_RETURN_IF_ERROR(inpaint.Validate());
  EXO_RETURN_IF_ERROR(render.Validate());
  if (min_hole_px < 1) return absl::InvalidArgumentError("completion min_hole_px must be >= 1");
  if (!(min_hole_fraction >= 0.0 && min_hole_fraction < 1.0))
    return absl::InvalidArgumentError("completion min_hole_fraction must be in [0, 1)");
  if (!(min_known_fraction > 0.0 && min_known_fraction < 1.0))
    return absl::InvalidArgumentError("completion min_known_fraction must be in (0, 1)");
  if (mesh_step_px < 1 || mesh_step_px > 64)
    return absl::InvalidArgumentError("completion mesh_step_px must be in [1, 64]");
  if (!(mesh_jump_rel > 0.0)) return absl::InvalidArgumentError("completion mesh_jump_rel must be > 0");
  if (!std::isfinite(detail_gain) || detail_gain > 4.0)
    return absl::InvalidArgumentError("completion detail_gain must be < 0 (off) or in [0, 4]");
  if (!(vertex_color_depth_tol_m >= 0.0 && vertex_color_depth_tol_m <= 1.0))
    return absl::InvalidArgumentError("completion vertex_color_depth_tol_m must be in [0, 1]");
  if (!(detail_sigma_px >= 0.5 && detail_sigma_px <= 64.0))
    return absl::InvalidArgumentError("completion detail_sigma_px must be in [0.5, 64]");
  return absl::OkStatus();
}

absl::StatusOr<CompletionHoles> FindHoles(const LumigraphModel& model, const PinholeCamera& camera,
                                          const Rigid3d& local_from_cam,
                                          const CompletionOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(camera.Validate());
  if (!FinitePose(local_from_cam))
    return absl::InvalidArgumentError("the completion camera's pose is not finite / not a rotation");
  const double t0 = WallMs();
  CpuRenderOptions ro = options.render;
  ro.blend.fill_holes = false;
  EXO_ASSIGN_OR_RETURN(auto renderer, CpuLumigraphRenderer::Create(model, ro));
  EXO_ASSIGN_OR_RETURN(CpuRenderOutput r, renderer->Render(camera, local_from_cam));
  const int w = camera.width, h = camera.height;
  CompletionHoles out;
  out.color = std::move(r.color);
  out.proxy_depth = ImageF(w, h, 1, 0.0f);
  const TriangleMesh mesh = model.ProxyMesh();
  if (!mesh.empty()) {
    RasterOptions rs;
    rs.z_depth = true;
    rs.num_threads = ro.num_threads;
    EXO_ASSIGN_OR_RETURN(RasterOutput raster, Rasterize(mesh, camera, local_from_cam, rs));
    out.proxy_depth = std::move(raster.z_depth_m);
  }
  out.holes = ImageU8(w, h, 1, 0);
  out.known = ImageU8(w, h, 1, 0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool covered = r.coverage.at(x, y) != 0;
      const bool background = r.background.at(x, y) != 0;
      const float z = out.proxy_depth.at(x, y);
      const bool surface = std::isfinite(z) && z > 0.0f;
      if (covered) ++out.covered_px;
      if (background) ++out.background_px;
      if (covered || background) {
        out.known.at(x, y) = 255;
        continue;
      }
      out.holes.at(x, y) = 255;
      ++out.hole_px;
      if (surface)
        ++out.surface_hole_px;
      else
        ++out.void_hole_px;
    }
  }
  out.render_ms = WallMs() - t0;
  return out;
}

TriangleMesh MeshFromDepth(const ImageF& depth_m, const ImageU8& mask, const PinholeCamera& camera,
                           const Rigid3d& local_from_cam, int step_px, double jump_rel) {
  TriangleMesh m;
  const int w = depth_m.width(), h = depth_m.height();
  if (step_px < 1 || w < 2 || h < 2) return m;
  // Grid lines every step_px and one more on the last pixel row / column.
  const int gw = (w - 2) / step_px + 2, gh = (h - 2) / step_px + 2;
  const auto gx = [&](int i) { return std::min(i * step_px, w - 1); };
  const auto gy = [&](int j) { return std::min(j * step_px, h - 1); };
 // Grid vertex (i, j) at pixel (gx(i), gy(j)); "near" when a mask pixel lies within one
  // step of it (the dilation that stitches the mesh to the proxy around the holes).
  std::vector<uint8_t> near(static_cast<size_t>(gw) * gh, 0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      if (!mask.at(x, y)) continue;
      const int i0 = std::max(0, (x - step_px) / step_px);
      const int i1 = std::min(gw - 1, (x + step_px) / step_px + 1);
      const int j0 = std::max(0, (y - step_px) / step_px);
      const int j1 = std::min(gh - 1, (y + step_px) / step_px + 1);
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i)
          if (std::abs(gx(i) - x) <= step_px && std::abs(gy(j) - y) <= step_px)
            near[static_cast<size_t>(j) * gw + i] = 1;
    }
  std::vector<int32_t> index(near.size(), -1);
  std::vector<float> zs(near.size(), 0.0f);
  const auto vertex = [&](int i, int j) -> int32_t {
    const size_t k = static_cast<size_t>(j) * gw + i;
    if (!near[k]) return -1;
    if (index[k] >= 0) return index[k];
    const int x = gx(i), y = gy(j);
    const float z = depth_m.at(x, y);
    if (!std::isfinite(z) || z <= 0.0f) return -1;
    // Vertices on the image's edge lie on the edge of its pixels (the rasterizer's pixel centre
    // rule would otherwise leave the outermost row / column uncovered).
    const double u = x == 0 ? -0.5 : x == w - 1 ? w - 0.5 : x;
    const double v = y == 0 ? -0.5 : y == h - 1 ? h - 0.5 : y;
    const glm::dvec3 pc((u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z);
    index[k] = static_cast<int32_t>(m.positions.size());
    zs[k] = z;
    m.positions.push_back(glm::vec3(local_from_cam * pc));
    return index[k];
  };
  for (int j = 0; j + 1 < gh; ++j) {
    for (int i = 0; i + 1 < gw; ++i) {
      const int32_t a = vertex(i, j), b = vertex(i + 1, j), c = vertex(i, j + 1),
                    d = vertex(i + 1, j + 1);
      if (a < 0 || b < 0 || c < 0 || d < 0) continue;
      const size_t k = static_cast<size_t>(j) * gw + i;
      const float z[4] = {zs[k], zs[k + 1], zs[k + gw], zs[k + gw + 1]};
      const float zmin = std::min({z[0], z[1], z[2], z[3]});
      const float zmax = std::max({z[0], z[1], z[2], z[3]});
      if (zmax - zmin > jump_rel * zmin) continue;
      // Two triangles, counter-clockwise seen from the camera (y down): a, c, b and b, c, d.
      m.indices.insert(m.indices.end(), {uint32_t(a), uint32_t(c), uint32_t(b), uint32_t(b),
                                         uint32_t(c), uint32_t(d)});
    }
  }
  if (m.indices.empty()) return TriangleMesh{};
  // Drop vertices no quad uses (compaction keeps the chunk small).
  std::vector<int32_t> remap(m.positions.size(), -1);
  std::vector<glm::vec3> pos;
  for (uint32_t& idx : m.indices) {
    if (remap[idx] < 0) {
      remap[idx] = static_cast<int32_t>(pos.size());
      pos.push_back(m.positions[idx]);
    }
    idx = static_cast<uint32_t>(remap[idx]);
  }
  m.positions = std::move(pos);
  return m;
}

absl::StatusOr<CompletionResult> CompleteView(const LumigraphModel& model,
                                              const PinholeCamera& camera,
                                              const Rigid3d& local_from_cam,
                                              const CompletionOptions& options,
                                              const TriangleMesh* coloured_proxy) {
  const double t0 = WallMs(), c0 = CpuMs();
  CompletionResult out;
  EXO_ASSIGN_OR_RETURN(out.before, FindHoles(model, camera, local_from_cam, options));
  out.render_ms = out.before.render_ms;
  const CompletionHoles& hb = out.before;
  const int w = camera.width, h = camera.height;
  const double n = double(w) * h;
  if (hb.hole_px < options.min_hole_px || hb.hole_px < options.min_hole_fraction * n) {
    out.total_ms = WallMs() - t0;
    out.total_cpu_ms = CpuMs() - c0;
    return out;  // nothing to complete
  }
  const int known = hb.covered_px + hb.background_px;
  if (known < options.min_known_fraction * n || hb.covered_px == 0)
    return absl::FailedPreconditionError(absl::StrCat(
        "nothing modelled in view: ", hb.covered_px, " px covered by stored views and ",
        hb.background_px, " background px of ", int64_t(n),
        "; no source to complete the holes from (fly closer to the modelled scene)"));
  // The keyframe: the render's colour, the proxy's depth where a stored view covers it.
  RgbdKeyframe kf;
  kf.color = hb.color;
  kf.depth_m = ImageF(w, h, 1, 0.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (hb.known.at(x, y) && hb.proxy_depth.at(x, y) > 0.0f)
        kf.depth_m.at(x, y) = hb.proxy_depth.at(x, y);
  kf.camera = camera;
  kf.world_from_cam = local_from_cam;
  // The proxy's fused colour at the surface holes (CompletionOptions::use_vertex_color): known
  // pixels of the keyframe; PatchMatch fills the rest (`fill`).
  ImageU8 fill = hb.holes;
  if (options.use_vertex_color && hb.surface_hole_px > 0) {
    TriangleMesh own;
    if (!coloured_proxy)
      for (const auto& [id, c] : model.chunks)
        if (!c.mesh.empty() && c.mesh.colors.size() == c.mesh.positions.size() &&
            c.mesh.normals.empty() == own.normals.empty())
          own.Append(c.mesh);
    const TriangleMesh& coloured = coloured_proxy ? *coloured_proxy : own;
    const float tol = static_cast<float>(options.vertex_color_depth_tol_m);
    if (!coloured.empty() && coloured.colors.size() == coloured.positions.size()) {
      RasterOptions rs;
      rs.z_depth = true;
      rs.position = true;
      rs.triangle_id = true;
      rs.num_threads = options.render.num_threads;
      EXO_ASSIGN_OR_RETURN(RasterOutput cr, Rasterize(coloured, camera, local_from_cam, rs));
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const float zp = hb.proxy_depth.at(x, y);
          const uint32_t t = cr.triangle_id.at(x, y);
          if (!hb.holes.at(x, y) || !(zp > 0.0f) || t == kNoTriangle) continue;
          // The coloured surface must be the proxy's front surface there.
          if (std::fabs(cr.z_depth_m.at(x, y) - zp) > std::max(1e-3f * zp + 1e-4f, tol)) continue;
          const glm::vec3 p(cr.position_local.at(x, y, 0), cr.position_local.at(x, y, 1),
                            cr.position_local.at(x, y, 2));
          const uint32_t* tri = &coloured.indices[3 * size_t(t)];
          const glm::vec3 a = coloured.positions[tri[0]], b = coloured.positions[tri[1]],
                          c = coloured.positions[tri[2]];
          // Barycentric weights of p in (a, b, c).
          const glm::vec3 e0 = b - a, e1 = c - a, ep = p - a;
          const float d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
          const float d20 = glm::dot(ep, e0), d21 = glm::dot(ep, e1);
          const float den = d00 * d11 - d01 * d01;
          if (!(std::fabs(den) > 1e-20f)) continue;
          const float v = std::clamp((d11 * d20 - d01 * d21) / den, 0.0f, 1.0f);
          const float wgt = std::clamp((d00 * d21 - d01 * d20) / den, 0.0f, 1.0f - v);
          const glm::vec3 lin = (1.0f - v - wgt) * coloured.colors[tri[0]] +
                                v * coloured.colors[tri[1]] + wgt * coloured.colors[tri[2]];
          const glm::vec3 srgb = blend::LinearToSrgb(glm::clamp(lin, 0.0f, 1.0f));
          for (int ch = 0; ch < 3; ++ch) kf.color.at(x, y, ch) = blend::UnitToU8(srgb[ch]);
          kf.depth_m.at(x, y) = zp;
          fill.at(x, y) = 0;
          ++out.before.fused_color_px;
        }
    }
  }
  int fill_px = 0;
  for (uint8_t m : fill.span()) fill_px += m != 0;
  const double ti = WallMs();
  InpaintResult r;
  if (fill_px > 0) {
    EXO_ASSIGN_OR_RETURN(r, InpaintKeyframe(kf, fill, options.inpaint));
  } else {  // every hole has fused colour (no void holes: those have no surface)
    r.color = kf.color;
    r.depth_m = kf.depth_m;
  }
  out.inpaint_ms = WallMs() - ti;
  out.stats = r.stats;
  // Depth of the view: the proxy's where it has a surface (surface holes included: the renderers
  // blend the keyframe at the proxy's surface point), the solved depth in the void holes, 0 where
  // the render shows background at infinity (nothing within range).
  ImageF depth(w, h, 1, 0.0f);
  ImageU8 void_mask(w, h, 1, 0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float zp = hb.proxy_depth.at(x, y);
      if (zp > 0.0f) {
        depth.at(x, y) = zp;
      } else if (hb.holes.at(x, y)) {
        const float zs = r.depth_m.at(x, y);
        depth.at(x, y) = std::isfinite(zs) && zs > 0.0f ? zs : 0.0f;
        void_mask.at(x, y) = 255;
      }
    }
  }
  const double tm = WallMs();
  // The mesh needs depth one step around the void holes: the solved / pre-filled depth there.
  ImageF mesh_depth = depth;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (mesh_depth.at(x, y) <= 0.0f) {
        const float zs = r.depth_m.at(x, y);
        if (std::isfinite(zs) && zs > 0.0f) mesh_depth.at(x, y) = zs;
      }
  if (hb.void_hole_px > 0)
    out.void_mesh = MeshFromDepth(mesh_depth, void_mask, camera, local_from_cam,
                                  options.mesh_step_px, options.mesh_jump_rel);
  out.mesh_ms = WallMs() - tm;
  out.view.camera = camera;
  out.view.local_from_cam = local_from_cam;
  if (options.detail_gain >= 0.0) {
    // Push-pull's low frequencies + PatchMatch's high frequencies (CompletionOptions).
    ImageU8 base = kf.color, known = hb.known;
    for (size_t i = 0; i < known.size(); ++i)
      if (hb.holes.data()[i] && !fill.data()[i]) known.data()[i] = 255;  // fused colour
    FillHoles(base, known);
    const std::vector<float> low = GaussianBlur3(r.color, options.detail_sigma_px);
    const float gain = static_cast<float>(options.detail_gain);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        if (!fill.at(x, y)) continue;
        for (int c = 0; c < 3; ++c) {
          const float detail = r.color.at(x, y, c) - low[(size_t(y) * w + x) * 3 + c];
          r.color.at(x, y, c) = static_cast<uint8_t>(
              std::clamp(std::lround(base.at(x, y, c) + gain * detail), 0L, 255L));
        }
      }
  }
  out.view.color = std::move(r.color);
  out.view.depth_m = std::move(depth);
  out.view.inpainted = true;
  out.view.labels = hb.holes;
  out.completed = true;
  out.total_ms = WallMs() - t0;
  out.total_cpu_ms = CpuMs() - c0;
  return out;
}

}  // namespace exo::inpainting
