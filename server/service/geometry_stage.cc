#include "server/service/geometry_stage.h"

#include "server/geometry/inpainted_surface.h"
#include "server/geometry/mesh_lod.h"
#include "server/inpainting/region_labels.h"
#include "common/state_io.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <unordered_map>
#include <utility>
#include <vector>

namespace exo {

void GeometryHandoff::Push(core::GeometryUpdate update) {
  std::lock_guard lock(mu_);
  updates_.push_back(std::move(update));
}

std::optional<core::GeometryUpdate> GeometryHandoff::Pop() {
  std::lock_guard lock(mu_);
  if (updates_.empty()) return std::nullopt;
  core::GeometryUpdate u = std::move(updates_.front());
  updates_.pop_front();
  return u;
}

namespace {

class GeometryStage final : public PipelineStage {
 public:
  GeometryStage(const GeometryStageOptions& options, const core::OnlineModelOptions& model,
                std::shared_ptr<GeometryHandoff> handoff,
                std::shared_ptr<InpaintedProxyLink> inpainted,
                std::shared_ptr<ObservedChunks> coloured)
      : options_(options), model_(model), handoff_(std::move(handoff)),
        link_(options.inpaint_fuse ? std::move(inpainted) : nullptr),
        coloured_(std::move(coloured)) {
    if (link_) link_->SetApplier([this] { ApplyFromLink(); });
  }
  ~GeometryStage() override {
    if (link_) link_->SetApplier(nullptr);  // waits for a Kick in progress
  }
  std::string name() const override { return "geometry"; }

  void SetBacklog(size_t queued, size_t capacity) override {
    queued_ = queued;
    capacity_ = capacity;
  }

  absl::Status Process(const PipelineFrame& f, const SceneContext& ctx) override {
    std::lock_guard stage(stage_mu_);
    ctx_ = &ctx;
    // Load shedding (GeometryStageOptions::shed_backlog_fraction): skip fusing this frame.
    const bool shed = options_.shed_backlog_fraction > 0 && has_geometry_ &&
                      static_cast<double>(queued_) >=
                          options_.shed_backlog_fraction * static_cast<double>(capacity_) &&
                      shed_run_ < options_.shed_max_run;
    if (shed) {
      ++shed_run_;
      shed_.fetch_add(1);
      if (handoff_) handoff_->Push(core::GeometryUpdate{});
      if (geometry_) PublishOverlay(SyncOverlay(), ctx, last_now_ns_);
      return absl::OkStatus();
    }
    shed_run_ = 0;
    const int64_t t0 = SteadyNowNs();
    absl::StatusOr<core::GeometryUpdate> u = Integrate(f.frame, ctx);
    has_geometry_ = true;
    integrate_ns_ += SteadyNowNs() - t0;
    // Exactly one hand-off entry per frame, also when integration failed (an empty update).
    if (handoff_) handoff_->Push(u.ok() ? *u : core::GeometryUpdate{});
    EXO_RETURN_IF_ERROR(u.status());
    if (coloured_) {  // scene completion's colour guide: the observed chunks, full res, colours
      for (const MeshChunk& c : u->chunks) coloured_->Set(c.id, ForColour(c.mesh));
      for (uint64_t id : u->removed) coloured_->Set(id, TriangleMesh{});
    }
    last_now_ns_ = static_cast<int64_t>(std::llround(f.frame.timestamp_s * 1e9));
    last_time_s_ = f.frame.timestamp_s;
    // The labelled proxy (the planner got the observed update above): blocks the overlay
    // changed are published below, the others' re-meshed chunks get the clients' mesh.
    const std::vector<uint64_t> dirty = SyncOverlay();
    ApplyOverlay(&*u, dirty);
    Publish(*std::move(u), ctx, f.frame.timestamp_s);
    PublishOverlay(dirty, ctx, last_now_ns_);
    return absl::OkStatus();
  }

  void AddCounters(std::map<std::string, double>* out) const override {
    std::lock_guard lock(mu_);
    if (!geometry_) return;
    (*out)["geometry.fused"] = static_cast<double>(geometry_->fused());
    (*out)["geometry.shed"] = static_cast<double>(shed_.load());
    (*out)["geometry.chunks_refreshed"] = static_cast<double>(refreshed_.load());
    // Wire bytes of the published chunks by why they went out (diagnostics, not checkpointed).
    (*out)["geometry.published_bytes_new"] = static_cast<double>(pub_bytes_[kNew].load());
    (*out)["geometry.published_bytes_structural"] =
        static_cast<double>(pub_bytes_[kStructural].load());
    (*out)["geometry.published_bytes_interval"] = static_cast<double>(pub_bytes_[kInterval].load());
    (*out)["geometry.published_bytes_refresh"] = static_cast<double>(pub_bytes_[kRefresh].load());
    (*out)["geometry.refresh_skipped_still"] = static_cast<double>(refresh_still_.load());
    (*out)["geometry.lod_triangles_in"] = static_cast<double>(lod_in_.load());
    (*out)["geometry.lod_triangles_out"] = static_cast<double>(lod_out_.load());
    (*out)["geometry.lod_fallbacks"] = static_cast<double>(lod_fallbacks_.load());
    (*out)["geometry.lod_ms"] = static_cast<double>(lod_ns_.load()) * 1e-6;
    (*out)["geometry.digest"] = static_cast<double>(geometry_->Digest());
    if (link_) {
      (*out)["geometry.inpaint_keyframes_fused"] = static_cast<double>(ip_fused_.load());
      (*out)["geometry.inpaint_keyframes_failed"] = static_cast<double>(ip_failed_.load());
      (*out)["geometry.inpaint_voxels_kept"] = static_cast<double>(ip_kept_.load());
      (*out)["geometry.inpaint_voxels_erased"] = static_cast<double>(ip_erased_.load());
      (*out)["geometry.inpaint_roi_voxels"] = static_cast<double>(ip_roi_voxels_.load());
      (*out)["geometry.inpaint_chunks_published"] = static_cast<double>(ip_published_.load());
      (*out)["geometry.inpaint_chunks_removed"] = static_cast<double>(ip_removed_.load());
      // Wall ms: fusing keyframes and regions (sync), the clients' mesh of re-meshed chunks
      // (apply), the chunks the overlay changed (publish: marching cubes, LOD, store).
      (*out)["geometry.inpaint_sync_ms_total"] = static_cast<double>(ip_sync_ns_.load()) * 1e-6;
      (*out)["geometry.inpaint_apply_ms_total"] = static_cast<double>(ip_apply_ns_.load()) * 1e-6;
      (*out)["geometry.inpaint_publish_ms_total"] = static_cast<double>(ip_ns_.load()) * 1e-6;
      (*out)["geometry.inpaint_waiting_dropped"] = static_cast<double>(link_->dropped());
    }
    (*out)["geometry.voxel_m"] = geometry_->volume().options().voxel_size_m;
    // TSDF integration + dirty-chunk meshing per frame (the rest of process_ms: hand-off, publish)
    (*out)["geometry.integrate_mesh_ms_mean"] =
        geometry_->fused() ? integrate_ns_.load() * 1e-6 / static_cast<double>(geometry_->fused())
                           : 0.0;
  }

 private:
  absl::StatusOr<core::GeometryUpdate> Integrate(const Frame& frame, const SceneContext& ctx) {
    std::lock_guard lock(mu_);
    if (!geometry_) {
      EXO_ASSIGN_OR_RETURN(geometry_, core::OnlineGeometry::Create(model_, ctx.setup));
    }
    return geometry_->Integrate(frame);
  }

  void Publish(core::GeometryUpdate u, const SceneContext& ctx, double source_time_s) {
    // The stream's own time (the frame's timestamp), not the server's clock: what is published
    // is a function of the frames alone (a restarted server replaying its journal at full speed
    // publishes what an uninterrupted one did, issue 20).
    const int64_t now = static_cast<int64_t>(std::llround(source_time_s * 1e9));
    for (MeshChunk& c : u.chunks) {
      ++extractions_[c.id];
      auto it = published_.find(c.id);
      if (it != published_.end()) {
        const double change = TriangleChange(c, it->second.triangles);
        const double age_s = (now - it->second.time_ns) * 1e-9;
        if (age_s < options_.republish_interval_s &&
            (change <= options_.republish_change_fraction || BudgetsStructural())) {
          // Newest mesh, published when due: at the interval, or by Refresh (a structural change
          // first, within the budget, when structural changes are budgeted).
          pending_[c.id] = std::move(c);
          continue;
        }
        pub_bytes_[age_s >= options_.republish_interval_s ? kInterval : kStructural] +=
            PublishChunk(std::move(c), now, ctx);
        continue;
      }
      pub_bytes_[kNew] += PublishChunk(std::move(c), now, ctx);
    }
    // Held-back chunks whose interval has passed.
    for (auto it = pending_.begin(); it != pending_.end();) {
      auto pub = published_.find(it->first);
      if (pub == published_.end() ||
          (now - pub->second.time_ns) * 1e-9 >= options_.republish_interval_s) {
        MeshChunk c = std::move(it->second);
        it = pending_.erase(it);
        pub_bytes_[kInterval] += PublishChunk(std::move(c), now, ctx);
      } else {
        ++it;
      }
    }
    Refresh(now, ctx, source_time_s);
    for (uint64_t id : u.removed) {
      pending_.erase(id);
      extractions_.erase(id);
      if (published_.erase(id)) (void)ctx.store->RemoveChunk(id);
    }
  }

  // The relative change of a chunk's triangle count against its last publication's.
  static double TriangleChange(const MeshChunk& c, size_t published_triangles) {
    const double old_n = static_cast<double>(published_triangles);
    return std::abs(static_cast<double>(c.mesh.num_triangles()) - old_n) / std::max(1.0, old_n);
  }

  // Structural changes of published chunks share the refresh bucket (ahead of the growth
  // refreshes) when there is a bucket to share.
  bool BudgetsStructural() const {
    return options_.budget_structural && options_.republish_extraction_factor > 0.0 &&
           options_.refresh_budget_kbps > 0.0;
  }

  // Held-back chunks whose extraction count grew by republish_extraction_factor since their
  // publication, largest growth first, within the token bucket (GeometryStageOptions).
  void Refresh(int64_t now, const SceneContext& ctx, double source_time_s) {
    if (options_.republish_extraction_factor <= 0.0) return;
    const double rate = options_.refresh_budget_kbps * 125.0;  // bytes per stream second
    const double burst = rate * options_.refresh_burst_s;
    if (rate > 0.0) {
      // Stream time, clamped: a clock jump or a restart of the stream neither floods nor starves.
      const double dt = last_source_s_ ? std::clamp(source_time_s - *last_source_s_, 0.0,
                                                    options_.refresh_burst_s)
                                       : 0.0;
      tokens_ = std::min(burst, tokens_ + dt * rate);
    }
    last_source_s_ = source_time_s;
    // (priority, chunk id): structural changes (budgeted) first, by relative change, then the
    // growth refreshes by growth.
    constexpr double kStructuralFirst = 1e12;
    std::vector<std::pair<double, uint64_t>> due;
    const bool structural = BudgetsStructural();
    for (const auto& [id, chunk] : pending_) {
      const auto pub = published_.find(id);
      if (pub == published_.end()) continue;
      if (structural) {
        const double change = TriangleChange(chunk, pub->second.triangles);
        if (change > options_.republish_change_fraction) {
          due.push_back({kStructuralFirst + change, id});
          continue;
        }
      }
      if (pub->second.extractions >= static_cast<uint64_t>(options_.republish_extraction_max))
        continue;
      const double growth = static_cast<double>(extractions_[id]) /
                            static_cast<double>(pub->second.extractions);
      if (growth >= options_.republish_extraction_factor) due.push_back({growth, id});
    }
    std::sort(due.begin(), due.end(), [](const auto& a, const auto& b) {
      return a.first != b.first ? a.first > b.first : a.second < b.second;
    });
    const double voxel = ctx.setup.voxel_m;
    for (const auto& [priority, id] : due) {
      auto it = pending_.find(id);
      Published& pub = published_[id];
      const bool is_structural = priority >= kStructuralFirst;
      if (!is_structural && options_.refresh_min_move_voxels > 0.0 &&
          MeanMove(it->second.mesh.positions, pub.positions, voxel) <
              options_.refresh_min_move_voxels * voxel) {
        pub.extractions = std::max<uint64_t>(1, extractions_[id]);  // wait for the next step
        refresh_still_.fetch_add(1);
        continue;
      }
      // A refresh goes out while the bucket holds tokens and is charged its actual bytes on the
      // wire (the encoding, LOD and zstd decide them): the bucket may go into debt by one chunk,
      // so the long-run rate is the budget in real bytes.
      if (rate > 0.0 && tokens_ <= 0.0) break;  // wait for tokens, keep the order
      MeshChunk c = std::move(it->second);
      pending_.erase(it);
      if (!is_structural) refreshed_.fetch_add(1);
      const size_t bytes = PublishChunk(std::move(c), now, ctx);
      pub_bytes_[is_structural ? kStructural : kRefresh] += bytes;
      if (rate > 0.0) tokens_ -= static_cast<double>(bytes);
    }
  }

  // --- InpaintFusion's labelled proxy (under stage_mu_) ---

  // The inpainting stage's keyframes arrive asynchronously: applied here when they come after
  // the last frame (InpaintedProxyLink::Kick, from the stage's publisher thread).
  void ApplyFromLink() {
    std::lock_guard stage(stage_mu_);
    if (!ctx_ || !geometry_) return;
    const ScopedDeltaSource source(last_time_s_);
    PublishOverlay(SyncOverlay(), *ctx_, last_now_ns_);
  }

  // New regions and waiting keyframes into the surface; the blocks whose clients' mesh may have
  // changed.
  std::vector<uint64_t> SyncOverlay() {
    if (!link_ || !geometry_) return {};
    const int64_t t0 = SteadyNowNs();
    const TsdfVolume& vol = geometry_->volume();
    if (!surface_) {
      geometry::InpaintedSurfaceOptions so;
      so.carve_margin_voxels = options_.inpaint_carve_margin_voxels;
      surface_ = std::make_unique<geometry::InpaintedSurface>(vol.options(), so);
    }
    const std::shared_ptr<const RegionSet> set = link_->regions()->Get();
    if (!roi_generation_ || *roi_generation_ != set->generation) {
      roi_generation_ = set->generation;
      std::vector<glm::ivec3> labels;
      double label_m = 0.0;
      for (const auto& r : set->regions) {
        label_m = r.voxel_m;
        for (uint64_t k : r.voxels) labels.push_back(inpainting::UnpackVoxel(k));
      }
      surface_->SetRoi(labels, label_m);
      ip_roi_voxels_ = surface_->roi_voxels();
    }
    InpaintedProxyLink::Pending p = link_->Take();
    if (p.reset) surface_->ClearInpainted();
    for (const InpaintedDepth& d : p.items) {
      auto st = surface_->IntegrateInpainted(vol, d.depth, d.mask, d.color.empty() ? nullptr : &d.color,
                                             d.camera, d.local_from_cam);
      if (!st.ok()) {
        ++ip_failed_;
        continue;
      }
      ++ip_fused_;
      ip_kept_ += st->voxels_kept;
      ip_erased_ += st->voxels_erased;
    }
    std::vector<uint64_t> dirty = surface_->TakeDirtyBlocks();
    ip_sync_ns_ += SteadyNowNs() - t0;
    return dirty;
  }

  // This frame's re-meshed chunks: the clients' mesh where the surface affects them; the blocks
  // in `dirty` are left to PublishOverlay (published at once, whatever the republish rules).
  void ApplyOverlay(core::GeometryUpdate* u, const std::vector<uint64_t>& dirty) {
    if (!surface_) return;
    const int64_t t0 = SteadyNowNs();
    const TsdfVolume& vol = geometry_->volume();
    auto in_dirty = [&](uint64_t id) { return std::binary_search(dirty.begin(), dirty.end(), id); };
    // The drone's map keeps the observed mesh of every chunk whose clients' mesh is (or was) the
    // overlay's, noted before the labelled mesh is published (observed_chunks.h).
    if (ObservedChunks* obs = link_->observed()) {
      auto labelled = [&](uint64_t id) {
        return surface_->Affects(id) || overlay_version_.contains(id) || in_dirty(id);
      };
      for (const MeshChunk& c : u->chunks)
        if (labelled(c.id)) obs->Set(c.id, c.mesh);
      for (uint64_t id : u->removed)
        if (labelled(id)) obs->Set(id, TriangleMesh{});
    }
    std::vector<MeshChunk> chunks;
    chunks.reserve(u->chunks.size());
    std::vector<uint64_t> removed;
    for (MeshChunk& c : u->chunks) {
      if (in_dirty(c.id)) continue;
      if (surface_->Affects(c.id)) {
        c.mesh = surface_->ExtractBlock(vol, c.id);
        overlay_version_.try_emplace(c.id, 0);  // the clients' mesh of this chunk is the overlay's
        if (c.mesh.empty()) {
          removed.push_back(c.id);
          continue;
        }
      }
      chunks.push_back(std::move(c));
    }
    for (uint64_t id : u->removed) {
      if (in_dirty(id)) continue;
      if (surface_->Affects(id)) {
        // The observation left the block empty; the inpainted surface may not.
        TriangleMesh m = surface_->ExtractBlock(vol, id);
        if (!m.empty()) {
          uint64_t& ov = overlay_version_[id];
          ov = std::max(ov, vol.ChunkVersion(id));
          chunks.push_back({id, ov, std::move(m)});
          continue;
        }
      }
      removed.push_back(id);
    }
    u->chunks = std::move(chunks);
    u->removed = std::move(removed);
    ip_apply_ns_ += SteadyNowNs() - t0;
  }

  // The blocks whose clients' mesh the overlay changed: published now (or removed when empty).
  void PublishOverlay(const std::vector<uint64_t>& dirty, const SceneContext& ctx, int64_t now) {
    if (!surface_ || dirty.empty()) return;
    const int64_t t0 = SteadyNowNs();
    const TsdfVolume& vol = geometry_->volume();
    for (uint64_t key : dirty) {
      // Neither affected now nor published by the overlay before: the clients have the observed
      // mesh, as they should.
      if (!surface_->Affects(key) && !overlay_version_.contains(key)) continue;
      if (ObservedChunks* obs = link_->observed(); obs && !obs->Contains(key))
        obs->Set(key, vol.ExtractBlock(key));  // before its labelled mesh goes out
      TriangleMesh mesh = surface_->ExtractBlock(vol, key);
      if (!pending_.contains(key) && !mesh.empty() && options_.refresh_min_move_voxels > 0.0) {
        // Unchanged since its publication (e.g. inpainted values that were all erased there).
        auto pub = published_.find(key);
        if (pub != published_.end() && pub->second.positions == mesh.positions) continue;
      }
      pending_.erase(key);  // a held-back mesh from before is stale
      if (!mesh.empty()) {
        uint64_t& ov = overlay_version_[key];
        ov = std::max(ov, vol.ChunkVersion(key));
        pub_bytes_[kStructural] += PublishChunk({key, ov, std::move(mesh)}, now, ctx);
        ++ip_published_;
      } else if (published_.erase(key)) {
        overlay_version_.try_emplace(key, 0);
        (void)ctx.store->RemoveChunk(key);
        ++ip_removed_;
      }
    }
    ip_ns_ += SteadyNowNs() - t0;
  }

  static TriangleMesh ForColour(const TriangleMesh& m) {
    TriangleMesh out;
    if (m.colors.size() != m.positions.size()) return out;  // no colours fused
    out.positions = m.positions;
    out.colors = m.colors;
    out.indices = m.indices;
    return out;
  }

  static void PutMesh(StateWriter* w, const TriangleMesh& m) {
    w->PutVec(m.positions);
    w->PutVec(m.normals);
    w->PutVec(m.colors);
    w->PutVec(m.indices);
    w->PutVec(m.material);
  }
  static bool GetMesh(StateReader* r, TriangleMesh* m) {
    return r->GetVec(&m->positions) && r->GetVec(&m->normals) && r->GetVec(&m->colors) &&
           r->GetVec(&m->indices) && r->GetVec(&m->material);
  }

 public:
  absl::StatusOr<std::string> SaveState() const override {
    std::lock_guard stage(stage_mu_);
    std::lock_guard lock(mu_);
    if (!geometry_) return std::string();
    StateWriter w;
    geometry_->SaveState(&w);
    w.Put(tokens_);
    w.Put<uint8_t>(last_source_s_.has_value());
    w.Put(last_source_s_.value_or(0.0));
    w.Put<int32_t>(shed_run_);
    w.Put<uint8_t>(has_geometry_);
    for (uint64_t v : {lod_in_.load(), lod_out_.load(), lod_fallbacks_.load(), shed_.load(),
                       refreshed_.load(), refresh_still_.load()})
      w.Put(v);
    PutUnordered(&w, published_, [&w](const Published& p) {
      w.Put<uint64_t>(p.triangles);
      w.Put(p.time_ns);
      w.Put(p.extractions);
      w.PutVec(p.positions);
    });
    PutUnordered(&w, pending_, [&w](const MeshChunk& c) {
      w.Put(c.id);
      w.Put(c.version);
      PutMesh(&w, c.mesh);
    });
    PutUnorderedPod(&w, extractions_);
    // The labelled proxy's chunk versions (its surface is rebuilt from the regions and the
    // inpainted views after a restart).
    PutUnorderedPod(&w, overlay_version_);
    return std::move(w.str());
  }

  absl::Status RestoreState(std::string_view state, const SceneContext& ctx) override {
    if (state.empty()) return absl::OkStatus();
    std::lock_guard stage(stage_mu_);
    std::lock_guard lock(mu_);
    ctx_ = &ctx;
    EXO_ASSIGN_OR_RETURN(geometry_, core::OnlineGeometry::Create(model_, ctx.setup));
    StateReader r(state);
    EXO_RETURN_IF_ERROR(geometry_->LoadState(&r));
    uint8_t has_last = 0, has_geometry = 0;
    double last = 0;
    int32_t shed_run = 0;
    r.Get(&tokens_) && r.Get(&has_last) && r.Get(&last) && r.Get(&shed_run) &&
        r.Get(&has_geometry);
    if (has_last) last_source_s_ = last;
    shed_run_ = shed_run;
    has_geometry_ = has_geometry != 0;
    for (std::atomic<uint64_t>* v :
         {&lod_in_, &lod_out_, &lod_fallbacks_, &shed_, &refreshed_, &refresh_still_}) {
      uint64_t x = 0;
      r.Get(&x);
      v->store(x);
    }
    GetUnordered(&r, &published_, [&r](Published* p) {
      uint64_t t = 0;
      const bool ok = r.Get(&t) && r.Get(&p->time_ns) && r.Get(&p->extractions) &&
                      r.GetVec(&p->positions);
      p->triangles = t;
      return ok;
    }) && GetUnordered(&r, &pending_, [&r](MeshChunk* c) {
      return r.Get(&c->id) && r.Get(&c->version) && GetMesh(&r, &c->mesh);
    }) && GetUnorderedPod(&r, &extractions_);
    if (!r.done()) GetUnorderedPod(&r, &overlay_version_);  // absent in older checkpoints
    EXO_RETURN_IF_ERROR(r.Status("geometry stage"));
    if (!r.done()) return absl::DataLossError("geometry stage state: trailing bytes");
    if (coloured_)
      for (const auto& [key, p] : published_)
        coloured_->Set(key, ForColour(geometry_->volume().ExtractBlock(key)));
    // The store's chunks of the checkpoint are the labelled ones: the drone's map gets their
    // observed mesh from the restored volume.
    if (link_ && link_->observed())
      for (const auto& [key, version] : overlay_version_)
        link_->observed()->Set(key, geometry_->volume().ExtractBlock(key));
    return absl::OkStatus();
  }

 private:
  struct Published {
    size_t triangles = 0;
    int64_t time_ns = 0;
    uint64_t extractions = 1;          // the chunk's extraction count when it was published
    std::vector<glm::vec3> positions;  // its published vertices (refresh_min_move_voxels)
  };
  // Returns the chunk's bytes on the wire.
  size_t PublishChunk(MeshChunk c, int64_t now, const SceneContext& ctx) {
    const MeshWireOptions wire{static_cast<float>(options_.publish_step_voxels * ctx.setup.voxel_m)};
    // A chunk the labelled proxy published keeps increasing versions (its own and the volume's).
    if (auto it = overlay_version_.find(c.id); it != overlay_version_.end()) {
      c.version = std::max(c.version, it->second + 1);
      it->second = c.version;
    }
    Published& p = published_[c.id];
    p.triangles = c.mesh.num_triangles();
    p.time_ns = now;
    p.extractions = std::max<uint64_t>(1, extractions_[c.id]);
    if (options_.refresh_min_move_voxels > 0.0) p.positions = c.mesh.positions;
    if (options_.publish_lod_error_voxels > 0.0) {
      const int64_t t0 = SteadyNowNs();
      geometry::MeshLodStats st;
      const TriangleMesh lod = geometry::SimplifyMesh(
          c.mesh, {options_.publish_lod_error_voxels * ctx.setup.voxel_m}, &st);
      lod_ns_ += SteadyNowNs() - t0;
      lod_in_ += st.triangles_in;
      lod_out_ += st.triangles_out;
      lod_fallbacks_ += st.fallback;
      size_t bytes = 0;
      ctx.store->UpsertChunk(c.id, c.version, lod, wire, &bytes);
      return bytes;
    }
    size_t bytes = 0;
    ctx.store->UpsertChunk(c.id, c.version, c.mesh, wire, &bytes);
    return bytes;
  }

  // Mean over `now` of the distance to the nearest vertex of `before` (hash grid of cell
  // `voxel`, the 27 cells around; a vertex with no neighbour within one voxel counts one voxel:
  // new surface). Marching-cubes vertices slide along their voxel edges as the zero crossing
  // moves, so this is the surface's motion.
  static double MeanMove(const std::vector<glm::vec3>& now, const std::vector<glm::vec3>& before,
                         double voxel) {
    if (now.empty()) return 0.0;
    if (before.empty() || !(voxel > 0.0)) return voxel;
    auto key = [voxel](const glm::vec3& p, int dx, int dy, int dz) {
      const int64_t x = static_cast<int64_t>(std::floor(p.x / voxel)) + dx;
      const int64_t y = static_cast<int64_t>(std::floor(p.y / voxel)) + dy;
      const int64_t z = static_cast<int64_t>(std::floor(p.z / voxel)) + dz;
      return static_cast<uint64_t>((x * 73856093) ^ (y * 19349663) ^ (z * 83492791));
    };
    std::unordered_multimap<uint64_t, uint32_t> grid;
    grid.reserve(before.size());
    for (uint32_t i = 0; i < before.size(); ++i) grid.emplace(key(before[i], 0, 0, 0), i);
    double sum = 0.0;
    for (const glm::vec3& p : now) {
      double best = voxel * voxel;
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            auto [a, b] = grid.equal_range(key(p, dx, dy, dz));
            for (; a != b; ++a) {
              const glm::vec3 d = before[a->second] - p;
              best = std::min(best, static_cast<double>(glm::dot(d, d)));
            }
          }
      sum += std::sqrt(best);
    }
    return sum / static_cast<double>(now.size());
  }

  const GeometryStageOptions options_;
  const core::OnlineModelOptions model_;
  std::shared_ptr<GeometryHandoff> handoff_;
  std::shared_ptr<InpaintedProxyLink> link_;  // null: no labelled proxy
  std::shared_ptr<ObservedChunks> coloured_;  // null: no scene completion
  // The stage's whole work (Process, ApplyFromLink, Save/RestoreState): the labelled proxy's
  // keyframes are applied from another thread. Lock order: stage_mu_ before mu_.
  mutable std::mutex stage_mu_;
  const SceneContext* ctx_ = nullptr;  // the pipeline's, set by the first Process / RestoreState
  int64_t last_now_ns_ = 0;            // stream time of the last frame
  double last_time_s_ = 0.0;
  std::unique_ptr<geometry::InpaintedSurface> surface_;  // created with the geometry
  std::optional<uint64_t> roi_generation_;                 // of the regions applied
  std::unordered_map<uint64_t, uint64_t> overlay_version_;  // chunk id -> last version published
  std::atomic<uint64_t> ip_fused_{0}, ip_failed_{0}, ip_kept_{0}, ip_erased_{0}, ip_roi_voxels_{0},
      ip_published_{0}, ip_removed_{0};
  std::atomic<int64_t> ip_ns_{0}, ip_sync_ns_{0}, ip_apply_ns_{0};
  mutable std::mutex mu_;  // geometry_ (stage thread) vs counters (stats thread)
  std::unique_ptr<core::OnlineGeometry> geometry_;  // created on the first frame (scene set-up)
  std::atomic<int64_t> integrate_ns_{0};
  std::atomic<uint64_t> shed_{0};
  std::atomic<uint64_t> refreshed_{0};
  std::atomic<uint64_t> refresh_still_{0};
  enum PublishReason { kNew, kStructural, kInterval, kRefresh, kReasons };
  std::atomic<uint64_t> pub_bytes_[kReasons] = {};
  std::atomic<uint64_t> lod_in_{0}, lod_out_{0}, lod_fallbacks_{0};
  std::atomic<int64_t> lod_ns_{0};
  double tokens_ = 0.0;                  // refresh budget, bytes (stage thread only)
  std::optional<double> last_source_s_;  // stream time of the previous frame
  size_t queued_ = 0, capacity_ = 1;  // stage thread only
  int shed_run_ = 0;
  bool has_geometry_ = false;
  std::unordered_map<uint64_t, Published> published_;
  std::unordered_map<uint64_t, MeshChunk> pending_;
  std::unordered_map<uint64_t, uint64_t> extractions_;  // per chunk: times re-extracted
};

}  // namespace

absl::StatusOr<std::unique_ptr<PipelineStage>> MakeGeometryStage(
    const GeometryStageOptions& options, const core::OnlineModelOptions& model,
    std::shared_ptr<GeometryHandoff> handoff, std::shared_ptr<InpaintedProxyLink> inpainted,
    std::shared_ptr<ObservedChunks> coloured) {
  EXO_RETURN_IF_ERROR(options.Validate());
  EXO_RETURN_IF_ERROR(model.Validate());
  return std::unique_ptr<PipelineStage>(new GeometryStage(
      options, model, std::move(handoff), std::move(inpainted), std::move(coloured)));
}

}  // namespace exo
