// skinbus/bus/protocol.h: the skinbus wire protocol, version 1, as data.
//
// docs/protocol.md is the specification in prose; this header is the same specification in
// code, and the codec, the reassembler, the decoder, the DBC generator and the bus budget all
// read their numbers from here. Change one, change the other, and the golden-frame tests in
// bus/src/codec_test.cc tell you when the two disagree.
//
// Summary:
//  * 11-bit standard identifiers: ID = class << 7 | node. The class (4 bits, lower = more
//    urgent) wins arbitration first; the node (7 bits) is the patch that sends, or for host
//    commands the patch addressed. `candump can0,<class<<7>:780` selects a class,
//    `candump can0,<node>:07F` one patch.
//  * Every frame starts with a 2-byte header: version (3 bits) | part index (5 bits), then the
//    transfer sequence (8 bits). A message larger than one frame is cut into parts of
//    62 bytes (CAN FD, 64-byte frames) or 6 bytes (classic CAN, 8-byte frames); the number of
//    parts follows from the class and the frame kind, so one frame can be decoded alone.
//  * Multi-part messages end in a CRC-16/CCITT-FALSE over the rest of the payload, so a
//    reassembly that mixed parts of different messages is detected.
//  * All integers are little-endian.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>

namespace skinbus::bus {

inline constexpr uint8_t kProtocolVersion = 1;  // 3 bits on the wire; 0 is never valid

// ---- Identifiers -----------------------------------------------------------------------------

inline constexpr uint8_t kNodeHost = 0;          // reserved: the host never sends with its own ID
inline constexpr uint8_t kNodeMin = 1;           // first patch node ID
inline constexpr uint8_t kNodeMax = 125;         // last patch node ID (125 patches per bus)
inline constexpr uint8_t kNodeUnassigned = 126;  // a node that has no ID configured yet
inline constexpr uint8_t kNodeBroadcast = 127;   // commands and SYNC addressed to every patch
inline constexpr uint32_t kNodeBits = 7;
inline constexpr uint32_t kNodeMask = 0x07F;
inline constexpr uint32_t kClassMask = 0x780;

// Message classes in arbitration order: a lower value wins the bus.
enum class MessageClass : uint8_t {
  kSync = 0,       // host -> all patches: sample now (single frame)
  kCommand = 1,    // host -> one patch or all: a request that is acknowledged (single frame)
  kAck = 2,        // patch -> host: result of a command (single frame)
  kSample = 3,     // patch -> host: one sample of all sensors (multi-part)
  kInfo = 4,       // patch -> host: answer to kGetInfo (multi-part)
  kHeartbeat = 5,  // patch -> host: health, about 1 Hz (multi-part)
};
inline constexpr int kMessageClassCount = 6;

constexpr bool is_known_class(uint8_t c) {
  return c < kMessageClassCount;
}
constexpr uint32_t make_can_id(MessageClass c, uint8_t node) {
  return (static_cast<uint32_t>(c) << kNodeBits) | (node & kNodeMask);
}
constexpr uint8_t can_id_node(uint32_t id) {
  return static_cast<uint8_t>(id & kNodeMask);
}
constexpr uint8_t can_id_class(uint32_t id) {
  return static_cast<uint8_t>((id >> kNodeBits) & 0xF);
}
constexpr bool is_patch_node(uint8_t node) {
  return node >= kNodeMin && node <= kNodeMax;
}

std::string_view message_class_name(MessageClass c);  // "sync", "command", ...

// ---- Frame header and segmentation -----------------------------------------------------------

inline constexpr std::size_t kHeaderLen = 2;
inline constexpr std::size_t kFdPartLen = 64 - kHeaderLen;      // 62 payload bytes a part
inline constexpr std::size_t kClassicPartLen = 8 - kHeaderLen;  // 6 payload bytes a part
inline constexpr std::size_t kMaxParts = 32;                    // 5-bit part index
inline constexpr std::size_t kCrcLen = 2;

enum class FrameKind : uint8_t { kClassic, kFd };

constexpr std::size_t part_len(FrameKind k) {
  return k == FrameKind::kFd ? kFdPartLen : kClassicPartLen;
}

struct FrameHeader {
  uint8_t version = kProtocolVersion;
  uint8_t part = 0;  // 0-based part index
  uint8_t seq = 0;   // transfer sequence, per sender and class, wraps at 256
};
constexpr uint8_t header_byte0(uint8_t version, uint8_t part) {
  return static_cast<uint8_t>((version & 0x7) << 5 | (part & 0x1F));
}

// ---- Payloads --------------------------------------------------------------------------------

inline constexpr int kSensorCount = 16;  // 4 x 4 grid, row-major from the patch's -x,-y corner
inline constexpr int kAxisCount = 3;
inline constexpr int kChannelCount = kSensorCount * kAxisCount;
inline constexpr double kFieldUtPerLsb = 0.1;   // wire unit of magnetic field: 0.1 uT
inline constexpr int16_t kFieldMaxLsb = 32767;  // +-3276.7 uT; clipped values set saturation

// A field in uT in the wire's units (kFieldUtPerLsb), rounded to the nearest and clamped to
// +-kFieldMaxLsb. `*clipped`, when given, is set to whether the value reached the limit or was
// not finite (NaN and Inf give 0): the sender must then flag the sensor saturated.
int16_t field_ut_to_lsb(double field_ut, bool* clipped = nullptr);

// Sample flags (Sample::flags).
namespace sample_flags {
inline constexpr uint16_t kContact = 1u << 0;        // the patch's gate sees a contact
inline constexpr uint16_t kSaturated = 1u << 1;      // at least one channel saturated
inline constexpr uint16_t kTareActive = 1u << 2;     // a tare (baseline capture) is in progress
inline constexpr uint16_t kTared = 1u << 3;          // field values are baseline-subtracted
inline constexpr uint16_t kSensorFault = 1u << 4;    // at least one sensor faulty (fault_mask)
inline constexpr uint16_t kSynced = 1u << 5;         // sampled on a host SYNC
inline constexpr uint16_t kEventTail = 1u << 6;      // event mode: post-contact tail sample
inline constexpr uint16_t kDriftTracking = 1u << 7;  // baseline is following slow drift
inline constexpr uint16_t kAll = 0x00FF;
}  // namespace sample_flags

struct Sample {
  uint32_t timestamp_us = 0;     // patch clock at the sample, microseconds, wraps at 2^32
  uint16_t flags = 0;            // sample_flags::*
  uint16_t fault_mask = 0;       // bit i: sensor i faulty, its channels are not valid
  uint16_t saturation_mask = 0;  // bit i: sensor i saturated or clipped to +-kFieldMaxLsb
  std::array<int16_t, kChannelCount> field_lsb{};  // sensor-major x,y,z; kFieldUtPerLsb units
  bool operator==(const Sample&) const = default;
};
inline constexpr std::size_t kSamplePayloadLen =
    4 + 2 + 2 + 2 + 2 * kChannelCount + kCrcLen;  // 108

enum class PatchState : uint8_t { kBooting = 0, kRunning = 1, kDegraded = 2, kFault = 3 };
enum class PatchMode : uint8_t { kOff = 0, kStream = 1, kEvent = 2 };
inline constexpr uint8_t kPatchStateCount = 4;
inline constexpr uint8_t kPatchModeCount = 3;
std::string_view patch_state_name(PatchState s);
std::string_view patch_mode_name(PatchMode m);

// Heartbeat status bits (Heartbeat::status).
namespace heartbeat_status {
inline constexpr uint8_t kSyncMode = 1u << 0;   // samples only on host SYNC
inline constexpr uint8_t kIdentify = 1u << 1;   // identify LED active
inline constexpr uint8_t kTared = 1u << 2;      // a baseline is held
inline constexpr uint8_t kSimulated = 1u << 3;  // the sensor source is the simulator
}  // namespace heartbeat_status

struct Heartbeat {
  PatchState state = PatchState::kBooting;
  PatchMode mode = PatchMode::kOff;
  uint16_t rate_chz = 0;      // sample rate, centihertz (4170 = 41.70 Hz)
  uint32_t uptime_s = 0;      // seconds since the node started
  uint64_t hardware_uid = 0;  // unique per board
  uint8_t fw_major = 0, fw_minor = 0, fw_patch = 0;
  uint8_t status = 0;             // heartbeat_status::*
  uint16_t fault_mask = 0;        // bit i: sensor i faulty
  uint16_t i2c_errors = 0;        // saturating counters since start
  uint16_t can_errors = 0;        // transmit errors and dropped frames
  uint16_t saturation_count = 0;  // samples with a saturated channel
  int16_t temperature_cdeg = 0;   // board temperature, 0.01 degC
  bool operator==(const Heartbeat&) const = default;
};
inline constexpr std::size_t kHeartbeatPayloadLen = 30 + kCrcLen;  // 32

enum class Opcode : uint8_t {
  kTare = 1,      // capture a new baseline; no argument
  kSetMode = 2,   // arg u8: PatchMode
  kSetRate = 3,   // arg u16: sample rate, centihertz
  kSyncMode = 4,  // arg u8: 1 = sample only on SYNC frames, 0 = free-running
  kIdentify = 5,  // arg u8: seconds to blink the identify LED, 0 = stop
  kReboot = 6,    // arg u32: must be kRebootMagic
  kGetInfo = 7,   // no argument; answered by an Ack and an Info message
};
inline constexpr uint8_t kOpcodeMin = 1, kOpcodeMax = 7;
inline constexpr uint32_t kRebootMagic = 0x544F4252;  // "RBOT" little-endian
std::string_view opcode_name(Opcode op);

struct Command {
  Opcode opcode = Opcode::kTare;
  std::array<uint8_t, 5> arg{};  // little-endian argument, meaning per opcode, zero-padded
  bool operator==(const Command&) const = default;
};
inline constexpr std::size_t kCommandPayloadLen = 6;  // single frame: 8 bytes with the header

enum class AckStatus : uint8_t {
  kOk = 0,
  kUnknownOpcode = 1,
  kBadArgument = 2,
  kBadLength = 3,
  kBusy = 4,
  kVersionMismatch = 5,
  kNotPermitted = 6,
};
inline constexpr uint8_t kAckStatusCount = 7;
std::string_view ack_status_name(AckStatus s);

// An acknowledgement carries its own transfer sequence (the patch's ack counter, so lost acks
// show as gaps) and names the command it answers by that command's sequence.
struct Ack {
  uint8_t opcode = 0;  // the opcode acknowledged (raw: unknown ones are echoed too)
  AckStatus status = AckStatus::kOk;
  uint8_t command_seq = 0;  // transfer sequence of the command answered
  bool broadcast = false;   // the command was addressed to every patch (node 127)
  uint16_t value = 0;       // applied value (mode, rate_chz, ...) or a detail code for a NACK
  bool operator==(const Ack&) const = default;
};
inline constexpr std::size_t kAckPayloadLen = 6;

struct Sync {
  uint32_t host_time_us = 0;  // low 32 bits of the host clock when sent
  uint16_t counter = 0;       // SYNC number; samples taken on it carry kSynced
  bool operator==(const Sync&) const = default;
};
inline constexpr std::size_t kSyncPayloadLen = 6;

struct Info {
  uint64_t hardware_uid = 0;
  uint8_t fw_major = 0, fw_minor = 0, fw_patch = 0;
  uint8_t protocol_version = kProtocolVersion;
  uint8_t sensor_count = kSensorCount;
  uint8_t axis_count = kAxisCount;
  uint8_t gain_sel = 0;             // MLX90393 GAIN_SEL
  uint8_t resolution = 0;           // RES_X | RES_Y << 2 | RES_Z << 4
  uint8_t oversampling = 0;         // OSR
  uint8_t digital_filter = 0;       // DIG_FILT
  uint16_t rate_chz = 0;            // current sample rate, centihertz
  uint16_t max_rate_chz = 0;        // fastest rate the sensor configuration allows
  uint16_t conversion_time_us = 0;  // one XYZ conversion, as configured
  uint16_t field_lsb_nt = 100;      // wire field unit in nT (v1: always 100)
  bool operator==(const Info&) const = default;
};
inline constexpr std::size_t kInfoPayloadLen = 26 + kCrcLen;  // 28

// Payload length of a class (multi-part classes include the trailing CRC).
constexpr std::size_t payload_len(MessageClass c) {
  switch (c) {
    case MessageClass::kSync:
      return kSyncPayloadLen;
    case MessageClass::kCommand:
      return kCommandPayloadLen;
    case MessageClass::kAck:
      return kAckPayloadLen;
    case MessageClass::kSample:
      return kSamplePayloadLen;
    case MessageClass::kInfo:
      return kInfoPayloadLen;
    case MessageClass::kHeartbeat:
      return kHeartbeatPayloadLen;
  }
  return 0;
}
constexpr bool is_multi_part(MessageClass c) {
  return c == MessageClass::kSample || c == MessageClass::kInfo || c == MessageClass::kHeartbeat;
}
constexpr std::size_t part_count(MessageClass c, FrameKind k) {
  if (!is_multi_part(c)) return 1;
  return (payload_len(c) + part_len(k) - 1) / part_len(k);
}
inline constexpr std::size_t kMaxPayloadLen = kSamplePayloadLen;

// ---- Field tables ----------------------------------------------------------------------------
// The layout of each payload as data, for the DBC generator and for describing a lone frame.
// `offset` is from the start of the payload (after the frame header).

enum class FieldType : uint8_t { kU8, kU16, kU32, kU64, kI16 };
constexpr std::size_t field_size(FieldType t) {
  switch (t) {
    case FieldType::kU8:
      return 1;
    case FieldType::kU16:
      return 2;
    case FieldType::kI16:
      return 2;
    case FieldType::kU32:
      return 4;
    case FieldType::kU64:
      return 8;
  }
  return 0;
}

struct FieldDesc {
  const char* name;
  uint16_t offset;
  FieldType type;
  double scale;      // physical = raw * scale
  const char* unit;  // "" when dimensionless
};

// Fields of a class's payload, in offset order, covering it exactly.
const FieldDesc* fields_begin(MessageClass c);
const FieldDesc* fields_end(MessageClass c);

}  // namespace skinbus::bus
