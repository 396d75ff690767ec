// skinbus/common/uid.h: a patch's 64-bit hardware UID as text.
#pragma once

#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <string>

namespace skinbus {

// 16 lower-case hex digits, as logs, events and JSON print it ("5b00000000000003").
inline std::string format_uid(uint64_t uid) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "%016" PRIx64, uid);
  return buf;
}

}  // namespace skinbus
