// libFuzzer target: the server's checkpoint loader and the frame journal's record decoder.
// The bytes as an exoview.v1.Checkpoint go through ModelStore::RestoreCheckpoint (what a
// restarting server does with its checkpoint file); a checkpoint it accepts must round-trip:
// MakeCheckpoint of the restored store, restored again into a fresh store, gives the same version
// and digest. The same bytes as a journal record (DecodeJournalRecord): an accepted record must
// re-encode to exactly the bytes it was decoded from.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "server/service/frame_journal.h"
#include "server/service/model_store.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  if (auto rec = exo::DecodeJournalRecord(bytes); rec.ok())
    if (exo::EncodeJournalRecord(rec->first) != bytes.substr(0, rec->second)) __builtin_trap();

  exo::v1::Checkpoint c;
  if (!c.ParseFromArray(data, static_cast<int>(size))) return 0;
  exo::ModelStore store;
  if (!store.RestoreCheckpoint(c).ok()) return 0;
  const auto s1 = store.GetSummary();
  const exo::v1::Checkpoint again = store.MakeCheckpoint(size_t{1} << 20);
  exo::v1::Checkpoint reparsed;
  if (!reparsed.ParseFromString(again.SerializeAsString())) __builtin_trap();
  exo::ModelStore second;
  if (!second.RestoreCheckpoint(reparsed).ok()) __builtin_trap();
  const auto s2 = second.GetSummary();
  if (s1.version != s2.version || s1.digest != s2.digest || s1.num_views != s2.num_views)
    __builtin_trap();
  return 0;
}
