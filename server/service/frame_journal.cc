#include "server/service/frame_journal.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"

namespace exo {
namespace {

constexpr uint32_t kMagic = 0x314A5845;  // "EXJ1"
constexpr size_t kHeader = 12;
constexpr size_t kMaxBody = (size_t{64} << 20) + 4096;  // transport_max_bytes + the record's fields
constexpr size_t kMaxUploader = 256;

void PutU32(std::string* s, uint32_t v) {
  for (int i = 0; i < 4; ++i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
void PutU64(std::string* s, uint64_t v) {
  for (int i = 0; i < 8; ++i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
uint32_t GetU32(const char* p) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= uint32_t{static_cast<unsigned char>(p[i])} << (8 * i);
  return v;
}
uint64_t GetU64(const char* p) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v |= uint64_t{static_cast<unsigned char>(p[i])} << (8 * i);
  return v;
}
uint32_t Crc(std::string_view b) {
  // zlib's crc32 takes a uInt length: feed it in pieces.
  uLong c = crc32(0L, Z_NULL, 0);
  for (size_t off = 0; off < b.size();) {
    const size_t n = std::min<size_t>(b.size() - off, 1u << 30);
    c = crc32(c, reinterpret_cast<const Bytef*>(b.data() + off), static_cast<uInt>(n));
    off += n;
  }
  return static_cast<uint32_t>(c);
}

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

absl::StatusOr<std::string> ReadFile(const std::string& path) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return absl::UnavailableError(absl::StrCat("cannot read ", path, ": ", std::strerror(errno)));
  std::string out;
  char buf[1 << 16];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) out.append(buf, n);
  const bool err = std::ferror(f);
  std::fclose(f);
  if (err) return absl::UnavailableError(absl::StrCat("read error on ", path));
  return out;
}

absl::Status SyncDir(const std::string& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return absl::UnavailableError(absl::StrCat("cannot open ", dir));
  const int rc = ::fsync(fd);
  ::close(fd);
  return rc == 0 ? absl::OkStatus() : absl::UnavailableError(absl::StrCat("fsync ", dir));
}

}  // namespace

absl::Status FrameJournalOptions::Validate() const {
  if (dir.empty()) return absl::InvalidArgumentError("journal: dir is empty");
  if (segment_bytes < 4096) return absl::InvalidArgumentError("journal_segment_bytes must be >= 4096");
  if (max_bytes < 2 * segment_bytes)
    return absl::InvalidArgumentError("journal_max_bytes must be >= 2 x journal_segment_bytes");
  return absl::OkStatus();
}

std::string EncodeJournalRecord(const JournalRecord& r) {
  std::string body;
  body.reserve(20 + r.uploader.size() + r.frame.size());
  PutU64(&body, r.lsn);
  PutU64(&body, r.sequence);
  PutU32(&body, static_cast<uint32_t>(r.uploader.size()));
  body += r.uploader;
  body += r.frame;
  std::string out;
  out.reserve(kHeader + body.size());
  PutU32(&out, kMagic);
  PutU32(&out, static_cast<uint32_t>(body.size()));
  PutU32(&out, Crc(body));
  out += body;
  return out;
}

absl::StatusOr<std::pair<JournalRecord, size_t>> DecodeJournalRecord(std::string_view b) {
  if (b.size() < kHeader)
    return absl::DataLossError(absl::StrCat("torn record: ", b.size(), " bytes of a 12-byte header"));
  if (GetU32(b.data()) != kMagic) return absl::DataLossError("bad record magic");
  const uint32_t len = GetU32(b.data() + 4);
  if (len < 20 || len > kMaxBody)
    return absl::DataLossError(absl::StrCat("implausible record length ", len));
  if (b.size() - kHeader < len)
    return absl::DataLossError(
        absl::StrCat("torn record: ", b.size() - kHeader, " of ", len, " body bytes"));
  const std::string_view body = b.substr(kHeader, len);
  if (Crc(body) != GetU32(b.data() + 8)) return absl::DataLossError("record CRC mismatch");
  JournalRecord r;
  r.lsn = GetU64(body.data());
  r.sequence = GetU64(body.data() + 8);
  const uint32_t ulen = GetU32(body.data() + 16);
  if (ulen > kMaxUploader || ulen > len - 20)
    return absl::DataLossError(absl::StrCat("implausible uploader length ", ulen));
  r.uploader.assign(body.data() + 20, ulen);
  r.frame.assign(body.data() + 20 + ulen, len - 20 - ulen);
  return std::make_pair(std::move(r), kHeader + len);
}

absl::StatusOr<std::unique_ptr<FrameJournal>> FrameJournal::Open(const FrameJournalOptions& options,
                                                                 OpenReport* report) {
  EXO_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  std::filesystem::create_directories(options.dir, ec);
  if (ec) return absl::UnavailableError(absl::StrCat("journal: cannot create ", options.dir, ": ", ec.message()));
  std::unique_ptr<FrameJournal> j(new FrameJournal(options));
  OpenReport rep;
  std::vector<std::string> paths;
  for (const auto& e : std::filesystem::directory_iterator(options.dir)) {
    const std::string name = e.path().filename().string();
    if (absl::StartsWith(name, "seg-") && absl::EndsWith(name, ".wal")) paths.push_back(e.path().string());
  }
  std::sort(paths.begin(), paths.end());
  for (const std::string& path : paths) {
    EXO_ASSIGN_OR_RETURN(const std::string bytes, ReadFile(path));
    Segment seg;
    seg.path = path;
    size_t off = 0;
    while (off < bytes.size()) {
      auto rec = DecodeJournalRecord(std::string_view(bytes).substr(off));
      if (!rec.ok()) {
        rep.cuts.push_back(absl::StrCat(path, ": ", rec.status().message(), " at offset ", off,
                                        "; cut ", bytes.size() - off, " bytes"));
        rep.bytes_cut += bytes.size() - off;
        if (::truncate(path.c_str(), static_cast<off_t>(off)) != 0)
          return absl::UnavailableError(absl::StrCat("journal: cannot cut ", path));
        break;
      }
      seg.min_lsn = std::min(seg.min_lsn, rec->first.lsn);
      seg.max_lsn = std::max(seg.max_lsn, rec->first.lsn);
      ++rep.records;
      off += rec->second;
    }
    seg.bytes = off;
    rep.max_lsn = std::max(rep.max_lsn, seg.max_lsn);
    if (off == 0) {  // nothing intact: the file goes
      std::filesystem::remove(path, ec);
      continue;
    }
    j->bytes_ += off;
    j->closed_.push_back(seg);
    ++rep.segments;
  }
  if (rep.bytes_cut > 0) EXO_RETURN_IF_ERROR(SyncDir(options.dir));
  j->counters_.segments = j->closed_.size();
  j->writer_ = std::thread([p = j.get()] { p->WriterLoop(); });
  if (report) *report = std::move(rep);
  return j;
}

FrameJournal::~FrameJournal() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (writer_.joinable()) writer_.join();
  std::lock_guard io(io_mu_);
  if (fd_ >= 0) ::close(fd_);
}

absl::Status FrameJournal::ForEach(uint64_t after_lsn,
                                   const std::function<absl::Status(JournalRecord)>& fn) const {
  struct Ref {
    uint64_t lsn;
    size_t segment, offset;
  };
  std::vector<Segment> segs;
  {
    std::lock_guard io(io_mu_);
    segs = closed_;
  }
  std::vector<Ref> refs;
  for (size_t s = 0; s < segs.size(); ++s) {
    if (segs[s].max_lsn <= after_lsn) continue;
    EXO_ASSIGN_OR_RETURN(const std::string bytes, ReadFile(segs[s].path));
    for (size_t off = 0; off < std::min(bytes.size(), segs[s].bytes);) {
      auto rec = DecodeJournalRecord(std::string_view(bytes).substr(off));
      if (!rec.ok()) break;
      if (rec->first.lsn > after_lsn) refs.push_back({rec->first.lsn, s, off});
      off += rec->second;
    }
  }
  // Records of concurrent streams reach the file in append order, not quite lsn order.
  std::sort(refs.begin(), refs.end(), [](const Ref& a, const Ref& b) { return a.lsn < b.lsn; });
  size_t loaded = ~size_t{0};
  std::string bytes;
  for (const Ref& r : refs) {
    if (r.segment != loaded) {
      EXO_ASSIGN_OR_RETURN(bytes, ReadFile(segs[r.segment].path));
      loaded = r.segment;
    }
    auto rec = DecodeJournalRecord(std::string_view(bytes).substr(r.offset));
    if (!rec.ok()) return rec.status();
    EXO_RETURN_IF_ERROR(fn(std::move(rec->first)));
  }
  return absl::OkStatus();
}

absl::StatusOr<uint64_t> FrameJournal::Append(const JournalRecord& r) {
  if (r.uploader.size() > kMaxUploader)
    return absl::InvalidArgumentError("journal: uploader name longer than 256 bytes");
  std::string rec = EncodeJournalRecord(r);
  std::lock_guard lock(mu_);
  if (!failed_.ok()) return failed_;
  if (bytes_ + rec.size() > options_.max_bytes)
    return absl::ResourceExhaustedError(
        absl::StrCat("journal full: ", bytes_, " bytes held, journal_max_bytes = ",
                     options_.max_bytes, " (waiting for a checkpoint to cover them)"));
  bytes_ += rec.size();
  pending_ += rec;
  pending_min_lsn_ = std::min(pending_min_lsn_, r.lsn);
  pending_max_lsn_ = std::max(pending_max_lsn_, r.lsn);
  ++counters_.appends;
  const uint64_t ticket = ++appended_;
  cv_.notify_all();
  return ticket;
}

absl::Status FrameJournal::WaitDurable(uint64_t ticket) {
  std::unique_lock lock(mu_);
  cv_.wait(lock, [&] { return durable_ >= ticket || !failed_.ok() || stop_; });
  if (durable_ >= ticket) return absl::OkStatus();
  if (!failed_.ok()) return failed_;
  return absl::UnavailableError("journal closed");
}

void FrameJournal::WriterLoop() {
  std::unique_lock lock(mu_);
  for (;;) {
    cv_.wait(lock, [&] { return stop_ || (!pending_.empty() && failed_.ok()); });
    if (pending_.empty() || !failed_.ok()) {
      if (stop_) return;
      continue;
    }
    std::string group;
    group.swap(pending_);
    const uint64_t upto = appended_, min_lsn = pending_min_lsn_, max_lsn = pending_max_lsn_;
    pending_min_lsn_ = ~uint64_t{0};
    pending_max_lsn_ = 0;
    lock.unlock();
    const int64_t t0 = NowNs();
    const absl::Status s = WriteGroup(group, min_lsn, max_lsn);
    const int64_t dt = NowNs() - t0;
    lock.lock();
    if (!s.ok()) {
      failed_ = s;
    } else {
      durable_ = upto;
      ++counters_.groups;
      counters_.bytes_written += group.size();
      counters_.sync_ns_total += static_cast<uint64_t>(dt);
      counters_.sync_ns_max = std::max(counters_.sync_ns_max, static_cast<uint64_t>(dt));
    }
    cv_.notify_all();
  }
}

absl::Status FrameJournal::WriteGroup(const std::string& bytes, uint64_t min_lsn, uint64_t max_lsn) {
  std::lock_guard io(io_mu_);
  if (fd_ >= 0 && current_.bytes >= options_.segment_bytes) CloseCurrentLocked();
  bool created = false;
  if (fd_ < 0) {
    char name[64];
    std::snprintf(name, sizeof name, "seg-%020llu.wal", static_cast<unsigned long long>(min_lsn));
    current_ = Segment{};
    current_.path = (std::filesystem::path(options_.dir) / name).string();
    fd_ = ::open(current_.path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0600);
    if (fd_ < 0)
      return absl::UnavailableError(absl::StrCat("journal: cannot create ", current_.path, ": ",
                                                 std::strerror(errno)));
    created = true;
  }
  for (size_t off = 0; off < bytes.size();) {
    const ssize_t n = ::write(fd_, bytes.data() + off, bytes.size() - off);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0)
      return absl::UnavailableError(absl::StrCat("journal: write to ", current_.path, ": ",
                                                 std::strerror(errno)));
    off += static_cast<size_t>(n);
  }
  if (::fdatasync(fd_) != 0)
    return absl::UnavailableError(absl::StrCat("journal: fdatasync ", current_.path, ": ",
                                               std::strerror(errno)));
  if (created) EXO_RETURN_IF_ERROR(SyncDir(options_.dir));  // the new file's name is durable too
  current_.bytes += bytes.size();
  current_.min_lsn = std::min(current_.min_lsn, min_lsn);
  current_.max_lsn = std::max(current_.max_lsn, max_lsn);
  return absl::OkStatus();
}

void FrameJournal::CloseCurrentLocked() {
  if (fd_ < 0) return;
  ::close(fd_);
  fd_ = -1;
  closed_.push_back(current_);
  current_ = Segment{};
}

void FrameJournal::Rotate() {
  std::lock_guard io(io_mu_);
  CloseCurrentLocked();
}

size_t FrameJournal::DropCovered(uint64_t applied_lsn) {
  size_t dropped = 0, freed = 0;
  {
    std::lock_guard io(io_mu_);
    std::vector<Segment> keep;
    for (const Segment& s : closed_) {
      if (s.max_lsn <= applied_lsn) {
        std::error_code ec;
        std::filesystem::remove(s.path, ec);
        if (!ec) {
          ++dropped;
          freed += s.bytes;
          continue;
        }
      }
      keep.push_back(s);
    }
    closed_ = std::move(keep);
  }
  std::lock_guard lock(mu_);
  bytes_ -= std::min(bytes_, freed);
  counters_.segments_dropped += dropped;
  return dropped;
}

size_t FrameJournal::bytes() const {
  std::lock_guard lock(mu_);
  return bytes_;
}

FrameJournal::Counters FrameJournal::counters() const {
  Counters c;
  {
    std::lock_guard lock(mu_);
    c = counters_;
    c.bytes = bytes_;
  }
  std::lock_guard io(io_mu_);
  c.segments = closed_.size() + (fd_ >= 0 ? 1 : 0);
  return c;
}

}  // namespace exo
