// Write-ahead journal of accepted frames (issue 20 item 3, SPEC §14 "an Ack that says durable
// means the frame's effects survive kill -9"). The server appends every frame it hands to the
// pipeline (its serialized exoview.v1.Frame, the uploader it came from and its log sequence
// number) and acks it as durable only once an fdatasync covers the record. A writer thread
// commits in groups: every record appended while the previous sync ran goes out with the next
// write + fdatasync, so N concurrent streams cost about one sync per group, not one per frame.
//
// On disk: segment files DIR/seg-<first lsn, 20 digits>.wal, each a sequence of records
//   u32 magic "EXJ1" | u32 body length | u32 CRC-32 (zlib) of the body |
//   body = u64 lsn | u64 uploader sequence | u32 uploader length | uploader | frame bytes
// (little-endian). Open() scans every segment; a record that is short, has a bad magic, an
// implausible length or a CRC mismatch ends its segment: the file is cut there (a torn tail after
// kill -9 or a power cut) and what follows is reported, never replayed.
// Truncation: Rotate() closes the current segment (a checkpoint does it before it snapshots the
// model); DropCovered(lsn) deletes the closed segments whose records all have lsn <= the
// checkpoint's applied lsn. The journal thus holds about two checkpoint intervals of frames.
// No gRPC here: the service decides what to append and when to ack.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "common/status.h"

namespace exo {

struct FrameJournalOptions {
  std::string dir;                          // created when missing
  size_t max_bytes = size_t{1} << 30;       // all segments; beyond it Append refuses
  size_t segment_bytes = size_t{64} << 20;  // a segment is closed once it is this large
  absl::Status Validate() const;
};

struct JournalRecord {
  uint64_t lsn = 0;
  uint64_t sequence = 0;  // the uploader's frame sequence number
  std::string uploader;   // "" = anonymous stream
  std::string frame;      // serialized exoview.v1.Frame
};

// Encodes / decodes one record (exposed for tests and the fuzzer). Decode returns the record and
// the bytes it used, or an error for a short, torn or corrupt record.
std::string EncodeJournalRecord(const JournalRecord& r);
absl::StatusOr<std::pair<JournalRecord, size_t>> DecodeJournalRecord(std::string_view bytes);

class FrameJournal {
 public:
  struct OpenReport {
    size_t segments = 0, records = 0;
    uint64_t max_lsn = 0;
    size_t bytes_cut = 0;          // torn / corrupt tails removed
    std::vector<std::string> cuts;  // one line per cut segment
  };
  static absl::StatusOr<std::unique_ptr<FrameJournal>> Open(const FrameJournalOptions& options,
                                                            OpenReport* report);
  ~FrameJournal();  // stops the writer after its last group
  FrameJournal(const FrameJournal&) = delete;
  FrameJournal& operator=(const FrameJournal&) = delete;

  // Calls `fn` for every intact record with lsn > after_lsn, in lsn order (records are read one
  // at a time). Call before the first Append.
  absl::Status ForEach(uint64_t after_lsn,
                       const std::function<absl::Status(JournalRecord)>& fn) const;

  // Queues one record; returns its ticket for WaitDurable. RESOURCE_EXHAUSTED when the journal
  // holds max_bytes (a checkpoint must cover some of it first).
  absl::StatusOr<uint64_t> Append(const JournalRecord& r);
  // Blocks until an fdatasync covers the ticket's record; an I/O error of the writer (the journal
  // stops taking records after one) comes back here.
  absl::Status WaitDurable(uint64_t ticket);

  void Rotate();                        // closes the current segment (if it holds records)
  size_t DropCovered(uint64_t applied_lsn);  // deletes closed, covered segments; returns how many

  struct Counters {
    uint64_t appends = 0, groups = 0, bytes_written = 0, segments_dropped = 0;
    uint64_t sync_ns_total = 0, sync_ns_max = 0;
    size_t bytes = 0, segments = 0;  // on disk now
  };
  Counters counters() const;
  size_t bytes() const;
  size_t max_bytes() const { return options_.max_bytes; }

 private:
  struct Segment {
    std::string path;
    uint64_t min_lsn = ~uint64_t{0}, max_lsn = 0;
    size_t bytes = 0;
  };
  explicit FrameJournal(const FrameJournalOptions& options) : options_(options) {}
  void WriterLoop();
  absl::Status WriteGroup(const std::string& bytes, uint64_t min_lsn, uint64_t max_lsn);
  void CloseCurrentLocked();  // io_mu_ held

  const FrameJournalOptions options_;
  // Queue of records not yet written (mu_).
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::string pending_;
  uint64_t pending_min_lsn_ = ~uint64_t{0}, pending_max_lsn_ = 0;
  uint64_t appended_ = 0, durable_ = 0;
  absl::Status failed_;
  bool stop_ = false;
  size_t bytes_ = 0;  // on disk + pending
  Counters counters_;
  // Files (io_mu_): the current segment and the closed ones, oldest first.
  mutable std::mutex io_mu_;
  int fd_ = -1;
  Segment current_;
  std::vector<Segment> closed_;
  std::thread writer_;
};

}  // namespace exo
