#include "common/status.h"

#include <cstdio>
#include <cstdlib>

namespace exo::internal {
void CheckFailed(const char* cond, const char* file, int line) {
  std::fprintf(stderr, "EXO_CHECK failed: %s at %s:%d\n", cond, file, line);
  std::abort();
}
}  // namespace exo::internal
