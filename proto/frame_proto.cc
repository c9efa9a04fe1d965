#include "proto/frame_proto.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <meshoptimizer.h>

#include "common/io/depth_codec.h"
#include "common/io/jpeg.h"
#include "common/io/zstd.h"

namespace exo {

void PoseToProto(const Rigid3d& pose, v1::Pose* out) {
  auto* q = out->mutable_quaternion();
  q->set_w(pose.rotation.w);
  q->set_x(pose.rotation.x);
  q->set_y(pose.rotation.y);
  q->set_z(pose.rotation.z);
  auto* t = out->mutable_translation();
  t->set_x(pose.translation.x);
  t->set_y(pose.translation.y);
  t->set_z(pose.translation.z);
}

// The wire enum mirrors google.rpc.Code, which absl::StatusCode follows number for number.
static_assert(static_cast<int>(absl::StatusCode::kOk) == v1::Ack::OK);
static_assert(static_cast<int>(absl::StatusCode::kInvalidArgument) == v1::Ack::INVALID_ARGUMENT);
static_assert(static_cast<int>(absl::StatusCode::kResourceExhausted) ==
              v1::Ack::RESOURCE_EXHAUSTED);
static_assert(static_cast<int>(absl::StatusCode::kFailedPrecondition) ==
              v1::Ack::FAILED_PRECONDITION);
static_assert(static_cast<int>(absl::StatusCode::kUnavailable) == v1::Ack::UNAVAILABLE);
static_assert(static_cast<int>(absl::StatusCode::kUnauthenticated) == v1::Ack::UNAUTHENTICATED);
static_assert(v1::Ack::Code_MAX == v1::Ack::UNAUTHENTICATED);

v1::Ack::Code AckCodeFromStatus(absl::StatusCode code) {
  const int c = static_cast<int>(code);
  return v1::Ack::Code_IsValid(c) ? static_cast<v1::Ack::Code>(c) : v1::Ack::UNKNOWN;
}

absl::StatusCode StatusCodeFromAck(v1::Ack::Code code) {
  return v1::Ack::Code_IsValid(code) ? static_cast<absl::StatusCode>(code)
                                     : absl::StatusCode::kUnknown;
}

absl::StatusOr<Rigid3d> PoseFromProto(const v1::Pose& pose) {
  Rigid3d out;
  switch (pose.rotation_case()) {
    case v1::Pose::kQuaternion: {
      const auto& q = pose.quaternion();
      const glm::dquat quat(q.w(), q.x(), q.y(), q.z());
      if (!std::isfinite(q.w()) || !std::isfinite(q.x()) || !std::isfinite(q.y()) ||
          !std::isfinite(q.z()))
        return absl::InvalidArgumentError("quaternion has a non-finite component (NaN or Inf)");
      const double norm = glm::length(quat);
      if (std::abs(norm - 1.0) > kRotationRepairTolerance)
        return absl::InvalidArgumentError(
            absl::StrCat("quaternion is not unit: |q| = ", norm, ", ||q| - 1| > ",
                         kRotationRepairTolerance, " (closer ones are normalised)"));
      // Unit within the strict tolerance: exactly as sent (keeps client/server bit-identical);
      // otherwise projected to a unit quaternion.
      out.rotation = std::abs(norm - 1.0) <= kRotationTolerance ? quat : quat / norm;
      break;
    }
    case v1::Pose::kMatrix: {
      const auto& m = pose.matrix();
      if (m.row_major_size() != 9)
        return absl::InvalidArgumentError(
            absl::StrCat("rotation matrix has ", m.row_major_size(), " values, expected 9"));
      std::array<double, 9> r;
      for (int i = 0; i < 9; ++i) r[i] = m.row_major(i);
      // Within kRotationRepairTolerance of orthonormal: the nearest rotation (SPEC §12).
      EXO_ASSIGN_OR_RETURN(const glm::dmat3 rm, ProjectToRotation(r));
      out.rotation = glm::normalize(glm::quat_cast(rm));
      break;
    }
    default:
      return absl::InvalidArgumentError("pose has no rotation (quaternion or matrix)");
  }
  const auto& t = pose.translation();
  out.translation = {t.x(), t.y(), t.z()};
  if (!std::isfinite(t.x()) || !std::isfinite(t.y()) || !std::isfinite(t.z()))
    return absl::InvalidArgumentError("pose translation has NaN or Inf");
  return out;
}

void IntrinsicsToProto(const PinholeCamera& c, v1::Intrinsics* out) {
  out->set_fx(c.fx);
  out->set_fy(c.fy);
  out->set_cx(c.cx);
  out->set_cy(c.cy);
  out->set_width(c.width);
  out->set_height(c.height);
}

absl::StatusOr<PinholeCamera> IntrinsicsFromProto(const v1::Intrinsics& in) {
  PinholeCamera c;
  c.fx = in.fx();
  c.fy = in.fy();
  c.cx = in.cx();
  c.cy = in.cy();
  c.width = in.width();
  c.height = in.height();
  EXO_RETURN_IF_ERROR(c.Validate());
  return c;
}

void DepthToProto(const ImageF& depth_m, double metres_per_unit, v1::DepthImage* out,
                  int zstd_level) {
  const ImageU16 raw = DepthU16FromMeters(depth_m, metres_per_unit);
  DepthCodecOptions o;
  o.zstd_level = zstd_level;
  auto encoded = EncodeDepth(raw, o);
  EXO_CHECK(encoded.ok());
  const std::vector<uint8_t>& bytes = *encoded;
  out->set_codec(v1::DEPTH_CODEC_EXO_U16);
  out->set_data(bytes.data(), bytes.size());
  out->set_width(raw.width());
  out->set_height(raw.height());
  out->set_depth_scale_m(metres_per_unit);
}

absl::StatusOr<ImageF> DepthFromProto(const v1::DepthImage& d, const FrameLimits& limits) {
  EXO_RETURN_IF_ERROR(CheckDepthScale(d.depth_scale_m(), limits));
  EXO_RETURN_IF_ERROR(CheckImageSize(d.width(), d.height(), limits, "depth image"));
  ImageU16 raw;
  switch (d.codec()) {
    case v1::DEPTH_CODEC_RAW_U16: {
      const size_t n = static_cast<size_t>(d.width()) * d.height();
      if (d.data().size() != n * 2)
        return absl::InvalidArgumentError(absl::StrCat(
            "raw depth has ", d.data().size(), " bytes, ", d.width(), "x", d.height(),
            " needs ", n * 2));
      raw = ImageU16(d.width(), d.height());
      std::memcpy(raw.data(), d.data().data(), n * 2);  // little-endian host
      break;
    }
    case v1::DEPTH_CODEC_EXO_U16: {
      const std::span<const uint8_t> bytes(reinterpret_cast<const uint8_t*>(d.data().data()),
                                           d.data().size());
      // The codec header first: its size must be the message's before anything is decoded.
      auto info = ReadDepthInfo(bytes);
      if (!info.ok())
        return absl::InvalidArgumentError(
            absl::StrCat("depth does not decode: ", info.status().message()));
      if (info->width != d.width() || info->height != d.height())
        return absl::InvalidArgumentError(
            absl::StrCat("depth decodes to ", info->width, "x", info->height,
                         " but the message says ", d.width(), "x", d.height()));
      auto decoded = DecodeDepth(bytes, limits.max_pixels);
      if (!decoded.ok())
        return absl::InvalidArgumentError(
            absl::StrCat("depth does not decode: ", decoded.status().message()));
      raw = *std::move(decoded);
      break;
    }
    default:
      return absl::InvalidArgumentError(
          absl::StrCat("unknown depth codec ", static_cast<int>(d.codec())));
  }
  return DepthMetersFromU16(raw, d.depth_scale_m());
}

absl::Status FrameEncodeOptions::Validate() const {
  if (jpeg_quality < 1 || jpeg_quality > 100)
    return absl::InvalidArgumentError("jpeg_quality must be in [1, 100]");
  if (!(depth_metres_per_unit > 0.0))
    return absl::InvalidArgumentError("depth_metres_per_unit must be > 0");
  return absl::OkStatus();
}

absl::StatusOr<v1::Frame> FrameToProto(const Frame& f, const FrameEncodeOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  v1::Frame msg;
  msg.set_sequence(f.sequence);
  msg.set_timestamp_s(f.timestamp_s);
  EXO_ASSIGN_OR_RETURN(std::vector<uint8_t> jpeg, EncodeJpeg(f.color, options.jpeg_quality));
  msg.set_color_jpeg(jpeg.data(), jpeg.size());
  if (!f.depth_m.empty()) DepthToProto(f.depth_m, options.depth_metres_per_unit, msg.mutable_depth());
  IntrinsicsToProto(f.color_camera, msg.mutable_color_intrinsics());
  const bool registered = f.depth_camera.fx == f.color_camera.fx &&
                          f.depth_camera.fy == f.color_camera.fy &&
                          f.depth_camera.cx == f.color_camera.cx &&
                          f.depth_camera.cy == f.color_camera.cy &&
                          f.depth_camera.width == f.color_camera.width &&
                          f.depth_camera.height == f.color_camera.height;
  if (!registered) {
    IntrinsicsToProto(f.depth_camera, msg.mutable_depth_intrinsics());
    PoseToProto(f.color_from_depth, msg.mutable_color_from_depth());
  }
  PoseToProto(f.world_from_cam, msg.mutable_world_from_cam());
  if (f.exposure) msg.set_exposure(*f.exposure);
  return msg;
}

absl::StatusOr<Frame> FrameFromProto(const v1::Frame& msg, const FrameDecodeOptions& options) {
  const FrameLimits& limits = options.limits;
  Frame f;
  f.sequence = msg.sequence();
  f.timestamp_s = msg.timestamp_s();
  EXO_RETURN_IF_ERROR(CheckTimestamp(msg.timestamp_s(), limits));
  if (!msg.has_color_intrinsics())
    return absl::InvalidArgumentError("missing intrinsics: the frame has no color_intrinsics");
  {
    auto cam = IntrinsicsFromProto(msg.color_intrinsics());
    if (!cam.ok())
      return absl::InvalidArgumentError(absl::StrCat("colour intrinsics: ", cam.status().message()));
    f.color_camera = *cam;
  }
  EXO_RETURN_IF_ERROR(CheckIntrinsics(f.color_camera, limits, "colour intrinsics"));
  f.depth_camera = f.color_camera;
  if (msg.has_depth_intrinsics()) {
    auto cam = IntrinsicsFromProto(msg.depth_intrinsics());
    if (!cam.ok())
      return absl::InvalidArgumentError(absl::StrCat("depth intrinsics: ", cam.status().message()));
    f.depth_camera = *cam;
    EXO_RETURN_IF_ERROR(CheckIntrinsics(f.depth_camera, limits, "depth intrinsics"));
  }
  if (msg.has_color_from_depth()) {
    auto p = PoseFromProto(msg.color_from_depth());
    if (!p.ok())
      return absl::InvalidArgumentError(
          absl::StrCat("depth-to-colour extrinsic: ", p.status().message()));
    f.color_from_depth = *p;
    EXO_RETURN_IF_ERROR(CheckColorFromDepth(f.color_from_depth, limits));
  }
  if (msg.has_world_from_cam()) {
    auto p = PoseFromProto(msg.world_from_cam());
    if (!p.ok()) return absl::InvalidArgumentError(absl::StrCat("pose: ", p.status().message()));
    f.world_from_cam = *p;
    EXO_RETURN_IF_ERROR(CheckCameraPosition(f.world_from_cam.translation, limits));
  } else if (options.pose_required) {
    return absl::InvalidArgumentError("missing pose: the frame has no world_from_cam");
  }
  if (msg.exposure() != 0.0) {  // 0 = not given
    EXO_RETURN_IF_ERROR(CheckExposure(msg.exposure(), limits));
    f.exposure = msg.exposure();
  }
  // Depth sizes before any decode allocates (colour or depth).
  if (msg.has_depth()) {
    const auto& d = msg.depth();
    if (d.width() != f.depth_camera.width || d.height() != f.depth_camera.height)
      return absl::InvalidArgumentError(absl::StrCat(
          "depth image is ", d.width(), "x", d.height(), " but depth intrinsics say ",
          f.depth_camera.width, "x", f.depth_camera.height));
  }
  // Colour: header first (cheap size and frame-type check), then the full decode.
  const std::span<const uint8_t> jpeg(reinterpret_cast<const uint8_t*>(msg.color_jpeg().data()),
                                      msg.color_jpeg().size());
  if (jpeg.empty()) return absl::InvalidArgumentError("colour JPEG is empty");
  JpegLimits jpeg_limits;
  jpeg_limits.max_pixels = limits.max_pixels;
  jpeg_limits.sequential_only = true;  // one MJPEG frame (proto: baseline JPEG)
  {
    auto info = ReadJpegInfo(jpeg, jpeg_limits);
    if (!info.ok())
      return absl::InvalidArgumentError(
          absl::StrCat("corrupt colour JPEG: ", info.status().message()));
    if (info->width != f.color_camera.width || info->height != f.color_camera.height)
      return absl::InvalidArgumentError(absl::StrCat(
          "colour JPEG is ", info->width, "x", info->height, " but intrinsics say ",
          f.color_camera.width, "x", f.color_camera.height));
  }
  if (msg.has_depth()) {
    // The depth header too, before the colour decode allocates.
    const auto& d = msg.depth();
    EXO_RETURN_IF_ERROR(CheckDepthScale(d.depth_scale_m(), limits));
    if (d.codec() == v1::DEPTH_CODEC_EXO_U16) {
      auto info = ReadDepthInfo(std::span<const uint8_t>(
          reinterpret_cast<const uint8_t*>(d.data().data()), d.data().size()));
      if (!info.ok())
        return absl::InvalidArgumentError(
            absl::StrCat("depth does not decode: ", info.status().message()));
    }
  }
  {
    auto rgb = DecodeJpeg(jpeg, jpeg_limits);
    if (!rgb.ok())
      return absl::InvalidArgumentError(
          absl::StrCat("corrupt colour JPEG: ", rgb.status().message()));
    f.color = *std::move(rgb);
  }
  if (msg.has_depth()) {
    auto depth = DepthFromProto(msg.depth(), limits);
    if (!depth.ok()) return depth.status();
    f.depth_m = *std::move(depth);
  }
  if (msg.has_world_from_cam() || options.pose_required) EXO_RETURN_IF_ERROR(CheckFrame(f, limits));
  else EXO_RETURN_IF_ERROR(f.Validate());
  return f;
}

namespace {

constexpr uint8_t kCompactMeshFormat = 1;
constexpr uint8_t kCompactMeshZstd = 2;  // u8 2, u32 size of the format-1/3 bytes, zstd frame of them
constexpr uint8_t kCompactMeshCodec = 3;  // header as format 1, u32 vertex bytes, meshopt streams
constexpr size_t kCompactHeaderBytes = 1 + 4 + 4 + 4 * 4;
constexpr size_t kMeshoptVertexBytes = 8;  // u16 x, y, z, 0 (the vertex codec wants 4-byte multiples)
constexpr size_t kMaxCompactMeshBytes = size_t{64} << 20;  // a chunk is < 1 MB in practice

template <typename T>
void PutLe(std::string* out, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));  // the supported targets are little-endian (x86-64, arm64)
  out->append(b, sizeof(T));
}
template <typename T>
T GetLe(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof(T));
  return v;
}

void EncodeCompact(const TriangleMesh& mesh, std::string* out) {
  const size_t nv = mesh.positions.size();
  glm::vec3 lo(0.0f), hi(0.0f);
  if (nv > 0) lo = hi = mesh.positions[0];
  for (const glm::vec3& p : mesh.positions) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  const float extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  // A step that maps the extent to <= 65535 after float rounding (the step is rounded up).
  const float step = extent > 0.0f ? std::nextafter(extent / 65535.0f, 1e30f) : 1.0f;
  out->clear();
  out->reserve(kCompactHeaderBytes + nv * 6 + mesh.indices.size() * 2);
  out->push_back(static_cast<char>(kCompactMeshFormat));
  PutLe<uint32_t>(out, static_cast<uint32_t>(nv));
  PutLe<uint32_t>(out, static_cast<uint32_t>(mesh.indices.size() / 3));
  for (int k = 0; k < 3; ++k) PutLe<float>(out, lo[k]);
  PutLe<float>(out, step);
  for (const glm::vec3& p : mesh.positions)
    for (int k = 0; k < 3; ++k) {
      const float q = std::round((p[k] - lo[k]) / step);
      PutLe<uint16_t>(out, static_cast<uint16_t>(std::clamp(q, 0.0f, 65535.0f)));
    }
  int64_t prev = 0;
  for (uint32_t idx : mesh.indices) {
    const int64_t d = static_cast<int64_t>(idx) - prev;
    prev = idx;
    uint64_t z = (static_cast<uint64_t>(d) << 1) ^ static_cast<uint64_t>(d >> 63);  // zigzag
    while (z >= 0x80) {
      out->push_back(static_cast<char>((z & 0x7f) | 0x80));
      z >>= 7;
    }
    out->push_back(static_cast<char>(z));
  }
}

// Format 3 (MeshWireOptions::step_m > 0): the same header as format 1 (origin snapped to a
// multiple of the step), u32 size of the vertex stream, meshopt_encodeVertexBuffer of u16[4]
// quantized positions in first-use order, meshopt_encodeIndexBuffer of the triangles in
// vertex-cache order. meshoptimizer's codecs are built for this (delta + bit packing of vertex
// bytes, a triangle-fan/edge cache for indices) and leave zstd the redundancy they miss.
void EncodeCodec(const TriangleMesh& mesh, float step_m, std::string* out) {
  const size_t nv = mesh.positions.size();
  const size_t ni = mesh.indices.size();
  glm::dvec3 lo(0.0), hi(0.0);
  if (nv > 0) lo = hi = glm::dvec3(mesh.positions[0]);
  for (const glm::vec3& p : mesh.positions) {
    lo = glm::min(lo, glm::dvec3(p));
    hi = glm::max(hi, glm::dvec3(p));
  }
  double step = step_m;
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  if (extent / step > 65000.0) step = std::nextafter(float(extent / 65000.0), 1e30f);
  const glm::vec3 origin(glm::floor(lo / step) * step);
  const float stepf = float(step);
  // Vertex-cache order, then vertices renumbered in first-use order (what both codecs like).
  std::vector<uint32_t> idx(ni);
  meshopt_optimizeVertexCache(idx.data(), mesh.indices.data(), ni, nv);
  std::vector<uint16_t> q(nv * 4, 0);
  for (size_t i = 0; i < nv; ++i)
    for (int k = 0; k < 3; ++k) {
      const float v = std::round((mesh.positions[i][k] - origin[k]) / stepf);
      q[4 * i + k] = static_cast<uint16_t>(std::clamp(v, 0.0f, 65535.0f));
    }
  std::vector<uint16_t> qv(nv * 4);
  const size_t used = meshopt_optimizeVertexFetch(qv.data(), idx.data(), ni, q.data(), nv,
                                                  kMeshoptVertexBytes);
  qv.resize(used * 4);
  std::vector<unsigned char> vbuf(meshopt_encodeVertexBufferBound(used, kMeshoptVertexBytes));
  vbuf.resize(meshopt_encodeVertexBuffer(vbuf.data(), vbuf.size(), qv.data(), used,
                                         kMeshoptVertexBytes));
  std::vector<unsigned char> ibuf(meshopt_encodeIndexBufferBound(ni, used));
  ibuf.resize(meshopt_encodeIndexBuffer(ibuf.data(), ibuf.size(), idx.data(), ni));
  out->clear();
  out->reserve(kCompactHeaderBytes + 4 + vbuf.size() + ibuf.size());
  out->push_back(static_cast<char>(kCompactMeshCodec));
  PutLe<uint32_t>(out, static_cast<uint32_t>(used));
  PutLe<uint32_t>(out, static_cast<uint32_t>(ni / 3));
  for (int k = 0; k < 3; ++k) PutLe<float>(out, origin[k]);
  PutLe<float>(out, stepf);
  PutLe<uint32_t>(out, static_cast<uint32_t>(vbuf.size()));
  out->append(reinterpret_cast<const char*>(vbuf.data()), vbuf.size());
  out->append(reinterpret_cast<const char*>(ibuf.data()), ibuf.size());
}

// Format 2: the format-1 bytes through zstd when that is smaller (the on-grid coordinates of
// marching-cubes vertices and the small index steps repeat).
void ZstdWrap(std::string* out) {
  auto z = ZstdCompress(reinterpret_cast<const uint8_t*>(out->data()), out->size(), 3,
                        std::vector<uint8_t>{});
  if (!z.ok() || z->size() + 5 >= out->size()) return;  // keep format 1
  std::string w;
  w.reserve(5 + z->size());
  w.push_back(static_cast<char>(kCompactMeshZstd));
  PutLe<uint32_t>(&w, static_cast<uint32_t>(out->size()));
  w.append(reinterpret_cast<const char*>(z->data()), z->size());
  *out = std::move(w);
}

absl::StatusOr<TriangleMesh> DecodeCompact(const std::string& b);

// The format-1/3 bytes inside a format-2 payload.
absl::StatusOr<std::string> UnwrapCompactZstd(const std::string& b) {
  if (b.size() < 5) return absl::InvalidArgumentError("compact mesh: zstd header cut");
  const uint32_t raw_size = GetLe<uint32_t>(b.data() + 1);
  if (raw_size < kCompactHeaderBytes || raw_size > kMaxCompactMeshBytes)
    return absl::InvalidArgumentError(
        absl::StrCat("compact mesh: ", raw_size, " decoded bytes outside [", kCompactHeaderBytes,
                     ", ", kMaxCompactMeshBytes, "]"));
  std::string raw(raw_size, '\0');
  EXO_RETURN_IF_ERROR(ZstdDecompress(
      std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(b.data()) + 5, b.size() - 5),
      reinterpret_cast<uint8_t*>(raw.data()), raw.size(), "compact mesh"));
  const uint8_t inner = static_cast<uint8_t>(raw[0]);
  if (inner != kCompactMeshFormat && inner != kCompactMeshCodec)
    return absl::InvalidArgumentError("compact mesh: zstd payload is not format 1 or 3");
  return raw;
}

absl::StatusOr<TriangleMesh> DecodeCompactZstd(const std::string& b) {
  EXO_ASSIGN_OR_RETURN(const std::string raw, UnwrapCompactZstd(b));
  return DecodeCompact(raw);
}

absl::StatusOr<TriangleMesh> DecodeCodec(const std::string& b) {
  if (b.size() < kCompactHeaderBytes + 4)
    return absl::InvalidArgumentError("compact mesh: shorter than its header");
  const char* p = b.data() + 1;
  const uint64_t nv = GetLe<uint32_t>(p);
  const uint64_t nt = GetLe<uint32_t>(p + 4);
  const glm::vec3 origin(GetLe<float>(p + 8), GetLe<float>(p + 12), GetLe<float>(p + 16));
  const float step = GetLe<float>(p + 20);
  const uint64_t vbytes = GetLe<uint32_t>(p + 24);
  if (!std::isfinite(origin.x) || !std::isfinite(origin.y) || !std::isfinite(origin.z) ||
      !std::isfinite(step) || !(step > 0.0f))
    return absl::InvalidArgumentError("compact mesh: origin or step not finite and positive");
  const size_t body = b.size() - kCompactHeaderBytes - 4;
  // Counts checked against the bytes present before anything is allocated: the index codec
  // spends at least one byte per triangle, the vertex codec at least 32 bytes per block of 256
  // 8-byte vertices (2 bits per 16-vertex group and byte lane).
  if (vbytes > body || nt > body - vbytes || nv > 8 * vbytes + 256 ||
      nv * kMeshoptVertexBytes > kMaxCompactMeshBytes || nt * 12 > kMaxCompactMeshBytes)
    return absl::InvalidArgumentError(absl::StrCat("compact mesh: ", nv, " vertices (", vbytes,
                                                   " bytes) and ", nt, " triangles do not fit in ",
                                                   b.size(), " bytes"));
  const auto* vb = reinterpret_cast<const unsigned char*>(b.data()) + kCompactHeaderBytes + 4;
  std::vector<uint16_t> q(nv * 4);
  if (nv > 0 && meshopt_decodeVertexBuffer(q.data(), nv, kMeshoptVertexBytes, vb, vbytes) != 0)
    return absl::InvalidArgumentError("compact mesh: vertex stream does not decode");
  TriangleMesh m;
  m.indices.resize(nt * 3);
  if (nt > 0 && meshopt_decodeIndexBuffer(m.indices.data(), nt * 3, sizeof(uint32_t), vb + vbytes,
                                          body - vbytes) != 0)
    return absl::InvalidArgumentError("compact mesh: index stream does not decode");
  for (uint32_t i : m.indices)
    if (i >= nv)
      return absl::InvalidArgumentError(
          absl::StrCat("compact mesh: index ", i, " outside ", nv, " vertices"));
  m.positions.resize(nv);
  for (uint64_t i = 0; i < nv; ++i)
    m.positions[i] = origin + step * glm::vec3(q[4 * i], q[4 * i + 1], q[4 * i + 2]);
  return m;
}

absl::StatusOr<TriangleMesh> DecodeCompact(const std::string& b) {
  if (!b.empty() && static_cast<uint8_t>(b[0]) == kCompactMeshZstd) return DecodeCompactZstd(b);
  if (!b.empty() && static_cast<uint8_t>(b[0]) == kCompactMeshCodec) return DecodeCodec(b);
  if (b.size() < kCompactHeaderBytes)
    return absl::InvalidArgumentError("compact mesh: shorter than its header");
  if (static_cast<uint8_t>(b[0]) != kCompactMeshFormat)
    return absl::InvalidArgumentError(
        absl::StrCat("compact mesh: unknown format ", static_cast<int>(static_cast<uint8_t>(b[0]))));
  const char* p = b.data() + 1;
  const uint64_t nv = GetLe<uint32_t>(p);
  const uint64_t nt = GetLe<uint32_t>(p + 4);
  const glm::vec3 origin(GetLe<float>(p + 8), GetLe<float>(p + 12), GetLe<float>(p + 16));
  const float step = GetLe<float>(p + 20);
  if (!std::isfinite(origin.x) || !std::isfinite(origin.y) || !std::isfinite(origin.z) ||
      !std::isfinite(step) || !(step > 0.0f))
    return absl::InvalidArgumentError("compact mesh: origin or step not finite and positive");
  // Sizes are checked against the bytes present before anything is allocated (a forged count
  // cannot make a reader allocate more than the message's own size allows).
  const size_t body = b.size() - kCompactHeaderBytes;
  if (nv * 6 > body || nt * 3 > body - nv * 6)
    return absl::InvalidArgumentError(absl::StrCat("compact mesh: ", nv, " vertices and ", nt,
                                                   " triangles do not fit in ", b.size(), " bytes"));
  TriangleMesh m;
  m.positions.resize(nv);
  const char* q = b.data() + kCompactHeaderBytes;
  for (uint64_t i = 0; i < nv; ++i, q += 6)
    m.positions[i] = origin + step * glm::vec3(GetLe<uint16_t>(q), GetLe<uint16_t>(q + 2),
                                               GetLe<uint16_t>(q + 4));
  const char* end = b.data() + b.size();
  m.indices.resize(nt * 3);
  int64_t prev = 0;
  for (uint64_t i = 0; i < nt * 3; ++i) {
    uint64_t z = 0;
    int shift = 0;
    for (;;) {
      if (q == end) return absl::InvalidArgumentError("compact mesh: indices truncated");
      if (shift > 63) return absl::InvalidArgumentError("compact mesh: index varint too long");
      const uint8_t c = static_cast<uint8_t>(*q++);
      z |= static_cast<uint64_t>(c & 0x7f) << shift;
      shift += 7;
      if (!(c & 0x80)) break;
    }
    const int64_t d = static_cast<int64_t>(z >> 1) ^ -static_cast<int64_t>(z & 1);
    prev += d;
    if (prev < 0 || static_cast<uint64_t>(prev) >= nv)
      return absl::InvalidArgumentError(
          absl::StrCat("compact mesh: index ", prev, " outside ", nv, " vertices"));
    m.indices[i] = static_cast<uint32_t>(prev);
  }
  if (q != end) return absl::InvalidArgumentError("compact mesh: trailing bytes");
  return m;
}

}  // namespace

void MeshToProto(const TriangleMesh& mesh, v1::MeshChunkUpserted* out, bool plain,
                 const MeshWireOptions& options) {
  if (!plain) {
    if (options.step_m > 0.0f && std::isfinite(options.step_m))
      EncodeCodec(mesh, options.step_m, out->mutable_compact());
    else
      EncodeCompact(mesh, out->mutable_compact());
    ZstdWrap(out->mutable_compact());
    return;
  }
  out->mutable_positions()->Reserve(static_cast<int>(mesh.positions.size() * 3));
  for (const auto& p : mesh.positions) {
    out->add_positions(p.x);
    out->add_positions(p.y);
    out->add_positions(p.z);
  }
  for (const auto& n : mesh.normals) {
    out->add_normals(n.x);
    out->add_normals(n.y);
    out->add_normals(n.z);
  }
  out->mutable_indices()->Add(mesh.indices.begin(), mesh.indices.end());
}

absl::StatusOr<TriangleMesh> MeshFromProto(const v1::MeshChunkUpserted& msg) {
  if (!msg.compact().empty()) {
    if (msg.positions_size() || msg.normals_size() || msg.indices_size())
      return absl::InvalidArgumentError("mesh has both the compact and the plain encoding");
    return DecodeCompact(msg.compact());
  }
  if (msg.positions_size() % 3 != 0)
    return absl::InvalidArgumentError("mesh positions are not xyz triples");
  if (msg.normals_size() != 0 && msg.normals_size() != msg.positions_size())
    return absl::InvalidArgumentError("mesh normals do not match positions");
  if (msg.indices_size() % 3 != 0)
    return absl::InvalidArgumentError("mesh indices are not triangles");
  TriangleMesh m;
  const int nv = msg.positions_size() / 3;
  m.positions.resize(nv);
  for (int i = 0; i < nv; ++i)
    m.positions[i] = {msg.positions(3 * i), msg.positions(3 * i + 1), msg.positions(3 * i + 2)};
  if (msg.normals_size() != 0) {
    m.normals.resize(nv);
    for (int i = 0; i < nv; ++i)
      m.normals[i] = {msg.normals(3 * i), msg.normals(3 * i + 1), msg.normals(3 * i + 2)};
  }
  m.indices.assign(msg.indices().begin(), msg.indices().end());
  for (uint32_t idx : m.indices)
    if (idx >= static_cast<uint32_t>(nv))
      return absl::InvalidArgumentError(absl::StrCat("mesh index ", idx, " >= ", nv, " vertices"));
  return m;
}

// ---- packed payloads: u32 little-endian size N of the raw bytes, then one zstd frame of them ----
namespace {
std::string SizedZstdPayload(size_t raw_size, const std::vector<uint8_t>& z) {
  std::string packed;
  packed.reserve(4 + z.size());
  PutLe<uint32_t>(&packed, static_cast<uint32_t>(raw_size));
  packed.append(reinterpret_cast<const char*>(z.data()), z.size());
  return packed;
}

// The raw bytes of a packed payload; a cut header, a size outside [1, max_bytes], a corrupt or
// truncated frame are errors naming `what`.
absl::StatusOr<std::string> UnpackSizedZstd(const std::string& b, size_t max_bytes,
                                            const char* what) {
  if (b.size() < 4) return absl::InvalidArgumentError(absl::StrCat(what, ": packed header cut"));
  const uint32_t raw_size = GetLe<uint32_t>(b.data());
  if (raw_size == 0 || raw_size > max_bytes)
    return absl::InvalidArgumentError(absl::StrCat(what, ": ", raw_size,
                                                   " packed bytes outside [1, ", max_bytes, "]"));
  std::string raw(raw_size, '\0');
  EXO_RETURN_IF_ERROR(ZstdDecompress(
      std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(b.data()) + 4, b.size() - 4),
      reinterpret_cast<uint8_t*>(raw.data()), raw.size(), what));
  return raw;
}
}  // namespace

// ---- cell references ----
namespace {
constexpr size_t kMaxCellRefsBytes = size_t{64} << 20;  // a whole 200-view model is ~0.2 MB
}  // namespace

void PackCellRefs(v1::CellRefsChanged* msg) {
  if (!msg->packed().empty()) return;
  const std::string raw = msg->SerializeAsString();
  if (raw.size() < 64 || raw.size() > kMaxCellRefsBytes) return;
  auto z = ZstdCompress(reinterpret_cast<const uint8_t*>(raw.data()), raw.size(), 9,
                        std::vector<uint8_t>{});
  if (!z.ok() || z->size() + 4 >= raw.size()) return;  // not smaller: stay plain
  msg->Clear();
  msg->set_packed(SizedZstdPayload(raw.size(), *z));
}

absl::StatusOr<v1::CellRefsChanged> UnpackCellRefs(const v1::CellRefsChanged& msg) {
  if (msg.packed().empty()) return msg;
  if (msg.cells_size() > 0 || msg.coverage_size() > 0)
    return absl::InvalidArgumentError("cell refs: both packed and plain entries");
  EXO_ASSIGN_OR_RETURN(const std::string raw,
                       UnpackSizedZstd(msg.packed(), kMaxCellRefsBytes, "cell refs"));
  v1::CellRefsChanged out;
  if (!out.ParseFromString(raw)) return absl::InvalidArgumentError("cell refs: packed payload does not parse");
  if (!out.packed().empty()) return absl::InvalidArgumentError("cell refs: nested packed payload");
  return out;
}

// ---- mesh chunk batches (snapshots) ----
namespace {
constexpr size_t kMaxChunkBatchBytes = size_t{256} << 20;  // the server cuts batches at ~1 MB
}  // namespace

absl::StatusOr<v1::MeshChunkBatch> PackMeshChunks(
    std::span<const v1::MeshChunkUpserted* const> chunks, int level) {
  v1::MeshChunkList list;
  list.mutable_chunks()->Reserve(static_cast<int>(chunks.size()));
  for (const v1::MeshChunkUpserted* c : chunks) {
    v1::MeshChunkUpserted* e = list.add_chunks();
    *e = *c;
    if (!e->compact().empty() && static_cast<uint8_t>(e->compact()[0]) == kCompactMeshZstd) {
      EXO_ASSIGN_OR_RETURN(std::string raw, UnwrapCompactZstd(e->compact()));
      e->set_compact(std::move(raw));
    }
  }
  const std::string raw = list.SerializeAsString();
  if (raw.size() > kMaxChunkBatchBytes)
    return absl::InvalidArgumentError(absl::StrCat("mesh chunk batch: ", raw.size(),
                                                   " bytes, more than ", kMaxChunkBatchBytes));
  EXO_ASSIGN_OR_RETURN(const std::vector<uint8_t> z,
                       ZstdCompress(reinterpret_cast<const uint8_t*>(raw.data()), raw.size(),
                                    level, std::vector<uint8_t>{}));
  v1::MeshChunkBatch out;
  out.set_packed(SizedZstdPayload(raw.size(), z));
  return out;
}

absl::StatusOr<std::vector<v1::MeshChunkUpserted>> UnpackMeshChunks(const v1::MeshChunkBatch& batch) {
  EXO_ASSIGN_OR_RETURN(const std::string raw,
                       UnpackSizedZstd(batch.packed(), kMaxChunkBatchBytes, "mesh chunk batch"));
  v1::MeshChunkList list;
  if (!list.ParseFromString(raw))
    return absl::InvalidArgumentError("mesh chunk batch: payload does not parse");
  if (list.chunks_size() == 0) return absl::InvalidArgumentError("mesh chunk batch: no chunks");
  return std::vector<v1::MeshChunkUpserted>(std::make_move_iterator(list.mutable_chunks()->begin()),
                                            std::make_move_iterator(list.mutable_chunks()->end()));
}

}  // namespace exo
