// Stored views, mesh chunks and cell references on the wire (exoview.v1 Delta payloads), and the
// model digest both ends compute to prove that a client's local store equals the server's model.
// What a view costs on the wire is set here (ViewEncodeOptions): JPEG quality of the colour and
// the downscale of the lossless depth (SPEC §10: <= 8 MB for a 200-view initial sync).
#pragma once

#include <cstdint>
#include <map>
#include <span>
#include <unordered_map>
#include <vector>

#include "common/lumigraph/model.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_proto.h"

namespace exo {

struct ViewEncodeOptions {
  int jpeg_quality = 50;
  bool jpeg_optimize = true;          // Huffman tables optimised per view (same pixels, ~7 % fewer bytes)
  int depth_downscale = 4;            // depth sent at 1/k resolution (nearest valid sample)
  int depth_zstd_level = 9;           // the lossless depth codec's zstd level (1..19; 9: service_bench initial sync 7.68 -> 7.46 MB against 1)
  double depth_metres_per_unit = 0.001;
  absl::Status Validate() const;
};

absl::StatusOr<v1::ViewAdded> ViewToProto(const StoredView& view, const ViewEncodeOptions& options);
// Decodes colour and depth; depth is brought back to the colour size (nearest neighbour), so
// the StoredView invariant "depth same size as colour" holds on the client.
absl::StatusOr<StoredView> ViewFromProto(const v1::ViewAdded& msg);

// 64-bit FNV-1a (stable across processes and machines, unlike absl::Hash).
uint64_t Fnv1a64(std::span<const uint8_t> bytes, uint64_t h = 0xcbf29ce484222325ull);
uint64_t MeshHash(const TriangleMesh& mesh);

// What the digest covers for one view: identity, camera, pose, exposure and the exact bytes
// that were published for it.
struct ViewDigestRecord {
  ViewId id = 0;
  PinholeCamera camera;
  Rigid3d local_from_cam;
  float exposure = 1.0f;
  uint64_t color_hash = 0;
  uint64_t depth_hash = 0;
};
ViewDigestRecord DigestRecordFromProto(const v1::ViewAdded& msg);

struct ChunkDigestRecord {
  uint64_t version = 0;
  uint64_t mesh_hash = 0;
};

// Order-independent inputs are sorted inside, so equal models give equal digests.
uint64_t ModelDigest(const std::map<ViewId, ViewDigestRecord>& views,
                     const std::unordered_map<CellId, std::vector<ViewId>>& cell_refs,
                     const std::map<uint64_t, ChunkDigestRecord>& chunks);

}  // namespace exo
