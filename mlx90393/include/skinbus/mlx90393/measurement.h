// skinbus/mlx90393/measurement.h: what a configuration of the Melexis MLX90393 3-axis Hall
// sensor does to a measurement.
//
// The chip's settings (GAIN_SEL, RES_X/Y/Z, OSR, DIG_FILT; Hall plate configuration 0xC), its
// sensitivity (uT per LSB), its 16-bit output codes (signedness, range, saturation), its
// conversion time and its temperature output. Shared by the patch node's driver (patch_fw/), the
// chip emulator (patch_sim/) and the simulator's sensor model (sim/), so all three agree on the
// chip. How the settings reach the chip (commands, register fields) is protocol.h.
//
// Sources: the MLX90393 datasheet: sensitivity table at HALLCONF 0xC; conversion time
// TCONV = 67 + 64 * 2^OSR * (2 + 2^DIG_FILT) us per magnetic axis and 67 + 192 * 2^OSR2 us for
// temperature (computed here with OSR in place of OSR2: the driver leaves OSR2 at its power-on
// 0, so the wait is never short); output format per RES; typical temperature transfer.
// docs/sim/physics.md lists them with the simulator's other parameters.
#pragma once

#include <cstdint>

namespace skinbus::mlx90393 {

// The measurement settings the chip is given (register fields in protocol.h).
struct Config {
  uint8_t gain_sel = 7;      // 0..7: 0 = highest range, 7 = finest resolution
  uint8_t res_xy = 0;        // 0..3: each step halves resolution (doubles range) on X and Y
  uint8_t res_z = 0;         // 0..3, on Z
  uint8_t osr = 1;           // 0..3: 2^OSR oversampling
  uint8_t dig_filt = 2;      // 0..7: digital filter depth
  bool temperature = false;  // also convert temperature (adds its conversion time)
};

// True if the configuration values are within the chip's ranges.
bool config_valid(const Config& c);

// uT per LSB for an X/Y or Z channel: the datasheet's table at RES = 0, HALLCONF = 0xC (X/Y
// 0.751 at GAIN_SEL 0 ... 0.150 at 7; Z 1.210 ... 0.242), doubled per RES step.
double sensitivity_xy_ut(const Config& c);
double sensitivity_z_ut(const Config& c);

// ADC samples averaged per magnetic axis: 2^OSR * (2 + 2^DIG_FILT).
double samples_per_axis(const Config& c);
// Time for one X, Y, Z (and temperature, if enabled) single measurement, microseconds.
double conversion_time_us(const Config& c);

// Converts a field (uT) to the chip's output code and back: RES 0/1 give signed 16-bit codes
// (clipped at +-32767 and reported saturated), RES 2/3 unsigned codes around 32768 (RES 3
// limited to 15 bits by the chip); `saturated` tells when the code was clipped (a non-finite
// field gives the zero-field code, saturated).
int32_t output_code(double field_ut, double sensitivity_ut, uint8_t res, bool* saturated);
double field_ut(int32_t code, double sensitivity_ut, uint8_t res);
// The 16-bit word the chip sends for an output code and back: RES 0/1 codes are two's
// complement (the word 0xFFFF is code -1), RES 2/3 codes are the word itself.
constexpr uint16_t code_word(int32_t code) {
  return static_cast<uint16_t>(code & 0xFFFF);
}
constexpr int32_t code_from_word(uint16_t word, uint8_t res) {
  return res <= 1 ? static_cast<int32_t>(static_cast<int16_t>(word)) : static_cast<int32_t>(word);
}
// True if `code` sits at a clip limit of resolution `res` (what output_code returns for a
// saturated field): a reading there only bounds the field.
bool code_at_limit(int32_t code, uint8_t res);

// Temperature output (datasheet typical, uncalibrated): code 46244 at 25 degC, 45.2 LSB/degC,
// the same in every RES.
inline constexpr double kTemperatureCode25C = 46244.0;
inline constexpr double kTemperatureLsbPerC = 45.2;
constexpr double temperature_c_from_code(uint16_t code) {
  return 25.0 + (static_cast<double>(code) - kTemperatureCode25C) / kTemperatureLsbPerC;
}
// The code a die at `temperature_c` reads: rounded, clamped to 0..65535 (0 when not finite).
uint16_t temperature_code(double temperature_c);

}  // namespace skinbus::mlx90393
