// mesh_wire_bench: bytes of the clients' proxy on the wire against the position error, per
// encoding of a mesh chunk (SPEC §10: initial sync of a 200-view store <= 8 MB; the 2 cm proxy a
// real room needs is the largest part of it).
//
//   mesh_wire_bench [--data DIR] [--frames N] [--voxel 0.02] [--lod_voxels 0.25]
//
// Fuses the 7-Scenes frames (depth camera, as geometry_bench) into the server's TSDF, extracts
// every chunk as the server publishes it (simplified within `lod_voxels` voxel, mesh_lod.h), and
// encodes each chunk with MeshToProto (the wire library: proto/frame_proto.h) under each
// encoding. Prints one JSON line per encoding: bytes of the chunks' Delta messages (what a
// snapshot sends), bytes per triangle, encode and decode ms (whole proxy, one thread), and the
// largest and mean position error of the decoded vertices (mm). The last line is a bound: every
// chunk's payload in ONE zstd stream (what no per-chunk encoding can beat by much).
#include <algorithm>
#include <array>
#include <tuple>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/cli/cli.h"
#include "common/datasets/seven_scenes.h"
#include "common/io/zstd.h"
#include "common/lumigraph/model.h"
#include "proto/frame_proto.h"
#include "server/geometry/mesh_lod.h"
#include "server/geometry/tsdf_volume.h"
#include "exoview_source_dir.h"

namespace exo {
namespace {

using Clock = std::chrono::steady_clock;
double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

struct Encoding {
  std::string name;
  MeshWireOptions options;
  bool plain = false;
};

int Main(int argc, char** argv) {
  std::string data = std::string(EXOVIEW_SOURCE_DIR) + "/../shared/data/7scenes-redkitchen";
  int frames = 300;
  double voxel = 0.02, lod_voxels = 0.25;
  CLI::App app{"Bytes of the clients' proxy per chunk encoding against the position error"};
  app.add_option("--data", data, "7-Scenes sequence directory");
  app.add_option("--frames", frames, "frames to fuse");
  app.add_option("--voxel", voxel, "TSDF voxel size (m)");
  app.add_option("--lod_voxels", lod_voxels, "published LOD error bound (voxels)");
  cli::Setup(app);
  if (auto rc = cli::Parse(app, argc, argv)) return *rc;

  auto reader_or = SevenScenesReader::Open(data);
  if (!reader_or.ok()) {
    std::fprintf(stderr, "mesh_wire_bench: no 7-Scenes data at %s: %s\n", data.c_str(),
                 std::string(reader_or.status().message()).c_str());
    return 2;
  }
  const SevenScenesReader& reader = **reader_or;
  TsdfOptions o;
  o.voxel_size_m = float(voxel);
  o.max_depth_m = 4.0f;
  TsdfVolume vol(o);
  frames = std::min<int>(frames, int(reader.size()));
  for (int i = 0; i < frames; ++i) {
    auto f = reader.Load(i);
    if (!f.ok() || !vol.Integrate(*f, LocalOrigin{}).ok()) {
      std::fprintf(stderr, "mesh_wire_bench: frame %d failed\n", i);
      return 1;
    }
    if (i % 50 == 0) std::fprintf(stderr, "fused %d/%d\n", i, frames);
  }
  std::vector<MeshChunk> chunks = vol.ExtractDirtyChunks();
  geometry::MeshLodOptions lod;
  lod.max_error_m = lod_voxels * voxel;
  size_t tris = 0;
  for (MeshChunk& c : chunks) {
    c.mesh = geometry::SimplifyMesh(c.mesh, lod);
    c.mesh.normals.clear();
    c.mesh.colors.clear();
    tris += c.mesh.num_triangles();
  }

  std::vector<Encoding> encodings;
  encodings.push_back({"plain floats", {}, true});
  encodings.push_back({"format 2 (u16 over the chunk box, varints, zstd)", {}, false});
  for (int div : {16, 32, 64, 256}) {
    Encoding e;
    e.name = "format 3 (meshopt, step voxel/" + std::to_string(div) + ", zstd)";
    e.options.step_m = float(voxel / div);
    encodings.push_back(e);
  }

  std::printf("{\"chunks\": %zu, \"triangles\": %zu, \"voxel_m\": %g, \"lod_voxels\": %g}\n",
              chunks.size(), tris, voxel, lod_voxels);
  for (const Encoding& e : encodings) {
    std::vector<v1::Delta> deltas(chunks.size());
    auto t0 = Clock::now();
    for (size_t i = 0; i < chunks.size(); ++i) {
      auto* m = deltas[i].mutable_mesh_chunk_upserted();
      m->set_chunk_id(chunks[i].id);
      m->set_chunk_version(chunks[i].version);
      MeshToProto(chunks[i].mesh, m, e.plain, e.options);
      deltas[i].set_version(100000 + i);
    }
    const double enc_ms = MsSince(t0);
    size_t bytes = 0, payload = 0;
    for (const v1::Delta& d : deltas) {
      bytes += d.ByteSizeLong();
      payload += d.mesh_chunk_upserted().compact().size();
    }
    double max_err = 0, sum_err = 0;
    size_t nv = 0;
    t0 = Clock::now();
    std::vector<TriangleMesh> back(chunks.size());
    for (size_t i = 0; i < chunks.size(); ++i) {
      auto m = MeshFromProto(deltas[i].mesh_chunk_upserted());
      if (!m.ok()) {
        std::fprintf(stderr, "%s: chunk %zu: %s\n", e.name.c_str(), i,
                     std::string(m.status().message()).c_str());
        return 1;
      }
      back[i] = *std::move(m);
    }
    const double dec_ms = MsSince(t0);
    for (size_t i = 0; i < chunks.size(); ++i) {
      const TriangleMesh& a = chunks[i].mesh;
      const TriangleMesh& b = back[i];
      if (a.num_triangles() != b.num_triangles()) {
        std::fprintf(stderr, "%s: chunk %zu lost triangles\n", e.name.c_str(), i);
        return 1;
      }
      // Triangles may be reordered and vertices renumbered: each decoded vertex against the
      // nearest input vertex of its chunk (chunks hold tens of vertices).
      for (const glm::vec3& q : b.positions) {
        double best = 1e30;
        for (const glm::vec3& p : a.positions) best = std::min(best, double(glm::length(q - p)));
        max_err = std::max(max_err, best);
        sum_err += best;
        ++nv;
      }
    }
    // Bound: the chunks' payloads (their zstd removed) as ONE zstd stream.
    std::string joined;
    for (const v1::Delta& d : deltas) {
      const std::string& c = d.mesh_chunk_upserted().compact();
      if (c.size() > 5 && static_cast<uint8_t>(c[0]) == 2) {
        uint32_t raw = 0;
        std::memcpy(&raw, c.data() + 1, 4);
        std::vector<uint8_t> buf(raw);
        if (ZstdDecompress(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(c.data()) + 5,
                                                    c.size() - 5),
                           buf.data(), raw, "bench").ok())
          joined.append(reinterpret_cast<const char*>(buf.data()), raw);
      } else {
        joined += c;
      }
    }
    size_t one_stream = 0;
    if (!joined.empty()) {
      auto z = ZstdCompress(reinterpret_cast<const uint8_t*>(joined.data()), joined.size(), 3, {});
      if (z.ok()) one_stream = z->size();
    }
    nlohmann::json j;
    j["encoding"] = e.name;
    j["delta_bytes"] = bytes;
    j["payload_bytes"] = payload;
    j["bytes_per_triangle"] = double(bytes) / double(std::max<size_t>(tris, 1));
    j["encode_ms"] = enc_ms;
    j["decode_ms"] = dec_ms;
    j["one_zstd_stream_bytes"] = one_stream;
    j["max_err_mm"] = max_err * 1e3;
    j["mean_err_mm"] = nv ? sum_err / nv * 1e3 : 0.0;
    std::printf("%s\n", j.dump().c_str());
    std::fflush(stdout);
  }
  return 0;
}

}  // namespace
}  // namespace exo

int main(int argc, char** argv) { return exo::Main(argc, argv); }
