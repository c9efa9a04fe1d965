#include "server/service/model_store.h"

#include <algorithm>
#include <chrono>
#include <random>

namespace exo {
namespace {
thread_local double t_source_timestamp_s = 0.0;

uint64_t NewEpochId() {
  std::random_device rd;
  uint64_t id = 0;
  while (id == 0) id = (uint64_t{rd()} << 32) ^ rd();
  return id;
}
}  // namespace

ScopedDeltaSource::ScopedDeltaSource(double timestamp_s) : previous_(t_source_timestamp_s) {
  t_source_timestamp_s = timestamp_s;
}
ScopedDeltaSource::~ScopedDeltaSource() { t_source_timestamp_s = previous_; }

absl::Status ModelStoreOptions::Validate() const {
  if (max_log_deltas < 1) return absl::InvalidArgumentError("max_log_deltas must be >= 1");
  if (max_log_bytes < 1) return absl::InvalidArgumentError("max_log_bytes must be >= 1");
  if (max_subscriber_lag < 1) return absl::InvalidArgumentError("max_subscriber_lag must be >= 1");
  return absl::OkStatus();
}

ModelStore::ModelStore(const ModelStoreOptions& options) : options_(options) {
  EXO_CHECK(options_.Validate().ok());
  if (!options_.replica) {
    own_epoch_ = NewEpochId();
    lineage_.push_back({own_epoch_, 0});
  }
}

uint64_t ModelStore::EpochAtLocked(uint64_t version) const {
  if (version == 0 || version > version_) return 0;
  for (auto it = lineage_.rbegin(); it != lineage_.rend(); ++it)
    if (version > it->start_version) return it->id;
  return 0;  // older than the kept history
}

uint64_t ModelStore::epoch() const {
  std::lock_guard lock(mu_);
  return lineage_.empty() ? 0 : lineage_.back().id;
}

uint64_t ModelStore::EpochAt(uint64_t version) const {
  std::lock_guard lock(mu_);
  return EpochAtLocked(version);
}

ModelStore::~ModelStore() { CloseAll(); }

uint64_t ModelStore::CommitLocked(v1::Delta delta) {
  EXO_CHECK(!options_.replica);  // a replica only replays another store's deltas
  delta.set_version(++version_);
  delta.set_source_timestamp_s(t_source_timestamp_s);
  delta.set_model_epoch(lineage_.back().id);
  AppendLogLocked(std::make_shared<const v1::Delta>(std::move(delta)));
  return version_;
}

void ModelStore::AppendLogLocked(DeltaPtr ptr) {
  snapshot_.reset();  // subscribers holding it keep theirs; no old parts pinned here
  log_bytes_ += ptr->ByteSizeLong();
  log_.push_back(std::move(ptr));
  // Compaction: the model is the snapshot, so the oldest deltas can simply go.
  while (log_.size() > options_.max_log_deltas ||
         (log_.size() > 1 && log_bytes_ > options_.max_log_bytes)) {
    log_bytes_ -= log_.front()->ByteSizeLong();
    log_.pop_front();
  }
  cv_.notify_all();
}

void ModelStore::BeginApply() {
  std::lock_guard lock(mu_);
  applying_ = true;
}

void ModelStore::EndApply(uint64_t lsn, const std::string& uploader, uint64_t sequence) {
  std::lock_guard lock(mu_);
  applying_ = false;
  apply_cv_.notify_all();
  if (lsn == 0) return;  // not a journaled frame
  ++ledger_changes_;
  bool twice = lsn <= applied_lsn_;
  applied_lsn_ = std::max(applied_lsn_, lsn);
  if (!uploader.empty()) {
    auto it = uploaders_.find(uploader);
    if (it == uploaders_.end()) {
      if (uploaders_.size() >= kMaxUploaders) {
        auto oldest = std::min_element(uploaders_.begin(), uploaders_.end(), [](const auto& a, const auto& b) {
          return a.second.last_lsn < b.second.last_lsn;
        });
        uploaders_.erase(oldest);
      }
      it = uploaders_.emplace(uploader, UploaderProgress{}).first;
    }
    UploaderProgress& p = it->second;
    if (p.applied_frames > 0 && sequence <= p.applied_max_sequence) twice = true;
    p.last_lsn = lsn;
    if (twice) {
      ++p.double_applied;
    } else {
      ++p.applied_frames;
      p.applied_max_sequence = sequence;
    }
  }
}

uint64_t ModelStore::applied_lsn() const {
  std::lock_guard lock(mu_);
  return applied_lsn_;
}

std::map<std::string, ModelStore::UploaderProgress> ModelStore::Uploaders() const {
  std::lock_guard lock(mu_);
  return uploaders_;
}

uint64_t ModelStore::ledger_changes() const {
  std::lock_guard lock(mu_);
  return ledger_changes_;
}

v1::Checkpoint ModelStore::MakeCheckpoint(size_t max_log_bytes) const {
  v1::Checkpoint c;
  std::unique_lock lock(mu_);
  // Not while the last stage is between a frame's first view change and its ledger entry.
  apply_cv_.wait(lock, [this] { return !applying_; });
  c.set_format(1);
  c.set_version(version_);
  c.set_applied_lsn(applied_lsn_);
  for (const auto& [name, p] : uploaders_) {
    auto* u = c.add_uploaders();
    u->set_uploader(name);
    u->set_applied_max_sequence(p.applied_max_sequence);
    u->set_applied_frames(p.applied_frames);
    u->set_double_applied(p.double_applied);
  }
  for (const EpochSpan& e : lineage_) {
    auto* out = c.add_lineage();
    out->set_id(e.id);
    out->set_start_version(e.start_version);
  }
  for (const DeltaPtr& d : *SnapshotLocked()) {
    if (d->has_snapshot_begin() || d->has_snapshot_end()) continue;
    v1::Delta* m = c.add_model();
    *m = *d;
    m->set_version(version_);  // the checkpoint's model is all at its version
  }
  // Newest log entries that fit, kept contiguous up to version_.
  size_t bytes = 0, n = 0;
  for (auto it = log_.rbegin(); it != log_.rend(); ++it, ++n) {
    bytes += (*it)->ByteSizeLong();
    if (bytes > max_log_bytes) break;
  }
  for (size_t i = log_.size() - n; i < log_.size(); ++i) *c.add_log() = *log_[i];
  return c;
}

absl::Status ModelStore::ApplyModelDeltaLocked(const v1::Delta& d) {
  switch (d.kind_case()) {
    case v1::Delta::kSceneParams:
      scene_ = d.scene_params();
      has_scene_ = true;
      return absl::OkStatus();
    case v1::Delta::kViewAdded: {
      auto ptr = std::make_shared<const v1::Delta>(d);
      const v1::ViewAdded& v = ptr->view_added();
      view_bytes_ += v.ByteSizeLong();
      view_records_[v.view_id()] = DigestRecordFromProto(v);
      views_[v.view_id()] = std::move(ptr);
      return absl::OkStatus();
    }
    case v1::Delta::kMeshChunkUpserted: {
      const auto& m = d.mesh_chunk_upserted();
      EXO_ASSIGN_OR_RETURN(TriangleMesh mesh, MeshFromProto(m));
      auto ptr = std::make_shared<const v1::Delta>(d);
      chunk_bytes_ += m.ByteSizeLong();
      chunks_[m.chunk_id()] = std::move(ptr);
      chunk_records_[m.chunk_id()] = {m.chunk_version(), MeshHash(mesh)};
      return absl::OkStatus();
    }
    case v1::Delta::kCellRefsChanged: {
      EXO_ASSIGN_OR_RETURN(const v1::CellRefsChanged c, UnpackCellRefs(d.cell_refs_changed()));
      for (const auto& e : c.cells())
        if (e.view_ids_size() > 0) cell_refs_[e.cell_id()].assign(e.view_ids().begin(), e.view_ids().end());
      for (const auto& e : c.coverage())
        cell_coverage_[e.cell_id()] = uint8_t(std::min<uint32_t>(e.tau_percent(), 100));
      return absl::OkStatus();
    }
    default:
      return absl::DataLossError("checkpoint: unexpected delta kind in the model");
  }
}

absl::Status ModelStore::RestoreCheckpoint(const v1::Checkpoint& c) {
  if (c.format() != 1)
    return absl::DataLossError(absl::StrCat("checkpoint: unknown format ", c.format()));
  std::lock_guard lock(mu_);
  if (version_ != 0) return absl::FailedPreconditionError("checkpoint: the store is not empty");
  for (const auto& d : c.model()) {
    if (d.version() != c.version()) return absl::DataLossError("checkpoint: model delta version mismatch");
    EXO_RETURN_IF_ERROR(ApplyModelDeltaLocked(d));
  }
  for (int i = 0; i < c.log_size(); ++i)
    if (c.log(i).version() != c.version() - static_cast<uint64_t>(c.log_size() - 1 - i))
      return absl::DataLossError("checkpoint: delta log tail is not contiguous");
  std::vector<EpochSpan> lineage;
  for (const auto& e : c.lineage()) {
    if (e.id() == 0 || e.start_version() > c.version() ||
        (!lineage.empty() && e.start_version() < lineage.back().start_version))
      return absl::DataLossError("checkpoint: malformed epoch lineage");
    lineage.push_back({e.id(), e.start_version()});
  }
  // This process continues the checkpoint's history under a new epoch: versions after
  // c.version() are new content even if an earlier process already produced those numbers.
  // A replica has no epoch of its own: its versions after c.version() are replayed ones.
  if (!options_.replica) lineage.push_back({own_epoch_, c.version()});
  if (lineage.size() > kMaxLineage) lineage.erase(lineage.begin(), lineage.end() - kMaxLineage);
  lineage_ = std::move(lineage);
  version_ = c.version();
  applied_lsn_ = c.applied_lsn();
  for (const auto& u : c.uploaders()) {
    UploaderProgress& p = uploaders_[u.uploader()];
    p.applied_max_sequence = u.applied_max_sequence();
    p.applied_frames = u.applied_frames();
    p.double_applied = u.double_applied();
  }
  for (const auto& d : c.log()) {
    auto ptr = std::make_shared<const v1::Delta>(d);
    log_bytes_ += ptr->ByteSizeLong();
    log_.push_back(std::move(ptr));
  }
  return absl::OkStatus();
}

absl::Status ModelStore::ReplayDelta(const v1::Delta& d) {
  std::lock_guard lock(mu_);
  if (d.version() != version_ + 1)
    return absl::DataLossError(absl::StrCat("replay: delta version ", d.version(),
                                            " does not follow the store's version ", version_));
  if (d.model_epoch() == 0)
    return absl::DataLossError(absl::StrCat("replay: delta ", d.version(), " has no model epoch"));
  // A server replays only before its own epoch produced anything.
  const bool own_last = !options_.replica && !lineage_.empty() &&
                        lineage_.back().id == own_epoch_;
  if (own_last && lineage_.back().start_version != version_)
    return absl::FailedPreconditionError(
        "replay: this store has committed deltas of its own; only a fresh or restored store "
        "replays a log");
  auto ptr = std::make_shared<v1::Delta>(d);
  switch (d.kind_case()) {
    case v1::Delta::kSceneParams:
      scene_ = d.scene_params();
      has_scene_ = true;
      break;
    case v1::Delta::kViewAdded: {
      const ViewId id = d.view_added().view_id();
      if (auto it = views_.find(id); it != views_.end())
        view_bytes_ -= it->second->view_added().ByteSizeLong();
      v1::Delta part;
      *part.mutable_view_added() = d.view_added();
      part.set_version(d.version());
      view_bytes_ += part.view_added().ByteSizeLong();
      view_records_[id] = DigestRecordFromProto(part.view_added());
      views_[id] = std::make_shared<const v1::Delta>(std::move(part));
      break;
    }
    case v1::Delta::kViewUpdated: {
      const auto& u = d.view_updated();
      auto it = views_.find(u.view_id());
      if (it == views_.end())
        return absl::DataLossError(absl::StrCat("replay: update of unknown view ", u.view_id()));
      auto updated = std::make_shared<v1::Delta>(*it->second);
      *updated->mutable_view_added()->mutable_local_from_cam() = u.local_from_cam();
      updated->mutable_view_added()->set_exposure(u.exposure());
      updated->set_version(d.version());
      view_records_[u.view_id()] = DigestRecordFromProto(updated->view_added());
      it->second = std::move(updated);
      break;
    }
    case v1::Delta::kViewRemoved: {
      auto it = views_.find(d.view_removed().view_id());
      if (it == views_.end())
        return absl::DataLossError(
            absl::StrCat("replay: removal of unknown view ", d.view_removed().view_id()));
      view_bytes_ -= it->second->view_added().ByteSizeLong();
      view_records_.erase(it->first);
      views_.erase(it);
      break;
    }
    case v1::Delta::kCellRefsChanged: {
      EXO_ASSIGN_OR_RETURN(const v1::CellRefsChanged c, UnpackCellRefs(d.cell_refs_changed()));
      for (const auto& e : c.cells()) {
        if (e.view_ids_size() == 0)
          cell_refs_.erase(e.cell_id());
        else
          cell_refs_[e.cell_id()].assign(e.view_ids().begin(), e.view_ids().end());
      }
      for (const auto& e : c.coverage())
        cell_coverage_[e.cell_id()] = uint8_t(std::min<uint32_t>(e.tau_percent(), 100));
      break;
    }
    case v1::Delta::kMeshChunkUpserted: {
      const auto& m = d.mesh_chunk_upserted();
      EXO_ASSIGN_OR_RETURN(TriangleMesh mesh, MeshFromProto(m));
      if (auto it = chunks_.find(m.chunk_id()); it != chunks_.end())
        chunk_bytes_ -= it->second->mesh_chunk_upserted().ByteSizeLong();
      v1::Delta part;
      *part.mutable_mesh_chunk_upserted() = m;
      part.set_version(d.version());
      chunk_bytes_ += m.ByteSizeLong();
      chunk_records_[m.chunk_id()] = {m.chunk_version(), MeshHash(mesh)};
      chunks_[m.chunk_id()] = std::make_shared<const v1::Delta>(std::move(part));
      break;
    }
    case v1::Delta::kMeshChunkRemoved: {
      auto it = chunks_.find(d.mesh_chunk_removed().chunk_id());
      if (it == chunks_.end())
        return absl::DataLossError(absl::StrCat("replay: removal of unknown chunk ",
                                                d.mesh_chunk_removed().chunk_id()));
      chunk_bytes_ -= it->second->mesh_chunk_upserted().ByteSizeLong();
      chunk_records_.erase(it->first);
      chunks_.erase(it);
      break;
    }
    default:
      return absl::DataLossError(
          absl::StrCat("replay: delta ", d.version(), " is not a model change (snapshot marker?)"));
  }
  // Lineage: the replayed epoch produced this version; a server's own epoch starts after it.
  if (own_last) lineage_.pop_back();
  if (lineage_.empty() || lineage_.back().id != d.model_epoch())
    lineage_.push_back({d.model_epoch(), version_});
  ++version_;
  if (own_last) lineage_.push_back({own_epoch_, version_});
  if (lineage_.size() > kMaxLineage)
    lineage_.erase(lineage_.begin(), lineage_.end() - kMaxLineage);
  AppendLogLocked(std::move(ptr));
  return absl::OkStatus();
}

absl::Status ModelStore::SkipVersionsTo(uint64_t version) {
  std::lock_guard lock(mu_);
  if (options_.replica) return absl::FailedPreconditionError("skip: a replica only replays");
  if (version < version_)
    return absl::FailedPreconditionError(
        absl::StrCat("skip: version ", version, " is below the store's ", version_));
  if (lineage_.empty() || lineage_.back().id != own_epoch_ ||
      lineage_.back().start_version != version_)
    return absl::FailedPreconditionError(
        "skip: this store has committed or replayed deltas of its own epoch");
  if (version == version_) return absl::OkStatus();
  version_ = version;  // lineage_.back() (own epoch) now spans the skipped versions too
  log_.clear();
  log_bytes_ = 0;
  snapshot_.reset();
  cv_.notify_all();
  return absl::OkStatus();
}

absl::StatusOr<std::vector<DeltaPtr>> ModelStore::DeltasAfter(uint64_t version, size_t max,
                                                               int timeout_ms) {
  std::unique_lock lock(mu_);
  cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
               [&] { return closed_ || version_ > version; });
  std::vector<DeltaPtr> out;
  // After CloseAll() too: a log shipper drains what the pipeline committed during shutdown.
  if (version_ <= version) return out;
  const uint64_t first = log_.empty() ? version_ + 1 : log_.front()->version();
  if (version + 1 < first)
    return absl::DataLossError(absl::StrCat("the delta log starts at version ", first,
                                            "; version ", version + 1, " was compacted away"));
  for (size_t i = static_cast<size_t>(version + 1 - first); i < log_.size() && out.size() < max;
       ++i)
    out.push_back(log_[i]);
  return out;
}

bool ModelStore::closed() const {
  std::lock_guard lock(mu_);
  return closed_;
}

bool ModelStore::has_scene() const {
  std::lock_guard lock(mu_);
  return has_scene_;
}

v1::SceneParams ModelStore::scene() const {
  std::lock_guard lock(mu_);
  return scene_;
}

std::vector<std::shared_ptr<const v1::ViewAdded>> ModelStore::Views() const {
  std::lock_guard lock(mu_);
  std::vector<std::shared_ptr<const v1::ViewAdded>> out;
  // Aliasing pointers: the ViewAdded inside each shared snapshot part.
  for (const auto& [id, part] : views_) out.emplace_back(part, &part->view_added());
  return out;
}

std::vector<CellId> ModelStore::CellIds() const {
  std::lock_guard lock(mu_);
  std::vector<CellId> out;
  for (const auto& [c, r] : cell_refs_) out.push_back(c);
  return out;
}

std::unordered_map<CellId, std::vector<ViewId>> ModelStore::CellRefs() const {
  std::lock_guard lock(mu_);
  return cell_refs_;
}

std::unordered_map<CellId, uint8_t> ModelStore::CellCoverage() const {
  std::lock_guard lock(mu_);
  return cell_coverage_;
}

std::vector<std::shared_ptr<const v1::MeshChunkUpserted>> ModelStore::Chunks() const {
  std::lock_guard lock(mu_);
  std::vector<std::shared_ptr<const v1::MeshChunkUpserted>> out;
  for (const auto& [id, part] : chunks_) out.emplace_back(part, &part->mesh_chunk_upserted());
  return out;
}

std::optional<LocalOrigin> ModelStore::Origin() const {
  std::lock_guard lock(mu_);
  if (!has_scene_) return std::nullopt;
  LocalOrigin o;
  o.origin_in_world = {scene_.origin_in_world().x(), scene_.origin_in_world().y(),
                       scene_.origin_in_world().z()};
  return o;
}

uint64_t ModelStore::SetSceneParams(const LocalOrigin& origin, double cell_size_m) {
  std::lock_guard lock(mu_);
  scene_.mutable_origin_in_world()->set_x(origin.origin_in_world.x);
  scene_.mutable_origin_in_world()->set_y(origin.origin_in_world.y);
  scene_.mutable_origin_in_world()->set_z(origin.origin_in_world.z);
  scene_.set_cell_size_m(cell_size_m);
  has_scene_ = true;
  v1::Delta d;
  *d.mutable_scene_params() = scene_;
  return CommitLocked(std::move(d));
}

uint64_t ModelStore::AddView(v1::ViewAdded view) {
  std::lock_guard lock(mu_);
  const ViewId id = view.view_id();
  if (auto it = views_.find(id); it != views_.end())
    view_bytes_ -= it->second->view_added().ByteSizeLong();
  v1::Delta part;
  *part.mutable_view_added() = std::move(view);
  part.set_version(version_ + 1);
  auto ptr = std::make_shared<const v1::Delta>(std::move(part));
  view_bytes_ += ptr->view_added().ByteSizeLong();
  view_records_[id] = DigestRecordFromProto(ptr->view_added());
  views_[id] = ptr;
  v1::Delta d;
  *d.mutable_view_added() = ptr->view_added();
  return CommitLocked(std::move(d));
}

absl::StatusOr<uint64_t> ModelStore::UpdateView(ViewId id, const Rigid3d& local_from_cam,
                                                float exposure) {
  std::lock_guard lock(mu_);
  auto it = views_.find(id);
  if (it == views_.end()) return absl::NotFoundError(absl::StrCat("no view ", id));
  // Copy-on-write: snapshots in flight keep the old part.
  auto updated = std::make_shared<v1::Delta>(*it->second);
  PoseToProto(local_from_cam, updated->mutable_view_added()->mutable_local_from_cam());
  updated->mutable_view_added()->set_exposure(exposure);
  updated->set_version(version_ + 1);
  view_records_[id] = DigestRecordFromProto(updated->view_added());
  it->second = std::move(updated);
  v1::Delta d;
  auto* u = d.mutable_view_updated();
  u->set_view_id(id);
  PoseToProto(local_from_cam, u->mutable_local_from_cam());
  u->set_exposure(exposure);
  return CommitLocked(std::move(d));
}

absl::StatusOr<uint64_t> ModelStore::RemoveView(ViewId id) {
  std::lock_guard lock(mu_);
  auto it = views_.find(id);
  if (it == views_.end()) return absl::NotFoundError(absl::StrCat("no view ", id));
  view_bytes_ -= it->second->view_added().ByteSizeLong();
  views_.erase(it);
  view_records_.erase(id);
  v1::Delta d;
  d.mutable_view_removed()->set_view_id(id);
  return CommitLocked(std::move(d));
}

uint64_t ModelStore::SetCellRefs(
    const std::vector<std::pair<CellId, std::vector<ViewId>>>& cells) {
  return SetCellRefs(cells, {});
}

uint64_t ModelStore::SetCellRefs(
    const std::vector<std::pair<CellId, std::vector<ViewId>>>& cells,
    const std::vector<std::pair<CellId, uint8_t>>& coverage) {
  v1::Delta d;
  auto* c = d.mutable_cell_refs_changed();
  for (const auto& [cell, refs] : cells) {
    auto* e = c->add_cells();
    e->set_cell_id(cell);
    e->mutable_view_ids()->Add(refs.begin(), refs.end());
  }
  for (const auto& [cell, percent] : coverage) {
    auto* e = c->add_coverage();
    e->set_cell_id(cell);
    e->set_tau_percent(std::min<uint8_t>(percent, 100));
  }
  PackCellRefs(c);  // outside the lock
  std::lock_guard lock(mu_);
  for (const auto& [cell, refs] : cells) {
    if (refs.empty())
      cell_refs_.erase(cell);
    else
      cell_refs_[cell] = refs;
  }
  for (const auto& [cell, percent] : coverage) cell_coverage_[cell] = std::min<uint8_t>(percent, 100);
  return CommitLocked(std::move(d));
}

uint64_t ModelStore::UpsertChunk(uint64_t chunk_id, uint64_t chunk_version,
                                 const TriangleMesh& mesh, const MeshWireOptions& wire,
                                 size_t* wire_bytes) {
  v1::Delta d;
  auto* m = d.mutable_mesh_chunk_upserted();
  m->set_chunk_id(chunk_id);
  m->set_chunk_version(chunk_version);
  MeshToProto(mesh, m, /*plain=*/false, wire);  // outside the lock: meshes can be large
  // The digest covers the mesh the clients decode (compact encoding: quantized positions).
  absl::StatusOr<TriangleMesh> sent = MeshFromProto(*m);
  EXO_CHECK(sent.ok());  // a mesh this server built always decodes
  const uint64_t hash = MeshHash(*sent);
  if (wire_bytes) *wire_bytes = m->ByteSizeLong();
  std::lock_guard lock(mu_);
  if (auto it = chunks_.find(chunk_id); it != chunks_.end())
    chunk_bytes_ -= it->second->mesh_chunk_upserted().ByteSizeLong();
  v1::Delta part;
  *part.mutable_mesh_chunk_upserted() = *m;
  part.set_version(version_ + 1);
  auto ptr = std::make_shared<const v1::Delta>(std::move(part));
  chunk_bytes_ += ptr->mesh_chunk_upserted().ByteSizeLong();
  chunks_[chunk_id] = std::move(ptr);
  chunk_records_[chunk_id] = {chunk_version, hash};
  return CommitLocked(std::move(d));
}

absl::StatusOr<uint64_t> ModelStore::RemoveChunk(uint64_t chunk_id) {
  std::lock_guard lock(mu_);
  auto it = chunks_.find(chunk_id);
  if (it == chunks_.end()) return absl::NotFoundError(absl::StrCat("no chunk ", chunk_id));
  chunk_bytes_ -= it->second->mesh_chunk_upserted().ByteSizeLong();
  chunks_.erase(it);
  chunk_records_.erase(chunk_id);
  v1::Delta d;
  d.mutable_mesh_chunk_removed()->set_chunk_id(chunk_id);
  return CommitLocked(std::move(d));
}

size_t ModelStore::SnapshotBytesLocked() const {
  return view_bytes_ + chunk_bytes_ + cell_refs_.size() * 24 + cell_coverage_.size() * 12 + 64;
}

std::shared_ptr<const std::vector<DeltaPtr>> ModelStore::SnapshotLocked() const {
  if (snapshot_ && snapshot_version_ == version_) return snapshot_;
  auto out = std::make_shared<std::vector<DeltaPtr>>();
  out->reserve(views_.size() + chunks_.size() + 4);
  auto push = [&](v1::Delta d) {
    d.set_version(version_);
    out->push_back(std::make_shared<const v1::Delta>(std::move(d)));
  };
  {
    v1::Delta d;
    d.mutable_snapshot_begin();
    push(std::move(d));
  }
  if (has_scene_) {
    v1::Delta d;
    *d.mutable_scene_params() = scene_;
    push(std::move(d));
  }
  // The parts themselves, not copies.
  for (const auto& [id, part] : chunks_) out->push_back(part);
  for (const auto& [id, part] : views_) out->push_back(part);
  if (!cell_refs_.empty() || !cell_coverage_.empty()) {
    v1::Delta d;
    auto* c = d.mutable_cell_refs_changed();
    for (const auto& [cell, refs] : cell_refs_) {
      auto* e = c->add_cells();
      e->set_cell_id(cell);
      e->mutable_view_ids()->Add(refs.begin(), refs.end());
    }
    for (const auto& [cell, percent] : cell_coverage_) {
      auto* e = c->add_coverage();
      e->set_cell_id(cell);
      e->set_tau_percent(percent);
    }
    PackCellRefs(c);
    push(std::move(d));
  }
  {
    v1::Delta d;
    d.mutable_snapshot_end();
    d.set_model_epoch(EpochAtLocked(version_));
    push(std::move(d));
  }
  snapshot_ = std::move(out);
  snapshot_version_ = version_;
  return snapshot_;
}

std::shared_ptr<Subscription> ModelStore::Subscribe(uint64_t last_version, uint64_t last_epoch) {
  std::lock_guard lock(mu_);
  bool snapshot = false;
  if (last_version > version_) {
    snapshot = true;  // a version from the future: the client's model is not ours
  } else if (last_version > 0 && last_epoch != EpochAtLocked(last_version)) {
    snapshot = true;  // same version number, another history (or an unknown epoch)
  } else if (last_version < version_) {
    const uint64_t first = log_.empty() ? version_ + 1 : log_.front()->version();
    if (last_version + 1 < first) {
      snapshot = true;  // compacted away
    } else if (options_.snapshot_when_cheaper) {
      size_t missed_bytes = 0;
      for (auto it = log_.rbegin(); it != log_.rend() && (*it)->version() > last_version; ++it)
        missed_bytes += (*it)->ByteSizeLong();
      snapshot = missed_bytes > SnapshotBytesLocked();
    }
  }
  ++subscribers_;
  return std::shared_ptr<Subscription>(new Subscription(this, last_version, snapshot),
                                       [this](Subscription* s) {
                                         {
                                           std::lock_guard l(mu_);
                                           --subscribers_;
                                         }
                                         delete s;
                                       });
}

std::vector<DeltaPtr> Subscription::Next(int timeout_ms) {
  ModelStore& m = *store_;
  std::unique_lock lock(m.mu_);
  m.cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms), [&] {
    return closed_ || m.closed_ || force_snapshot_ || m.version_ > sent_version_;
  });
  if (closed_ || m.closed_) return {};
  const uint64_t first = m.log_.empty() ? m.version_ + 1 : m.log_.front()->version();
  const bool fell_behind = m.version_ > sent_version_ &&
                           (sent_version_ + 1 < first ||
                            m.version_ - sent_version_ > m.options_.max_subscriber_lag);
  if (force_snapshot_ || fell_behind) {
    force_snapshot_ = false;
    ++snapshots_;
    ++m.snapshots_sent_;
    sent_version_ = m.version_;
    return *m.SnapshotLocked();  // pointers to the shared parts
  }
  std::vector<DeltaPtr> out;
  if (m.version_ <= sent_version_) return out;
  // Log entries with version > sent_version_ (contiguous versions).
  const size_t start = static_cast<size_t>(sent_version_ + 1 - first);
  constexpr size_t kMaxBatch = 64;
  for (size_t i = start; i < m.log_.size() && out.size() < kMaxBatch; ++i) out.push_back(m.log_[i]);
  sent_version_ = out.back()->version();
  return out;
}

std::vector<DeltaPtr> Subscription::NextForWire(int timeout_ms) {
  std::vector<DeltaPtr> out = Next(timeout_ms);
  if (out.size() < 2 || !out.front()->has_snapshot_begin()) return out;
  return store_->PackSnapshotForWire(std::move(out));
}

std::vector<DeltaPtr> ModelStore::PackSnapshotForWire(std::vector<DeltaPtr> parts) const {
  const size_t limit = options_.snapshot_chunk_batch_bytes;
  if (limit == 0 || !parts.back()->has_snapshot_end()) return parts;
  const uint64_t version = parts.back()->version(), epoch = parts.back()->model_epoch();
  std::lock_guard lock(wire_mu_);
  if (wire_snapshot_ && wire_snapshot_version_ == version && wire_snapshot_epoch_ == epoch)
    return *wire_snapshot_;
  std::vector<DeltaPtr> out;
  out.reserve(parts.size());
  std::vector<DeltaPtr> run;  // consecutive chunk parts, at most `limit` bytes
  size_t run_bytes = 0;
  auto flush = [&] {
    if (run.size() >= 2) {
      std::vector<const v1::MeshChunkUpserted*> chunks;
      chunks.reserve(run.size());
      for (const DeltaPtr& d : run) chunks.push_back(&d->mesh_chunk_upserted());
      auto batch = PackMeshChunks(chunks, options_.snapshot_chunk_batch_level);
      if (batch.ok()) {
        v1::Delta d;
        d.set_version(version);
        *d.mutable_mesh_chunk_batch() = *std::move(batch);
        out.push_back(std::make_shared<const v1::Delta>(std::move(d)));
        run.clear();
      }
      // Not packable (cannot happen for chunks this store encoded): sent one by one below.
    }
    out.insert(out.end(), run.begin(), run.end());
    run.clear();
    run_bytes = 0;
  };
  for (DeltaPtr& d : parts) {
    if (!d->has_mesh_chunk_upserted()) {
      flush();
      out.push_back(std::move(d));
      continue;
    }
    const size_t n = d->mesh_chunk_upserted().ByteSizeLong();
    if (!run.empty() && run_bytes + n > limit) flush();
    run_bytes += n;
    run.push_back(std::move(d));
  }
  flush();
  wire_snapshot_ = std::make_shared<const std::vector<DeltaPtr>>(out);
  wire_snapshot_version_ = version;
  wire_snapshot_epoch_ = epoch;
  return out;
}

void Subscription::Close() {
  std::lock_guard lock(store_->mu_);
  closed_ = true;
  store_->cv_.notify_all();
}

void ModelStore::CloseAll() {
  std::lock_guard lock(mu_);
  closed_ = true;
  cv_.notify_all();
}

uint64_t ModelStore::DigestLocked() const {
  return ModelDigest(view_records_, cell_refs_, chunk_records_);
}

ModelStore::Summary ModelStore::GetSummary() const {
  std::lock_guard lock(mu_);
  Summary s;
  s.version = version_;
  s.digest = DigestLocked();
  s.num_views = static_cast<uint32_t>(views_.size());
  s.num_cells = static_cast<uint32_t>(cell_refs_.size());
  s.num_chunks = static_cast<uint32_t>(chunks_.size());
  s.log_first_version = log_.empty() ? version_ + 1 : log_.front()->version();
  s.snapshot_bytes = SnapshotBytesLocked();
  s.log_deltas = log_.size();
  s.log_bytes = log_bytes_;
  s.subscribers = static_cast<uint32_t>(subscribers_);
  s.snapshots_sent = snapshots_sent_;
  return s;
}

uint64_t ModelStore::version() const {
  std::lock_guard lock(mu_);
  return version_;
}

bool ModelStore::has_view(ViewId id) const {
  std::lock_guard lock(mu_);
  return views_.count(id) > 0;
}

}  // namespace exo
