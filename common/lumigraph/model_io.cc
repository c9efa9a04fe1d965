#include "common/lumigraph/model_io.h"

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <type_traits>

#include "common/io/depth_codec.h"
#include "common/io/jpeg.h"

namespace exo {
namespace {

constexpr char kMagic[8] = {'E', 'X', 'O', 'M', 'O', 'D', 'L', '1'};
constexpr uint32_t kFormatVersion = 1;
constexpr uint32_t Tag(char a, char b, char c, char d) {
  return uint32_t(uint8_t(a)) | uint32_t(uint8_t(b)) << 8 | uint32_t(uint8_t(c)) << 16 |
         uint32_t(uint8_t(d)) << 24;
}
constexpr uint32_t kTagOrigin = Tag('O', 'R', 'I', 'G');
constexpr uint32_t kTagView = Tag('V', 'I', 'E', 'W');
constexpr uint32_t kTagCells = Tag('C', 'E', 'L', 'L');
constexpr uint32_t kTagChunk = Tag('C', 'H', 'N', 'K');
// Optional (a reader that predates it skips it): per-cell coverage, u64 count, (u64 cell, u8 %).
constexpr uint32_t kTagCoverage = Tag('C', 'O', 'V', 'R');
constexpr uint8_t kColorRaw = 0, kColorJpeg = 1;
// Sanity bounds (a corrupt count must not allocate gigabytes before failing).
constexpr uint64_t kMaxSection = uint64_t{1} << 34;

// FNV-1a 64 of a payload: detects corruption (not an authenticity check).
uint64_t Checksum(std::span<const uint8_t> b) {
  uint64_t h = 1469598103934665603ull;
  for (uint8_t c : b) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

class Writer {
 public:
  template <typename T>
  void Put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    out.insert(out.end(), p, p + sizeof(T));
  }
  void PutBytes(std::span<const uint8_t> b) {
    Put<uint64_t>(b.size());
    out.insert(out.end(), b.begin(), b.end());
  }
  std::vector<uint8_t> out;
};

class Reader {
 public:
  explicit Reader(std::span<const uint8_t> b, std::string what) : b_(b), what_(std::move(what)) {}
  template <typename T>
  absl::Status Get(T* v) {
    if (b_.size() - pos_ < sizeof(T))
      return absl::DataLossError(absl::StrCat("model file truncated in ", what_, " at byte ", pos_));
    std::memcpy(v, b_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return absl::OkStatus();
  }
  absl::StatusOr<std::span<const uint8_t>> GetBytes() {
    uint64_t n = 0;
    EXO_RETURN_IF_ERROR(Get(&n));
    if (n > b_.size() - pos_)
      return absl::DataLossError(absl::StrCat("model file truncated in ", what_, ": ", n,
                                              " bytes announced, ", b_.size() - pos_, " left"));
    auto s = b_.subspan(pos_, n);
    pos_ += n;
    return s;
  }
  // Count of items of at least `min_item_bytes` each that must still fit in the input.
  absl::StatusOr<uint64_t> GetCount(size_t min_item_bytes) {
    uint64_t n = 0;
    EXO_RETURN_IF_ERROR(Get(&n));
    if (min_item_bytes > 0 && n > (b_.size() - pos_) / min_item_bytes)
      return absl::DataLossError(absl::StrCat("model file corrupt in ", what_, ": count ", n,
                                              " does not fit in the remaining bytes"));
    return n;
  }
  absl::Status Skip(uint64_t n) {
    if (n > b_.size() - pos_)
      return absl::DataLossError(absl::StrCat("model file truncated in ", what_));
    pos_ += n;
    return absl::OkStatus();
  }
  bool done() const { return pos_ == b_.size(); }
  size_t pos() const { return pos_; }

 private:
  std::span<const uint8_t> b_;
  size_t pos_ = 0;
  std::string what_;
};

void PutSection(Writer& file, uint32_t tag, const std::vector<uint8_t>& payload) {
  file.Put(tag);
  file.Put<uint64_t>(payload.size());
  file.out.insert(file.out.end(), payload.begin(), payload.end());
  file.Put<uint64_t>(Checksum(payload));
}

absl::StatusOr<std::vector<uint8_t>> ViewPayload(const StoredView& v, const ModelIoOptions& o) {
  EXO_RETURN_IF_ERROR(v.camera.Validate());
  if (v.color.width() != v.camera.width || v.color.height() != v.camera.height ||
      v.color.channels() != 3)
    return absl::InvalidArgumentError(absl::StrCat("view ", v.id, ": colour is not RGB8 of the camera size"));
  if (v.depth_m.width() != v.camera.width || v.depth_m.height() != v.camera.height ||
      v.depth_m.channels() != 1)
    return absl::InvalidArgumentError(absl::StrCat("view ", v.id, ": depth is not 1 channel of the camera size"));
  Writer w;
  w.Put<uint32_t>(v.id);
  w.Put<int32_t>(v.camera.width);
  w.Put<int32_t>(v.camera.height);
  for (double d : {v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy}) w.Put(d);
  const auto& q = v.local_from_cam.rotation;
  for (double d : {q.w, q.x, q.y, q.z}) w.Put(d);
  for (int k = 0; k < 3; ++k) w.Put<double>(v.local_from_cam.translation[k]);
  w.Put<float>(v.exposure);
  if (o.color_jpeg_quality > 0) {
    EXO_ASSIGN_OR_RETURN(auto jpeg, EncodeJpeg(v.color, o.color_jpeg_quality));
    w.Put<uint8_t>(kColorJpeg);
    w.PutBytes(jpeg);
  } else {
    w.Put<uint8_t>(kColorRaw);
    w.PutBytes(std::span<const uint8_t>(v.color.data(), v.color.size()));
  }
  // Depth: finite positive values quantised with a per-view step (max depth / 65535).
  float max_depth = 0.0f;
  ImageF clean(v.depth_m.width(), v.depth_m.height(), 1, 0.0f);
  for (size_t i = 0; i < v.depth_m.size(); ++i) {
    const float z = v.depth_m.data()[i];
    if (std::isfinite(z) && z > 0.0f) {
      clean.data()[i] = z;
      max_depth = std::max(max_depth, z);
    }
  }
  const double step = std::max(o.min_depth_step_m, double(max_depth) / 65535.0);
  w.Put<double>(step);
  EXO_ASSIGN_OR_RETURN(auto depth, EncodeDepth(DepthU16FromMeters(clean, step), DepthCodecOptions{}));
  w.PutBytes(depth);
  return std::move(w.out);
}

absl::StatusOr<StoredView> ParseView(std::span<const uint8_t> payload) {
  Reader r(payload, "view");
  StoredView v;
  EXO_RETURN_IF_ERROR(r.Get(&v.id));
  int32_t wi = 0, hi = 0;
  EXO_RETURN_IF_ERROR(r.Get(&wi));
  EXO_RETURN_IF_ERROR(r.Get(&hi));
  v.camera.width = wi;
  v.camera.height = hi;
  for (double* d : {&v.camera.fx, &v.camera.fy, &v.camera.cx, &v.camera.cy})
    EXO_RETURN_IF_ERROR(r.Get(d));
  if (auto st = v.camera.Validate(); !st.ok())
    return absl::DataLossError(absl::StrCat("view ", v.id, ": ", st.message()));
  auto& q = v.local_from_cam.rotation;
  for (double* d : {&q.w, &q.x, &q.y, &q.z}) EXO_RETURN_IF_ERROR(r.Get(d));
  for (int k = 0; k < 3; ++k) EXO_RETURN_IF_ERROR(r.Get(&v.local_from_cam.translation[k]));
  if (auto st = ValidateQuaternion(q); !st.ok())
    return absl::DataLossError(absl::StrCat("view ", v.id, ": ", st.message()));
  for (int k = 0; k < 3; ++k)
    if (!std::isfinite(v.local_from_cam.translation[k]))
      return absl::DataLossError(absl::StrCat("view ", v.id, ": non-finite position"));
  EXO_RETURN_IF_ERROR(r.Get(&v.exposure));
  if (!std::isfinite(v.exposure) || v.exposure <= 0.0f)
    return absl::DataLossError(absl::StrCat("view ", v.id, ": bad exposure ", v.exposure));
  uint8_t color_kind = 0;
  EXO_RETURN_IF_ERROR(r.Get(&color_kind));
  EXO_ASSIGN_OR_RETURN(auto color, r.GetBytes());
  if (color_kind == kColorRaw) {
    if (color.size() != size_t(wi) * hi * 3)
      return absl::DataLossError(absl::StrCat("view ", v.id, ": raw colour has ", color.size(),
                                              " bytes, expected ", size_t(wi) * hi * 3));
    v.color = ImageU8(wi, hi, 3);
    std::memcpy(v.color.data(), color.data(), color.size());
  } else if (color_kind == kColorJpeg) {
    EXO_ASSIGN_OR_RETURN(v.color, DecodeJpeg(color));
    if (v.color.width() != wi || v.color.height() != hi)
      return absl::DataLossError(absl::StrCat("view ", v.id, ": JPEG size differs from camera"));
  } else {
    return absl::DataLossError(absl::StrCat("view ", v.id, ": unknown colour encoding ", int(color_kind)));
  }
  double step = 0;
  EXO_RETURN_IF_ERROR(r.Get(&step));
  if (!std::isfinite(step) || step <= 0.0)
    return absl::DataLossError(absl::StrCat("view ", v.id, ": bad depth step"));
  EXO_ASSIGN_OR_RETURN(auto depth_bytes, r.GetBytes());
  EXO_ASSIGN_OR_RETURN(ImageU16 depth, DecodeDepth(depth_bytes));
  if (depth.width() != wi || depth.height() != hi)
    return absl::DataLossError(absl::StrCat("view ", v.id, ": depth size differs from camera"));
  v.depth_m = DepthMetersFromU16(depth, step);
  if (!r.done()) return absl::DataLossError(absl::StrCat("view ", v.id, ": trailing bytes"));
  return v;
}

}  // namespace

absl::Status ModelIoOptions::Validate() const {
  if (color_jpeg_quality < 0 || color_jpeg_quality > 100)
    return absl::InvalidArgumentError("color_jpeg_quality must be 0 (raw) or 1..100");
  if (!std::isfinite(min_depth_step_m) || min_depth_step_m <= 0.0)
    return absl::InvalidArgumentError("min_depth_step_m must be > 0");
  return absl::OkStatus();
}

absl::StatusOr<std::vector<uint8_t>> SerializeModel(const LumigraphModel& model,
                                                    const ModelIoOptions& options) {
  EXO_RETURN_IF_ERROR(options.Validate());
  Writer file;
  file.out.insert(file.out.end(), kMagic, kMagic + 8);
  file.Put(kFormatVersion);
  file.Put<uint32_t>(uint32_t(2 + model.views.size() + model.chunks.size() +
                             (model.cell_coverage.empty() ? 0 : 1)));
  {
    Writer w;
    for (int k = 0; k < 3; ++k) w.Put<double>(model.origin.origin_in_world[k]);
    w.Put<double>(model.grid.cell_size_m);
    w.Put<uint64_t>(model.version);
    PutSection(file, kTagOrigin, w.out);
  }
  for (const auto& [id, v] : model.views) {
    if (v.id != id)
      return absl::InvalidArgumentError(absl::StrCat("view keyed ", id, " has id ", v.id));
    EXO_ASSIGN_OR_RETURN(auto payload, ViewPayload(v, options));
    PutSection(file, kTagView, payload);
  }
  {
    Writer w;
    w.Put<uint64_t>(model.cell_refs.size());
    for (const auto& [cell, refs] : model.cell_refs) {
      w.Put<uint64_t>(cell);
      w.Put<uint32_t>(uint32_t(refs.size()));
      for (ViewId r : refs) w.Put<uint32_t>(r);
    }
    PutSection(file, kTagCells, w.out);
  }
  if (!model.cell_coverage.empty()) {
    Writer w;
    w.Put<uint64_t>(model.cell_coverage.size());
    for (const auto& [cell, percent] : model.cell_coverage) {
      w.Put<uint64_t>(cell);
      w.Put<uint8_t>(percent);
    }
    PutSection(file, kTagCoverage, w.out);
  }
  for (const auto& [id, c] : model.chunks) {
    Writer w;
    w.Put<uint64_t>(c.id);
    w.Put<uint64_t>(c.version);
    w.Put<uint64_t>(c.mesh.positions.size());
    for (const auto& p : c.mesh.positions) w.Put(p);
    w.Put<uint64_t>(c.mesh.indices.size());
    for (uint32_t i : c.mesh.indices) w.Put(i);
    PutSection(file, kTagChunk, w.out);
  }
  return std::move(file.out);
}

absl::StatusOr<LumigraphModel> DeserializeModel(std::span<const uint8_t> bytes) {
  if (bytes.size() < 16 || std::memcmp(bytes.data(), kMagic, 8) != 0)
    return absl::DataLossError("not an Exoview model file (bad magic)");
  Reader r(bytes.subspan(8), "header");
  uint32_t version = 0, sections = 0;
  EXO_RETURN_IF_ERROR(r.Get(&version));
  if (version != kFormatVersion)
    return absl::InvalidArgumentError(absl::StrCat("model file format version ", version,
                                                   " is not supported (expected ", kFormatVersion, ")"));
  EXO_RETURN_IF_ERROR(r.Get(&sections));
  LumigraphModel m;
  bool have_origin = false, have_cells = false;
  for (uint32_t s = 0; s < sections; ++s) {
    uint32_t tag = 0;
    uint64_t n = 0;
    EXO_RETURN_IF_ERROR(r.Get(&tag));
    EXO_RETURN_IF_ERROR(r.Get(&n));
    const size_t start = 8 + r.pos();
    if (n > kMaxSection || n + 8 > bytes.size() - start)
      return absl::DataLossError(absl::StrCat("model file truncated: section ", s, " announces ",
                                              n, " bytes, ", bytes.size() - start, " left"));
    const auto payload = bytes.subspan(start, n);
    uint64_t sum = 0;
    std::memcpy(&sum, bytes.data() + start + n, 8);
    if (sum != Checksum(payload))
      return absl::DataLossError(absl::StrCat("model file corrupt: checksum mismatch in section ", s));
    EXO_RETURN_IF_ERROR(r.Skip(n + 8));  // payload + checksum
    if (tag == kTagOrigin) {
      Reader p(payload, "origin");
      for (int k = 0; k < 3; ++k) EXO_RETURN_IF_ERROR(p.Get(&m.origin.origin_in_world[k]));
      EXO_RETURN_IF_ERROR(p.Get(&m.grid.cell_size_m));
      EXO_RETURN_IF_ERROR(p.Get(&m.version));
      if (!std::isfinite(m.grid.cell_size_m) || m.grid.cell_size_m <= 0.0)
        return absl::DataLossError("model file: bad cell size");
      have_origin = true;
    } else if (tag == kTagView) {
      EXO_ASSIGN_OR_RETURN(StoredView v, ParseView(payload));
      const ViewId id = v.id;
      if (!m.views.emplace(id, std::move(v)).second)
        return absl::DataLossError(absl::StrCat("model file: view ", id, " twice"));
    } else if (tag == kTagCells) {
      Reader p(payload, "cells");
      EXO_ASSIGN_OR_RETURN(uint64_t cells, p.GetCount(12));
      for (uint64_t c = 0; c < cells; ++c) {
        uint64_t id = 0;
        uint32_t k = 0;
        EXO_RETURN_IF_ERROR(p.Get(&id));
        EXO_RETURN_IF_ERROR(p.Get(&k));
        std::vector<ViewId> refs(0);
        if (uint64_t(k) * 4 > payload.size()) return absl::DataLossError("model file: bad ref count");
        refs.resize(k);
        for (auto& v : refs) EXO_RETURN_IF_ERROR(p.Get(&v));
        m.cell_refs[id] = std::move(refs);
      }
      if (!p.done()) return absl::DataLossError("model file: trailing bytes in cells");
      have_cells = true;
    } else if (tag == kTagCoverage) {
      Reader p(payload, "coverage");
      EXO_ASSIGN_OR_RETURN(uint64_t cells, p.GetCount(9));
      for (uint64_t c = 0; c < cells; ++c) {
        uint64_t id = 0;
        uint8_t percent = 0;
        EXO_RETURN_IF_ERROR(p.Get(&id));
        EXO_RETURN_IF_ERROR(p.Get(&percent));
        if (percent > 100) return absl::DataLossError("model file: coverage above 100 %");
        m.cell_coverage[id] = percent;
      }
      if (!p.done()) return absl::DataLossError("model file: trailing bytes in coverage");
    } else if (tag == kTagChunk) {
      Reader p(payload, "mesh chunk");
      MeshChunk c;
      EXO_RETURN_IF_ERROR(p.Get(&c.id));
      EXO_RETURN_IF_ERROR(p.Get(&c.version));
      EXO_ASSIGN_OR_RETURN(uint64_t nv, p.GetCount(12));
      c.mesh.positions.resize(nv);
      for (auto& v : c.mesh.positions) EXO_RETURN_IF_ERROR(p.Get(&v));
      EXO_ASSIGN_OR_RETURN(uint64_t ni, p.GetCount(4));
      if (ni % 3 != 0) return absl::DataLossError(absl::StrCat("chunk ", c.id, ": index count not a multiple of 3"));
      c.mesh.indices.resize(ni);
      for (auto& i : c.mesh.indices) {
        EXO_RETURN_IF_ERROR(p.Get(&i));
        if (i >= nv) return absl::DataLossError(absl::StrCat("chunk ", c.id, ": index out of range"));
      }
      if (!p.done()) return absl::DataLossError("model file: trailing bytes in chunk");
      const uint64_t id = c.id;
      if (!m.chunks.emplace(id, std::move(c)).second)
        return absl::DataLossError(absl::StrCat("model file: chunk ", id, " twice"));
    } else {
      // Unknown sections of a future minor revision are skipped (their checksum was verified).
    }
  }
  if (!r.done()) return absl::DataLossError("model file: trailing bytes after the last section");
  if (!have_origin || !have_cells)
    return absl::DataLossError("model file: missing origin or cell section");
  return m;
}

absl::Status SaveModel(const std::string& path, const LumigraphModel& model,
                       const ModelIoOptions& options) {
  EXO_ASSIGN_OR_RETURN(auto bytes, SerializeModel(model, options));
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) return absl::UnavailableError(absl::StrCat("cannot write ", tmp));
    f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
    if (!f) return absl::UnavailableError(absl::StrCat("write failed: ", tmp));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    return absl::UnavailableError(absl::StrCat("cannot rename ", tmp, " to ", path));
  return absl::OkStatus();
}

absl::StatusOr<LumigraphModel> LoadModel(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return absl::NotFoundError(absl::StrCat("cannot open model file ", path));
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  auto m = DeserializeModel(bytes);
  if (!m.ok())
    return absl::Status(m.status().code(), absl::StrCat(path, ": ", m.status().message()));
  return m;
}

}  // namespace exo
