// Error handling for Exoview: recoverable failures are absl::Status / absl::StatusOr, whose
// codes are gRPC's codes, so the service edge maps them one to one.
#pragma once

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"

// Returns from the enclosing function when `expr` (an absl::Status) is not OK.
#define EXO_RETURN_IF_ERROR(expr)                 \
  do {                                            \
    ::absl::Status exo_status_ = (expr);          \
    if (!exo_status_.ok()) return exo_status_;    \
  } while (0)

#define EXO_CONCAT_INNER_(a, b) a##b
#define EXO_CONCAT_(a, b) EXO_CONCAT_INNER_(a, b)
// EXO_ASSIGN_OR_RETURN(auto x, MakeX()); assigns the value or returns the error.
#define EXO_ASSIGN_OR_RETURN(lhs, expr) \
  EXO_ASSIGN_OR_RETURN_IMPL_(EXO_CONCAT_(exo_statusor_, __LINE__), lhs, expr)
#define EXO_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                               \
  if (!tmp.ok()) return tmp.status();              \
  lhs = std::move(tmp).value()

// Invariant check: aborts with a message. For programming errors only, never for input.
#define EXO_CHECK(cond)                                                              \
  do {                                                                               \
    if (!(cond)) ::exo::internal::CheckFailed(#cond, __FILE__, __LINE__);            \
  } while (0)

namespace exo::internal {
[[noreturn]] void CheckFailed(const char* cond, const char* file, int line);
}  // namespace exo::internal
