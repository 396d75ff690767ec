#include "skinbus/bus/command.h"

#include "byte_order.h"

namespace skinbus::bus {

namespace {

// Index of the first non-zero argument byte at or after `from`, or -1.
int first_nonzero(const Command& c, int from) {
  for (int i = from; i < static_cast<int>(c.arg.size()); ++i) {
    if (c.arg[i] != 0) return i;
  }
  return -1;
}

CommandCheck bad_arg(uint16_t detail) {
  return {AckStatus::kBadArgument, detail};
}

}  // namespace

CommandCheck check_command(const Command& c, const CommandLimits& lim) {
  int used = 0;  // argument bytes the opcode uses
  CommandCheck ok{AckStatus::kOk, 0};
  switch (c.opcode) {
    case Opcode::kTare:
    case Opcode::kGetInfo:
      used = 0;
      break;
    case Opcode::kSetMode:
      used = 1;
      if (c.arg[0] >= kPatchModeCount) return bad_arg(1);
      ok.value = c.arg[0];
      break;
    case Opcode::kSetRate: {
      used = 2;
      const uint16_t rate = internal::get_u16(c.arg.data());
      if (rate < lim.min_rate_chz || rate > lim.max_rate_chz) return bad_arg(1);
      ok.value = rate;
      break;
    }
    case Opcode::kSyncMode:
      used = 1;
      if (c.arg[0] > 1) return bad_arg(1);
      ok.value = c.arg[0];
      break;
    case Opcode::kIdentify:
      used = 1;
      if (c.arg[0] > lim.max_identify_s) return bad_arg(1);
      ok.value = c.arg[0];
      break;
    case Opcode::kReboot:
      used = 4;
      if (internal::get_u32(c.arg.data()) != kRebootMagic) return {AckStatus::kNotPermitted, 1};
      break;
    default:
      return {AckStatus::kUnknownOpcode, 0};
  }
  if (const int i = first_nonzero(c, used); i >= 0) return bad_arg(static_cast<uint16_t>(1 + i));
  return ok;
}

bool answer_command_frame(const CanFrame& frame, uint8_t own_node, uint8_t ack_seq,
                          const CommandLimits& limits, Message* ack, Command* accepted) {
  if (frame.extended || frame.rtr || frame.error) return false;
  if (can_id_class(frame.id) != static_cast<uint8_t>(MessageClass::kCommand)) return false;
  const uint8_t to = can_id_node(frame.id);
  if (to != own_node && to != kNodeBroadcast) return false;
  Ack a;
  a.broadcast = to == kNodeBroadcast;
  a.command_seq = frame.len >= kHeaderLen ? frame.data[1] : 0;
  a.opcode = frame.len > kHeaderLen ? frame.data[2] : 0;
  Message cmd;
  const DecodeError e = decode_single(frame, &cmd);
  if (e == DecodeError::kNone) {
    const Command& c = std::get<Command>(cmd.body);
    const CommandCheck chk = check_command(c, limits);
    a.status = chk.status;
    a.value = chk.value;
    if (chk.status == AckStatus::kOk && accepted) *accepted = c;
  } else if (e == DecodeError::kBadVersion) {
    a.status = AckStatus::kVersionMismatch;
    a.value = kProtocolVersion;  // tell the host which version this node speaks
  } else {
    a.status = AckStatus::kBadLength;
    a.value = frame.len;
  }
  *ack = Message{own_node, ack_seq, frame.fd ? FrameKind::kFd : FrameKind::kClassic, a};
  return true;
}

}  // namespace skinbus::bus
