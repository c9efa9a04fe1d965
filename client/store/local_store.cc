#include "client/store/local_store.h"

#include "proto/frame_proto.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace exo {

namespace {
void PutChunk(const v1::MeshChunkUpserted& m, TriangleMesh mesh, LumigraphModel* model,
              std::map<uint64_t, ChunkDigestRecord>* chunks) {
  (*chunks)[m.chunk_id()] = {m.chunk_version(), MeshHash(mesh)};
  MeshChunk& c = model->chunks[m.chunk_id()];
  c.id = m.chunk_id();
  c.version = m.chunk_version();
  c.mesh = std::move(mesh);
}
}  // namespace

absl::Status LocalStore::ApplyKind(const v1::Delta& d, LumigraphModel* model,
                                   std::map<ViewId, ViewDigestRecord>* views,
                                   std::map<uint64_t, ChunkDigestRecord>* chunks) {
  switch (d.kind_case()) {
    case v1::Delta::kSceneParams: {
      const auto& s = d.scene_params();
      model->origin.origin_in_world = {s.origin_in_world().x(), s.origin_in_world().y(),
                                       s.origin_in_world().z()};
      if (!(s.cell_size_m() > 0.0)) return absl::InvalidArgumentError("scene cell size <= 0");
      model->grid.cell_size_m = s.cell_size_m();
      return absl::OkStatus();
    }
    case v1::Delta::kViewAdded: {
      EXO_ASSIGN_OR_RETURN(StoredView v, ViewFromProto(d.view_added()));
      (*views)[v.id] = DigestRecordFromProto(d.view_added());
      model->views[v.id] = std::move(v);
      return absl::OkStatus();
    }
    case v1::Delta::kViewUpdated: {
      const auto& u = d.view_updated();
      auto it = model->views.find(u.view_id());
      if (it == model->views.end())
        return absl::FailedPreconditionError(absl::StrCat("update of unknown view ", u.view_id()));
      EXO_ASSIGN_OR_RETURN(it->second.local_from_cam, PoseFromProto(u.local_from_cam()));
      it->second.exposure = u.exposure();
      auto& r = (*views)[u.view_id()];
      r.local_from_cam = it->second.local_from_cam;
      r.exposure = u.exposure();
      return absl::OkStatus();
    }
    case v1::Delta::kViewRemoved:
      if (model->views.erase(d.view_removed().view_id()) == 0)
        return absl::FailedPreconditionError(
            absl::StrCat("removal of unknown view ", d.view_removed().view_id()));
      views->erase(d.view_removed().view_id());
      return absl::OkStatus();
    case v1::Delta::kCellRefsChanged: {
      // Packed (zstd) or plain; decoded and checked before anything changes: all or nothing.
      EXO_ASSIGN_OR_RETURN(const v1::CellRefsChanged refs, UnpackCellRefs(d.cell_refs_changed()));
      for (const auto& c : refs.coverage())
        if (c.tau_percent() > 100)
          return absl::InvalidArgumentError(
              absl::StrCat("cell coverage ", c.tau_percent(), " % is above 100"));
      for (const auto& c : refs.cells()) {
        if (c.view_ids().empty())
          model->cell_refs.erase(c.cell_id());
        else
          model->cell_refs[c.cell_id()].assign(c.view_ids().begin(), c.view_ids().end());
      }
      for (const auto& c : refs.coverage())
        model->cell_coverage[c.cell_id()] = uint8_t(c.tau_percent());
      return absl::OkStatus();
    }
    case v1::Delta::kMeshChunkUpserted: {
      const auto& m = d.mesh_chunk_upserted();
      EXO_ASSIGN_OR_RETURN(TriangleMesh mesh, MeshFromProto(m));
      PutChunk(m, std::move(mesh), model, chunks);
      return absl::OkStatus();
    }
    case v1::Delta::kMeshChunkBatch: {
      // A snapshot's chunks in one frame (Apply lets it in only inside a snapshot); every mesh is
      // decoded and checked before any of them is applied: all or nothing.
      EXO_ASSIGN_OR_RETURN(const std::vector<v1::MeshChunkUpserted> list,
                           UnpackMeshChunks(d.mesh_chunk_batch()));
      std::vector<TriangleMesh> meshes;
      meshes.reserve(list.size());
      for (const auto& m : list) {
        EXO_ASSIGN_OR_RETURN(TriangleMesh mesh, MeshFromProto(m));
        meshes.push_back(std::move(mesh));
      }
      for (size_t i = 0; i < list.size(); ++i) PutChunk(list[i], std::move(meshes[i]), model, chunks);
      return absl::OkStatus();
    }
    case v1::Delta::kMeshChunkRemoved:
      if (model->chunks.erase(d.mesh_chunk_removed().chunk_id()) == 0)
        return absl::FailedPreconditionError("removal of unknown mesh chunk");
      chunks->erase(d.mesh_chunk_removed().chunk_id());
      return absl::OkStatus();
    default:
      return absl::InvalidArgumentError("delta has no payload");
  }
}

absl::Status LocalStore::Apply(const v1::Delta& d) {
  if (d.has_snapshot_begin()) {
    in_snapshot_ = true;
    pending_ = LumigraphModel{};
    pending_views_.clear();
    pending_chunks_.clear();
    return absl::OkStatus();
  }
  if (d.has_snapshot_end()) {
    if (!in_snapshot_) return absl::FailedPreconditionError("snapshot end without begin");
    in_snapshot_ = false;
    pending_.version = d.version();
    epoch_ = d.model_epoch();
    model_ = std::move(pending_);
    view_records_ = std::move(pending_views_);
    chunk_records_ = std::move(pending_chunks_);
    pending_ = LumigraphModel{};
    ++snapshots_applied_;
    return absl::OkStatus();
  }
  if (in_snapshot_) return ApplyKind(d, &pending_, &pending_views_, &pending_chunks_);
  if (d.has_mesh_chunk_batch())
    return absl::FailedPreconditionError("a mesh chunk batch outside a snapshot");
  if (d.version() != model_.version + 1)
    return absl::FailedPreconditionError(absl::StrCat(
        "delta version ", d.version(), " does not follow the local version ", model_.version));
  EXO_RETURN_IF_ERROR(ApplyKind(d, &model_, &view_records_, &chunk_records_));
  model_.version = d.version();
  epoch_ = d.model_epoch();
  ++deltas_applied_;
  return absl::OkStatus();
}

uint64_t LocalStore::Digest() const {
  return ModelDigest(view_records_, model_.cell_refs, chunk_records_);
}

absl::Status CheckRenderableView(const StoredView& v) {
  EXO_RETURN_IF_ERROR(v.camera.Validate());
  const int w = v.camera.width, h = v.camera.height;
  if (w > 16384 || h > 16384)
    return absl::InvalidArgumentError(absl::StrCat("size ", w, "x", h, " above 16384"));
  if (v.color.width() != w || v.color.height() != h || v.color.channels() != 3)
    return absl::InvalidArgumentError(absl::StrCat("colour is not RGB8 ", w, "x", h));
  if (v.depth_m.width() != w || v.depth_m.height() != h || v.depth_m.channels() != 1)
    return absl::InvalidArgumentError(absl::StrCat("depth is not 1 channel ", w, "x", h));
  if (!std::isfinite(v.exposure) || !(v.exposure > 0.0f))
    return absl::InvalidArgumentError(
        absl::StrCat("exposure must be finite and > 0, got ", v.exposure));
  EXO_RETURN_IF_ERROR(ValidateQuaternion(v.local_from_cam.rotation));
  const glm::dvec3& t = v.local_from_cam.translation;
  if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z))
    return absl::InvalidArgumentError("non-finite position");
  return absl::OkStatus();
}

std::optional<LumigraphModel> WithoutUnusableViews(const LumigraphModel& model,
                                                   std::vector<std::string>* skipped) {
  if (std::all_of(model.views.begin(), model.views.end(),
                  [](const auto& kv) { return CheckRenderableView(kv.second).ok(); }))
    return std::nullopt;
  LumigraphModel out = model;
  for (auto it = out.views.begin(); it != out.views.end();) {
    if (absl::Status s = CheckRenderableView(it->second); !s.ok()) {
      skipped->push_back(absl::StrCat("view ", it->first, ": ", s.message()));
      const ViewId id = it->first;
      it = out.views.erase(it);
      for (auto& [cell, refs] : out.cell_refs) refs.erase(std::remove(refs.begin(), refs.end(), id), refs.end());
    } else {
      ++it;
    }
  }
  return out;
}

}  // namespace exo
