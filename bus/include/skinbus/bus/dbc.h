// skinbus/bus/dbc.h: a DBC file (Vector CANdb++ text format, as read by SavvyCAN, cantools and
// most CAN tools) generated from the protocol's field tables.
//
// Each (class, node) is one DBC message. Multi-part classes are multiplexed on the part index
// (bits 0..4 of byte 0): a field appears under the part that carries it. A field that straddles
// two parts (only 32- and 64-bit fields in classic frames) cannot be a DBC signal; it is listed
// in a comment instead. FD and classic layouts share identifiers, so one file serves one kind.
#pragma once

#include <string>

#include "skinbus/bus/protocol.h"

namespace skinbus::bus {

// DBC text for patch nodes first_node..last_node (inclusive) and the host's commands to them.
std::string generate_dbc(FrameKind kind, uint8_t first_node, uint8_t last_node);

}  // namespace skinbus::bus
