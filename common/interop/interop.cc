#include "common/interop/interop.h"

#include <bit>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <tuple>

#include "absl/strings/str_format.h"
#include "common/io/image_file.h"

namespace exo::interop {
namespace {

namespace fs = std::filesystem;

absl::Status CreateDir(const std::string& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot create ", dir, ": ", ec.message()));
  return absl::OkStatus();
}

// Writes `text` to `path` through a temporary file (never a half-written export).
absl::Status WriteText(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return absl::InternalError(absl::StrCat("cannot write ", tmp));
    out << text;
    if (!out.flush()) return absl::InternalError(absl::StrCat("write failed: ", tmp));
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) return absl::InternalError(absl::StrCat("cannot rename ", tmp, ": ", ec.message()));
  return absl::OkStatus();
}

template <typename T>
void Put(std::string* out, const T& v) {
  static_assert(std::endian::native == std::endian::little, "PLY writer assumes little endian");
  out->append(reinterpret_cast<const char*>(&v), sizeof(T));
}

}  // namespace

absl::Status ExportOptions::Validate() const {
  if (image_jpeg_quality < 1 || image_jpeg_quality > 100)
    return absl::InvalidArgumentError("export: image_jpeg_quality must be in [1, 100]");
  return absl::OkStatus();
}

absl::StatusOr<NormalMesh> PrepareMesh(const TriangleMesh& mesh, const glm::dvec3& offset) {
  if (mesh.indices.size() % 3 != 0)
    return absl::InvalidArgumentError("mesh: index count is not a multiple of 3");
  const size_t nv = mesh.positions.size();
  for (uint32_t i : mesh.indices)
    if (i >= nv)
      return absl::InvalidArgumentError(absl::StrCat("mesh: index ", i, " >= vertex count ", nv));
  const bool own_normals = mesh.normals.size() == nv && nv > 0;

  // Keep triangles of non-zero area (double precision cross product of the float corners).
  NormalMesh out;
  std::vector<glm::dvec3> acc(nv, glm::dvec3(0.0));
  std::vector<glm::dvec3> largest(nv, glm::dvec3(0.0));  // fallback: normal of the largest face
  std::vector<double> largest_area(nv, 0.0);
  std::vector<uint32_t> kept;
  kept.reserve(mesh.indices.size());
  for (size_t t = 0; t < mesh.indices.size(); t += 3) {
    const uint32_t a = mesh.indices[t], b = mesh.indices[t + 1], c = mesh.indices[t + 2];
    const glm::dvec3 pa(mesh.positions[a]), pb(mesh.positions[b]), pc(mesh.positions[c]);
    const glm::dvec3 n2 = glm::cross(pb - pa, pc - pa);  // |n2| = 2 * area
    const double len = glm::length(n2);
    if (!(len > 0.0) || !std::isfinite(len)) {
      ++out.dropped_triangles;
      continue;
    }
    for (uint32_t v : {a, b, c}) {
      acc[v] += n2;  // area weighted
      if (len > largest_area[v]) {
        largest_area[v] = len;
        largest[v] = n2 / len;
      }
    }
    kept.insert(kept.end(), {a, b, c});
  }
  // Compact: only vertices a kept triangle uses.
  std::vector<uint32_t> remap(nv, UINT32_MAX);
  for (uint32_t v : kept)
    if (remap[v] == UINT32_MAX) {
      remap[v] = static_cast<uint32_t>(out.positions.size());
      out.positions.push_back(glm::vec3(glm::dvec3(mesh.positions[v]) + offset));
      glm::dvec3 n = own_normals ? glm::dvec3(mesh.normals[v]) : acc[v];
      double len = glm::length(n);
      if (!(len > 1e-12) || !std::isfinite(len)) {  // opposite faces cancel, or a zero normal
        n = largest[v];
        len = 1.0;
      }
      out.normals.push_back(glm::vec3(n / len));
    }
  out.dropped_vertices = nv - out.positions.size();
  out.indices.reserve(kept.size());
  for (uint32_t v : kept) out.indices.push_back(remap[v]);
  return out;
}

absl::Status WritePly(const std::string& path, const NormalMesh& mesh,
                      const std::vector<std::string>& comments) {
  if (mesh.normals.size() != mesh.positions.size() || mesh.indices.size() % 3 != 0)
    return absl::InvalidArgumentError("ply: inconsistent mesh");
  if (mesh.positions.size() > size_t{INT32_MAX})
    return absl::InvalidArgumentError("ply: too many vertices for int indices");
  std::string s = "ply\nformat binary_little_endian 1.0\n";
  for (const std::string& c : comments) {
    if (c.find('\n') != std::string::npos)
      return absl::InvalidArgumentError("ply: a comment must be one line");
    absl::StrAppend(&s, "comment ", c, "\n");
  }
  absl::StrAppend(&s, "element vertex ", mesh.positions.size(), "\n",
                  "property float x\nproperty float y\nproperty float z\n",
                  "property float nx\nproperty float ny\nproperty float nz\n", "element face ",
                  mesh.indices.size() / 3, "\n",
                  "property list uchar int vertex_indices\nend_header\n");
  s.reserve(s.size() + mesh.positions.size() * 24 + mesh.indices.size() / 3 * 13);
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    for (int k = 0; k < 3; ++k) Put(&s, mesh.positions[i][k]);
    for (int k = 0; k < 3; ++k) Put(&s, mesh.normals[i][k]);
  }
  for (size_t t = 0; t < mesh.indices.size(); t += 3) {
    Put(&s, uint8_t{3});
    for (int k = 0; k < 3; ++k) Put(&s, static_cast<int32_t>(mesh.indices[t + k]));
  }
  return WriteText(path, s);
}

glm::dquat CanonicalQuaternion(const glm::dquat& q) {
  glm::dquat n = glm::normalize(q);
  if (n.w < 0) n = -n;
  return n;
}

absl::Status WriteTumTrajectory(const std::string& path, const std::vector<PosedView>& views) {
  std::string s =
      "# exoview stored views: timestamp(view id) tx ty tz qx qy qz qw, camera-to-world\n";
  for (const PosedView& v : views) {
    const glm::dquat q = CanonicalQuaternion(v.world_from_cam.rotation);
    const glm::dvec3& t = v.world_from_cam.translation;
    absl::StrAppend(&s, absl::StrFormat("%u %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", v.id, t.x,
                                        t.y, t.z, q.x, q.y, q.z, q.w));
  }
  return WriteText(path, s);
}

absl::Status WriteColmapText(const std::string& dir, const std::vector<PosedView>& views,
                             const std::vector<std::string>& image_names) {
  if (image_names.size() != views.size())
    return absl::InvalidArgumentError("colmap: one image name per view");
  EXO_RETURN_IF_ERROR(CreateDir(dir));
  // One PINHOLE camera per distinct intrinsics, ids from 1 in order of first use.
  using Key = std::tuple<int, int, double, double, double, double>;
  std::map<Key, int> ids;
  std::vector<int> camera_of(views.size());
  std::string cams =
      "# Camera list with one line of data per camera:\n"
      "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  std::string cam_lines;
  for (size_t i = 0; i < views.size(); ++i) {
    const PinholeCamera& c = views[i].camera;
    EXO_RETURN_IF_ERROR(c.Validate());
    const Key k{c.width, c.height, c.fx, c.fy, c.cx, c.cy};
    auto [it, added] = ids.emplace(k, static_cast<int>(ids.size()) + 1);
    if (added)
      absl::StrAppend(&cam_lines,
                      absl::StrFormat("%d PINHOLE %d %d %.17g %.17g %.17g %.17g\n", it->second,
                                      c.width, c.height, c.fx, c.fy, c.cx + 0.5, c.cy + 0.5));
    camera_of[i] = it->second;
  }
  absl::StrAppend(&cams, "# Number of cameras: ", ids.size(), "\n", cam_lines);

  std::string imgs =
      "# Image list with two lines of data per image:\n"
      "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      "#   POINTS2D[] as (X, Y, POINT3D_ID)\n";
  absl::StrAppend(&imgs, "# Number of images: ", views.size(),
                  ", mean observations per image: 0\n");
  for (size_t i = 0; i < views.size(); ++i) {
    if (image_names[i].empty() || image_names[i].find_first_of(" \n") != std::string::npos)
      return absl::InvalidArgumentError(
          absl::StrCat("colmap: bad image name '", image_names[i], "'"));
    const Rigid3d cam_from_world = views[i].world_from_cam.Inverse();
    const glm::dquat q = CanonicalQuaternion(cam_from_world.rotation);
    const glm::dvec3& t = cam_from_world.translation;
    absl::StrAppend(&imgs, absl::StrFormat("%u %.17g %.17g %.17g %.17g %.17g %.17g %.17g %d %s\n\n",
                                           views[i].id, q.w, q.x, q.y, q.z, t.x, t.y, t.z,
                                           camera_of[i], image_names[i]));
  }
  const std::string pts =
      "# 3D point list with one line of data per point:\n"
      "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
      "# Number of points: 0, mean track length: 0\n";
  EXO_RETURN_IF_ERROR(WriteText(dir + "/cameras.txt", cams));
  EXO_RETURN_IF_ERROR(WriteText(dir + "/images.txt", imgs));
  return WriteText(dir + "/points3D.txt", pts);
}

absl::StatusOr<ExportSummary> ExportModel(const LumigraphModel& model, const std::string& dir,
                                          const ExportOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(CreateDir(dir));
  const bool world = options.frame == ExportFrame::kWorld;
  const glm::dvec3 offset = world ? model.origin.origin_in_world : glm::dvec3(0.0);
  ExportSummary sum;
  sum.frame = world ? "world" : "local";
  sum.origin_in_world = model.origin.origin_in_world;

  // Mesh: every chunk, with its own normals only when every chunk carries them.
  TriangleMesh all;
  bool all_normals = !model.chunks.empty();
  for (const auto& [id, c] : model.chunks)
    all_normals = all_normals && c.mesh.normals.size() == c.mesh.positions.size();
  for (const auto& [id, c] : model.chunks) {
    TriangleMesh m;
    m.positions = c.mesh.positions;
    m.indices = c.mesh.indices;
    if (all_normals) m.normals = c.mesh.normals;
    all.Append(m);
  }
  EXO_ASSIGN_OR_RETURN(NormalMesh nm, PrepareMesh(all, offset));
  sum.mesh_vertices = nm.positions.size();
  sum.mesh_triangles = nm.indices.size() / 3;
  sum.dropped_triangles = nm.dropped_triangles;
  sum.dropped_vertices = nm.dropped_vertices;
  EXO_RETURN_IF_ERROR(
      WritePly(dir + "/mesh.ply", nm,
               {"exoview proxy mesh", absl::StrFormat("frame %s", sum.frame),
                absl::StrFormat("origin_in_world %.17g %.17g %.17g", offset.x, offset.y, offset.z),
                absl::StrCat("model_version ", model.version)}));
  sum.files.push_back("mesh.ply");

  std::vector<PosedView> views;
  std::vector<std::string> names;
  for (const auto& [id, v] : model.views) {
    PosedView p;
    p.id = id;
    p.camera = v.camera;
    p.world_from_cam = v.local_from_cam;
    p.world_from_cam.translation += offset;
    views.push_back(p);
    names.push_back(absl::StrFormat("view_%06u.jpg", id));
  }
  sum.views = views.size();
  EXO_RETURN_IF_ERROR(WriteTumTrajectory(dir + "/trajectory.tum", views));
  sum.files.push_back("trajectory.tum");
  EXO_RETURN_IF_ERROR(WriteColmapText(dir + "/colmap", views, names));
  for (const char* f : {"colmap/cameras.txt", "colmap/images.txt", "colmap/points3D.txt"})
    sum.files.push_back(f);
  {
    std::map<std::tuple<int, int, double, double, double, double>, int> distinct;
    for (const PosedView& p : views)
      distinct[{p.camera.width, p.camera.height, p.camera.fx, p.camera.fy, p.camera.cx,
                p.camera.cy}] = 1;
    sum.colmap_cameras = distinct.size();
  }
  if (options.write_images) {
    EXO_RETURN_IF_ERROR(CreateDir(dir + "/colmap/images"));
    size_t i = 0;
    for (const auto& [id, v] : model.views) {
      const std::string rel = "colmap/images/" + names[i++];
      if (v.color.empty()) return absl::DataLossError(absl::StrCat("view ", id, " has no colour"));
      EXO_RETURN_IF_ERROR(WriteColorImage(dir + "/" + rel, v.color, options.image_jpeg_quality));
      sum.files.push_back(rel);
    }
  }
  return sum;
}

}  // namespace exo::interop
