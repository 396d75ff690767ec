// skinbus/bus/command.h: how a patch judges a command and what it answers.
//
// Every command frame addressed to a patch gets exactly one acknowledgement: `ok` with the value
// applied, or a negative acknowledgement whose status says why (unknown opcode, bad argument,
// bad length, other protocol version). This is the one place those rules live; the patch node
// (patch_fw/) applies the accepted ones.
#pragma once

#include <cstdint>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/codec.h"

namespace skinbus::bus {

struct CommandLimits {
  uint16_t min_rate_chz = 100;    // 1 Hz
  uint16_t max_rate_chz = 10000;  // what the sensor configuration allows (Info::max_rate_chz)
  uint8_t max_identify_s = 60;
};

struct CommandCheck {
  AckStatus status = AckStatus::kOk;
  uint16_t value = 0;  // kOk: the value to apply; otherwise a detail (e.g. the bad byte's index)
};

// Checks one decoded command against the protocol and the node's limits. Argument bytes a
// command does not use must be zero (detail: 1 + the index of the first non-zero one).
CommandCheck check_command(const Command& cmd, const CommandLimits& limits);

// The acknowledgement a patch `own_node` sends for a command frame it received (`frame`,
// addressed to it or to all), whatever state the frame is in: a decodable command is checked
// with check_command; a frame too short or of another protocol version gets a NACK saying so.
// Returns false for frames that are not commands to this node (no answer is due). `ack_seq` is
// the patch's own ack counter.
bool answer_command_frame(const CanFrame& frame, uint8_t own_node, uint8_t ack_seq,
                          const CommandLimits& limits, Message* ack, Command* accepted);

}  // namespace skinbus::bus
