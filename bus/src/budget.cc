#include "skinbus/bus/budget.h"

#include <algorithm>
#include <cmath>

#include "skinbus/bus/codec.h"

namespace skinbus::bus {

namespace {

std::size_t stuff_bits(std::size_t stuffed_region_bits) {
  return stuffed_region_bits == 0 ? 0 : (stuffed_region_bits - 1) / 4;
}

// Wire time of every frame of one message of class `c`, as the encoder cuts it.
double message_time_us(const BusTiming& t, MessageClass c, double* frames) {
  Message m;
  m.node = kNodeMin;
  m.kind = t.fd ? FrameKind::kFd : FrameKind::kClassic;
  m.body = default_body(c);
  CanFrame out[kMaxParts];
  const EncodeResult r = encode(m, out);
  double us = 0;
  for (std::size_t i = 0; i < r.frames; ++i) us += frame_time_us(t, out[i].len);
  if (frames) *frames = static_cast<double>(r.frames);
  return us;
}

}  // namespace

double frame_time_us(const BusTiming& t, std::size_t len) {
  if (!t.fd) {
    // SOF, ID 11, RTR, IDE, r0, DLC 4, data, CRC 15: stuffed; then CRC delimiter, ACK slot and
    // delimiter, EOF 7, IFS 3.
    const std::size_t stuffed = 1 + 11 + 1 + 1 + 1 + 4 + 8 * len + 15;
    const std::size_t bits = stuffed + stuff_bits(stuffed) + 1 + 2 + 7 + 3;
    return static_cast<double>(bits) * 1e6 / t.nominal_bps;
  }
  // Arbitration phase: SOF, ID 11, RRS, IDE, FDF, res, BRS (stuffed), then at the end CRC
  // delimiter, ACK slot and delimiter, EOF 7, IFS 3.
  const std::size_t arb_stuffed = 1 + 11 + 1 + 1 + 1 + 1 + 1;
  const std::size_t nominal_bits = arb_stuffed + stuff_bits(arb_stuffed) + 1 + 2 + 7 + 3;
  // Data phase: ESI, DLC 4, data (dynamic stuffing), stuff count 4, CRC 17 or 21 with a fixed
  // stuff bit before every 4 bits of stuff count and CRC.
  const std::size_t dyn = 1 + 4 + 8 * len;
  const std::size_t crc = len > 16 ? 21 : 17;
  const std::size_t fixed = 4 + crc;
  const std::size_t data_bits = dyn + stuff_bits(dyn) + fixed + (fixed + 3) / 4;
  return static_cast<double>(nominal_bits) * 1e6 / t.nominal_bps +
         static_cast<double>(data_bits) * 1e6 / t.data_bps;
}

BudgetResult compute_budget(const BusTiming& t, const PatchTraffic& traffic, int patches,
                            double load_limit) {
  BudgetResult r;
  double hb_frames = 0;
  r.sample_time_us = message_time_us(t, MessageClass::kSample, &r.sample_frames);
  r.heartbeat_time_us = message_time_us(t, MessageClass::kHeartbeat, &hb_frames);
  const double sample_msgs = traffic.sample_rate_hz * std::clamp(traffic.active_fraction, 0.0, 1.0);
  r.frames_per_s_per_patch = sample_msgs * r.sample_frames + traffic.heartbeat_hz * hb_frames;
  r.load_per_patch =
      (sample_msgs * r.sample_time_us + traffic.heartbeat_hz * r.heartbeat_time_us) * 1e-6;
  r.load_total = r.load_per_patch * patches;
  // Computed in double and clamped before the conversion to int (no overflow for tiny loads).
  const double fit = r.load_per_patch > 0 ? std::floor(load_limit / r.load_per_patch) : kNodeMax;
  r.max_patches = static_cast<int>(std::clamp(fit, 0.0, static_cast<double>(kNodeMax)));
  r.full_bus_frames_per_s = 1e6 / frame_time_us(t, t.fd ? kFdMaxLen : kClassicMaxLen);
  return r;
}

}  // namespace skinbus::bus
