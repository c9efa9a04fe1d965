// The Exoview modeling server: gRPC service exoview.v1.Exoview (Upload, Subscribe, GetStats) +
// the standard health service, wired to ingest validation, the staged pipeline and the
// versioned ModelStore/publisher. Config: `key = value` file lines and `--key=value` flags share
// one set of keys (ConfigKeys, server_config.cc; `exoview_server --help` lists them).
#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>
#include <memory>
#include <string>
#include <vector>

#include "common/process/malloc_tuning.h"
#include "common/status.h"
#include "server/service/ingest.h"
#include "proto/model_proto.h"
#include "server/service/model_store.h"
#include "server/service/delta_log.h"
#include "server/service/frame_journal.h"
#include "server/service/udp_pose_input.h"
#include "server/service/geometry_stage.h"
#include "server/service/pipeline.h"
#include "server/service/planning_stage.h"
#include "server/service/control_service.h"
#include "server/service/inpainting_stage.h"
#include "server/service/completion_stage.h"
#include "server/service/regions.h"
#include "server/service/observed_chunks.h"

namespace grpc {
class Server;
class ServerCredentials;
}

namespace exo {

struct ServerConfig {
  std::string listen = "127.0.0.1:50051";  // port 0 = pick a free port (see ExoviewServer::port)
  IngestOptions ingest;
  // Transport limit (gRPC max receive size). Above ingest.max_frame_bytes a frame still gets a
  // per-frame REJECTED ack; only messages above this hard limit end the stream.
  size_t transport_max_bytes = size_t{64} << 20;
  PipelineOptions pipeline;
  ModelStoreOptions store;
  DeltaLogOptions delta_log;         // where published deltas go (memory | jetstream)
  ViewEncodeOptions publish;         // what clients receive per view
  // Stages (each only where the server was built with it).
  bool enable_geometry = true;
  GeometryStageOptions geometry;
  bool enable_planning = true;
  PlanningStageOptions planning;     // planning.publish is taken from `publish`
  bool planning_cell_areas = true;   // planner uses geometry's per-cell proxy areas A(b_k)
  // InpaintFusion (SPEC §7, docs/inpainting.md): region marking RPCs and the inpainting stage.
  bool enable_inpainting = true;
  RegionRegistryOptions regions;
  InpaintingStageOptions inpainting;  // inpainting.publish is taken from `publish`
  // Scene completion at a viewer's request (CompleteView; completion_stage.h).
  bool enable_completion = true;
  CompletionStageOptions completion;  // completion.publish is taken from `publish`
  // Optional UDP pose input: -1 = off; 0 = any free port (see ExoviewServer::udp_pose_port).
  int udp_pose_port = -1;
  std::string udp_pose_address = "127.0.0.1";
  double udp_pose_tolerance_s = 0.02;  // a frame with no pose sample this close is rejected
  // Timestamp bounds of pose datagrams against the server clock (udp_pose_input.h).
  PoseTimeGateOptions udp_pose_time;
  // Shared key of authenticated pose datagrams (HMAC-SHA256, udp_pose_input.h); empty: plain
  // datagrams, only on a loopback address unless allow_insecure_remote.
  std::string udp_pose_key_file;
  // Checkpoint (SPEC §12): empty path = off. Written every `checkpoint_interval_s` when the model
  // changed (tmp + fsync + rename) and at graceful shutdown; loaded at start when present.
  std::string checkpoint_path;
  double checkpoint_interval_s = 30.0;
  size_t checkpoint_max_log_bytes = size_t{16} << 20;  // delta log tail kept in the checkpoint
  // A checkpoint pauses admission until the pipeline has drained (every admitted frame through
  // every stage, no async work pending) and saves the stages' state with the model; beyond this
  // wait it is written without that state (a restart then rebuilds the planner, new TSDF).
  double checkpoint_quiesce_s = 10.0;
  // Frame journal (issue 20 item 3; server/service/frame_journal.h): with a checkpoint path, every
  // accepted frame is appended to a write-ahead journal and acked `durable` only after an
  // fdatasync covers it; a restart replays what the checkpoint does not cover. journal_dir ""
  // = checkpoint_path + ".journal". Beyond journal_max_bytes not yet covered by a checkpoint,
  // frames are REJECTED RESOURCE_EXHAUSTED (a checkpoint is requested at half of it).
  bool journal = true;
  std::string journal_dir;
  size_t journal_max_bytes = size_t{1} << 30;
  size_t journal_segment_bytes = size_t{64} << 20;
  bool journal_enabled() const { return journal && !checkpoint_path.empty(); }
  std::string journal_directory() const {
    return journal_dir.empty() ? checkpoint_path + ".journal" : journal_dir;
  }
  // Transport security and roles (docs/security.md). TLS when tls_cert/tls_key are given (PEM
  // files); with tls_client_ca also mutual TLS (a client certificate signed by that CA is
  // required). Bearer tokens from auth_tokens_file ("ROLE TOKEN NAME" lines) are then required
  // on every call (server/service/auth.h); tokens need TLS. Plain text is the embedded demo
  // default and only on a loopback address unless allow_insecure_remote.
  std::string tls_cert, tls_key, tls_client_ca;
  std::string auth_tokens_file;
  bool allow_insecure_remote = false;
  // Abuse bounds (issue 20 item 4; docs/security.md). Beyond a count limit a new call ends at
  // once with RESOURCE_EXHAUSTED and a reason naming the limit.
  int max_upload_streams = 16;
  int max_subscribers = 1024;
  // glibc malloc arenas (M_ARENA_MAX, set by exoview_server before any thread starts; 0 = glibc's
  // default of 8 per core). With the default, the pipeline's and gRPC's threads each grow their
  // own arena and the free memory they keep rose 91 -> 162 MB over 10 000 unpaced frames; 2 keeps
  // it near 56 MB and RSS flat (docs/service.md "Memory over a long session").
  int malloc_arena_max = process::kDefaultMallocArenaMax;
  // glibc M_MMAP_THRESHOLD (bytes; 0 = glibc's dynamic threshold), set with malloc_arena_max:
  // a fixed 128 KiB keeps large transient buffers (frames, meshes) out of the arenas, where they
  // left ~40 MB of free holes (docs/service.md "Memory over a long session").
  size_t malloc_mmap_threshold = process::kDefaultMallocMmapThreshold;
  // Decoded bytes of a client's accepted frames still inside the pipeline (client = the peer
  // host, or the authenticated principal); beyond it a frame is REJECTED RESOURCE_EXHAUSTED.
  size_t max_client_inflight_bytes = size_t{256} << 20;
  // A subscriber whose Write has not completed for this long (it does not read) is cancelled;
  // an upload stream with no message for this long is cancelled. 0 = never.
  double subscriber_write_timeout_s = 10.0;
  double upload_idle_timeout_s = 120.0;
  // HTTP/2 keepalive: the server pings an idle connection every keepalive_time_s and closes it
  // when no answer comes within keepalive_timeout_s (a vanished client frees its calls).
  double keepalive_time_s = 30.0;
  double keepalive_timeout_s = 10.0;
  // Log: at most this many rejected-frame lines per second per upload stream (the rest are
  // counted and reported with the next line and in the stream's summary).
  int log_rejections_per_s = 5;
  // Drone control service (control_* keys); served when a flight zone is configured.
  ControlServiceOptions control;
  absl::Status Validate() const;
};

// One config key: the same name in the file (`key = value`) and as a flag (--key=value).
struct ConfigKey {
  std::string name;
  std::string help;
  std::function<std::string(const ServerConfig&)> get;  // the value as text
  std::function<absl::Status(const std::string&, ServerConfig*)> set;
};
// Every key, in the order --help lists them (server_config.cc).
const std::vector<ConfigKey>& ConfigKeys();
// Applies one key/value (from a config file line or a --key=value flag).
absl::Status ApplyConfigValue(const std::string& key, const std::string& value, ServerConfig* c);
// Reads `key = value` lines ('#' starts a comment).
absl::Status LoadConfigFile(const std::string& path, ServerConfig* c);
// Stage names this binary was built with.
std::vector<std::string> AvailableStages();

class ExoviewServer {
 public:
  explicit ExoviewServer(const ServerConfig& config);
  ~ExoviewServer();
  absl::Status Start();
  int port() const { return port_; }
  int udp_pose_port() const;
  // Graceful: stops taking frames, ends subscriptions, drains the pipeline, stops gRPC.
  void Shutdown();
  void Wait();
  ModelStore& store() { return *store_; }
  // Writes the checkpoint now (atomic). No-op without checkpoint_path.
  absl::Status WriteCheckpoint(bool force = false);
  uint64_t restored_version() const { return restored_version_; }
  // The drone control core (null when no flight zone is configured).
  control::ControlCore* control_core() { return control_ ? &control_->core() : nullptr; }

 private:
  class Service;
  struct Durability;
  absl::Status ReplayJournal(std::unique_ptr<FrameJournal> journal,
                             const FrameJournal::OpenReport& report);
  absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> MakeServerCredentials() const;
  std::unique_ptr<class UdpPoseInput> udp_;
  ServerConfig config_;
  std::unique_ptr<ModelStore> store_;
  std::unique_ptr<DeltaLog> delta_log_;
  std::unique_ptr<Pipeline> pipeline_;
  std::shared_ptr<RegionRegistry> regions_;  // null without inpainting
  InpaintingStage* inpainting_ = nullptr;    // owned by pipeline_
  // The labelled proxy's chunks as observed: geometry stage -> drone control (observed_chunks.h).
  std::shared_ptr<ObservedChunks> observed_chunks_ = std::make_shared<ObservedChunks>();
  // Every chunk at full resolution with its fused vertex colours: geometry stage -> scene
  // completion's colour guide (null without completion).
  std::shared_ptr<ObservedChunks> coloured_chunks_;
  std::unique_ptr<CompletionStage> completion_;  // null with completion off
  std::unique_ptr<Durability> durability_;
  std::unique_ptr<Service> service_;
  std::unique_ptr<ControlServiceHost> control_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
  std::atomic<bool> shutting_down_{false};
  std::atomic<bool> pipeline_state_warned_{false};
  uint64_t restored_version_ = 0;
  uint64_t checkpoint_version_ = 0;  // last written
  uint64_t checkpoint_regions_generation_ = 0;
  uint64_t checkpoint_ledger_ = 0;   // ModelStore::ledger_changes() of the last written
  uint64_t journal_dropped_upto_ = 0;  // applied lsn of the previous generation
  bool checkpoint_requested_ = false;  // checkpoint_mu_
  // The periodic thread, shutdown, region RPCs and the journal's requests write checkpoints.
  std::mutex checkpoint_write_mu_;
  std::mutex checkpoint_mu_;
  std::condition_variable checkpoint_cv_;
  std::thread checkpoint_thread_;
};

}  // namespace exo
