// Writes a lumigraph model in the formats that Open3D, MeshLab, COLMAP and the TUM RGB-D tools
// read: the proxy mesh as binary PLY with per-vertex normals, the stored views' poses as a TUM
// trajectory and as a COLMAP text model (cameras.txt, images.txt, points3D.txt), optionally with
// the stored colour images. Pure library: files in, files out, no network or GPU.
//
// Conventions (documented in docs/export.md):
// - Frame: world (scene-local + the model's origin_in_world, default) or the scene-local frame.
// - TUM: one line per stored view, `timestamp tx ty tz qx qy qz qw`, camera-to-world, camera x
//   right / y down / z forward; the timestamp column is the view id (stored views carry no
//   capture time; ids increase in arrival order).
// - COLMAP: PINHOLE cameras (one per distinct intrinsics; COLMAP puts the centre of the top-left
//   pixel at (0.5, 0.5), Exoview at (0, 0), so cx, cy are written + 0.5); images.txt has
//   world-to-camera `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` (IMAGE_ID = view id) and an
//   empty 2D-points line per image; points3D.txt is empty (header only).
// - PLY: triangles of zero area and vertices no triangle uses are dropped; a vertex's normal is
//   the area-weighted mean of its triangles' normals (the chunk's own normals when every chunk
//   carries them), unit length.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <string>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"

namespace exo::interop {

enum class ExportFrame { kWorld, kLocal };

struct ExportOptions {
  ExportFrame frame = ExportFrame::kWorld;
  bool write_images = true;  // images/view_<id>.jpg beside the COLMAP model
  int image_jpeg_quality = 95;
  absl::Status Validate() const;
};

// A mesh ready to write: positions, unit normals, triangles (3 indices each).
struct NormalMesh {
  std::vector<glm::vec3> positions;
  std::vector<glm::vec3> normals;
  std::vector<uint32_t> indices;
  size_t dropped_triangles = 0;  // zero area
  size_t dropped_vertices = 0;   // used by no remaining triangle
};

// Drops degenerate triangles and unused vertices, offsets positions by `offset` (computed in
// double before the float cast) and gives every vertex a unit normal (see above). Errors:
// indices out of range or not a multiple of 3.
absl::StatusOr<NormalMesh> PrepareMesh(const TriangleMesh& mesh, const glm::dvec3& offset);

// Binary little-endian PLY: vertex x y z nx ny nz (float), face vertex_indices (uchar, int).
absl::Status WritePly(const std::string& path, const NormalMesh& mesh,
                      const std::vector<std::string>& comments);

struct PosedView {
  uint32_t id = 0;
  PinholeCamera camera;
  Rigid3d world_from_cam;
};

// The quaternion written for a rotation: unit, w >= 0.
glm::dquat CanonicalQuaternion(const glm::dquat& q);

absl::Status WriteTumTrajectory(const std::string& path, const std::vector<PosedView>& views);
// Writes cameras.txt, images.txt and points3D.txt into `dir` (created). Image names are
// `image_names[i]` (same order as views).
absl::Status WriteColmapText(const std::string& dir, const std::vector<PosedView>& views,
                             const std::vector<std::string>& image_names);

struct ExportSummary {
  std::string frame;  // "world" | "local"
  glm::dvec3 origin_in_world{0.0};
  size_t views = 0;
  size_t colmap_cameras = 0;
  size_t mesh_vertices = 0, mesh_triangles = 0;
  size_t dropped_triangles = 0, dropped_vertices = 0;
  std::vector<std::string> files;  // relative to the output folder
};

// Writes mesh.ply, trajectory.tum, colmap/{cameras,images,points3D}.txt and (optionally)
// colmap/images/view_<id>.jpg into `dir` (created). A model without views or without mesh
// triangles still exports what it has (empty files, counts 0).
absl::StatusOr<ExportSummary> ExportModel(const LumigraphModel& model, const std::string& dir,
                                          const ExportOptions& options = {});

}  // namespace exo::interop
