#include "skinbus/bus/protocol.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

namespace skinbus::bus {

int16_t field_ut_to_lsb(double field_ut, bool* clipped) {
  const double lsb = std::round(field_ut / kFieldUtPerLsb);
  const bool finite = std::isfinite(lsb);
  if (clipped != nullptr) *clipped = !(std::fabs(lsb) < kFieldMaxLsb);
  if (!finite) return 0;
  return static_cast<int16_t>(std::clamp(lsb, -double{kFieldMaxLsb}, double{kFieldMaxLsb}));
}

std::string_view message_class_name(MessageClass c) {
  switch (c) {
    case MessageClass::kSync:
      return "sync";
    case MessageClass::kCommand:
      return "command";
    case MessageClass::kAck:
      return "ack";
    case MessageClass::kSample:
      return "sample";
    case MessageClass::kInfo:
      return "info";
    case MessageClass::kHeartbeat:
      return "heartbeat";
  }
  return "unknown";
}

std::string_view patch_state_name(PatchState s) {
  switch (s) {
    case PatchState::kBooting:
      return "booting";
    case PatchState::kRunning:
      return "running";
    case PatchState::kDegraded:
      return "degraded";
    case PatchState::kFault:
      return "fault";
  }
  return "unknown";
}

std::string_view patch_mode_name(PatchMode m) {
  switch (m) {
    case PatchMode::kOff:
      return "off";
    case PatchMode::kStream:
      return "stream";
    case PatchMode::kEvent:
      return "event";
  }
  return "unknown";
}

std::string_view opcode_name(Opcode op) {
  switch (op) {
    case Opcode::kTare:
      return "tare";
    case Opcode::kSetMode:
      return "set_mode";
    case Opcode::kSetRate:
      return "set_rate";
    case Opcode::kSyncMode:
      return "sync_mode";
    case Opcode::kIdentify:
      return "identify";
    case Opcode::kReboot:
      return "reboot";
    case Opcode::kGetInfo:
      return "get_info";
  }
  return "unknown";
}

std::string_view ack_status_name(AckStatus s) {
  switch (s) {
    case AckStatus::kOk:
      return "ok";
    case AckStatus::kUnknownOpcode:
      return "unknown_opcode";
    case AckStatus::kBadArgument:
      return "bad_argument";
    case AckStatus::kBadLength:
      return "bad_length";
    case AckStatus::kBusy:
      return "busy";
    case AckStatus::kVersionMismatch:
      return "version_mismatch";
    case AckStatus::kNotPermitted:
      return "not_permitted";
  }
  return "unknown";
}

namespace {

constexpr FieldDesc kSyncFields[] = {
    {"host_time_us", 0, FieldType::kU32, 1, "us"},
    {"counter", 4, FieldType::kU16, 1, ""},
};

constexpr FieldDesc kCommandFields[] = {
    {"opcode", 0, FieldType::kU8, 1, ""}, {"arg0", 1, FieldType::kU8, 1, ""},
    {"arg1", 2, FieldType::kU8, 1, ""},   {"arg2", 3, FieldType::kU8, 1, ""},
    {"arg3", 4, FieldType::kU8, 1, ""},   {"arg4", 5, FieldType::kU8, 1, ""},
};

constexpr FieldDesc kAckFields[] = {
    {"opcode", 0, FieldType::kU8, 1, ""},      {"status", 1, FieldType::kU8, 1, ""},
    {"command_seq", 2, FieldType::kU8, 1, ""}, {"flags", 3, FieldType::kU8, 1, ""},
    {"value", 4, FieldType::kU16, 1, ""},
};

constexpr FieldDesc kHeartbeatFields[] = {
    {"state", 0, FieldType::kU8, 1, ""},
    {"mode", 1, FieldType::kU8, 1, ""},
    {"rate", 2, FieldType::kU16, 0.01, "Hz"},
    {"uptime", 4, FieldType::kU32, 1, "s"},
    {"hardware_uid", 8, FieldType::kU64, 1, ""},
    {"fw_major", 16, FieldType::kU8, 1, ""},
    {"fw_minor", 17, FieldType::kU8, 1, ""},
    {"fw_patch", 18, FieldType::kU8, 1, ""},
    {"status", 19, FieldType::kU8, 1, ""},
    {"fault_mask", 20, FieldType::kU16, 1, ""},
    {"i2c_errors", 22, FieldType::kU16, 1, ""},
    {"can_errors", 24, FieldType::kU16, 1, ""},
    {"saturation_count", 26, FieldType::kU16, 1, ""},
    {"temperature", 28, FieldType::kI16, 0.01, "degC"},
    {"crc", 30, FieldType::kU16, 1, ""},
};

constexpr FieldDesc kInfoFields[] = {
    {"hardware_uid", 0, FieldType::kU64, 1, ""},
    {"fw_major", 8, FieldType::kU8, 1, ""},
    {"fw_minor", 9, FieldType::kU8, 1, ""},
    {"fw_patch", 10, FieldType::kU8, 1, ""},
    {"protocol_version", 11, FieldType::kU8, 1, ""},
    {"sensor_count", 12, FieldType::kU8, 1, ""},
    {"axis_count", 13, FieldType::kU8, 1, ""},
    {"gain_sel", 14, FieldType::kU8, 1, ""},
    {"resolution", 15, FieldType::kU8, 1, ""},
    {"oversampling", 16, FieldType::kU8, 1, ""},
    {"digital_filter", 17, FieldType::kU8, 1, ""},
    {"rate", 18, FieldType::kU16, 0.01, "Hz"},
    {"max_rate", 20, FieldType::kU16, 0.01, "Hz"},
    {"conversion_time", 22, FieldType::kU16, 1, "us"},
    {"field_lsb", 24, FieldType::kU16, 1, "nT"},
    {"crc", 26, FieldType::kU16, 1, ""},
};

// The sample's 48 channel fields get generated names ("s00_x" ... "s15_z").
const std::vector<FieldDesc>& sample_fields() {
  static const std::vector<FieldDesc> fields = [] {
    static char names[kChannelCount][8];
    std::vector<FieldDesc> f = {
        {"timestamp", 0, FieldType::kU32, 1, "us"},
        {"flags", 4, FieldType::kU16, 1, ""},
        {"fault_mask", 6, FieldType::kU16, 1, ""},
        {"saturation_mask", 8, FieldType::kU16, 1, ""},
    };
    for (int ch = 0; ch < kChannelCount; ++ch) {
      std::snprintf(names[ch], sizeof names[ch], "s%02d_%c", ch / kAxisCount,
                    "xyz"[ch % kAxisCount]);
      f.push_back(
          {names[ch], static_cast<uint16_t>(10 + 2 * ch), FieldType::kI16, kFieldUtPerLsb, "uT"});
    }
    f.push_back({"crc", static_cast<uint16_t>(10 + 2 * kChannelCount), FieldType::kU16, 1, ""});
    return f;
  }();
  return fields;
}

template <std::size_t N>
constexpr std::pair<const FieldDesc*, const FieldDesc*> range(const FieldDesc (&a)[N]) {
  return {a, a + N};
}

std::pair<const FieldDesc*, const FieldDesc*> fields_of(MessageClass c) {
  switch (c) {
    case MessageClass::kSync:
      return range(kSyncFields);
    case MessageClass::kCommand:
      return range(kCommandFields);
    case MessageClass::kAck:
      return range(kAckFields);
    case MessageClass::kInfo:
      return range(kInfoFields);
    case MessageClass::kHeartbeat:
      return range(kHeartbeatFields);
    case MessageClass::kSample: {
      const auto& f = sample_fields();
      return {f.data(), f.data() + f.size()};
    }
  }
  return {nullptr, nullptr};
}

}  // namespace

const FieldDesc* fields_begin(MessageClass c) {
  return fields_of(c).first;
}
const FieldDesc* fields_end(MessageClass c) {
  return fields_of(c).second;
}

}  // namespace skinbus::bus
