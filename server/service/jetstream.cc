#include "server/service/jetstream.h"

#include <nats/nats.h>

#include <algorithm>
#include <chrono>
#include <thread>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace exo {
namespace {

std::string NatsError(const char* what, natsStatus s, jsErrCode jerr = static_cast<jsErrCode>(0)) {
  const char* last = nats_GetLastError(nullptr);
  return absl::StrCat(what, ": ", natsStatus_GetText(s), jerr ? absl::StrCat(" (JetStream error ", static_cast<int>(jerr), ")") : "",
                      last && *last ? absl::StrCat(" - ", last) : "");
}

absl::Status Unavailable(const char* what, natsStatus s, jsErrCode jerr = static_cast<jsErrCode>(0)) {
  if (s == NATS_NOT_FOUND) return absl::NotFoundError(NatsError(what, s, jerr));
  return absl::UnavailableError(NatsError(what, s, jerr));
}

constexpr size_t kMaxChunk = 256 << 10;  // snapshot chunk (below NATS's default 1 MB payload)

}  // namespace

absl::Status ValidateSceneName(const std::string& scene) {
  if (scene.empty() || scene.size() > 64 ||
      !std::all_of(scene.begin(), scene.end(), [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
               c == '-' || c == '_';
      }))
    return absl::InvalidArgumentError(absl::StrCat(
        "scene name '", scene, "': 1 to 64 letters, digits, '-' or '_' (it names NATS streams)"));
  return absl::OkStatus();
}

struct JetStreamScene::Impl {
  natsOptions* opts = nullptr;
  natsConnection* nc = nullptr;
  jsCtx* js = nullptr;
  kvStore* kv = nullptr;
  ~Impl() {
    if (kv) kvStore_Destroy(kv);
    if (js) jsCtx_Destroy(js);
    if (nc) {
      natsConnection_Close(nc);
      natsConnection_Destroy(nc);
    }
    if (opts) natsOptions_Destroy(opts);
  }
};

JetStreamScene::~JetStreamScene() = default;

int64_t JetStreamScene::max_payload() const { return natsConnection_GetMaxPayload(impl_->nc); }

absl::StatusOr<std::unique_ptr<JetStreamScene>> JetStreamScene::Connect(
    const JetStreamSceneOptions& o, bool create) {
  EXO_RETURN_IF_ERROR(ValidateSceneName(o.scene));
  std::unique_ptr<JetStreamScene> s(new JetStreamScene);
  s->impl_ = std::make_unique<Impl>();
  s->stream_ = "EXOVIEW_" + o.scene;
  s->snap_stream_ = "EXOVIEW_" + o.scene + "_SNAP";
  s->subject_ = "exoview." + o.scene + ".deltas";
  s->snap_subject_ = "exoview." + o.scene + ".snapshot";
  s->bucket_ = "EXOVIEW_" + o.scene;
  Impl& m = *s->impl_;
  if (natsOptions_Create(&m.opts) != NATS_OK) return absl::InternalError("natsOptions_Create");
  const std::vector<std::string> urls = absl::StrSplit(o.url, ',');
  std::vector<const char*> url_ptrs;
  for (const auto& u : urls) url_ptrs.push_back(u.c_str());
  natsOptions_SetServers(m.opts, url_ptrs.data(), static_cast<int>(url_ptrs.size()));
  natsOptions_SetMaxReconnect(m.opts, -1);  // forever: a NATS node restarting is routine
  natsOptions_SetReconnectWait(m.opts, 250);
  natsOptions_SetTimeout(m.opts, 2000);
  natsOptions_SetName(m.opts, create ? "exoview_server" : "exoview_relay");
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(o.connect_timeout_s);
  natsStatus st;
  while ((st = natsConnection_Connect(&m.nc, m.opts)) != NATS_OK) {
    if (std::chrono::steady_clock::now() > deadline)
      return Unavailable(absl::StrCat("cannot connect to NATS at ", o.url).c_str(), st);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  jsOptions jo;
  jsOptions_Init(&jo);
  jo.Wait = 5000;
  if ((st = natsConnection_JetStream(&m.js, m.nc, &jo)) != NATS_OK)
    return Unavailable("JetStream context", st);

  // Streams: file storage (survives a NATS restart), replicated in a cluster.
  auto ensure = [&](const std::string& name, const std::string& subject,
                    int64_t max_bytes) -> absl::Status {
    jsStreamInfo* si = nullptr;
    jsErrCode jerr = static_cast<jsErrCode>(0);
    natsStatus gs = js_GetStreamInfo(&si, m.js, name.c_str(), nullptr, &jerr);
    if (gs == NATS_OK) {
      jsStreamInfo_Destroy(si);
      return absl::OkStatus();
    }
    if (!create) return Unavailable(absl::StrCat("stream ", name).c_str(), gs, jerr);
    jsStreamConfig cfg;
    jsStreamConfig_Init(&cfg);
    cfg.Name = name.c_str();
    const char* subjects[] = {subject.c_str()};
    cfg.Subjects = subjects;
    cfg.SubjectsLen = 1;
    cfg.Storage = js_FileStorage;
    cfg.Replicas = o.replicas;
    cfg.MaxBytes = max_bytes;
    cfg.AllowDirect = true;
    jerr = static_cast<jsErrCode>(0);
    natsStatus as = js_AddStream(&si, m.js, &cfg, nullptr, &jerr);
    if (as != NATS_OK) return Unavailable(absl::StrCat("create stream ", name).c_str(), as, jerr);
    jsStreamInfo_Destroy(si);
    return absl::OkStatus();
  };
  EXO_RETURN_IF_ERROR(ensure(s->stream_, s->subject_, static_cast<int64_t>(o.max_stream_bytes)));
  EXO_RETURN_IF_ERROR(ensure(s->snap_stream_, s->snap_subject_, -1));
  if (create) {
    kvConfig kc;
    kvConfig_Init(&kc);
    kc.Bucket = s->bucket_.c_str();
    kc.History = 1;
    kc.StorageType = js_FileStorage;
    kc.Replicas = o.replicas;
    if ((st = js_CreateKeyValue(&m.kv, m.js, &kc)) != NATS_OK)
      if ((st = js_KeyValue(&m.kv, m.js, s->bucket_.c_str())) != NATS_OK)
        return Unavailable(absl::StrCat("KV bucket ", s->bucket_).c_str(), st);
  } else if ((st = js_KeyValue(&m.kv, m.js, s->bucket_.c_str())) != NATS_OK) {
    return Unavailable(absl::StrCat("KV bucket ", s->bucket_).c_str(), st);
  }
  return s;
}

absl::StatusOr<StreamState> JetStreamScene::DeltaStreamState() {
  jsStreamInfo* si = nullptr;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  natsStatus st = js_GetStreamInfo(&si, impl_->js, stream_.c_str(), nullptr, &jerr);
  if (st != NATS_OK) return Unavailable(absl::StrCat("stream info ", stream_).c_str(), st, jerr);
  StreamState out{si->State.FirstSeq, si->State.LastSeq, si->State.Msgs, si->State.Bytes};
  jsStreamInfo_Destroy(si);
  return out;
}

absl::StatusOr<v1::Delta> JetStreamScene::GetDelta(uint64_t version) {
  natsMsg* msg = nullptr;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  natsStatus st = js_GetMsg(&msg, impl_->js, stream_.c_str(), version, nullptr, &jerr);
  if (st != NATS_OK)
    return Unavailable(absl::StrCat("get ", stream_, " sequence ", version).c_str(), st, jerr);
  v1::Delta d;
  const bool ok = d.ParseFromArray(natsMsg_GetData(msg), natsMsg_GetDataLength(msg));
  natsMsg_Destroy(msg);
  if (!ok || d.version() != version)
    return absl::DataLossError(absl::StrCat(stream_, " sequence ", version,
                                            " is not the Delta of that version"));
  return d;
}

absl::Status JetStreamScene::PublishDelta(const v1::Delta& delta) {
  const std::string bytes = delta.SerializeAsString();
  jsPubOptions po;
  jsPubOptions_Init(&po);
  // After a purge on nats-server 2.9 (see below) the expectation is replaced by a check of the
  // sequence the delta got: a second writer is still found, one message later.
  po.ExpectLastSeq = expect_unreliable_ ? 0 : delta.version() - 1;
  po.ExpectStream = stream_.c_str();
  // De-duplication of a retried publish (the first attempt's ack was lost).
  const std::string id = absl::StrCat(delta.model_epoch(), ":", delta.version());
  po.MsgId = id.c_str();
  jsPubAck* pa = nullptr;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  natsStatus st = js_Publish(&pa, impl_->js, subject_.c_str(), bytes.data(),
                             static_cast<int>(bytes.size()), &po, &jerr);
  if (st == NATS_OK) {
    const bool dup = pa->Duplicate;
    const uint64_t seq = pa->Sequence;
    jsPubAck_Destroy(pa);
    if (expect_unreliable_) ++unconditional_;
    if (seq != delta.version() && !dup)
      return absl::InternalError(absl::StrCat("published version ", delta.version(),
                                              " got stream sequence ", seq));
    return absl::OkStatus();
  }
  if (jerr == JSStreamWrongLastSequenceErr) {
    // nats-server 2.9 keeps a stale expected-last-sequence mark after a purge that moved the
    // stream's sequence up (PurgeDeltasBelow): when the stream's state says it does end at
    // version - 1, the delta goes without the expectation and the sequence it got is checked
    // (from then on every delta: one round trip each, not three).
    if (auto state = DeltaStreamState(); state.ok() && state->last_seq + 1 == delta.version()) {
      po.ExpectLastSeq = 0;
      jerr = static_cast<jsErrCode>(0);
      st = js_Publish(&pa, impl_->js, subject_.c_str(), bytes.data(),
                      static_cast<int>(bytes.size()), &po, &jerr);
      if (st == NATS_OK) {
        ++unconditional_;
        expect_unreliable_ = true;
        const bool dup = pa->Duplicate;
        const uint64_t seq = pa->Sequence;
        jsPubAck_Destroy(pa);
        if (seq != delta.version() && !dup)
          return absl::InternalError(absl::StrCat("published version ", delta.version(),
                                                  " got stream sequence ", seq));
        return absl::OkStatus();
      }
    }
  }
  if (jerr == JSStreamWrongLastSequenceErr)
    return absl::FailedPreconditionError(absl::StrCat(
        "stream ", stream_, " does not end at version ", delta.version() - 1,
        " (another server publishing this scene, or the stream was changed under this one)"));
  if (st == NATS_MAX_PAYLOAD)
    return absl::ResourceExhaustedError(absl::StrCat(
        "delta ", delta.version(), " is ", bytes.size(), " bytes, above the NATS max_payload ",
        max_payload(), ": raise max_payload in nats-server's configuration"));
  return Unavailable(absl::StrCat("publish version ", delta.version()).c_str(), st, jerr);
}

absl::Status JetStreamScene::PurgeDeltasBelow(uint64_t next_seq) {
  jsOptions jo;
  jsOptions_Init(&jo);
  jo.Stream.Purge.Sequence = next_seq;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  natsStatus st = js_PurgeStream(impl_->js, stream_.c_str(), &jo, &jerr);
  if (st != NATS_OK) return Unavailable("purge delta stream", st, jerr);
  return absl::OkStatus();
}

absl::StatusOr<SnapshotManifest> JetStreamScene::WriteSnapshot(const v1::Checkpoint& c) {
  const std::string bytes = c.SerializeAsString();
  const size_t chunk = std::min<size_t>(kMaxChunk, static_cast<size_t>(max_payload()) - 1024);
  SnapshotManifest m;
  m.version = c.version();
  m.bytes = bytes.size();
  for (size_t off = 0; off < bytes.size() || m.chunks == 0; off += chunk) {
    const size_t n = std::min(chunk, bytes.size() - off);
    jsPubAck* pa = nullptr;
    jsErrCode jerr = static_cast<jsErrCode>(0);
    natsStatus st = js_Publish(&pa, impl_->js, snap_subject_.c_str(), bytes.data() + off,
                               static_cast<int>(n), nullptr, &jerr);
    if (st != NATS_OK) return Unavailable("publish snapshot chunk", st, jerr);
    if (m.chunks == 0) m.first_seq = pa->Sequence;
    jsPubAck_Destroy(pa);
    ++m.chunks;
    if (n == 0) break;
  }
  const std::string manifest = absl::StrCat(m.version, " ", m.first_seq, " ", m.chunks, " ",
                                            m.bytes);
  uint64_t rev = 0;
  natsStatus st = kvStore_Put(&rev, impl_->kv, "snapshot", manifest.data(),
                              static_cast<int>(manifest.size()));
  if (st != NATS_OK) return Unavailable("put snapshot manifest", st);
  // Older snapshots go (a relay reading one retries with the new manifest).
  jsOptions jo;
  jsOptions_Init(&jo);
  jo.Stream.Purge.Sequence = m.first_seq;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  if ((st = js_PurgeStream(impl_->js, snap_stream_.c_str(), &jo, &jerr)) != NATS_OK)
    return Unavailable("purge old snapshots", st, jerr);
  return m;
}

absl::StatusOr<std::optional<v1::Checkpoint>> JetStreamScene::ReadSnapshot() {
  absl::Status last;
  for (int attempt = 0; attempt < 5; ++attempt) {
    kvEntry* e = nullptr;
    natsStatus st = kvStore_Get(&e, impl_->kv, "snapshot");
    if (st == NATS_NOT_FOUND) return std::optional<v1::Checkpoint>();
    if (st != NATS_OK) return Unavailable("get snapshot manifest", st);
    const std::string text(static_cast<const char*>(kvEntry_Value(e)), kvEntry_ValueLen(e));
    kvEntry_Destroy(e);
    const std::vector<std::string> f = absl::StrSplit(text, ' ');
    SnapshotManifest m;
    if (f.size() != 4 || !absl::SimpleAtoi(f[0], &m.version) ||
        !absl::SimpleAtoi(f[1], &m.first_seq) || !absl::SimpleAtoi(f[2], &m.chunks) ||
        !absl::SimpleAtoi(f[3], &m.bytes))
      return absl::DataLossError(absl::StrCat("snapshot manifest '", text, "' does not parse"));
    std::string bytes;
    bytes.reserve(m.bytes);
    bool gone = false;
    for (uint64_t i = 0; i < m.chunks && !gone; ++i) {
      natsMsg* msg = nullptr;
      jsErrCode jerr = static_cast<jsErrCode>(0);
      st = js_GetMsg(&msg, impl_->js, snap_stream_.c_str(), m.first_seq + i, nullptr, &jerr);
      if (st != NATS_OK) {
        last = Unavailable("get snapshot chunk", st, jerr);
        gone = true;  // purged by a newer snapshot meanwhile: read the new manifest
        break;
      }
      bytes.append(natsMsg_GetData(msg), natsMsg_GetDataLength(msg));
      natsMsg_Destroy(msg);
    }
    if (gone) continue;
    v1::Checkpoint c;
    if (bytes.size() != m.bytes || !c.ParseFromString(bytes) || c.version() != m.version)
      return absl::DataLossError(absl::StrCat("snapshot of version ", m.version,
                                              " does not parse (", bytes.size(), " of ", m.bytes,
                                              " bytes)"));
    return std::optional<v1::Checkpoint>(std::move(c));
  }
  return last;
}

absl::Status JetStreamScene::Follow(uint64_t first_version,
                                    const std::function<bool(const v1::Delta&)>& on_delta,
                                    const std::function<bool()>& keep_going) {
  jsSubOptions so;
  jsSubOptions_Init(&so);
  so.Ordered = true;  // the library re-creates the consumer on a gap or a lost heartbeat
  so.Config.DeliverPolicy = js_DeliverByStartSequence;
  so.Config.OptStartSeq = std::max<uint64_t>(first_version, 1);
  natsSubscription* sub = nullptr;
  jsErrCode jerr = static_cast<jsErrCode>(0);
  natsStatus st = js_SubscribeSync(&sub, impl_->js, subject_.c_str(), nullptr, &so, &jerr);
  if (st != NATS_OK) return Unavailable("subscribe to the delta stream", st, jerr);
  natsSubscription_SetPendingLimits(sub, 1 << 20, 512 << 20);
  absl::Status result;
  while (keep_going()) {
    natsMsg* msg = nullptr;
    st = natsSubscription_NextMsg(&msg, sub, 200);
    if (st == NATS_TIMEOUT) continue;
    if (st != NATS_OK) {
      result = Unavailable("delta stream", st);
      break;
    }
    v1::Delta d;
    const bool ok = d.ParseFromArray(natsMsg_GetData(msg), natsMsg_GetDataLength(msg));
    natsMsg_Destroy(msg);
    if (!ok) {
      result = absl::DataLossError("a message of the delta stream does not parse as a Delta");
      break;
    }
    if (!on_delta(d)) break;
  }
  natsSubscription_Unsubscribe(sub);
  natsSubscription_Destroy(sub);
  return result;
}

}  // namespace exo
