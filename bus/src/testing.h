// Helpers shared by bus/ tests, fuzz targets and benchmarks. Not part of the public API.
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "skinbus/bus/candump.h"
#include "skinbus/bus/codec.h"
#include "skinbus/common/test_seed.h"

namespace skinbus::bus::testing {

using skinbus::test_seed;  // skinbus/common/test_seed.h

// A valid message of class `c` with random field values, for node `node` (or broadcast for SYNC).
inline Message random_message(std::mt19937_64& rng, MessageClass c, FrameKind kind, uint8_t node,
                              uint8_t seq) {
  auto u = [&](uint64_t max) { return std::uniform_int_distribution<uint64_t>(0, max)(rng); };
  Message m;
  m.kind = kind;
  m.seq = seq;
  m.node = node;
  switch (c) {
    case MessageClass::kSync:
      m.node = kNodeBroadcast;
      m.body = Sync{static_cast<uint32_t>(u(0xFFFFFFFF)), static_cast<uint16_t>(u(0xFFFF))};
      break;
    case MessageClass::kCommand: {
      Command cmd;
      cmd.opcode = static_cast<Opcode>(u(kOpcodeMax - 1) + 1);
      for (auto& b : cmd.arg) b = static_cast<uint8_t>(u(255));
      m.body = cmd;
      break;
    }
    case MessageClass::kAck:
      m.body = Ack{static_cast<uint8_t>(u(255)), static_cast<AckStatus>(u(kAckStatusCount - 1)),
                   static_cast<uint8_t>(u(255)), u(1) == 1, static_cast<uint16_t>(u(0xFFFF))};
      break;
    case MessageClass::kSample: {
      Sample s;
      s.timestamp_us = static_cast<uint32_t>(u(0xFFFFFFFF));
      s.flags = static_cast<uint16_t>(u(sample_flags::kAll));
      s.fault_mask = static_cast<uint16_t>(u(0xFFFF));
      s.saturation_mask = static_cast<uint16_t>(u(0xFFFF));
      for (auto& f : s.field_lsb) f = static_cast<int16_t>(static_cast<int64_t>(u(65535)) - 32768);
      m.body = s;
      break;
    }
    case MessageClass::kInfo: {
      Info i;
      i.hardware_uid = u(~0ull);
      i.fw_major = static_cast<uint8_t>(u(255));
      i.gain_sel = static_cast<uint8_t>(u(7));
      i.rate_chz = static_cast<uint16_t>(u(0xFFFF));
      i.max_rate_chz = static_cast<uint16_t>(u(0xFFFF));
      i.conversion_time_us = static_cast<uint16_t>(u(0xFFFF));
      m.body = i;
      break;
    }
    case MessageClass::kHeartbeat: {
      Heartbeat h;
      h.state = static_cast<PatchState>(u(kPatchStateCount - 1));
      h.mode = static_cast<PatchMode>(u(kPatchModeCount - 1));
      h.rate_chz = static_cast<uint16_t>(u(0xFFFF));
      h.uptime_s = static_cast<uint32_t>(u(0xFFFFFFFF));
      h.hardware_uid = u(~0ull);
      h.fw_major = static_cast<uint8_t>(u(255));
      h.fw_minor = static_cast<uint8_t>(u(255));
      h.fw_patch = static_cast<uint8_t>(u(255));
      h.status = static_cast<uint8_t>(u(15));
      h.fault_mask = static_cast<uint16_t>(u(0xFFFF));
      h.i2c_errors = static_cast<uint16_t>(u(0xFFFF));
      h.can_errors = static_cast<uint16_t>(u(0xFFFF));
      h.saturation_count = static_cast<uint16_t>(u(0xFFFF));
      h.temperature_cdeg = static_cast<int16_t>(static_cast<int64_t>(u(65535)) - 32768);
      m.body = h;
      break;
    }
  }
  return m;
}

// Encodes and returns the frames of `m` (tests only: allocates).
inline std::vector<CanFrame> encode_frames(const Message& m) {
  std::vector<CanFrame> frames(kMaxParts);
  const EncodeResult r = encode(m, frames);
  frames.resize(r.frames);
  return frames;
}

// cansend syntax of each frame, joined by spaces.
inline std::string frames_text(const std::vector<CanFrame>& frames) {
  std::string out;
  char buf[kCandumpLineMax];
  for (const CanFrame& f : frames) {
    if (!out.empty()) out += ' ';
    out.append(buf, format_frame_text(f, buf));
  }
  return out;
}

}  // namespace skinbus::bus::testing
