// Building Errors (result.h) with formatted messages, for code that reports what it was doing.
#pragma once

#include <cstdarg>
#include <cstdio>
#include <string>
#include <utility>

#include "skinbus/common/result.h"

namespace skinbus {

// make_error with a printf-style message: errorf(ErrorCode::kIo, "cannot write %s", path.c_str()).
[[gnu::format(printf, 2, 3)]] inline Error errorf(ErrorCode code, const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  const int n = std::vsnprintf(nullptr, 0, fmt, ap);
  va_end(ap);
  std::string message(n > 0 ? static_cast<std::size_t>(n) : 0, '\0');
  if (n > 0) {
    va_start(ap, fmt);
    std::vsnprintf(message.data(), message.size() + 1, fmt, ap);
    va_end(ap);
  }
  return make_error(code, std::move(message));
}

// `error` with `context` and ": " before its message (what was being done when it failed).
inline Error with_context(const Error& error, const std::string& context) {
  return make_error(error.code, context + ": " + error.message);
}

}  // namespace skinbus
