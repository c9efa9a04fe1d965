// Process-wide glibc malloc tuning shared by the long-running binaries (exoview_server,
// exoview_relay): the arena cap that keeps a many-threaded process's RSS flat, and the heap's
// live vs free bytes (mallinfo2) that tell live data from memory the arenas keep.
// docs/service.md "Memory over a long session".
#pragma once

#include <cstddef>

#include "absl/status/status.h"

namespace exo::process {

// glibc creates up to 8 arenas per core; buffers allocated on one thread and freed on another
// leave free memory in every arena a thread ever used. 2 kept exoview_server's RSS flat.
inline constexpr int kDefaultMallocArenaMax = 2;
inline constexpr char kMallocArenaMaxHelp[] =
    "glibc malloc arenas (0: glibc default, 8 per core); bounds the free memory threads keep";

// Sets M_ARENA_MAX. Call before any thread starts (gRPC's included). 0 leaves glibc's default;
// < 0 is InvalidArgument; a failing mallopt is Internal. A no-op (OK) without glibc.
absl::Status LimitMallocArenas(int max_arenas);

// Sets M_MMAP_THRESHOLD: allocations of at least this many bytes are mmapped and unmapped on
// free. 0 leaves glibc's dynamic threshold (128 KiB, raised to the size of every mmapped block
// freed, up to 32 MiB: after the first freed frame buffer every later one comes from an arena
// and can leave holes there). Call before any thread starts. A no-op (OK) without glibc.
// A fixed 128 KiB kept exoview_server's free heap at 35-47 MB and RSS within +1 % from frame
// 5 000 to 30 000 (with the dynamic threshold free bytes rose 51 -> 90 MB, RSS +8 %).
inline constexpr size_t kDefaultMallocMmapThreshold = size_t{128} << 10;
inline constexpr char kMallocMmapThresholdHelp[] =
    "glibc M_MMAP_THRESHOLD in bytes (0: glibc's dynamic threshold); larger blocks are mmapped "
    "and returned on free";
absl::Status SetMallocMmapThreshold(size_t bytes);

struct HeapUsage {
  bool known = false;        // false without glibc
  size_t in_use_bytes = 0;   // live allocations (arena chunks + mmapped blocks)
  size_t free_bytes = 0;     // free bytes the arenas hold (not returned to the system)
};
HeapUsage ReadHeapUsage();

}  // namespace exo::process
