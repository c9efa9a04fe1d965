// Conversion between the exoview.v1 wire messages and the domain types (exo::Frame, poses,
// intrinsics, meshes), with the ingest validation of SPEC §12: every bad field becomes a clear
// absl::Status (InvalidArgument) that the server puts on the frame's ack (reason and Ack.code).
// No gRPC here, only the generated protobuf messages; both the server and the clients link this
// (`exoview_wire`).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "common/camera.h"
#include "common/frame.h"
#include "common/image.h"
#include "common/mesh.h"
#include "common/rigid3.h"
#include "common/status.h"
#include "proto/exoview.pb.h"
#include "proto/frame_limits.h"

namespace exo {

namespace v1 = ::exoview::v1;

// Pose: the quaternion or the 3x3 matrix is validated (finite, unit / orthonormal, det +1). Within
// kRotationRepairTolerance (common/rigid3.h) a rotation is projected to SO(3) (nearest rotation,
// normalised quaternion) and accepted; farther it is rejected with the measured error.
void PoseToProto(const Rigid3d& pose, v1::Pose* out);
absl::StatusOr<Rigid3d> PoseFromProto(const v1::Pose& pose);

void IntrinsicsToProto(const PinholeCamera& camera, v1::Intrinsics* out);
// "missing intrinsics" (all zero / absent message) and invalid values are errors.
absl::StatusOr<PinholeCamera> IntrinsicsFromProto(const v1::Intrinsics& intrinsics);

// Depth: encodes metres as u16 with `metres_per_unit` using the lossless common/io codec.
void DepthToProto(const ImageF& depth_m, double metres_per_unit, v1::DepthImage* out,
                  int zstd_level = 1);
// The size (against `limits`) and the codec header are checked before anything is allocated; the
// depth scale must lie within the limits.
absl::StatusOr<ImageF> DepthFromProto(const v1::DepthImage& depth, const FrameLimits& limits = {});

// Frame for upload: colour re-encoded as JPEG of `jpeg_quality`, depth losslessly as u16.
struct FrameEncodeOptions {
  int jpeg_quality = 90;
  double depth_metres_per_unit = 0.001;
  absl::Status Validate() const;
};
absl::StatusOr<v1::Frame> FrameToProto(const Frame& frame, const FrameEncodeOptions& options);

// Full ingest decode + validation of one uploaded frame: every plausibility limit of
// frame_limits.h, sizes checked before any decode allocates. `pose_required` = false when the
// server has a UDP pose stream (the pose may then be absent and is filled in by the caller, who
// then runs CheckFrame).
struct FrameDecodeOptions {
  bool pose_required = true;
  FrameLimits limits;
};
absl::StatusOr<Frame> FrameFromProto(const v1::Frame& msg, const FrameDecodeOptions& options);

// Ack.code <-> absl::StatusCode (same names and numbers as google.rpc.Code); a code outside the
// enum becomes UNKNOWN.
v1::Ack::Code AckCodeFromStatus(absl::StatusCode code);
absl::StatusCode StatusCodeFromAck(v1::Ack::Code code);

// Mesh chunks on the wire. MeshToProto writes the compact encoding (MeshChunkUpserted.compact:
// positions quantized to 16 bits over the chunk's bounding box, i.e. to ~1/131 000 of its
// extent, delta-coded indices, no normals; 2.7x smaller than the plain floats on 7-Scenes);
// `plain` writes the float fields with the mesh's normals. MeshFromProto reads both and checks
// every index.
//
// MeshWireOptions::step_m > 0 (the server's choice: a fraction of its voxel) writes format 3
// instead: positions quantized to that step on a grid snapped to multiples of the step (so the
// on-grid coordinates of marching-cubes vertices land on exact integers), triangles in vertex-cache
// order and vertices in first-use order, both through meshoptimizer's vertex and index codecs,
// then zstd. The decoded position is within step_m / 2 of the input (per coordinate); a chunk
// wider than 65 535 steps uses the coarser step extent / 65 535 instead. Triangle order may change
// (each triangle keeps its winding); the mesh's normals and colours are not sent.
struct MeshWireOptions {
  float step_m = 0.0f;  // 0: format 1/2 (16 bits over the chunk's bounding box)
};
void MeshToProto(const TriangleMesh& mesh, v1::MeshChunkUpserted* out, bool plain = false,
                 const MeshWireOptions& options = {});
absl::StatusOr<TriangleMesh> MeshFromProto(const v1::MeshChunkUpserted& msg);

// Cell references on the wire (CellRefsChanged.packed): PackCellRefs replaces the cells and
// coverage of `msg` by their zstd-packed form when that is smaller (an empty or tiny message is
// left as it is); UnpackCellRefs returns the plain message (a plain input unchanged; a packed one
// decoded, bounded in size, and rejected if it is corrupt, nests another packed payload, or also
// carries plain entries).
void PackCellRefs(v1::CellRefsChanged* msg);
absl::StatusOr<v1::CellRefsChanged> UnpackCellRefs(const v1::CellRefsChanged& msg);

// Mesh chunks of a snapshot on the wire (Delta.mesh_chunk_batch). PackMeshChunks puts the chunks
// into one zstd frame at `level`, each chunk's `compact` unwrapped from format 2 to its format 1/3
// bytes (the mesh it decodes to is unchanged); a plain (float) chunk goes in as it is.
// UnpackMeshChunks decodes and bounds the frame and returns the chunks (their meshes are checked
// when applied, by MeshFromProto).
absl::StatusOr<v1::MeshChunkBatch> PackMeshChunks(
    std::span<const v1::MeshChunkUpserted* const> chunks, int level = 6);
absl::StatusOr<std::vector<v1::MeshChunkUpserted>> UnpackMeshChunks(const v1::MeshChunkBatch& batch);

}  // namespace exo
