// skinbus/bus/format.h: one readable line per message or frame, for tools and logs.
//
// The line formats are stable (tests compare them) and documented in docs/protocol.md:
//   sample node=5 seq=42 t_us=16909060 flags=contact,tared fault=0000 sat=0000 field_ut=-240.0,...
//   heartbeat node=5 seq=9 state=running mode=event rate_hz=41.70 uptime_s=3600
//   uid=0123456789abcdef ...
// These allocate (they build strings): use them at tool edges, not on hot paths.
#pragma once

#include <string>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/codec.h"

namespace skinbus::bus {

// The whole message on one line, without a trailing newline.
std::string format_message(const Message& msg);

// What one frame says on its own: class, node, sequence, part i/n and every field that lies
// wholly inside this part; or the reason it is not a valid skinbus frame.
std::string describe_frame(const CanFrame& frame);

// "contact,tared" ("-" when no flag is set).
std::string format_sample_flags(uint16_t flags);

}  // namespace skinbus::bus
