// The observed mesh of the chunks whose published (clients') mesh is InpaintFusion's labelled
// proxy (issue 18, geometry_stage.h inpaint_fuse): the marked objects carved, inpainted surface
// in their place. The clients must see that; the drone must not: the removed object is
// physically there, so the control service's ray casting (gaze-to-see) and occupancy take the
// observed surface of these chunks from here instead of the published one (the planner gets the
// observed GeometryUpdate through GeometryHandoff the same way).
//
// The geometry stage Set()s a chunk's observed mesh (empty: no observed surface) BEFORE it
// publishes the chunk's labelled mesh, and keeps it current while the chunk is re-meshed; an id
// once here stays here (its observed mesh is kept up to date, also after the regions are
// cleared), so a reader ignores the published deltas of every id Contains() reports and applies
// TakeChanged() instead. Thread-safe.
// A second instance (ServerConfig: completion with geometry) holds every chunk's full-resolution
// observed mesh with its fused vertex colours (no normals) for scene completion's colour guide.
#pragma once

#include <cstdint>
#include <mutex>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "common/mesh.h"

namespace exo {

class ObservedChunks {
 public:
  void Set(uint64_t id, TriangleMesh observed_local) {
    std::lock_guard lock(mu_);
    meshes_[id] = std::move(observed_local);
    changed_.insert(id);
  }
  bool Contains(uint64_t id) const {
    std::lock_guard lock(mu_);
    return meshes_.contains(id);
  }
  // The chunks Set since the last call, with their current observed mesh (copies).
  std::vector<std::pair<uint64_t, TriangleMesh>> TakeChanged() {
    std::lock_guard lock(mu_);
    std::vector<std::pair<uint64_t, TriangleMesh>> out;
    out.reserve(changed_.size());
    for (uint64_t id : changed_) out.emplace_back(id, meshes_.at(id));
    changed_.clear();
    return out;
  }
  // Every mesh held, appended (those with vertex colours of their size, or all when none has
  // colours): the server's coloured proxy for scene completion (completion_stage.h).
  TriangleMesh Merged() const {
    std::lock_guard lock(mu_);
    TriangleMesh out;
    for (const auto& [id, m] : meshes_)
      if (!m.empty() && m.colors.size() == m.positions.size() && m.normals.empty()) out.Append(m);
    return out;
  }
  void Clear() {
    std::lock_guard lock(mu_);
    meshes_.clear();
    changed_.clear();
  }
  size_t size() const {
    std::lock_guard lock(mu_);
    return meshes_.size();
  }

 private:
  mutable std::mutex mu_;
  std::unordered_map<uint64_t, TriangleMesh> meshes_;
  std::unordered_set<uint64_t> changed_;
};

}  // namespace exo
