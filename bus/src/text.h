// printf-style appending to a std::string, for the text outputs of bus/ (decoder lines, DBC).
// Internal to bus/; tool-edge code only (it allocates).
#pragma once

#include <cstdio>
#include <string>

namespace skinbus::bus::internal {

template <typename... Args>
void appendf(std::string* s, const char* fmt, Args... args) {
  char buf[256];
  const int n = std::snprintf(buf, sizeof buf, fmt, args...);
  if (n < 0) return;
  if (static_cast<std::size_t>(n) < sizeof buf) {
    s->append(buf, static_cast<std::size_t>(n));
    return;
  }
  const std::size_t old = s->size();  // longer than the buffer: format again in place
  s->resize(old + static_cast<std::size_t>(n) + 1);
  std::snprintf(s->data() + old, static_cast<std::size_t>(n) + 1, fmt, args...);
  s->resize(old + static_cast<std::size_t>(n));
}

}  // namespace skinbus::bus::internal
