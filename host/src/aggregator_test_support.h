// Test support shared by the aggregator's tests (aggregator_test.cc, aggregator_refine_test.cc):
// a patch node that sends its heartbeats and samples as CAN FD frames into an aggregator.
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <span>

#include "skinbus/bus/codec.h"
#include "skinbus/host/aggregator.h"

namespace skinbus::host::test_support {

inline constexpr uint64_t kPeriodUs = 23'981;  // 41.7 Hz

// Sends messages of one node as frames into the aggregator.
struct Node {
  uint8_t node;
  uint64_t uid;
  uint8_t seq_sample = 0, seq_hb = 0;
  uint32_t clock_us = 1000;

  void heartbeat(Aggregator& a, uint64_t rx_us, uint32_t uptime_s) {
    bus::Heartbeat hb;
    hb.state = bus::PatchState::kRunning;
    hb.mode = bus::PatchMode::kEvent;
    hb.hardware_uid = uid;
    hb.uptime_s = uptime_s;
    send(a, bus::Message{node, seq_hb++, bus::FrameKind::kFd, hb}, rx_us);
  }
  // A sample taken at host time `rx_us` (the patch clock set to follow the host's, as a real
  // patch's does however late the host processes it).
  void sample_at(Aggregator& a, uint64_t rx_us, std::span<const double> tared_ut) {
    clock_us = static_cast<uint32_t>(rx_us);
    sample(a, rx_us, tared_ut, true);
  }
  // A sample received at `rx_us`, the patch clock one period on from the last.
  void sample(Aggregator& a, uint64_t rx_us, std::span<const double> tared_ut, bool contact,
              uint16_t fault_mask = 0) {
    bus::Sample s;
    s.timestamp_us = clock_us;
    clock_us += static_cast<uint32_t>(kPeriodUs);
    s.flags = bus::sample_flags::kTared | (contact ? bus::sample_flags::kContact : 0);
    if (fault_mask) s.flags |= bus::sample_flags::kSensorFault;
    s.fault_mask = fault_mask;
    for (int c = 0; c < bus::kChannelCount; ++c) {
      s.field_lsb[static_cast<std::size_t>(c)] =
          bus::field_ut_to_lsb(tared_ut[static_cast<std::size_t>(c)]);
    }
    send(a, bus::Message{node, seq_sample++, bus::FrameKind::kFd, s}, rx_us);
  }
  static void send(Aggregator& a, const bus::Message& m, uint64_t rx_us) {
    std::array<bus::CanFrame, 4> frames;
    const bus::EncodeResult r = bus::encode(m, frames);
    ASSERT_EQ(r.error, bus::EncodeError::kNone);
    for (std::size_t i = 0; i < r.frames; ++i) a.on_frame(0, frames[i], rx_us + i * 50);
  }
};

}  // namespace skinbus::host::test_support
