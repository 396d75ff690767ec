// skinbus/sim/mlx90393.h: the simulator's noise model of the Melexis MLX90393.
//
// The chip's datasheet facts (settings, sensitivity, output codes, conversion time) are in
// skinbus/mlx90393/measurement.h, shared with the patch node's driver; what the simulator adds
// here is the noise a configuration gives, which the datasheet does not pin down.
//
// Source (docs/sim/physics.md): an assumption anchored on the datasheet's order of magnitude
// (about 1 uT RMS at the fastest settings), scaled as 1/sqrt(ADC samples averaged per axis).
#pragma once

#include <cmath>

#include "skinbus/mlx90393/measurement.h"

namespace skinbus::sim {

// Noise anchor (assumption): RMS at OSR = 0, DIG_FILT = 0 (3 ADC samples per axis).
inline constexpr double kMlx90393NoiseXyAnchorUt = 1.4;
inline constexpr double kMlx90393NoiseZAnchorUt = 2.3;

// Noise, uT RMS, per X/Y and Z channel.
inline double mlx90393_noise_xy_ut(const mlx90393::Config& c) {
  return kMlx90393NoiseXyAnchorUt * std::sqrt(3.0 / mlx90393::samples_per_axis(c));
}
inline double mlx90393_noise_z_ut(const mlx90393::Config& c) {
  return kMlx90393NoiseZAnchorUt * std::sqrt(3.0 / mlx90393::samples_per_axis(c));
}

}  // namespace skinbus::sim
