// exoview_product_eval: the product path's quality on real held-out frames (issue 15). Renders a
// model a real exoview_viewer saved (--save_model) at the poses of the 7-Scenes frames the uploader
// held out (--hold_out_every / --hold_out_offset, the split of exoview_eval and the uploader:
// common/datasets IsHeldOut; held-out frames whose colour is byte-identical to an ingested frame's
// are dropped, as exoview_eval does) with the product renderer (client/vulkan VulkanRenderer, the
// viewer's default blend options), and compares each render with the held-out colour image using
// exoview_eval's metrics (common/metrics: SSIM of the hole-filled and of the unfilled frame, PSNR,
// MS-SSIM, GMSD, coverage). Beside it, fused per-vertex-colour meshes rendered at the same poses
// with the CPU rasterizer the eval's vertex_color policy uses:
//   "ours"   the server's TSDF mesh with vertex colour: server/core OnlineGeometry with the
//            server's defaults on the ingested frames (the same code and frames as the server, so
//            the same proxy when every frame was accepted; its geometry digest is printed)
//   --mesh_ply=FILE:LABEL  any per-vertex-colour mesh in world coordinates (binary PLY, colours
//            uchar sRGB), e.g. Open3D's ScalableTSDFVolume (tools/product_eval.py)
// Prints one JSON line per method. --write_registered=DIR writes the ingested frames' registered
// depth (16-bit PNG, mm, colour camera) and a frames.json for an external fusion (Open3D).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "client/vulkan/vulkan_renderer.h"
#include "common/cli/cli.h"
#include "common/datasets/dataset.h"
#include "common/interop/readback_for_tests.h"
#include "common/io/image_file.h"
#include "common/lumigraph/blend_math.h"
#include "common/lumigraph/cpu_renderer.h"
#include "common/lumigraph/model_io.h"
#include "common/metrics/metrics.h"
#include "common/metrics/perceptual.h"
#include "common/metrics/view_scores.h"
#include "common/lumigraph/vertex_color.h"
#include "common/raster/rasterizer.h"
#include "server/core/online_model.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}
double Mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / double(v.size());
}
double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}
double Round(double v, int digits) {
  if (!std::isfinite(v)) return v;
  const double p = std::pow(10.0, digits);
  return std::round(v * p) / p;
}

// The metrics of exoview_eval's EvalSink (server/eval/eval.cc) on one view: the headline figures
// of the frame the product shows (uncovered pixels filled by FillHoles), the unfilled ones beside.
struct Sink {
  std::vector<double> ssim, psnr, ssim_unfilled, psnr_unfilled, coverage, ssim_covered, ms_ssim,
      gmsd, render_ms;
  absl::Status Add(const ImageU8& img, const ImageU8& gt, const ImageU8& mask, const ImageU8& known,
                   double ms) {
    ImageU8 filled = img;
    FillHoles(filled, known);
    EXO_ASSIGN_OR_RETURN(const ViewScores v, ScoreView(filled, img, gt, mask));
    ssim.push_back(v.ssim);
    psnr.push_back(v.psnr);
    ssim_unfilled.push_back(v.ssim_unfilled);
    psnr_unfilled.push_back(v.psnr_unfilled);
    coverage.push_back(v.coverage);
    if (v.ms_ssim) ms_ssim.push_back(*v.ms_ssim);
    gmsd.push_back(v.gmsd);
    if (v.ssim_covered) ssim_covered.push_back(*v.ssim_covered);
    render_ms.push_back(ms);
    return absl::OkStatus();
  }
  nlohmann::json Json() const {
    nlohmann::json q;
    q["ssim"] = Round(Mean(ssim), 4);
    q["psnr"] = Round(Mean(psnr), 2);
    q["ssim_unfilled"] = Round(Mean(ssim_unfilled), 4);
    q["psnr_unfilled"] = Round(Mean(psnr_unfilled), 2);
    q["coverage"] = Round(Mean(coverage), 4);
    q["ssim_covered"] = Round(Mean(ssim_covered), 4);
    q["ms_ssim"] =
        ms_ssim.empty() ? nlohmann::json(nullptr) : nlohmann::json(Round(Mean(ms_ssim), 4));
    q["gmsd"] = Round(Mean(gmsd), 4);
    q["views"] = ssim.size();
    q["render_ms_median"] = Round(Median(render_ms), 1);
    q["per_view_ssim"] = nlohmann::json::array();
    for (double s : ssim) q["per_view_ssim"].push_back(Round(s, 4));
    return q;
  }
};

// 2x2 (k x k) box average of an RGB image whose size is a multiple of k.
ImageU8 BoxDownscale(const ImageU8& in, int w, int h) {
  if (in.width() == w && in.height() == h) return in;
  ImageU8 out(w, h, 3, 0);
  const int kx = in.width() / w, ky = in.height() / h;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        int s = 0;
        for (int dy = 0; dy < ky; ++dy)
          for (int dx = 0; dx < kx; ++dx) s += in.at(x * kx + dx, y * ky + dy, c);
        out.at(x, y, c) = uint8_t((s + kx * ky / 2) / (kx * ky));
      }
  return out;
}

// A binary PLY with per-vertex uchar colours (world frame) as a local-frame mesh with linear
// colours.
absl::StatusOr<TriangleMesh> LoadColoredPly(const std::string& path, const LocalOrigin& origin) {
  const interop::testing::PlyData d = interop::testing::ReadBinaryPly(path);
  if (!d.error.empty()) return absl::InvalidArgumentError(path + ": " + d.error);
  for (const char* k : {"x", "y", "z", "red", "green", "blue"})
    if (!d.vertex.count(k))
      return absl::InvalidArgumentError(path + ": no vertex property '" + k + "'");
  TriangleMesh m;
  const auto &x = d.vertex.at("x"), &y = d.vertex.at("y"), &z = d.vertex.at("z");
  const auto &r = d.vertex.at("red"), &g = d.vertex.at("green"), &b = d.vertex.at("blue");
  for (size_t i = 0; i < x.size(); ++i) {
    m.positions.push_back(origin.ToLocal(glm::dvec3(x[i], y[i], z[i])));
    m.colors.push_back(blend::SrgbToLinear(glm::vec3(r[i], g[i], b[i]) / 255.0f));
  }
  for (const auto& f : d.faces) {
    if (f.size() != 3) return absl::InvalidArgumentError(path + ": a face is not a triangle");
    for (int64_t i : f) {
      if (i < 0 || size_t(i) >= x.size())
        return absl::InvalidArgumentError(path + ": face index out of range");
      m.indices.push_back(uint32_t(i));
    }
  }
  return m;
}

struct Args {
  std::string data, model, write_registered, sheets_dir, sheet_label = "fold";
  std::vector<std::string> mesh_ply;
  int hold_out_every = 10, hold_out_offset = -1, frames = 0, max_views = 0;
  int width = 640, height = 480, sheet_views = 0;
  bool ours = true;
  bool cpu_oracle = false;
  std::string swap;  // diagnostic: stored-view ingredients replaced by the dataset's
};

struct Split {
  std::vector<Frame> input;  // ingested (what the uploader sent)
  std::vector<Frame> test;   // held out, duplicates dropped
  int held_out = 0, dropped_duplicates = 0;
};

absl::StatusOr<Split> LoadSplit(const Args& a, bool need_input) {
  DatasetOptions o;
  o.format = "7scenes";
  o.register_depth = true;  // what exoview_uploader --format=7scenes sends (its default)
  EXO_ASSIGN_OR_RETURN(auto reader, OpenDataset(a.data, o));
  const size_t total = a.frames > 0 ? std::min<size_t>(a.frames, reader->size()) : reader->size();
  Split s;
  std::unordered_map<std::string, int> colour;
  std::vector<size_t> held;
  for (size_t i = 0; i < total; ++i) {
    if (IsHeldOut(i, a.hold_out_every, a.hold_out_offset)) {
      held.push_back(i);
      continue;
    }
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    colour[std::string(reinterpret_cast<const char*>(f.color.data()), f.color.bytes())] = 1;
    if (need_input) s.input.push_back(std::move(f));
  }
  s.held_out = int(held.size());
  for (size_t i : held) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    if (colour.count(std::string(reinterpret_cast<const char*>(f.color.data()), f.color.bytes()))) {
      ++s.dropped_duplicates;
      continue;
    }
    f.sequence = i;
    s.test.push_back(std::move(f));
    if (a.max_views > 0 && int(s.test.size()) >= a.max_views) break;
  }
  return s;
}

// Registered depth (mm, 16 bit, colour camera) + frames.json for an external TSDF (Open3D).
absl::Status WriteRegistered(const Args& a) {
  DatasetOptions o;
  o.format = "7scenes";
  o.register_depth = true;
  EXO_ASSIGN_OR_RETURN(auto reader, OpenDataset(a.data, o));
  const size_t total = a.frames > 0 ? std::min<size_t>(a.frames, reader->size()) : reader->size();
  std::filesystem::create_directories(a.write_registered);
  nlohmann::json frames = nlohmann::json::array();
  nlohmann::json intr;
  for (size_t i = 0; i < total; ++i) {
    EXO_ASSIGN_OR_RETURN(Frame f, reader->Load(i));
    const ImageF depth = core::RegisterDepthToColor(f);
    ImageU16 mm(depth.width(), depth.height());
    for (int y = 0; y < depth.height(); ++y)
      for (int x = 0; x < depth.width(); ++x) {
        const float z = depth.at(x, y);
        mm.at(x, y) =
            (z > 0 && std::isfinite(z)) ? uint16_t(std::min(65535.0f, std::round(z * 1000.0f))) : 0;
      }
    char name[64];
    std::snprintf(name, sizeof(name), "depth-%06zu.png", i);
    EXO_RETURN_IF_ERROR(WritePng16(a.write_registered + "/" + name, mm));
    std::snprintf(name, sizeof(name), "color-%06zu.png", i);
    EXO_RETURN_IF_ERROR(WriteColorImage(a.write_registered + "/" + name, f.color));
    const glm::dmat3 r = f.world_from_cam.RotationMatrix();
    nlohmann::json pose = nlohmann::json::array();
    for (int row = 0; row < 3; ++row)
      pose.push_back({r[0][row], r[1][row], r[2][row], f.world_from_cam.translation[row]});
    pose.push_back({0.0, 0.0, 0.0, 1.0});
    frames.push_back({{"index", i},
                      {"color", std::string(name)},
                      {"depth", std::string("depth-") + std::string(name).substr(6)},
                      {"world_from_cam", pose}});
    const PinholeCamera& c = f.color_camera;
    intr = {{"width", c.width}, {"height", c.height}, {"fx", c.fx},
            {"fy", c.fy},       {"cx", c.cx},         {"cy", c.cy}};
  }
  std::ofstream(a.write_registered + "/frames.json")
      << nlohmann::json{{"intrinsics", intr}, {"depth_scale", 1000.0}, {"frames", frames}}.dump()
      << "\n";
  std::printf("%s\n", nlohmann::json{{"tool", "exoview_product_eval"},
                                     {"wrote_registered", a.write_registered},
                                     {"frames", frames.size()}}
                          .dump()
                          .c_str());
  return absl::OkStatus();
}

ImageU8 Hstack(const std::vector<const ImageU8*>& imgs) {
  int w = 0, h = 0;
  for (auto* i : imgs) w += i->width(), h = std::max(h, i->height());
  ImageU8 out(w, h, 3, 0);
  int x0 = 0;
  for (auto* i : imgs) {
    for (int y = 0; y < i->height(); ++y)
      for (int x = 0; x < i->width(); ++x)
        for (int c = 0; c < 3; ++c) out.at(x0 + x, y, c) = i->at(x, y, i->channels() == 3 ? c : 0);
    x0 += i->width();
  }
  return out;
}

// Our fused mesh of the ingested frames (the server's geometry defaults, voxel from the first
// frame), in the model's local frame, with per-vertex colour.
absl::StatusOr<TriangleMesh> OurMesh(const Split& split, const LumigraphModel& model,
                                     nlohmann::json* base) {
  core::OnlineModelOptions mo;
  EXO_ASSIGN_OR_RETURN(const core::SceneSetup setup, core::ChooseSceneSetup(split.input[0], mo));
  const glm::dvec3 d = setup.origin.origin_in_world - model.origin.origin_in_world;
  if (glm::length(d) > 1e-6)
    std::fprintf(stderr,
                 "exoview_product_eval: warning: the model's origin differs from the first "
                 "ingested frame's by %.3f m (the server's first frame was not frame %llu?)\n",
                 glm::length(d), static_cast<unsigned long long>(split.input[0].sequence));
  EXO_ASSIGN_OR_RETURN(auto geo, core::OnlineGeometry::Create(mo, setup));
  core::ProxyMesh proxy;
  for (const Frame& f : split.input) {
    EXO_ASSIGN_OR_RETURN(core::GeometryUpdate u, geo->Integrate(f));
    proxy.Apply(u);
  }
  TriangleMesh m = proxy.All();
  for (auto& p : m.positions) p = model.origin.ToLocal(setup.origin.ToWorld(p));
  (*base)["ours_geometry_digest"] = core::DigestHex(geo->Digest());
  (*base)["ours_voxel_m"] = setup.voxel_m;
  return m;
}

absl::Status Run(const Args& a) {
  if (!a.write_registered.empty()) return WriteRegistered(a);
  if (a.model.empty())
    return absl::InvalidArgumentError("give --model=FILE (or --write_registered)");
  EXO_ASSIGN_OR_RETURN(LumigraphModel model, LoadModel(a.model));
  if (model.views.empty())
    return absl::FailedPreconditionError(a.model + ": the model has no views");
  EXO_ASSIGN_OR_RETURN(Split split, LoadSplit(a, a.ours || !a.swap.empty()));
  if (split.test.empty()) return absl::FailedPreconditionError("no held-out test frames");
  const PinholeCamera cam = split.test[0].color_camera.Scaled(a.width, a.height);
  if (split.test[0].color.width() % a.width != 0 || split.test[0].color.height() % a.height != 0 ||
      split.test[0].color.width() / a.width != split.test[0].color.height() / a.height)
    return absl::InvalidArgumentError("--width/--height must divide the colour image size evenly");
  std::vector<ImageU8> gt;
  std::vector<Rigid3d> poses;
  for (const Frame& f : split.test) {
    gt.push_back(BoxDownscale(f.color, a.width, a.height));
    poses.push_back(model.origin.ToLocal(f.world_from_cam));
  }
  nlohmann::json base = {{"bench", "product_eval"},
                         {"dataset", "7scenes/redkitchen"},
                         {"hold_out_every", a.hold_out_every},
                         {"fold", a.hold_out_offset < 0 ? a.hold_out_every - 1 : a.hold_out_offset},
                         {"held_out", split.held_out},
                         {"dropped_duplicates", split.dropped_duplicates},
                         {"width", a.width},
                         {"height", a.height}};
  std::vector<std::vector<ImageU8>> sheet_cols;  // per method, the first sheet_views renders
  // ---- the viewer's store through the product renderer ----
  {
    VulkanRendererOptions vo;
    for (const auto& [c, refs] : model.cell_refs)
      vo.max_refs_per_cell = std::max<int>(vo.max_refs_per_cell, int(refs.size()));
    EXO_ASSIGN_OR_RETURN(auto r, VulkanRenderer::Create(vo));
    EXO_RETURN_IF_ERROR(r->SyncModel(model));
    blend::BlendOptions bo;  // the viewer's / exoview_render's defaults
    bo.fill_holes = false;   // filled below (FillHoles), so both versions are measured
    Sink sink;
    sheet_cols.emplace_back();
    for (size_t t = 0; t < poses.size(); ++t) {
      const auto t0 = Clock::now();
      EXO_ASSIGN_OR_RETURN(RenderResult out, r->Render(cam, poses[t], bo));
      const double ms = MsSince(t0);
      ImageU8 mask(cam.width, cam.height, 1, 0), known(cam.width, cam.height, 1, 0);
      for (size_t i = 0; i < mask.size(); ++i) {
        const uint8_t c = out.coverage.data()[i];
        mask.data()[i] = c == 2 ? 255 : 0;               // blended
        known.data()[i] = (c == 2 || c == 3) ? 255 : 0;  // blended or filled at infinity
      }
      EXO_RETURN_IF_ERROR(sink.Add(out.color, gt[t], mask, known, ms));
      if (int(t) < a.sheet_views) {
        ImageU8 filled = out.color;
        FillHoles(filled, known);
        sheet_cols.back().push_back(std::move(filled));
      }
    }
    nlohmann::json j = base;
    j["method"] = "lumigraph_product";
    j["renderer"] = r->DeviceName();
    j["store_views"] = model.views.size();
    {  // which stream frames the store kept (the server numbers frames in arrival order)
      std::vector<int64_t> ids;
      for (const auto& [id, v] : model.views) ids.push_back(static_cast<int64_t>(id));
      j["store_ids"] = ids;
    }
    j["cells"] = model.cell_refs.size();
    j["chunks"] = model.chunks.size();
    j["proxy_triangles"] = model.ProxyMesh().num_triangles();
    j["quality"] = sink.Json();
    std::printf("%s\n", j.dump().c_str());
    std::fflush(stdout);
  }
  // ---- diagnostic: stored-view ingredients swapped for the dataset's (issue 15 attribution) ----
  if (!a.swap.empty()) {
    const bool sc = a.swap.find("color") != std::string::npos;
    const bool sd = a.swap.find("depth") != std::string::npos;
    const bool sp = a.swap.find("pose") != std::string::npos;
    const bool se = a.swap.find("exposure") != std::string::npos;
    if (a.swap.find("proxy") != std::string::npos) {  // the proxy: our fused mesh, one chunk
      nlohmann::json scratch;
      EXO_ASSIGN_OR_RETURN(TriangleMesh m, OurMesh(split, model, &scratch));
      MeshChunk c;
      c.id = 1;
      c.version = 1;
      c.mesh = std::move(m);
      std::fprintf(stderr, "exoview_product_eval: proxy %zu -> %zu triangles\n",
                   model.ProxyMesh().num_triangles(), c.mesh.num_triangles());
      model.chunks.clear();
      model.chunks[1] = std::move(c);
    }
    size_t matched = 0;
    double max_dt = 0;
    for (auto& [id, v] : model.views) {
      // The ingested frame this view came from: the nearest input pose.
      double best = 1e300;
      const Frame* src = nullptr;
      for (const Frame& f : split.input) {
        const Rigid3d p = model.origin.ToLocal(f.world_from_cam);
        const double d = glm::length(p.translation - v.local_from_cam.translation) +
                         std::abs(1.0 - std::abs(glm::dot(p.rotation, v.local_from_cam.rotation)));
        if (d < best) {
          best = d;
          src = &f;
        }
      }
      if (src == nullptr) continue;
      ++matched;
      max_dt = std::max(max_dt, best);
      if (sc) v.color = src->color;
      if (sd) v.depth_m = core::RegisterDepthToColor(*src);
      if (sp) v.local_from_cam = model.origin.ToLocal(src->world_from_cam);
      if (se) v.exposure = 1.0f;
    }
    std::fprintf(stderr, "exoview_product_eval: swapped %s in %zu views (max pose mismatch %.4f)\n",
                 a.swap.c_str(), matched, max_dt);
  }
  // ---- the same store through the CPU oracle (diagnostic: renderer vs model content) ----
  if (a.cpu_oracle) {
    CpuRenderOptions ro;
    ro.blend.fill_holes = false;  // filled by the sink, as above
    EXO_ASSIGN_OR_RETURN(auto r, CpuLumigraphRenderer::Create(model, ro));
    Sink sink;
    for (size_t t = 0; t < poses.size(); ++t) {
      const auto t0 = Clock::now();
      EXO_ASSIGN_OR_RETURN(CpuRenderOutput out, r->Render(cam, poses[t]));
      const double ms = MsSince(t0);
      ImageU8 known = out.coverage;
      for (size_t i = 0; i < known.size(); ++i) known.data()[i] |= out.background.data()[i];
      EXO_RETURN_IF_ERROR(sink.Add(out.color, gt[t], out.coverage, known, ms));
    }
    nlohmann::json j = base;
    j["method"] = "lumigraph_product_cpu_oracle";
    j["store_views"] = model.views.size();
    j["quality"] = sink.Json();
    std::printf("%s\n", j.dump().c_str());
    std::fflush(stdout);
  }
  // ---- fused per-vertex-colour meshes ----
  std::vector<std::pair<std::string, TriangleMesh>> meshes;
  if (a.ours) {
    EXO_ASSIGN_OR_RETURN(TriangleMesh m, OurMesh(split, model, &base));
    meshes.emplace_back("vertex_color_ours", std::move(m));
  }
  for (const std::string& spec : a.mesh_ply) {
    const size_t colon = spec.rfind(':');
    const std::string path = colon == std::string::npos ? spec : spec.substr(0, colon);
    const std::string label = colon == std::string::npos ? "mesh" : spec.substr(colon + 1);
    EXO_ASSIGN_OR_RETURN(TriangleMesh m, LoadColoredPly(path, model.origin));
    meshes.emplace_back(label, std::move(m));
  }
  for (const auto& [label, mesh] : meshes) {
    Sink sink;
    sheet_cols.emplace_back();
    for (size_t t = 0; t < poses.size(); ++t) {
      const auto t0 = Clock::now();
      ImageU8 img, mask;
      EXO_RETURN_IF_ERROR(RenderVertexColor(mesh, cam, poses[t], &img, &mask));
      EXO_RETURN_IF_ERROR(sink.Add(img, gt[t], mask, mask, MsSince(t0)));
      if (int(t) < a.sheet_views) {
        ImageU8 filled = img;
        FillHoles(filled, mask);
        sheet_cols.back().push_back(std::move(filled));
      }
    }
    nlohmann::json j = base;
    j["method"] = label;
    j["triangles"] = mesh.num_triangles();
    j["quality"] = sink.Json();
    std::printf("%s\n", j.dump().c_str());
    std::fflush(stdout);
  }
  // ---- contact sheets: real | product lumigraph | fused meshes ----
  if (!a.sheets_dir.empty() && a.sheet_views > 0) {
    std::filesystem::create_directories(a.sheets_dir);
    for (int t = 0; t < a.sheet_views && t < int(gt.size()); ++t) {
      std::vector<const ImageU8*> row = {&gt[t]};
      for (const auto& col : sheet_cols)
        if (t < int(col.size())) row.push_back(&col[t]);
      char name[128];
      std::snprintf(name, sizeof(name), "/%s_frame%03llu.png", a.sheet_label.c_str(),
                    static_cast<unsigned long long>(split.test[t].sequence));
      EXO_RETURN_IF_ERROR(WriteColorImage(a.sheets_dir + name, Hstack(row)));
    }
  }
  return absl::OkStatus();
}

int Main(int argc, char** argv) {
  Args a;
  CLI::App app{
      "Product-path quality on real held-out 7-Scenes frames: a saved viewer model "
      "rendered with the Vulkan renderer at the held-out poses, beside fused "
      "per-vertex-colour meshes; one JSON line per method.",
      "exoview_product_eval"};
  cli::Setup(app);
  app.add_option("--data", a.data, "7-Scenes folder (required)");
  app.add_option("--model", a.model, "model saved by exoview_viewer --save_model");
  app.add_option("--hold_out_every", a.hold_out_every, "k: frames i % k == offset were held out")
      ->check(CLI::Range(2, 1000))
      ->capture_default_str();
  app.add_option("--hold_out_offset", a.hold_out_offset, "the fold (-1: k - 1)")
      ->check(CLI::Range(-1, 999))
      ->capture_default_str();
  app.add_option("--frames", a.frames, "first N frames of the dataset (0: all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max_views", a.max_views, "at most this many test views (0: all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--width", a.width, "render / test width (divides 640)")->capture_default_str();
  app.add_option("--height", a.height, "render / test height (divides 480)")->capture_default_str();
  app.add_option("--swap", a.swap,
                 "diagnostic: before the CPU oracle renders, replace each stored view's "
                 "color,depth,pose,exposure (any of them) by the ingested frame's, proxy by our fused mesh");
  app.add_flag("--cpu_oracle", a.cpu_oracle,
               "also render the store with the CPU oracle (common/lumigraph/cpu_renderer)");
  app.add_option("--ours", a.ours, "also our TSDF vertex-colour mesh (server defaults)")
      ->capture_default_str();
  app.add_option("--mesh_ply", a.mesh_ply,
                 "PLY:LABEL: a world-frame per-vertex-colour mesh to render beside (repeatable)");
  app.add_option("--sheets_dir", a.sheets_dir, "write contact sheets (real | ours | meshes) here");
  app.add_option("--sheet_views", a.sheet_views, "contact sheets of the first N test views")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--sheet_label", a.sheet_label, "file name prefix of the contact sheets");
  app.add_option("--write_registered", a.write_registered,
                 "write every frame's registered depth (mm PNG), colour and frames.json here and "
                 "exit");
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;
  if (a.data.empty()) {
    std::fprintf(stderr, "exoview_product_eval: --data is required\n");
    return 2;
  }
  if (a.width < 16 || a.height < 16 || a.width > 640 || a.height > 480) {
    std::fprintf(stderr,
                 "exoview_product_eval: --width/--height must be in [16, 640] x [16, 480]\n");
    return 2;
  }
  if (a.hold_out_offset >= a.hold_out_every) {
    std::fprintf(stderr, "exoview_product_eval: --hold_out_offset must be < --hold_out_every\n");
    return 2;
  }
  if (auto s = Run(a); !s.ok()) {
    std::fprintf(stderr, "exoview_product_eval: %s\n", s.ToString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
