// Writes the seed corpus of the fuzz targets (fuzz/corpus/{jpeg,depth,frame}/): valid inputs of
// each kind and the hostile inputs of issue 20. Run once by tools/fuzz/run_fuzz.sh when a corpus
// folder is empty; the seeds are committed.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/io/depth_codec.h"
#include "common/io/hostile_inputs.h"
#include "common/io/jpeg.h"
#include "proto/frame_proto.h"
#include "proto/model_proto.h"
#include "server/service/frame_journal.h"
#include "server/service/model_store.h"

namespace {
void Write(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}
std::string Str(const std::vector<uint8_t>& v) { return std::string(v.begin(), v.end()); }

exo::Frame SmallFrame(int w, int h) {
  exo::Frame f;
  f.sequence = 1;
  f.timestamp_s = 0.1;
  f.color_camera = exo::PinholeCamera::FromFov(w, h, 1.0);
  f.depth_camera = f.color_camera;
  f.color = exo::ImageU8(w, h, 3);
  f.depth_m = exo::ImageF(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c)
        f.color.at(x, y, c) = static_cast<uint8_t>(x * 9 + y * 5 + 60 * c);
      f.depth_m.at(x, y) = 1.0f + 0.02f * x;
    }
  f.world_from_cam.translation = {0.5, 0.2, 1.0};
  f.exposure = 1.0;
  return f;
}
}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_seeds CORPUS_DIR\n");
    return 2;
  }
  const std::string root = argv[1];
  for (const char* d : {"jpeg", "depth", "frame", "delta", "checkpoint"})
    std::filesystem::create_directories(root + "/" + d);
  const exo::Frame f = SmallFrame(16, 12);
  Write(root + "/jpeg/baseline_16x12.jpg", Str(*exo::EncodeJpeg(f.color, 80)));
  Write(root + "/jpeg/progressive_640_scans.jpg",
        Str(exo::hostile::ManyScanProgressiveJpeg(16, 8)));
  exo::ImageU16 d(16, 12);
  for (int y = 0; y < 12; ++y)
    for (int x = 0; x < 16; ++x) d.at(x, y) = static_cast<uint16_t>(1000 + 7 * x + 3 * y);
  for (exo::DepthCodec c : {exo::DepthCodec::kRawZstd, exo::DepthCodec::kDeltaZstd,
                            exo::DepthCodec::kDeltaPlanesZstd, exo::DepthCodec::kPng}) {
    exo::DepthCodecOptions o;
    o.codec = c;
    Write(root + "/depth/" + std::string(exo::DepthCodecName(c)) + ".exd",
          Str(*exo::EncodeDepth(d, o)));
  }
  Write(root + "/depth/pgm_in_png.exd",
        exo::hostile::DepthStream(4, 8, 6, exo::hostile::Pgm16(8, 6)));
  Write(root + "/depth/png_header_16384.exd",
        exo::hostile::DepthStream(4, 16, 12, exo::hostile::PngHeader(16384, 16384)));
  auto msg = exo::FrameToProto(f, {});
  Write(root + "/frame/small.pb", msg->SerializeAsString());
  exo::v1::Frame bad = *msg;
  bad.set_exposure(1e300);
  bad.mutable_color_intrinsics()->set_cx(1e300);
  Write(root + "/frame/absurd_values.pb", bad.SerializeAsString());
  exo::Frame unreg = f;
  unreg.depth_camera = exo::PinholeCamera::FromFov(8, 6, 1.0);
  unreg.depth_m = exo::ImageF(8, 6, 1, 1.5f);
  unreg.color_from_depth.translation = {0.02, 0, 0};
  Write(root + "/frame/unregistered_depth.pb", exo::FrameToProto(unreg, {})->SerializeAsString());
  // A small model as the server publishes it: scene, two views, a mesh chunk, cell references,
  // an update and a removal. Its checkpoint seeds checkpoint_fuzz; the snapshot a new client
  // gets plus the delta log seed delta_fuzz.
  {
    exo::ModelStore store;
    store.SetSceneParams(exo::LocalOrigin{}, 0.5);
    for (uint32_t id : {1u, 2u}) {
      exo::StoredView v;
      v.id = id;
      v.camera = f.color_camera;
      v.color = f.color;
      v.depth_m = f.depth_m;
      v.local_from_cam.translation = {0.1 * id, 0, 0};
      store.AddView(*exo::ViewToProto(v, {}));
    }
    exo::TriangleMesh mesh;
    mesh.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    mesh.indices = {0, 1, 2};
    store.UpsertChunk(7, 1, mesh);
    store.SetCellRefs({{exo::CellId{42}, {1, 2}}});
    exo::Rigid3d moved;
    moved.translation = {0.3, 0.1, 0};
    (void)store.UpdateView(2, moved, 1.2f);
    store.BeginApply();
    store.EndApply(5, "drone-1", 9);
    Write(root + "/checkpoint/small_model.ckpt", store.MakeCheckpoint(1 << 20).SerializeAsString());
    exo::v1::Checkpoint batch;
    auto sub = store.Subscribe(0, 0);
    for (const auto& d : sub->Next(0)) *batch.add_model() = *d;
    Write(root + "/delta/snapshot.pb", batch.SerializeAsString());
    exo::v1::Checkpoint log = store.MakeCheckpoint(1 << 20);
    log.clear_model();
    Write(root + "/delta/log.pb", log.SerializeAsString());
    exo::JournalRecord r;
    r.lsn = 3;
    r.sequence = 17;
    r.uploader = "uploader:drone-1/cam0";
    r.frame = msg->SerializeAsString();
    Write(root + "/checkpoint/journal_record.bin", exo::EncodeJournalRecord(r));
  }
  std::printf("seeds written to %s\n", root.c_str());
  return 0;
}
