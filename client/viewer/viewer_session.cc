#include "client/viewer/viewer_session.h"

#include <chrono>
#include <filesystem>
#include <thread>

#include <grpcpp/grpcpp.h>

#include "proto/exoview.grpc.pb.h"

namespace exo {
namespace {
int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
}  // namespace

absl::StatusOr<std::unique_ptr<ViewerSession>> ViewerSession::Open(
    std::shared_ptr<grpc::Channel> channel, const std::string& journal_path) {
  auto s = std::unique_ptr<ViewerSession>(new ViewerSession);
  s->channel_ = std::move(channel);
  s->journal_path_ = journal_path;
  if (!journal_path.empty()) {
    EXO_RETURN_IF_ERROR(s->Replay());
    s->journal_.open(journal_path, std::ios::binary | std::ios::app);
    if (!s->journal_) return absl::UnavailableError("cannot open journal " + journal_path);
  }
  return s;
}

ViewerSession::~ViewerSession() = default;

// Journal record: u32 little-endian length, then the serialized Delta. A record cut short by a
// kill is dropped and the file truncated to the last complete record.
absl::Status ViewerSession::Replay() {
  std::ifstream in(journal_path_, std::ios::binary);
  if (!in) return absl::OkStatus();  // first run
  uint64_t good = 0;
  std::string buf;
  for (;;) {
    uint32_t len = 0;
    if (!in.read(reinterpret_cast<char*>(&len), 4)) break;
    buf.resize(len);
    if (!in.read(buf.data(), len)) break;
    v1::Delta d;
    if (!d.ParseFromString(buf)) break;
    if (!store_.Apply(d).ok()) break;
    good += 4 + len;
    ++stats_.replayed;
  }
  in.close();
  std::error_code ec;
  if (std::filesystem::file_size(journal_path_, ec) != good && !ec)
    std::filesystem::resize_file(journal_path_, good, ec);
  // An unfinished snapshot in the journal: the store kept its previous consistent version.
  return absl::OkStatus();
}

absl::Status ViewerSession::Journal(const v1::Delta& d) {
  if (!journal_.is_open()) return absl::OkStatus();
  const std::string bytes = d.SerializeAsString();
  const uint32_t len = static_cast<uint32_t>(bytes.size());
  journal_.write(reinterpret_cast<const char*>(&len), 4);
  journal_.write(bytes.data(), bytes.size());
  journal_.flush();
  if (!journal_) return absl::UnavailableError("journal write failed");
  return absl::OkStatus();
}

absl::StatusOr<v1::Stats> ViewerSession::ServerStats() const {
  auto stub = v1::Exoview::NewStub(channel_);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  v1::Stats out;
  const grpc::Status s = stub->GetStats(&ctx, v1::StatsRequest{}, &out);
  if (!s.ok()) return absl::UnavailableError("GetStats: " + s.error_message());
  return out;
}

absl::Status ViewerSession::Sync(const SyncOptions& options) {
  auto stub = v1::Exoview::NewStub(channel_);
  grpc::ClientContext ctx;
  v1::SubscribeRequest req;
  {
    std::lock_guard lock(mu_);
    // Mid-snapshot in the journal: resume from the last consistent version.
    req.set_last_version(store_.version());
    req.set_last_model_epoch(store_.epoch());
  }
  req.set_client_name(options.client_name);
  stats_.resumed_from = req.last_version();
  auto reader = stub->Subscribe(&ctx, req);
  absl::Status apply_error;
  std::atomic<int64_t> last_change_ns{NowNs()};
  std::atomic<bool> done{false};
  std::thread rx([&] {
    v1::Delta d;
    while (reader->Read(&d)) {
      const int64_t t = NowNs();
      std::lock_guard lock(mu_);
      if (auto s = store_.Apply(d); !s.ok()) {
        apply_error = s;
        break;
      }
      if (auto s = Journal(d); !s.ok()) {
        apply_error = s;
        break;
      }
      ++stats_.deltas;
      const uint64_t n = d.ByteSizeLong();
      stats_.bytes += n;
      if (d.has_mesh_chunk_upserted() || d.has_mesh_chunk_batch()) {
        stats_.mesh_bytes += n;
        ++stats_.mesh_chunks;
      }
      if (d.has_view_added() || d.has_view_updated()) stats_.view_bytes += n;
      if (d.has_snapshot_end()) ++stats_.snapshots;
      if (on_delta_) on_delta_(d, t);
      last_change_ns.store(t);
    }
    done.store(true);
  });
  const int64_t t0 = NowNs();
  while (!done.load() && !stop_.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if ((NowNs() - t0) * 1e-9 > options.max_seconds) break;
    if (!options.until_synced) continue;
    if ((NowNs() - last_change_ns.load()) < int64_t{options.settle_ms} * 1000000) continue;
    auto st = ServerStats();
    if (!st.ok()) continue;
    uint64_t local;
    bool in_snapshot;
    {
      std::lock_guard lock(mu_);
      local = store_.version();
      in_snapshot = store_.in_snapshot();
    }
    if (!in_snapshot && local == st->model_version() &&
        st->frames_processed() == st->frames_accepted() && st->async_pending() == 0 &&
        st->frames_received() >= options.min_server_frames)
      break;
  }
  ctx.TryCancel();
  rx.join();
  const grpc::Status gs = reader->Finish();
  if (!apply_error.ok()) return apply_error;
  if (!gs.ok() && gs.error_code() != grpc::StatusCode::CANCELLED)
    return absl::UnavailableError("subscribe: " + gs.error_message());
  return absl::OkStatus();
}

}  // namespace exo
