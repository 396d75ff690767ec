#include "skinbus/sim/mlx90393.h"

#include <cmath>

namespace skinbus::sim {

namespace {

// Datasheet sensitivities at RES = 0, HALLCONF = 0xC, per GAIN_SEL (uT/LSB).
constexpr double kSensXy[8] = {0.751, 0.601, 0.451, 0.376, 0.300, 0.250, 0.200, 0.150};
constexpr double kSensZ[8] = {1.210, 0.968, 0.726, 0.605, 0.484, 0.403, 0.323, 0.242};

// Noise anchor (assumption): RMS at OSR = 0, DIG_FILT = 0 (3 ADC samples per axis).
constexpr double kNoiseXyAnchorUt = 1.4;
constexpr double kNoiseZAnchorUt = 2.3;

double samples_per_axis(const Mlx90393Config& c) {
  return std::ldexp(1.0, c.osr) * (2 + std::ldexp(1.0, c.dig_filt));
}

}  // namespace

bool mlx90393_config_valid(const Mlx90393Config& c) {
  return c.gain_sel <= 7 && c.res_xy <= 3 && c.res_z <= 3 && c.osr <= 3 && c.dig_filt <= 7;
}

double mlx90393_sensitivity_xy_ut(const Mlx90393Config& c) {
  return kSensXy[c.gain_sel & 7] * std::ldexp(1.0, c.res_xy & 3);
}
double mlx90393_sensitivity_z_ut(const Mlx90393Config& c) {
  return kSensZ[c.gain_sel & 7] * std::ldexp(1.0, c.res_z & 3);
}

double mlx90393_conversion_time_us(const Mlx90393Config& c) {
  const double per_axis = 67 + 64 * samples_per_axis(c);
  const double temp = c.temperature ? 67 + 192 * std::ldexp(1.0, c.osr) : 0;
  return 3 * per_axis + temp;
}

double mlx90393_noise_xy_ut(const Mlx90393Config& c) {
  return kNoiseXyAnchorUt * std::sqrt(3.0 / samples_per_axis(c));
}
double mlx90393_noise_z_ut(const Mlx90393Config& c) {
  return kNoiseZAnchorUt * std::sqrt(3.0 / samples_per_axis(c));
}

int32_t mlx90393_code(double field_ut, double sensitivity_ut, uint8_t res, bool* saturated) {
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

double mlx90393_field_ut(int32_t code, double sensitivity_ut, uint8_t res) {
  const double offset = res == 2 ? 32768 : res == 3 ? 16384 : 0;
  return (code - offset) * sensitivity_ut;
}

bool mlx90393_code_at_limit(int32_t code, uint8_t res) {
  if (res == 2) return code <= 0 || code >= 65535;
  if (res == 3) return code <= 0 || code >= 32767;
  return code <= -32767 || code >= 32767;
}

}  // namespace skinbus::sim
