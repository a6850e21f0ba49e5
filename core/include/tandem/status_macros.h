// Early returns on absl::Status / absl::StatusOr, for code that passes a failure up unchanged
// (a failure that gets a prefix or a note keeps its hand-written `if`).
#ifndef TANDEM_STATUS_MACROS_H_
#define TANDEM_STATUS_MACROS_H_

#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

// Evaluates its argument (an absl::Status; commas allowed) once and returns it from the enclosing
// function when it is not OK.
#define TANDEM_RETURN_IF_ERROR(...)                                            \
  do {                                                                         \
    if (::absl::Status tandem_status_ = (__VA_ARGS__); !tandem_status_.ok()) { \
      return tandem_status_;                                                   \
    }                                                                          \
  } while (false)

// Evaluates its second argument (an absl::StatusOr<T>) once: returns its status when it is not OK,
// else moves its value into `lhs` (a declaration such as `auto x` or an existing lvalue).
#define TANDEM_ASSIGN_OR_RETURN(lhs, ...)                                                      \
  TANDEM_ASSIGN_OR_RETURN_IMPL_(TANDEM_STATUS_MACROS_CONCAT_(tandem_statusor_, __LINE__), lhs, \
                                __VA_ARGS__)

#define TANDEM_ASSIGN_OR_RETURN_IMPL_(statusor, lhs, ...)  \
  auto statusor = (__VA_ARGS__);                           \
  if (!statusor.ok()) return std::move(statusor).status(); \
  lhs = *std::move(statusor)

#define TANDEM_STATUS_MACROS_CONCAT_INNER_(x, y) x##y
#define TANDEM_STATUS_MACROS_CONCAT_(x, y) TANDEM_STATUS_MACROS_CONCAT_INNER_(x, y)

#endif  // TANDEM_STATUS_MACROS_H_
