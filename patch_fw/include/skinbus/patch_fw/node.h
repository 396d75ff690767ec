// skinbus/patch_fw/node.h: the patch node: sampling schedule, modes, commands, publishing.
//
// PatchNode is the daemon without its sockets: it is given CAN frames (on_frame) and the time
// (poll), and sends frames through a FrameSink. Everything the node does is decided here, so
// tests run it on a ManualClock with the emulated sensors and check every frame it sends.
//
// Modes (bus::PatchMode):
//  * stream: every sample is sent;
//  * event:  samples are sent only while the gate sees a contact, then for `event_tail_ms`
//            more (flagged kEventTail); an idle patch sends only its heartbeat;
//  * off:    no sampling at all; heartbeats continue.
// Heartbeats go out every `heartbeat_period_ms` in every mode. In sync mode the node samples
// only when a SYNC arrives (a CAN SYNC frame or an edge on the SYNC input line), flagged kSynced.
// Commands (bus/command.h decides the answer): tare, set_mode, set_rate, sync_mode, identify
// (blinks the identify LED at 2 Hz for the given seconds), reboot (acknowledged, then
// reboot_requested() turns true: the daemon re-executes itself), get_info (an Ack and an Info).
#pragma once

#include <cstdint>
#include <functional>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/codec.h"
#include "skinbus/bus/command.h"
#include "skinbus/bus/protocol.h"
#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/gate.h"
#include "skinbus/patch_fw/gpio.h"
#include "skinbus/patch_fw/sensor_array.h"

namespace skinbus::patch_fw {

inline constexpr uint8_t kFirmwareMajor = 0, kFirmwareMinor = 1, kFirmwarePatch = 0;

// Where the node's frames go: a SocketCAN port, a candump log, a test's vector.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual Status send(const bus::CanFrame& frame) = 0;
};

struct NodeConfig {
  uint8_t node_id = bus::kNodeMin;
  bus::FrameKind kind = bus::FrameKind::kFd;
  bus::PatchMode mode = bus::PatchMode::kEvent;
  uint16_t rate_chz = 4170;  // 41.70 Hz
  bool sync_mode = false;
  uint32_t event_tail_ms = 250;
  uint32_t heartbeat_period_ms = 1000;
  uint64_t hardware_uid = 0;
  bool simulated = false;         // sets heartbeat_status::kSimulated
  bool send_tared = true;         // send field minus baseline (kTared) once a baseline is held
  uint16_t max_rate_chz = 10000;  // fastest rate the sensor configuration allows
};

struct NodeStats {
  uint64_t samples_taken = 0;
  uint64_t samples_sent = 0;
  uint64_t heartbeats_sent = 0;
  uint64_t acks_sent = 0;
  uint64_t frames_sent = 0;
  uint64_t send_errors = 0;
  uint64_t sample_errors = 0;
  uint64_t syncs = 0;
  uint64_t overruns = 0;            // sample deadlines missed by more than one period
  uint64_t temperature_errors = 0;  // heartbeats whose temperature could not be measured
};

class PatchNode {
 public:
  // Not owned, outliving the node: array (already init()ed), clock, sink; led may be null.
  PatchNode(NodeConfig config, GateConfig gate, SensorArray* array, Clock* clock, FrameSink* sink,
            GpioOutput* identify_led);

  // A frame from the bus (commands to this node or broadcast, SYNC); others are ignored.
  void on_frame(const bus::CanFrame& frame);
  // A rising edge on the SYNC input line.
  void on_sync_edge();
  // Does what is due at the clock's current time (sample, heartbeat, LED) and returns the
  // time of the next thing due, Clock microseconds.
  uint64_t poll();

  const NodeConfig& config() const { return config_; }
  const NodeStats& stats() const { return stats_; }
  const ContactGate& gate() const { return gate_; }
  bool identify_active() const { return identify_until_us_ > clock_->now_us(); }
  bool reboot_requested() const { return reboot_requested_; }
  bus::Heartbeat heartbeat() const;
  bus::Info info() const;
  // Called with every sample taken (sent or not) and the gate's view: for logs and tests.
  std::function<void(const bus::Sample&, const GateOutput&, bool sent)> on_sample;

 private:
  void take_sample(bool synced);
  // One sensor's die temperature into temperature_cdeg_ (blocks a few ms; see poll()).
  void measure_temperature();
  void send_message(const bus::Message& msg);
  void apply(const bus::Command& cmd);
  uint64_t period_us() const;

  NodeConfig config_;
  ContactGate gate_;
  SensorArray* array_;
  Clock* clock_;
  FrameSink* sink_;
  GpioOutput* led_;
  NodeStats stats_;
  GateOutput gate_out_;
  uint64_t start_us_ = 0;
  uint64_t next_sample_us_ = 0;
  uint64_t next_heartbeat_us_ = 0;
  uint64_t tail_until_us_ = 0;
  uint64_t identify_until_us_ = 0;
  bool led_on_ = false;
  bool pending_sync_ = false;
  bool reboot_requested_ = false;
  uint8_t seq_sample_ = 0, seq_heartbeat_ = 0, seq_ack_ = 0, seq_info_ = 0;
  uint16_t saturation_count_ = 0;
  uint16_t can_errors_ = 0;
  int16_t temperature_cdeg_ = 0;  // last measured die temperature (0 until the first)
  bool temperature_due_ = false;  // a heartbeat went out since the last measurement
};

}  // namespace skinbus::patch_fw
