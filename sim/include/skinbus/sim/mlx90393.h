// skinbus/sim/mlx90393.h: the measurement model of the Melexis MLX90393 3-axis Hall sensor.
//
// What a configuration (GAIN_SEL, RES_XYZ, OSR, DIG_FILT; Hall plate configuration 0xC) does
// to a measurement: sensitivity (uT per LSB), the 16-bit output range (saturation), the
// quantisation, the noise and the conversion time. Shared by the simulator and by the patch
// node's driver and emulator (patch_fw/), so both agree on the chip.
//
// Sources (docs/sim/physics.md): sensitivities and conversion time from the MLX90393
// datasheet (HALLCONF 0xC table; TCONV = 67 + 64 * 2^OSR * (2 + 2^DIG_FILT) us per axis); the
// noise level is an assumption anchored on the datasheet's order of magnitude (about 1 uT RMS
// at the fastest settings) and scaled as 1/sqrt(samples averaged).
#pragma once

#include <cstdint>

namespace skinbus::sim {

struct Mlx90393Config {
  uint8_t gain_sel = 7;      // 0..7: 0 = highest range, 7 = finest resolution
  uint8_t res_xy = 0;        // 0..3: each step halves resolution (doubles range) on X and Y
  uint8_t res_z = 0;         // 0..3, on Z
  uint8_t osr = 1;           // 0..3: 2^OSR oversampling
  uint8_t dig_filt = 2;      // 0..7: digital filter depth
  bool temperature = false;  // also convert temperature (adds its conversion time)
};

// uT per LSB for an X/Y or Z channel.
double mlx90393_sensitivity_xy_ut(const Mlx90393Config& c);
double mlx90393_sensitivity_z_ut(const Mlx90393Config& c);
// Time for one X, Y, Z (and temperature, if enabled) single measurement, microseconds.
double mlx90393_conversion_time_us(const Mlx90393Config& c);
// Noise, uT RMS, per X/Y and Z channel.
double mlx90393_noise_xy_ut(const Mlx90393Config& c);
double mlx90393_noise_z_ut(const Mlx90393Config& c);
// True if the configuration values are within the chip's ranges.
bool mlx90393_config_valid(const Mlx90393Config& c);

// Converts a field (uT) to the chip's output code and back: RES 0/1 give signed 16-bit codes
// (clipped at +-32767 and reported saturated), RES 2/3 unsigned codes around 32768 (RES 3
// limited to 15 bits by the chip); `saturated` tells when the code was clipped.
int32_t mlx90393_code(double field_ut, double sensitivity_ut, uint8_t res, bool* saturated);
double mlx90393_field_ut(int32_t code, double sensitivity_ut, uint8_t res);
// True if `code` sits at a clip limit of resolution `res` (what mlx90393_code returns for a
// saturated field): a reading there only bounds the field.
bool mlx90393_code_at_limit(int32_t code, uint8_t res);

}  // namespace skinbus::sim
