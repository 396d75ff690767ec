#include "skinbus/patch_fw/sensor_array.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

namespace skinbus::patch_fw {

namespace {
// Bits on the wire (START/STOP, address and data bytes with their ACK bits) of the commands.
constexpr uint32_t kTriggerBits = 40;    // SM: write 1 byte, read status
constexpr uint32_t kReadBits = 93;       // RM xyz: write 1 byte, read status + 6 bytes
constexpr uint32_t kMuxSelectBits = 20;  // control byte write
}  // namespace

SensorArray::SensorArray(I2cBus* bus, Tca9546a* mux, Clock* clock, SensorArrayConfig config,
                         std::vector<GpioInput*> drdy_lines)
    : bus_(bus),
      mux_(mux),
      clock_(clock),
      config_(std::move(config)),
      drdy_(std::move(drdy_lines)) {
  const int n = static_cast<int>(config_.slots.size());
  sensors_.reserve(n);
  for (const SensorSlot& s : config_.slots) sensors_.emplace_back(bus_, s.address, clock_);
  health_.resize(n);
  last_code_.assign(n, {INT32_MIN, INT32_MIN, INT32_MIN});
  triggered_.assign(n, 0);
  for (int i = 0; i < n; ++i) order_.push_back(i);
  std::stable_sort(order_.begin(), order_.end(), [&](int a, int b) {
    return config_.slots[a].channel < config_.slots[b].channel;
  });
}

uint32_t SensorArray::cycle_time_us(const SensorArrayConfig& config) {
  std::set<int> mux_channels;
  for (const SensorSlot& s : config.slots)
    if (s.channel >= 0) mux_channels.insert(s.channel);
  const uint32_t channels = static_cast<uint32_t>(mux_channels.size());
  const uint32_t n = static_cast<uint32_t>(config.slots.size());
  const uint64_t bits = n * (kTriggerBits + kReadBits) + 2u * channels * kMuxSelectBits;
  const uint64_t transactions = 2u * n + 2u * channels;
  const double bus_us =
      1e6 * static_cast<double>(bits) / std::max<uint32_t>(config.i2c_clock_hz, 1);
  mlx90393::Config chip = config.settings.chip;
  chip.temperature = false;
  return static_cast<uint32_t>(mlx90393::conversion_time_us(chip) + bus_us +
                               static_cast<double>(transactions * config.transaction_overhead_us));
}

double SensorArray::max_rate_hz(const SensorArrayConfig& config) {
  return 1e6 / std::max<uint32_t>(cycle_time_us(config), 1);
}

Status SensorArray::select(int channel) {
  if (channel < 0 || mux_ == nullptr) return Status::Ok();
  return mux_->select(channel);
}

void SensorArray::fail(int i, const Error& e) {
  SensorHealth& h = health_[i];
  ++h.i2c_errors;
  ++h.consecutive_failures;
  h.last_error = e.message;
  if (h.consecutive_failures >= static_cast<uint32_t>(config_.dead_after_failures)) h.faulty = true;
}

bool SensorArray::bring_up(int i) {
  Status st = select(config_.slots[i].channel);
  if (st.ok()) st = sensors_[i].reset();
  if (st.ok()) st = sensors_[i].configure(config_.settings);
  if (!st.ok()) {
    fail(i, st.error());
    return false;
  }
  return true;
}

Status SensorArray::init() {
  if (mux_ != nullptr) {
    Status st = mux_->reset();
    if (st.ok()) st = mux_->deselect();
    if (st.ok()) {
      Result<uint8_t> ctl = mux_->read_control();
      if (!ctl.ok()) st = ctl.error();
    }
    if (!st.ok()) {
      return make_error(ErrorCode::kNotFound, "multiplexer does not answer: " + st.error().message +
                                                  " (check mux_address and the I2C wiring)");
    }
  }
  int alive = 0;
  std::string missing;
  for (int i : order_) {
    if (bring_up(i)) {
      ++alive;
      health_[i].consecutive_failures = 0;
    } else {
      health_[i].faulty = true;
      char buf[48];
      std::snprintf(buf, sizeof buf, "%s sensor %d (channel %d, 0x%02X)",
                    missing.empty() ? "" : ",", i, config_.slots[i].channel,
                    config_.slots[i].address);
      missing += buf;
    }
  }
  if (alive == 0) {
    return make_error(ErrorCode::kNotFound,
                      "no MLX90393 answers on " + std::string(bus_->name()) + ":" + missing);
  }
  return Status::Ok();
}

Result<double> SensorArray::temperature_c() {
  for (int i : order_) {
    const SensorHealth& h = health_[i];
    if (h.faulty || !sensors_[i].configured()) continue;
    Status st = select(config_.slots[i].channel);
    if (!st.ok()) {
      fail(i, st.error());
      continue;
    }
    Result<double> t = sensors_[i].measure_temperature_c();
    if (t.ok()) return t;
    fail(i, t.error());
  }
  return make_error(ErrorCode::kUnavailable, "no sensor answered a temperature measurement");
}

uint32_t SensorArray::temperature_time_us() const {
  // The conversion and three short I2C transactions (mux select, SM, RM) with a margin.
  return Mlx90393::temperature_conversion_time_us(config_.settings.chip) + 1000u;
}

Status SensorArray::sample(ArraySample* out) {
  ++samples_;
  const bool retry_round =
      config_.retry_interval_samples > 0 && samples_ % config_.retry_interval_samples == 0;
  // Trigger.
  uint64_t first_trigger_us = 0;
  bool any = false;
  for (int i : order_) {
    triggered_[i] = 0;
    SensorHealth& h = health_[i];
    const bool dead = h.faulty && !h.stuck;
    // A dead sensor is retried every retry_interval_samples; one that lost its configuration
    // (it reset itself) is brought back at once.
    if (dead && !retry_round) continue;
    if ((dead || !sensors_[i].configured()) && !bring_up(i)) continue;
    Status st = select(config_.slots[i].channel);
    if (st.ok()) st = sensors_[i].start_single(mlx90393::kAxesXyz);
    if (!st.ok()) {
      fail(i, st.error());
      continue;
    }
    if (!any) first_trigger_us = clock_->now_us();
    any = true;
    triggered_[i] = 1;
  }
  // Wait for the conversions: data-ready edges if wired, never past twice the conversion time;
  // then at least until the conversion time has passed since the last trigger.
  const uint64_t conversion_us = sensors_.empty() ? 0 : sensors_[0].conversion_time_us();
  const uint64_t last_trigger_us = clock_->now_us();
  if (any && !drdy_.empty()) {
    const uint64_t limit = last_trigger_us + 2 * conversion_us;
    bool seen = false;
    for (GpioInput* line : drdy_) {
      const uint64_t now = clock_->now_us();
      GpioEvent ev;
      Result<bool> got = line->wait_event(limit > now ? limit - now : 0, &ev);
      if (got.ok() && *got) seen = true;
    }
    seen ? ++drdy_events_ : ++drdy_timeouts_;
  }
  if (any) clock_->sleep_until_us(last_trigger_us + conversion_us);
  out->timestamp_us = first_trigger_us + conversion_us / 2;
  out->fault_mask = 0;
  out->saturation_mask = 0;
  // Read.
  for (int i : order_) {
    double* f = &out->field_ut[3 * i];
    f[0] = f[1] = f[2] = 0;
    SensorHealth& h = health_[i];
    if (!triggered_[i]) {
      out->fault_mask = static_cast<uint16_t>(out->fault_mask | (1u << i));
      continue;
    }
    Mlx90393Reading r;
    Status st = select(config_.slots[i].channel);
    if (st.ok()) st = sensors_[i].read_measurement(&r);
    if (!st.ok()) {
      fail(i, st.error());
      out->fault_mask = static_cast<uint16_t>(out->fault_mask | (1u << i));
      continue;
    }
    if (h.faulty && !h.stuck) ++h.recoveries;
    if (!h.stuck) h.faulty = false;
    h.consecutive_failures = 0;
    // Stuck: the same three codes again and again.
    const bool same = r.code[0] == last_code_[i][0] && r.code[1] == last_code_[i][1] &&
                      r.code[2] == last_code_[i][2];
    last_code_[i] = {r.code[0], r.code[1], r.code[2]};
    h.identical_samples = same ? h.identical_samples + 1 : 0;
    if (h.identical_samples >= static_cast<uint32_t>(config_.stuck_after_samples)) {
      h.stuck = h.faulty = true;
    } else if (h.stuck) {
      h.stuck = h.faulty = false;
      ++h.recoveries;
    }
    if (h.faulty) {
      out->fault_mask = static_cast<uint16_t>(out->fault_mask | (1u << i));
      continue;
    }
    h.saturated = r.saturated[0] || r.saturated[1] || r.saturated[2];
    if (h.saturated) out->saturation_mask = static_cast<uint16_t>(out->saturation_mask | (1u << i));
    f[0] = r.field_ut[0];
    f[1] = r.field_ut[1];
    f[2] = r.field_ut[2];
  }
  return Status::Ok();
}

uint32_t SensorArray::i2c_errors() const {
  uint32_t total = mux_ != nullptr ? mux_->errors() : 0;
  for (const SensorHealth& h : health_) total += h.i2c_errors;
  return total;
}

uint16_t SensorArray::fault_mask() const {
  uint16_t m = 0;
  for (std::size_t i = 0; i < health_.size(); ++i)
    if (health_[i].faulty) m = static_cast<uint16_t>(m | (1u << i));
  return m;
}

}  // namespace skinbus::patch_fw
