// Return-if-error helpers for absl::Status / absl::StatusOr, used across core/.
#pragma once

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define RIM_CONCAT_INNER(a, b) a##b
#define RIM_CONCAT(a, b) RIM_CONCAT_INNER(a, b)

// Evaluates `expr` (an absl::Status) and returns it from the caller if it is not OK.
#define RIM_RETURN_IF_ERROR(expr)              \
  do {                                         \
    ::absl::Status rim_status_ = (expr);       \
    if (!rim_status_.ok()) return rim_status_; \
  } while (0)

// `RIM_ASSIGN_OR_RETURN(auto x, MakeX());` unwraps an absl::StatusOr or returns its status.
#define RIM_ASSIGN_OR_RETURN(lhs, expr) \
  RIM_ASSIGN_OR_RETURN_IMPL(RIM_CONCAT(rim_statusor_, __LINE__), lhs, expr)
#define RIM_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                              \
  if (!tmp.ok()) return tmp.status();             \
  lhs = std::move(tmp).value()
