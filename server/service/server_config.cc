// ServerConfig: validation, the table of config keys (one entry per key: name, help, how to read
// and write it), the `key = value` file reader. The flags of exoview_server are built from the
// same table, so a key added here is a flag and a file key at once, with its default in --help.
#include <fstream>
#include <type_traits>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/strip.h"
#include "server/service/server.h"

namespace exo {
namespace {

template <typename T>
absl::Status ParseValue(const std::string& key, const std::string& v, T* out) {
  if constexpr (std::is_same_v<T, planning::PlannerOptions::Policy>) {
    for (int p = 0; p <= 3; ++p)
      if (v == planning::PolicyName(p) || v == absl::StrCat(p)) {
        *out = static_cast<T>(p);
        return absl::OkStatus();
      }
    return absl::InvalidArgumentError(absl::StrCat(
        "config ", key, ": '", v, "' is not a policy (lumigraph, min_distance, every_n, every_n_online)"));
  } else if constexpr (std::is_same_v<T, std::string>) {
    *out = v;
    return absl::OkStatus();
  } else if constexpr (std::is_same_v<T, double>) {
    if (absl::SimpleAtod(v, out)) return absl::OkStatus();
  } else if constexpr (std::is_same_v<T, bool>) {
    if (absl::SimpleAtob(v, out)) return absl::OkStatus();
  } else {
    int64_t x;
    if (absl::SimpleAtoi(v, &x) && x >= 0) {
      *out = static_cast<T>(x);
      return absl::OkStatus();
    }
  }
  return absl::InvalidArgumentError(absl::StrCat("config ", key, ": cannot parse '", v, "'"));
}

template <typename T>
std::string ValueText(const T& v) {
  if constexpr (std::is_same_v<T, bool>) {
    return v ? "true" : "false";
  } else if constexpr (std::is_same_v<T, planning::PlannerOptions::Policy>) {
    return planning::PolicyName(static_cast<int>(v));
  } else if constexpr (std::is_enum_v<T>) {
    return absl::StrCat(static_cast<int>(v));
  } else {
    return absl::StrCat(v);
  }
}

// One key bound to a field of ServerConfig (`field` returns a reference to it).
template <typename Field>
ConfigKey Key(std::string name, std::string help, Field field) {
  ConfigKey k;
  k.name = name;
  k.help = std::move(help);
  k.get = [field](const ServerConfig& c) {
    ServerConfig& m = const_cast<ServerConfig&>(c);  // `field` only reads here
    return ValueText(field(m));
  };
  k.set = [field, name](const std::string& v, ServerConfig* c) {
    return ParseValue(name, v, &field(*c));
  };
  return k;
}

#define EXO_FIELD(expr) \
  [](ServerConfig & c) -> auto& { return c.expr; }

std::vector<ConfigKey> MakeKeys() {
  std::vector<ConfigKey> keys = {
      Key("listen", "gRPC address host:port (port 0: a free port)", EXO_FIELD(listen)),
      Key("max_frame_bytes", "per-frame limit; larger frames are REJECTED",
          EXO_FIELD(ingest.max_frame_bytes)),
      Key("max_pixels", "per-image pixel limit (colour and depth each), checked before decoding",
          EXO_FIELD(ingest.decode.limits.max_pixels)),
      Key("scene_radius_m", "camera positions must lie within this radius of the scene centre",
          EXO_FIELD(ingest.decode.limits.scene_radius_m)),
      Key("scene_center_x", "scene centre x (world, m)", EXO_FIELD(ingest.decode.limits.scene_center.x)),
      Key("scene_center_y", "scene centre y (world, m)", EXO_FIELD(ingest.decode.limits.scene_center.y)),
      Key("scene_center_z", "scene centre z (world, m)", EXO_FIELD(ingest.decode.limits.scene_center.z)),
      Key("min_exposure", "smallest accepted relative exposure", EXO_FIELD(ingest.decode.limits.min_exposure)),
      Key("max_exposure", "largest accepted relative exposure", EXO_FIELD(ingest.decode.limits.max_exposure)),
      Key("transport_max_bytes", "gRPC message limit; larger messages end the stream",
          EXO_FIELD(transport_max_bytes)),
      Key("admission_queue", "frames admitted but not yet processed",
          EXO_FIELD(pipeline.admission_queue)),
      Key("stage_queue", "queue between pipeline stages", EXO_FIELD(pipeline.stage_queue)),
      Key("admission_block", "a full admission queue slows the client (no frame dropped)",
          EXO_FIELD(pipeline.admission_block)),
      Key("cell_size_m", "lumigraph cell size in m (0: from the first frame)", EXO_FIELD(pipeline.model.cell_m)),
      Key("max_log_deltas", "delta log bound (entries)", EXO_FIELD(store.max_log_deltas)),
      Key("max_log_bytes", "delta log bound (bytes)", EXO_FIELD(store.max_log_bytes)),
      Key("max_subscriber_lag", "deltas a subscriber may lag before a snapshot resync",
          EXO_FIELD(store.max_subscriber_lag)),
      Key("snapshot_when_cheaper", "resume with a snapshot when it costs less than the deltas",
          EXO_FIELD(store.snapshot_when_cheaper)),
      Key("snapshot_chunk_batch_bytes",
          "a snapshot's mesh chunks in zstd batches of up to this many bytes (0: one by one)",
          EXO_FIELD(store.snapshot_chunk_batch_bytes)),
      Key("publish_jpeg_quality", "JPEG quality of published views",
          EXO_FIELD(publish.jpeg_quality)),
      Key("publish_depth_downscale", "published depth at 1/k resolution",
          EXO_FIELD(publish.depth_downscale)),
      Key("publish_jpeg_optimize", "published views' JPEGs with optimised Huffman tables",
          EXO_FIELD(publish.jpeg_optimize)),
      Key("publish_depth_zstd_level", "zstd level of the published (lossless) depth",
          EXO_FIELD(publish.depth_zstd_level)),
      Key("geometry", "geometry stage (TSDF proxy)", EXO_FIELD(enable_geometry)),
      Key("voxel_size_m", "TSDF voxel of the proxy in m (0: from the first frame)", EXO_FIELD(pipeline.model.voxel_m)),
      Key("max_depth_m", "depth beyond this is not fused", EXO_FIELD(pipeline.model.max_depth_m)),
      Key("mesh_every_n_frames", "mesh extraction period in frames",
          EXO_FIELD(pipeline.model.mesh_every_n_frames)),
      Key("fuse_depth_downscale", "depth fused at 1/k resolution",
          EXO_FIELD(pipeline.model.fuse_depth_downscale)),
      Key("tsdf_threads", "TSDF integration threads", EXO_FIELD(pipeline.model.tsdf_threads)),
      Key("chunk_republish_change", "fraction of a chunk that must change to republish it",
          EXO_FIELD(geometry.republish_change_fraction)),
      Key("chunk_republish_extractions", "refresh a chunk on the clients when the frames fused into it grew by this factor since its last publication (0 = off)",
          EXO_FIELD(geometry.republish_extraction_factor)),
      Key("chunk_republish_extractions_max", "... while the chunk's last publication held fewer extractions than this",
          EXO_FIELD(geometry.republish_extraction_max)),
      Key("chunk_refresh_kbps", "budget for those refreshes: kbit per second of the stream's own time, largest growth first (0 = unlimited)",
          EXO_FIELD(geometry.refresh_budget_kbps)),
      Key("chunk_budget_structural", "structural chunk changes (triangle count beyond chunk_republish_change) share that budget, ahead of the refreshes (0 = sent at once)",
          EXO_FIELD(geometry.budget_structural)),
      Key("chunk_refresh_min_move_voxels", "... only chunks whose surface moved at least this much (mean vertex motion, voxels; 0 = all)",
          EXO_FIELD(geometry.refresh_min_move_voxels)),
      Key("chunk_lod_error_voxels", "clients' proxy LOD: published chunks simplified (quadric edge collapse, chunk borders locked) within this many voxels of the full mesh (0 = full resolution)",
          EXO_FIELD(geometry.publish_lod_error_voxels)),
      Key("chunk_step_voxels", "position step of the published chunks on the wire, voxels (0 = 16 bits over each chunk's box)",
          EXO_FIELD(geometry.publish_step_voxels)),
      Key("chunk_refresh_burst_s", "... bursts of up to this many seconds of the budget",
          EXO_FIELD(geometry.refresh_burst_s)),
      Key("chunk_republish_interval_s", "minimum seconds of stream time (frame timestamps) between republishing a chunk",
          EXO_FIELD(geometry.republish_interval_s)),
      Key("geometry_shed_backlog", "skip fusing a frame while this fraction of the admission queue waits (0 = never; off with admission_block)",
          EXO_FIELD(geometry.shed_backlog_fraction)),
      Key("planning", "planning stage (view store)", EXO_FIELD(enable_planning)),
      Key("inpainting", "InpaintFusion: region marking RPCs and the inpainting stage",
          EXO_FIELD(enable_inpainting)),
      Key("inpaint_radius_px", "r_ROI: default stroke radius of a marked region (pixels)",
          EXO_FIELD(regions.region.roi.radius_px)),
      Key("inpaint_depth_tol_m", "d_ROI: default depth tolerance along the normal (m)",
          EXO_FIELD(regions.region.roi.depth_tol_m)),
      Key("inpaint_voxel_m", "size of an L_ROI label voxel (m)", EXO_FIELD(regions.region.voxel_m)),
      Key("inpaint_max_regions", "marked regions at most", EXO_FIELD(regions.max_regions)),
      Key("completion", "scene completion at a viewer's request (CompleteView)",
          EXO_FIELD(enable_completion)),
      Key("completion_max_side_px", "longer side of a completion keyframe (the viewer's camera is scaled down to it)",
          EXO_FIELD(completion.max_side_px)),
      Key("completion_max_views", "completion views kept (oldest withdrawn beyond)",
          EXO_FIELD(completion.max_views)),
      Key("completion_min_hole_px", "fewer hole pixels than this: nothing to complete",
          EXO_FIELD(completion.completion.min_hole_px)),
      Key("completion_detail_gain", "completion colour in the holes: push-pull fill + this x PatchMatch's high frequencies (0 = push-pull only, the PSNR/SSIM optimum; < 0 = PatchMatch's colour, session 15)",
          EXO_FIELD(completion.completion.detail_gain)),
      Key("completion_refresh_period_s", "completion views re-checked against new observations this often (0 = never)",
          EXO_FIELD(completion.refresh_period_s)),
      Key("completion_nice", "the completion thread runs this much nicer than the server",
          EXO_FIELD(completion.nice)),
      Key("inpaint_max_keyframes", "inpainted keyframes kept (oldest withdrawn beyond)",
          EXO_FIELD(inpainting.max_keyframes)),
      Key("inpaint_method", "inpainted keyframes: dr (observed colour first from earlier frames, then PatchMatch; session 11) or keyframe (the whole ROI by PatchMatch; session 9)",
          EXO_FIELD(inpainting.method)),
      Key("inpaint_observation_views", "dr: earlier frames kept as observation views (0 = keyframes only; ~2 MB each at 640x480)",
          EXO_FIELD(inpainting.observation_views)),
      Key("inpaint_observation_stride", "dr: every Nth frame while a region is marked is kept as one",
          EXO_FIELD(inpainting.observation_stride)),
      Key("inpaint_fuse_proxy", "the clients' proxy without the marked regions: their surface carved, the inpainted keyframes' depth fused into L_IP voxels (the planner keeps the observed proxy); false = the object stays in the proxy",
          EXO_FIELD(geometry.inpaint_fuse)),
      Key("inpaint_carve_margin_voxels", "the carved ROI: the regions' label voxels grown by this many TSDF voxels",
          EXO_FIELD(geometry.inpaint_carve_margin_voxels)),
      Key("inpaint_refresh_min_px", "dr: republish a keyframe once this many of its inpainted pixels were later observed (0 = never)",
          EXO_FIELD(inpainting.refresh_min_px)),
      Key("inpaint_frame_stride", "the inpainting stage looks at every Nth frame (re-projection of the regions, keyframe rule, observations); 1 = every frame",
          EXO_FIELD(inpainting.frame_stride)),
      Key("inpaint_live_views", "live DR view: look-up views per frame (nearest pose first)",
          EXO_FIELD(inpainting.live_views)),
      Key("inpaint_live_always", "live DR view: composite every frame even when nobody watches (benchmarks)",
          EXO_FIELD(inpainting.live_always)),
      Key("inpaint_nice", "the inpainting stage's threads run this much nicer than the server (0 = the same priority)",
          EXO_FIELD(inpainting.nice)),
      Key("inpaint_frame_nice", "the inpainting stage's frame thread (re-projection, rule, live DR view) runs this much nicer than the server while the pipeline keeps up (see inpaint_frame_backoff_ms); -1 = inpaint_nice",
          EXO_FIELD(inpainting.frame_nice)),
      Key("inpaint_keyframe_nice", "the inpainting stage's keyframe thread runs this much nicer than the server while the pipeline keeps up (see inpaint_frame_backoff_ms); -1 = inpaint_nice",
          EXO_FIELD(inpainting.keyframe_nice)),
      Key("inpaint_frame_backoff_ms", "the DR frame and keyframe threads drop to inpaint_nice while frames reach the inpainting stage more than this many ms after admission (back at half of it); 0 = never",
          EXO_FIELD(inpainting.frame_backoff_ms)),
      Key("inpaint_kf_crop_margin_px", "dr: a keyframe inpaints a crop around its ROI grown by max(this, inpaint_kf_crop_margin_rel x the ROI's larger side) px (both 0: the whole frame)",
          EXO_FIELD(inpainting.kf_crop_margin_px)),
      Key("inpaint_kf_crop_margin_rel", "dr: see inpaint_kf_crop_margin_px",
          EXO_FIELD(inpainting.kf_crop_margin_rel)),
      Key("inpaint_threads", "threads of one keyframe's PatchMatch", EXO_FIELD(inpainting.inpaint.num_threads)),
      Key("inpaint_keyframe_pose_distance", "new keyframe beyond this ||I - Mi^-1 Mk||_F",
          EXO_FIELD(inpainting.policy.max_pose_distance)),
      Key("inpaint_keyframe_unlabelled", "new keyframe beyond this fraction of the ROI uncovered",
          EXO_FIELD(inpainting.policy.max_unlabelled_fraction)),
      Key("max_views", "view store capacity (views)", EXO_FIELD(pipeline.model.max_views)),
      Key("max_store_bytes", "view store capacity (bytes)", EXO_FIELD(pipeline.model.max_bytes)),
      Key("r_max", "references per cell of the planner's pre-selection R(b_k)", EXO_FIELD(pipeline.model.r_max)),
      Key("render_refs_max", "references per cell sent to the clients (0 = R(b_k); N = every stored observer, at most max(N, r_max))", EXO_FIELD(pipeline.model.render_refs_max)),
      Key("d_max_m", "ideal view distance in m (0: from the first frame)", EXO_FIELD(pipeline.model.d_max_m)),
      Key("sigma_m", "distance falloff in m (0: from the first frame)", EXO_FIELD(pipeline.model.sigma_m)),
      Key("lambda", "directional vs positional coverage weight (SPEC 3.6)",
          EXO_FIELD(pipeline.model.lambda)),
      Key("delta_tau_sum", "minimum objective gain to accept a view",
          EXO_FIELD(pipeline.model.delta_tau_sum)),
      Key("planner_policy",
          "which frames the view store keeps: lumigraph (the coverage planner, default) or an online baseline deciding from camera poses alone (min_distance, every_n = the length-aware oracle, needs planner_baseline_stream_frames; every_n_online = progressive); the planner's references follow the baseline's store (docs/planning.md \"Session 17 (lead)\")",
          EXO_FIELD(pipeline.model.policy)),
      Key("planner_baseline_m_per_rad", "min_distance policy: pose distance = metres + this x radians of turn",
          EXO_FIELD(pipeline.model.baseline_m_per_rad)),
      Key("planner_baseline_stream_frames", "every_n policy: the stream's length in frames (an oracle a real stream does not have)",
          EXO_FIELD(pipeline.model.baseline_stream_frames)),
      Key("planner_dispersion",
          "view selection: 0 = the thesis' coverage objective alone, 1 = pose dispersion among coverage ties, 2 = pose dispersion first, guarded by coverage (docs/planning.md)",
          EXO_FIELD(pipeline.model.dispersion)),
      Key("planner_dispersion_m_per_rad", "pose distance: metres per radian of turn (0: d_max)",
          EXO_FIELD(pipeline.model.dispersion_m_per_rad)),
      Key("planner_dispersion_time_steps", "pose distance: + this many of the stream's mean pose steps per frame between two views (time as a dimension; real sensors' errors are correlated in time; 0 = pose only; docs/planning.md \"Session 15\")",
          EXO_FIELD(pipeline.model.dispersion_time_steps)),
      Key("planner_dispersion_time_max", "... the larger of pose distance and time term instead of their sum (time sets apart only frames where the camera lingered)",
          EXO_FIELD(pipeline.model.dispersion_time_max)),
      Key("planner_dispersion_time_arc", "the time term's clock is the camera's travelled pose path instead of frame ids (a camera standing perfectly still adds no time; docs/planning.md \"Session 16\")",
          EXO_FIELD(pipeline.model.dispersion_time_arc)),
      Key("planner_dispersion_time_auto_ref", "> 0: the time term is on only where the stream's measured growth g of depth disagreement from 1 to 15 frames apart reaches this (time-correlated error: ~0 with exact poses; off below half of it, linear in between; 0 = κ as set; docs/planning.md \"Session 16\")",
          EXO_FIELD(pipeline.model.dispersion_time_auto_ref)),
      Key("planner_dispersion_rotation_scale", "pose distance when planner_dispersion_m_per_rad is 0: metres per radian of turn = this x d_max, in (0, 1] (docs/planning.md \"Session 15\")",
          EXO_FIELD(pipeline.model.dispersion_rotation_scale)),
      Key("planner_dispersion_guard", "dispersion 2: a view whose removal loses more coverage (tau) than this is kept, a frame that gains more is stored (1e9: no guard, pure pose dispersion)",
          EXO_FIELD(pipeline.model.dispersion_guard)),
      Key("planner_dispersion_guard_relative", "dispersion 2: the guard as this fraction of the mean tau per stored view (0: the absolute planner_dispersion_guard)",
          EXO_FIELD(pipeline.model.dispersion_guard_relative)),
      Key("planner_dispersion_guard_unique", "dispersion 2: the guard counts only the coverage a removal leaves with no stored view (true) instead of the tau from the coverage frozen at acceptance (false)",
          EXO_FIELD(pipeline.model.dispersion_guard_unique)),
      Key("planner_dispersion_guard_unique_after", "dispersion 2: the unique-coverage guard once the planner has been offered more than this many frames per view of capacity (0: never; planner_dispersion_guard_unique=true: always)",
          EXO_FIELD(pipeline.model.dispersion_guard_unique_after)),
      Key("max_candidates_per_s_when_full",
          "planner candidates per s once the store is full (0: all)",
          EXO_FIELD(pipeline.model.max_candidates_per_s_when_full)),
      Key("refinement", "refine accepted views' depth", EXO_FIELD(planning.refine)),
      Key("refine_queue", "views waiting for refinement", EXO_FIELD(planning.refine_queue)),
      Key("refine_downscale", "refinement at 1/k resolution", EXO_FIELD(planning.refine_downscale)),
      Key("refine_max_pose_m", "refinement keeps the input pose when it would move the camera farther (m; 0 = no limit)",
          EXO_FIELD(planning.refine_max_pose_m)),
      Key("refine_max_pose_deg", "refinement keeps the input pose when it would turn the camera more (deg; 0 = no limit)",
          EXO_FIELD(planning.refine_max_pose_deg)),
      Key("refine_max_exposure_ratio", "refinement keeps the prior exposure outside [1/r, r] (0 = no limit)",
          EXO_FIELD(planning.refine_max_exposure_ratio)),
      Key("refine_remove_outliers", "drop outlier depth in refinement",
          EXO_FIELD(planning.refine_remove_outliers)),
      Key("planning_id_from_proxy", "cell ids rendered from the proxy mesh instead of the depth",
          EXO_FIELD(pipeline.model.id_from_proxy)),
      Key("planning_cell_areas", "planner uses geometry's per-cell proxy areas",
          EXO_FIELD(planning_cell_areas)),
      Key("id_buffer_stride", "cell-id buffer = depth subsampled by this factor",
          EXO_FIELD(pipeline.model.id_buffer_stride)),
      Key("checkpoint_path", "checkpoint file (empty: off)", EXO_FIELD(checkpoint_path)),
      Key("checkpoint_interval_s", "seconds between checkpoints (0: only at shutdown)",
          EXO_FIELD(checkpoint_interval_s)),
      Key("checkpoint_max_log_bytes", "delta log tail kept in the checkpoint (bytes)",
          EXO_FIELD(checkpoint_max_log_bytes)),
      Key("checkpoint_quiesce_s", "a checkpoint waits at most this long for the pipeline to drain (beyond: written without the stages' state)",
          EXO_FIELD(checkpoint_quiesce_s)),
      Key("journal", "write-ahead journal of accepted frames (needs checkpoint_path): acks durable",
          EXO_FIELD(journal)),
      Key("journal_dir", "journal directory (empty: checkpoint_path + \".journal\")",
          EXO_FIELD(journal_dir)),
      Key("journal_max_bytes", "journal bytes not yet covered by a checkpoint (beyond: REJECTED)",
          EXO_FIELD(journal_max_bytes)),
      Key("journal_segment_bytes", "journal segment size (bytes)", EXO_FIELD(journal_segment_bytes)),
      Key("delta_log",
          "where published deltas go: memory (embedded, the server serves every viewer) or "
          "jetstream (NATS JetStream, read by exoview_relay; docs/deploy.md)",
          EXO_FIELD(delta_log.kind)),
      Key("nats_url", "NATS server URL(s), comma-separated (delta_log=jetstream)",
          EXO_FIELD(delta_log.nats_url)),
      Key("scene", "scene name: names the JetStream stream, snapshot stream and KV bucket",
          EXO_FIELD(delta_log.scene)),
      Key("nats_replicas", "JetStream stream replicas (3 in a NATS cluster)",
          EXO_FIELD(delta_log.nats_replicas)),
      Key("nats_snapshot_interval_s", "seconds between model snapshots in JetStream",
          EXO_FIELD(delta_log.snapshot_interval_s)),
      Key("nats_max_stream_bytes", "bound of the scene's delta stream (bytes; oldest dropped)",
          EXO_FIELD(delta_log.max_stream_bytes)),
      Key("nats_connect_timeout_s", "how long the server retries the first NATS connection",
          EXO_FIELD(delta_log.connect_timeout_s)),
      Key("udp_pose_address", "address of the UDP pose input", EXO_FIELD(udp_pose_address)),
      Key("udp_pose_key_file",
          "file with the shared key of HMAC-authenticated UDP pose datagrams (empty: plain)",
          EXO_FIELD(udp_pose_key_file)),
      Key("udp_pose_tolerance_s", "a frame with no UDP pose this close is rejected",
          EXO_FIELD(udp_pose_tolerance_s)),
      Key("udp_pose_max_lead_s",
          "a pose datagram whose timestamp runs this far ahead of the server clock is rejected",
          EXO_FIELD(udp_pose_time.max_lead_s)),
      Key("udp_pose_max_lag_s",
          "a pose datagram whose timestamp lags the server clock this much is rejected",
          EXO_FIELD(udp_pose_time.max_lag_s)),
      Key("udp_pose_max_backwards_s",
          "a pose datagram this much older than the newest accepted one is rejected",
          EXO_FIELD(udp_pose_time.max_backwards_s)),
      Key("udp_pose_rebase_after_s",
          "after this long of consistent rejected pose datagrams the time base is re-anchored",
          EXO_FIELD(udp_pose_time.rebase_after_s)),
      Key("tls_cert", "server certificate chain (PEM); with tls_key: TLS", EXO_FIELD(tls_cert)),
      Key("tls_key", "server private key (PEM)", EXO_FIELD(tls_key)),
      Key("tls_client_ca", "CA (PEM) of required client certificates: mutual TLS",
          EXO_FIELD(tls_client_ca)),
      Key("auth_tokens_file", "bearer tokens, 'ROLE TOKEN NAME' lines (needs TLS; empty: no auth)",
          EXO_FIELD(auth_tokens_file)),
      Key("allow_insecure_remote", "allow plain text on a non-loopback address (never in production)",
          EXO_FIELD(allow_insecure_remote)),
      Key("max_upload_streams", "concurrent Upload streams (beyond: RESOURCE_EXHAUSTED)",
          EXO_FIELD(max_upload_streams)),
      Key("max_subscribers", "concurrent Subscribe calls (beyond: RESOURCE_EXHAUSTED)",
          EXO_FIELD(max_subscribers)),
      Key("malloc_arena_max", process::kMallocArenaMaxHelp, EXO_FIELD(malloc_arena_max)),
      Key("malloc_mmap_threshold", process::kMallocMmapThresholdHelp,
          EXO_FIELD(malloc_mmap_threshold)),
      Key("max_client_inflight_bytes",
          "decoded bytes of one client's frames inside the pipeline (beyond: REJECTED)",
          EXO_FIELD(max_client_inflight_bytes)),
      Key("subscriber_write_timeout_s", "a subscriber not reading for this long is cancelled (0: never)",
          EXO_FIELD(subscriber_write_timeout_s)),
      Key("upload_idle_timeout_s", "an upload stream idle for this long is cancelled (0: never)",
          EXO_FIELD(upload_idle_timeout_s)),
      Key("keepalive_time_s", "HTTP/2 keepalive ping interval on idle connections",
          EXO_FIELD(keepalive_time_s)),
      Key("keepalive_timeout_s", "a connection that does not answer a ping this fast is closed",
          EXO_FIELD(keepalive_timeout_s)),
      Key("log_rejections_per_s",
          "rejected-frame log lines per second per stream (the rest counted)",
          EXO_FIELD(log_rejections_per_s)),
  };
  ConfigKey udp = Key("udp_pose_port", "UDP pose input port (-1: off, 0: a free port)",
                      EXO_FIELD(udp_pose_port));
  udp.set = [](const std::string& value, ServerConfig* c) {
    int64_t p;
    if (!absl::SimpleAtoi(value, &p) || p < -1 || p > 65535)
      return absl::InvalidArgumentError("config udp_pose_port: -1 (off) or 0..65535");
    c->udp_pose_port = static_cast<int>(p);
    return absl::OkStatus();
  };
  keys.push_back(std::move(udp));
  AppendControlConfigKeys(&keys);
  return keys;
}

#undef EXO_FIELD

}  // namespace

const std::vector<ConfigKey>& ConfigKeys() {
  static const std::vector<ConfigKey> keys = MakeKeys();
  return keys;
}

absl::Status ServerConfig::Validate() const {
  if (listen.empty()) return absl::InvalidArgumentError("listen address is empty");
  EXO_RETURN_IF_ERROR(ingest.Validate());
  if (transport_max_bytes < ingest.max_frame_bytes)
    return absl::InvalidArgumentError("transport_max_bytes must be >= max_frame_bytes");
  EXO_RETURN_IF_ERROR(pipeline.Validate());
  EXO_RETURN_IF_ERROR(store.Validate());
  EXO_RETURN_IF_ERROR(delta_log.Validate());
  EXO_RETURN_IF_ERROR(publish.Validate());
  EXO_RETURN_IF_ERROR(geometry.Validate());
  EXO_RETURN_IF_ERROR(planning.Validate());
  if (enable_inpainting) {
    EXO_RETURN_IF_ERROR(regions.Validate());
    EXO_RETURN_IF_ERROR(inpainting.Validate());
  }
  if (enable_completion) EXO_RETURN_IF_ERROR(completion.Validate());
  if (!(checkpoint_quiesce_s >= 0.0 && checkpoint_quiesce_s <= 600.0))
    return absl::InvalidArgumentError("checkpoint_quiesce_s must be in [0, 600]");
  if (!(checkpoint_interval_s >= 0.0))
    return absl::InvalidArgumentError("checkpoint_interval_s must be >= 0 (0 = only at shutdown)");
  if (journal_enabled()) {
    if (journal_segment_bytes < 4096)
      return absl::InvalidArgumentError("journal_segment_bytes must be >= 4096");
    if (journal_max_bytes < 2 * journal_segment_bytes || journal_max_bytes < 2 * transport_max_bytes)
      return absl::InvalidArgumentError(
          "journal_max_bytes must be >= 2 x journal_segment_bytes and >= 2 x transport_max_bytes");
  }
  if (tls_cert.empty() != tls_key.empty())
    return absl::InvalidArgumentError("tls_cert and tls_key go together");
  if (!tls_client_ca.empty() && tls_cert.empty())
    return absl::InvalidArgumentError("tls_client_ca (mutual TLS) needs tls_cert and tls_key");
  if (!auth_tokens_file.empty() && tls_cert.empty())
    return absl::InvalidArgumentError(
        "auth_tokens_file needs TLS (tls_cert, tls_key): bearer tokens in plain text can be read "
        "by anyone on the path");
  if (max_upload_streams < 1) return absl::InvalidArgumentError("max_upload_streams must be >= 1");
  if (max_subscribers < 1) return absl::InvalidArgumentError("max_subscribers must be >= 1");
  if (malloc_arena_max < 0)
    return absl::InvalidArgumentError("malloc_arena_max must be >= 0 (0 = glibc default)");
  if (malloc_mmap_threshold > (size_t{32} << 20))
    return absl::InvalidArgumentError("malloc_mmap_threshold must be <= 32 MiB (0 = glibc dynamic)");
  if (max_client_inflight_bytes < (size_t{1} << 20))
    return absl::InvalidArgumentError("max_client_inflight_bytes must be >= 1 MiB");
  if (!(subscriber_write_timeout_s >= 0.0) || !(upload_idle_timeout_s >= 0.0))
    return absl::InvalidArgumentError("timeouts must be >= 0 (0 = never)");
  if (!(keepalive_time_s >= 1.0) || !(keepalive_timeout_s >= 1.0))
    return absl::InvalidArgumentError("keepalive_time_s and keepalive_timeout_s must be >= 1");
  if (log_rejections_per_s < 1)
    return absl::InvalidArgumentError("log_rejections_per_s must be >= 1");
  return absl::OkStatus();
}

absl::Status ApplyConfigValue(const std::string& key, const std::string& value, ServerConfig* c) {
  for (const ConfigKey& k : ConfigKeys())
    if (k.name == key) return k.set(value, c);
  return absl::InvalidArgumentError(absl::StrCat("unknown config key '", key, "'"));
}

absl::Status LoadConfigFile(const std::string& path, ServerConfig* c) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot open config file ", path));
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    absl::string_view s = absl::StripAsciiWhitespace(line);
    if (s.empty()) continue;
    const auto eq = s.find('=');
    if (eq == absl::string_view::npos)
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": expected key = value"));
    const std::string key(absl::StripAsciiWhitespace(s.substr(0, eq)));
    const std::string value(absl::StripAsciiWhitespace(s.substr(eq + 1)));
    if (auto st = ApplyConfigValue(key, value, c); !st.ok())
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": ", st.message()));
  }
  return absl::OkStatus();
}

}  // namespace exo
