// libFuzzer target: the client's delta application (client/store/local_store.h). The bytes are a
// container of deltas (an exoview.v1.Checkpoint: its `model` then its `log`, as a server would
// send a snapshot and then a tail): each is applied to a LocalStore in order, errors ignored (a
// bad delta must be refused, never crash); after every accepted delta the digest is computed,
// and at the end the viewer's defensive filter (WithoutUnusableViews) runs over the model.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "client/store/local_store.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  exo::v1::Checkpoint batch;
  if (!batch.ParseFromArray(data, static_cast<int>(size))) return 0;
  exo::LocalStore store;
  auto apply = [&](const exo::v1::Delta& d) {
    const uint64_t before = store.version();
    if (store.Apply(d).ok()) {
      (void)store.Digest();
    } else if (store.version() != before) {
      __builtin_trap();  // a refused delta must not move the client's version
    }
  };
  for (const auto& d : batch.model()) apply(d);
  for (const auto& d : batch.log()) apply(d);
  std::vector<std::string> skipped;
  (void)exo::WithoutUnusableViews(store.model(), &skipped);
  return 0;
}
