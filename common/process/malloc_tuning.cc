#include "common/process/malloc_tuning.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <string>

namespace exo::process {

absl::Status LimitMallocArenas(int max_arenas) {
  if (max_arenas < 0)
    return absl::InvalidArgumentError("malloc_arena_max must be >= 0 (0 = glibc default)");
#if defined(__GLIBC__)
  if (max_arenas > 0 && mallopt(M_ARENA_MAX, max_arenas) != 1)
    return absl::InternalError("mallopt(M_ARENA_MAX, " + std::to_string(max_arenas) + ") failed");
#endif
  return absl::OkStatus();
}

absl::Status SetMallocMmapThreshold(size_t bytes) {
  if (bytes > (size_t{32} << 20))
    return absl::InvalidArgumentError("malloc_mmap_threshold must be <= 32 MiB (0 = glibc dynamic)");
#if defined(__GLIBC__)
  if (bytes > 0 && mallopt(M_MMAP_THRESHOLD, static_cast<int>(bytes)) != 1)
    return absl::InternalError("mallopt(M_MMAP_THRESHOLD, " + std::to_string(bytes) + ") failed");
#endif
  return absl::OkStatus();
}

HeapUsage ReadHeapUsage() {
  HeapUsage h;
#if defined(__GLIBC__)
  const struct mallinfo2 mi = mallinfo2();
  h.known = true;
  h.in_use_bytes = mi.uordblks + mi.hblkhd;
  h.free_bytes = mi.fordblks;
#endif
  return h;
}

}  // namespace exo::process
