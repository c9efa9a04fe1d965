// exoview_export: writes a saved model in the formats Open3D, MeshLab, COLMAP and the TUM tools
// read: the proxy mesh as binary PLY with normals, the stored views' poses as a TUM trajectory
// and a COLMAP text model (with the stored colour images), plus export.json (what was written).
// Input: a server checkpoint (exoview_server --checkpoint_path) or a model file
// (exoview_viewer --save_model, exoview_render --save_model). Conventions: docs/export.md.
//   exoview_export (--checkpoint FILE | --model FILE) --out DIR [--frame world|local] [--no_images]
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "client/store/local_store.h"
#include "common/cli/cli.h"
#include "common/interop/interop.h"
#include "common/lumigraph/model_io.h"
#include "proto/exoview.pb.h"

namespace {

// A checkpoint's model deltas (the snapshot without its begin/end markers) into a model.
absl::StatusOr<exo::LumigraphModel> LoadCheckpoint(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError("cannot open checkpoint " + path);
  exo::v1::Checkpoint c;
  if (!c.ParseFromIstream(&in))
    return absl::DataLossError("not a checkpoint (protobuf parse failed): " + path);
  if (c.format() != 1)
    return absl::InvalidArgumentError("checkpoint format " + std::to_string(c.format()) +
                                      " is not 1: " + path);
  exo::LocalStore store;
  exo::v1::Delta begin, end;
  begin.mutable_snapshot_begin();
  end.mutable_snapshot_end();
  end.set_version(c.version());
  EXO_RETURN_IF_ERROR(store.Apply(begin));
  for (const exo::v1::Delta& d : c.model()) EXO_RETURN_IF_ERROR(store.Apply(d));
  EXO_RETURN_IF_ERROR(store.Apply(end));
  return store.model();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Exports a checkpoint or a model file as PLY mesh, TUM trajectory and COLMAP text.",
               "exoview_export"};
  exo::cli::Setup(app);
  std::string checkpoint, model_path, out, frame = "world";
  bool no_images = false;
  int jpeg_quality = 95;
  auto* ck = app.add_option("--checkpoint", checkpoint, "server checkpoint file")
                 ->check(CLI::ExistingFile);
  auto* mo = app.add_option("--model", model_path, "model file (exoview_viewer --save_model)")
                 ->check(CLI::ExistingFile);
  ck->excludes(mo);
  app.add_option("--out", out, "output folder (created; required)");
  app.add_option("--frame", frame, "coordinates: world (origin added) or local")
      ->check(CLI::IsMember({"world", "local"}));
  app.add_flag("--no_images", no_images, "do not write the stored colour images");
  app.add_option("--jpeg_quality", jpeg_quality, "quality of the written images")
      ->check(CLI::Range(1, 100));
  if (auto rc = exo::cli::Parse(app, argc, argv)) return *rc;
  if (out.empty()) {
    std::fprintf(stderr, "exoview_export: --out DIR is required\n");
    return 2;
  }
  if (checkpoint.empty() == model_path.empty()) {
    std::fprintf(stderr, "exoview_export: give one of --checkpoint or --model\n");
    return 2;
  }

  auto model = checkpoint.empty() ? exo::LoadModel(model_path) : LoadCheckpoint(checkpoint);
  if (!model.ok()) {
    std::fprintf(stderr, "exoview_export: %s\n", std::string(model.status().message()).c_str());
    return 1;
  }
  exo::interop::ExportOptions eo;
  eo.frame =
      frame == "local" ? exo::interop::ExportFrame::kLocal : exo::interop::ExportFrame::kWorld;
  eo.write_images = !no_images;
  eo.image_jpeg_quality = jpeg_quality;
  auto sum = exo::interop::ExportModel(*model, out, eo);
  if (!sum.ok()) {
    std::fprintf(stderr, "exoview_export: %s\n", std::string(sum.status().message()).c_str());
    return 1;
  }
  nlohmann::json j = {
      {"input", checkpoint.empty() ? model_path : checkpoint},
      {"input_kind", checkpoint.empty() ? "model" : "checkpoint"},
      {"model_version", model->version},
      {"frame", sum->frame},
      {"origin_in_world", {sum->origin_in_world.x, sum->origin_in_world.y, sum->origin_in_world.z}},
      {"views", sum->views},
      {"colmap_cameras", sum->colmap_cameras},
      {"mesh_vertices", sum->mesh_vertices},
      {"mesh_triangles", sum->mesh_triangles},
      {"dropped_degenerate_triangles", sum->dropped_triangles},
      {"dropped_unused_vertices", sum->dropped_vertices},
      {"files", sum->files}};
  std::ofstream(out + "/export.json") << j.dump(2) << "\n";
  std::printf(
      "exoview_export: %zu views, mesh %zu vertices / %zu triangles -> %s "
      "(mesh.ply, trajectory.tum, colmap/, export.json)\n",
      sum->views, sum->mesh_vertices, sum->mesh_triangles, out.c_str());
  return 0;
}
