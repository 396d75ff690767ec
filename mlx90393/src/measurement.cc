#include "skinbus/mlx90393/measurement.h"

#include <algorithm>
#include <cmath>

namespace skinbus::mlx90393 {

namespace {

// Datasheet sensitivities at RES = 0, HALLCONF = 0xC, per GAIN_SEL (uT/LSB).
constexpr double kSensXy[8] = {0.751, 0.601, 0.451, 0.376, 0.300, 0.250, 0.200, 0.150};
constexpr double kSensZ[8] = {1.210, 0.968, 0.726, 0.605, 0.484, 0.403, 0.323, 0.242};

}  // namespace

bool config_valid(const Config& c) {
  return c.gain_sel <= 7 && c.res_xy <= 3 && c.res_z <= 3 && c.osr <= 3 && c.dig_filt <= 7;
}

double sensitivity_xy_ut(const Config& c) {
  return kSensXy[c.gain_sel & 7] * std::ldexp(1.0, c.res_xy & 3);
}
double sensitivity_z_ut(const Config& c) {
  return kSensZ[c.gain_sel & 7] * std::ldexp(1.0, c.res_z & 3);
}

double samples_per_axis(const Config& c) {
  return std::ldexp(1.0, c.osr) * (2 + std::ldexp(1.0, c.dig_filt));
}

double conversion_time_us(const Config& c) {
  const double per_axis = 67 + 64 * samples_per_axis(c);
  const double temp = c.temperature ? 67 + 192 * std::ldexp(1.0, c.osr) : 0;
  return 3 * per_axis + temp;
}

int32_t output_code(double field_ut, double sensitivity_ut, uint8_t res, bool* saturated) {
  const bool finite = std::isfinite(field_ut);
  double code = finite ? std::round(field_ut / sensitivity_ut) : 0.0;
  double lo = -32767, hi = 32767, offset = 0;
  if (res == 2) {
    offset = 32768;
    lo = -32768;
    hi = 32767;
  } else if (res == 3) {
    offset = 16384;
    lo = -16384;
    hi = 16383;
  }
  *saturated = !finite || code < lo || code > hi;
  code = std::fmin(std::fmax(code, lo), hi);
  return static_cast<int32_t>(code + offset);
}

double field_ut(int32_t code, double sensitivity_ut, uint8_t res) {
  const double offset = res == 2 ? 32768 : res == 3 ? 16384 : 0;
  return (code - offset) * sensitivity_ut;
}

bool code_at_limit(int32_t code, uint8_t res) {
  if (res == 2) return code <= 0 || code >= 65535;
  if (res == 3) return code <= 0 || code >= 32767;
  return code <= -32767 || code >= 32767;
}

uint16_t temperature_code(double temperature_c) {
  const double t = std::round(kTemperatureCode25C + (temperature_c - 25.0) * kTemperatureLsbPerC);
  return static_cast<uint16_t>(std::isfinite(t) ? std::clamp(t, 0.0, 65535.0) : 0.0);
}

}  // namespace skinbus::mlx90393
