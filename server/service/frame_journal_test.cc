// The frame journal on its own (server/service/frame_journal.h): records round-trip through
// group commit and reopen in lsn order; a torn or corrupt tail is cut at the last intact record
// and never replayed; covered segments are dropped after Rotate; the size bound refuses.
#include "server/service/frame_journal.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <thread>

#include <gtest/gtest.h>

namespace exo {
namespace {

class FrameJournalTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/exoview_journal_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    opt_.dir = dir_ + "/j";
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  static JournalRecord Rec(uint64_t lsn, std::string uploader = "drone-1") {
    JournalRecord r;
    r.lsn = lsn;
    r.sequence = lsn * 10;
    r.uploader = std::move(uploader);
    r.frame = std::string(100 + lsn, static_cast<char>('a' + lsn % 26));
    return r;
  }
  std::vector<JournalRecord> ReadAllRecords(uint64_t after, FrameJournal::OpenReport* rep = nullptr) {
    auto j = FrameJournal::Open(opt_, rep);
    EXPECT_TRUE(j.ok()) << j.status();
    std::vector<JournalRecord> out;
    EXPECT_TRUE((*j)->ForEach(after, [&](JournalRecord r) {
      out.push_back(std::move(r));
      return absl::OkStatus();
    }).ok());
    return out;
  }
  std::vector<std::string> Segments() const {
    std::vector<std::string> out;
    for (const auto& e : std::filesystem::directory_iterator(opt_.dir)) out.push_back(e.path().string());
    std::sort(out.begin(), out.end());
    return out;
  }
  std::string dir_;
  FrameJournalOptions opt_;
};

TEST_F(FrameJournalTest, RecordRoundTripAndCorruptionIsDetected) {
  const JournalRecord r = Rec(7, "admin:ops/drone-7");
  const std::string b = EncodeJournalRecord(r);
  auto d = DecodeJournalRecord(b);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->second, b.size());
  EXPECT_EQ(d->first.lsn, 7u);
  EXPECT_EQ(d->first.sequence, 70u);
  EXPECT_EQ(d->first.uploader, "admin:ops/drone-7");
  EXPECT_EQ(d->first.frame, r.frame);
  // Every cut is torn, every flipped byte is caught (magic, length or CRC).
  for (size_t cut = 0; cut < b.size(); ++cut)
    EXPECT_FALSE(DecodeJournalRecord(std::string_view(b).substr(0, cut)).ok()) << cut;
  for (size_t i = 0; i < b.size(); ++i) {
    std::string c = b;
    c[i] ^= 0x20;
    EXPECT_FALSE(DecodeJournalRecord(c).ok()) << i;
  }
}

TEST_F(FrameJournalTest, ConcurrentAppendsAreDurableInGroupsAndReopenInLsnOrder) {
  {
    auto j = FrameJournal::Open(opt_, nullptr);
    ASSERT_TRUE(j.ok()) << j.status();
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t)
      threads.emplace_back([&, t] {
        for (uint64_t i = 0; i < 25; ++i) {
          auto ticket = (*j)->Append(Rec(1 + t + 4 * i));
          ASSERT_TRUE(ticket.ok());
          ASSERT_TRUE((*j)->WaitDurable(*ticket).ok());
        }
      });
    for (auto& t : threads) t.join();
    const auto c = (*j)->counters();
    EXPECT_EQ(c.appends, 100u);
    EXPECT_LE(c.groups, 100u);
    EXPECT_GE(c.groups, 1u);
  }
  FrameJournal::OpenReport rep;
  const auto all = ReadAllRecords(0, &rep);
  EXPECT_EQ(rep.records, 100u);
  EXPECT_EQ(rep.max_lsn, 100u);
  EXPECT_EQ(rep.bytes_cut, 0u);
  ASSERT_EQ(all.size(), 100u);
  for (size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(all[i].lsn, i + 1);
    EXPECT_EQ(all[i].frame, Rec(i + 1).frame);
  }
  // Only what a checkpoint does not cover.
  EXPECT_EQ(ReadAllRecords(60).size(), 40u);
}

TEST_F(FrameJournalTest, TornTailIsCutAtTheLastIntactRecordAndNotReplayed) {
  {
    auto j = FrameJournal::Open(opt_, nullptr);
    ASSERT_TRUE(j.ok());
    for (uint64_t i = 1; i <= 5; ++i) ASSERT_TRUE((*j)->WaitDurable(*(*j)->Append(Rec(i))).ok());
  }
  const auto segs = Segments();
  ASSERT_EQ(segs.size(), 1u);
  const auto full = std::filesystem::file_size(segs[0]);
  const size_t last = EncodeJournalRecord(Rec(5)).size();
  // kill -9 in the middle of the last record's write.
  std::filesystem::resize_file(segs[0], full - last / 2);
  FrameJournal::OpenReport rep;
  auto recs = ReadAllRecords(0, &rep);
  ASSERT_EQ(recs.size(), 4u);
  EXPECT_EQ(recs.back().lsn, 4u);
  EXPECT_EQ(rep.bytes_cut, last - last / 2);
  ASSERT_EQ(rep.cuts.size(), 1u);
  EXPECT_NE(rep.cuts[0].find("torn record"), std::string::npos) << rep.cuts[0];
  EXPECT_EQ(std::filesystem::file_size(segs[0]), full - last);  // cut cleanly
  // A flipped byte inside record 3: records 3.. are cut, 1..2 stay.
  {
    std::fstream f(segs[0], std::ios::in | std::ios::out | std::ios::binary);
    const size_t off = EncodeJournalRecord(Rec(1)).size() + EncodeJournalRecord(Rec(2)).size() + 40;
    f.seekp(static_cast<std::streamoff>(off));
    f.put('\x7f');
  }
  recs = ReadAllRecords(0, &rep);
  ASSERT_EQ(recs.size(), 2u);
  EXPECT_NE(rep.cuts.at(0).find("CRC mismatch"), std::string::npos) << rep.cuts[0];
  // Appending after a cut continues cleanly in a new segment.
  {
    auto j = FrameJournal::Open(opt_, nullptr);
    ASSERT_TRUE(j.ok());
    ASSERT_TRUE((*j)->WaitDurable(*(*j)->Append(Rec(9))).ok());
  }
  recs = ReadAllRecords(0, &rep);
  ASSERT_EQ(recs.size(), 3u);
  EXPECT_EQ(recs.back().lsn, 9u);
  EXPECT_TRUE(rep.cuts.empty());
}

TEST_F(FrameJournalTest, RotateAndDropCoveredBoundTheJournal) {
  opt_.segment_bytes = 4096;
  opt_.max_bytes = 3 * 4096;
  auto j = FrameJournal::Open(opt_, nullptr);
  ASSERT_TRUE(j.ok());
  uint64_t lsn = 0;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE((*j)->WaitDurable(*(*j)->Append(Rec(++lsn))).ok());
  (*j)->Rotate();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE((*j)->WaitDurable(*(*j)->Append(Rec(++lsn))).ok());
  EXPECT_EQ(Segments().size(), 2u);
  // A checkpoint covering lsn 4 covers nothing whole; one covering 5 drops the first segment;
  // the open segment is never dropped.
  EXPECT_EQ((*j)->DropCovered(4), 0u);
  EXPECT_EQ((*j)->DropCovered(5), 1u);
  EXPECT_EQ(Segments().size(), 1u);
  EXPECT_EQ((*j)->DropCovered(100), 0u);
  // Fill to the bound: Append refuses with the limit in the reason.
  absl::Status refused;
  for (int i = 0; i < 200 && refused.ok(); ++i) {
    auto t = (*j)->Append(Rec(++lsn));
    if (!t.ok()) refused = t.status();
    else ASSERT_TRUE((*j)->WaitDurable(*t).ok());
  }
  EXPECT_EQ(refused.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(refused.message().find("journal_max_bytes = 12288"), std::string::npos) << refused;
  EXPECT_LE((*j)->bytes(), opt_.max_bytes);
  (*j)->Rotate();
  EXPECT_GE((*j)->DropCovered(lsn), 1u);
  EXPECT_TRUE((*j)->Append(Rec(++lsn)).ok());
}

}  // namespace
}  // namespace exo
