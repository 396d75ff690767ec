#include "skinbus/patch_fw/node.h"

#include <algorithm>
#include <cmath>

namespace skinbus::patch_fw {

namespace {
constexpr uint64_t kLedHalfPeriodUs = 250000;  // identify blink: 2 Hz

uint16_t saturating_u16(uint64_t v) {
  return static_cast<uint16_t>(std::min<uint64_t>(v, 0xFFFF));
}
}  // namespace

PatchNode::PatchNode(NodeConfig config, GateConfig gate, SensorArray* array, Clock* clock,
                     FrameSink* sink, GpioOutput* identify_led)
    : config_(config), gate_(gate), array_(array), clock_(clock), sink_(sink), led_(identify_led) {
  start_us_ = clock_->now_us();
  next_sample_us_ = start_us_;
  next_heartbeat_us_ = start_us_;
}

uint64_t PatchNode::period_us() const {
  return 100000000ull / std::max<uint16_t>(config_.rate_chz, 1);
}

void PatchNode::send_message(const bus::Message& msg) {
  std::array<bus::CanFrame, bus::kMaxParts> frames;
  const bus::EncodeResult r = bus::encode(msg, frames);
  if (r.error != bus::EncodeError::kNone) {
    ++stats_.send_errors;
    return;
  }
  for (std::size_t i = 0; i < r.frames; ++i) {
    Status st = sink_->send(frames[i]);
    if (st.ok()) {
      ++stats_.frames_sent;
    } else {
      ++stats_.send_errors;
      can_errors_ = saturating_u16(uint64_t{can_errors_} + 1);
    }
  }
}

bus::Heartbeat PatchNode::heartbeat() const {
  bus::Heartbeat hb;
  const uint16_t faults = array_->fault_mask();
  const int n = static_cast<int>(array_->config().slots.size());
  const uint16_t all = static_cast<uint16_t>(n >= 16 ? 0xFFFF : (1u << n) - 1);
  hb.state = (faults & all) == all ? bus::PatchState::kFault
             : faults != 0         ? bus::PatchState::kDegraded
                                   : bus::PatchState::kRunning;
  hb.mode = config_.mode;
  hb.rate_chz = config_.rate_chz;
  hb.uptime_s = static_cast<uint32_t>((clock_->now_us() - start_us_) / 1000000u);
  hb.hardware_uid = config_.hardware_uid;
  hb.fw_major = kFirmwareMajor;
  hb.fw_minor = kFirmwareMinor;
  hb.fw_patch = kFirmwarePatch;
  hb.status = static_cast<uint8_t>((config_.sync_mode ? bus::heartbeat_status::kSyncMode : 0) |
                                   (identify_active() ? bus::heartbeat_status::kIdentify : 0) |
                                   (gate_out_.tared ? bus::heartbeat_status::kTared : 0) |
                                   (config_.simulated ? bus::heartbeat_status::kSimulated : 0));
  hb.fault_mask = faults;
  hb.i2c_errors = saturating_u16(array_->i2c_errors());
  hb.can_errors = can_errors_;
  hb.saturation_count = saturation_count_;
  hb.temperature_cdeg = temperature_cdeg_;
  return hb;
}

bus::Info PatchNode::info() const {
  bus::Info in;
  const mlx90393::Config& c = array_->config().settings.chip;
  in.hardware_uid = config_.hardware_uid;
  in.fw_major = kFirmwareMajor;
  in.fw_minor = kFirmwareMinor;
  in.fw_patch = kFirmwarePatch;
  in.sensor_count = static_cast<uint8_t>(array_->config().slots.size());
  in.gain_sel = c.gain_sel;
  in.resolution = static_cast<uint8_t>(c.res_xy | c.res_xy << 2 | c.res_z << 4);
  in.oversampling = c.osr;
  in.digital_filter = c.dig_filt;
  in.rate_chz = config_.rate_chz;
  in.max_rate_chz = config_.max_rate_chz;
  mlx90393::Config xyz = c;
  xyz.temperature = false;
  in.conversion_time_us =
      static_cast<uint16_t>(std::min(65535.0, std::ceil(mlx90393::conversion_time_us(xyz))));
  return in;
}

void PatchNode::take_sample(bool synced) {
  ArraySample s;
  Status st = array_->sample(&s);
  if (!st.ok()) {
    ++stats_.sample_errors;
    return;
  }
  ++stats_.samples_taken;
  gate_.update(s, &gate_out_);
  const uint64_t now = clock_->now_us();
  bus::Sample out;
  out.timestamp_us = static_cast<uint32_t>(s.timestamp_us);
  out.fault_mask =
      static_cast<uint16_t>(s.fault_mask | (gate_out_.tared ? gate_out_.unbased_mask : 0));
  out.saturation_mask = s.saturation_mask;
  const bool tared = config_.send_tared && gate_out_.tared;
  for (int i = 0; i < bus::kChannelCount; ++i) {
    const int sensor = i / 3;
    if (out.fault_mask & (1u << sensor)) continue;
    bool clipped = false;
    out.field_lsb[i] =
        bus::field_ut_to_lsb(tared ? gate_out_.tared_ut[i] : s.field_ut[i], &clipped);
    if (clipped) out.saturation_mask = static_cast<uint16_t>(out.saturation_mask | 1u << sensor);
  }
  uint16_t flags = 0;
  if (gate_out_.contact) flags |= bus::sample_flags::kContact;
  if (out.saturation_mask) flags |= bus::sample_flags::kSaturated;
  if (gate_out_.tare_active) flags |= bus::sample_flags::kTareActive;
  if (tared) flags |= bus::sample_flags::kTared;
  if (out.fault_mask) flags |= bus::sample_flags::kSensorFault;
  if (synced) flags |= bus::sample_flags::kSynced;
  if (gate_out_.drift_tracking) flags |= bus::sample_flags::kDriftTracking;
  if (out.saturation_mask) saturation_count_ = saturating_u16(uint64_t{saturation_count_} + 1);

  bool send = false;
  if (config_.mode == bus::PatchMode::kStream) {
    send = true;
  } else if (config_.mode == bus::PatchMode::kEvent) {
    if (gate_out_.contact) {
      send = true;
      tail_until_us_ = now + uint64_t{config_.event_tail_ms} * 1000u;
    } else if (now < tail_until_us_) {
      send = true;
      flags |= bus::sample_flags::kEventTail;
    }
  }
  out.flags = flags;
  if (send) {
    send_message(bus::Message{config_.node_id, seq_sample_++, config_.kind, out});
    ++stats_.samples_sent;
  }
  if (on_sample) on_sample(out, gate_out_, send);
}

void PatchNode::on_sync_edge() {
  ++stats_.syncs;
  if (config_.sync_mode && config_.mode != bus::PatchMode::kOff) pending_sync_ = true;
}

void PatchNode::apply(const bus::Command& cmd) {
  const uint64_t now = clock_->now_us();
  switch (cmd.opcode) {
    case bus::Opcode::kTare:
      gate_.start_tare();
      break;
    case bus::Opcode::kSetMode:
      config_.mode = static_cast<bus::PatchMode>(cmd.arg[0]);
      tail_until_us_ = 0;
      next_sample_us_ = now;
      break;
    case bus::Opcode::kSetRate:
      config_.rate_chz = static_cast<uint16_t>(cmd.arg[0] | cmd.arg[1] << 8);
      next_sample_us_ = now;
      break;
    case bus::Opcode::kSyncMode:
      config_.sync_mode = cmd.arg[0] != 0;
      pending_sync_ = false;
      next_sample_us_ = now;
      break;
    case bus::Opcode::kIdentify:
      identify_until_us_ = now + uint64_t{cmd.arg[0]} * 1000000u;
      break;
    case bus::Opcode::kReboot:
      reboot_requested_ = true;
      break;
    case bus::Opcode::kGetInfo:
      break;  // answered after the ack
  }
}

void PatchNode::on_frame(const bus::CanFrame& frame) {
  if (frame.extended || frame.rtr || frame.error) return;
  const uint8_t cls = bus::can_id_class(frame.id);
  if (cls == static_cast<uint8_t>(bus::MessageClass::kSync)) {
    bus::Message m;
    if (bus::decode_single(frame, &m) == bus::DecodeError::kNone) on_sync_edge();
    return;
  }
  bus::CommandLimits limits;
  limits.max_rate_chz = config_.max_rate_chz;
  bus::Message ack;
  bus::Command cmd;
  if (!bus::answer_command_frame(frame, config_.node_id, seq_ack_, limits, &ack, &cmd)) return;
  ++seq_ack_;
  const bool ok = std::get<bus::Ack>(ack.body).status == bus::AckStatus::kOk;
  if (ok) apply(cmd);
  ack.kind = config_.kind;
  send_message(ack);
  ++stats_.acks_sent;
  if (ok && cmd.opcode == bus::Opcode::kGetInfo) {
    send_message(bus::Message{config_.node_id, seq_info_++, config_.kind, info()});
  }
}

void PatchNode::measure_temperature() {
  temperature_due_ = false;
  Result<double> t = array_->temperature_c();
  if (!t.ok()) {
    ++stats_.temperature_errors;
    return;
  }
  temperature_cdeg_ = static_cast<int16_t>(std::clamp(std::round(*t * 100.0), -32768.0, 32767.0));
}

uint64_t PatchNode::poll() {
  uint64_t now = clock_->now_us();
  // Identify LED: blink while active, off after.
  if (led_ != nullptr) {
    const bool want = identify_active() && ((now / kLedHalfPeriodUs) % 2 == 0);
    if (want != led_on_) {
      if (led_->set(want).ok()) led_on_ = want;
    }
  }
  // The heartbeat goes first: after a restart it is the node's first message, so a host
  // recognises the restart (uptime back to 0) before anything else arrives.
  if (now >= next_heartbeat_us_) {
    send_message(bus::Message{config_.node_id, seq_heartbeat_++, config_.kind, heartbeat()});
    // The next heartbeat carries a temperature measured in the meantime (below).
    temperature_due_ = true;
    if (config_.mode == bus::PatchMode::kOff) measure_temperature();
    ++stats_.heartbeats_sent;
    next_heartbeat_us_ += uint64_t{config_.heartbeat_period_ms} * 1000u;
    if (next_heartbeat_us_ <= now)
      next_heartbeat_us_ = now + uint64_t{config_.heartbeat_period_ms} * 1000u;
  }
  if (config_.mode != bus::PatchMode::kOff) {
    if (config_.sync_mode) {
      if (pending_sync_) {
        pending_sync_ = false;
        take_sample(true);
        // SYNCs come at the host's pace: measure only when the configured rate leaves room for
        // the conversion besides the sample.
        if (temperature_due_ && period_us() > array_->temperature_time_us() +
                                                  SensorArray::cycle_time_us(array_->config())) {
          measure_temperature();
        }
      }
    } else if (now >= next_sample_us_) {
      take_sample(false);
      const uint64_t period = period_us();
      next_sample_us_ += period;
      now = clock_->now_us();
      // Right after a sample, when the temperature conversion fits before the next one: the
      // samples keep their schedule (a sample period too short for it keeps the last value).
      if (temperature_due_ && next_sample_us_ > now + array_->temperature_time_us()) {
        measure_temperature();
        now = clock_->now_us();
      }
      if (next_sample_us_ + period <= now) {  // fell behind: skip, do not burst
        ++stats_.overruns;
        next_sample_us_ = now + period;
      }
    }
  }
  uint64_t next = next_heartbeat_us_;
  if (config_.mode != bus::PatchMode::kOff && !config_.sync_mode)
    next = std::min(next, next_sample_us_);
  if (identify_active() || led_on_)
    next = std::min(next, (now / kLedHalfPeriodUs + 1) * kLedHalfPeriodUs);
  return next;
}

}  // namespace skinbus::patch_fw
