// skinbus/host/ambient.h: rejecting the uniform field change a moving limb sees.
//
// A patch's baseline is taken with the limb in one orientation; as the limb turns, the Earth's
// field (about 50 uT) turns with respect to the patch and every sensor sees the same change,
// up to twice the field's magnitude. Stray fields of motors and slow thermal drift add similar
// common-mode changes. The per-patch networks are trained on tared samples without it, so a
// common-mode change shifts their estimates.
//
// A press deforms the lattice locally: it moves the magnets of the few sensors near it and
// leaves the far sensors nearly unchanged, while a uniform change moves every sensor alike.
// estimate_common_mode() therefore takes, per axis, a robust location of the tared fields over
// the sensors (methods below), and remove_common_mode() subtracts it from every sensor.
//
// Frames: the change is uniform in the patch frame; a sensor mounted tilted by a few degrees
// sees it rotated by that tilt, which the estimate absorbs only approximately (the residual is
// part of the measured error: docs/benchmarks/aggregator.md).
//
// Nothing here allocates; costs are O(sensors).
#pragma once

#include <cstdint>
#include <span>

namespace skinbus::host {

enum class CommonModeMethod : uint8_t {
  kNone,       // no rejection
  kMedian,     // per-axis median over the usable sensors
  kQuietMean,  // per-axis mean of the sensors closest to the median (the quiet half)
};

struct CommonModeOptions {
  CommonModeMethod method = CommonModeMethod::kQuietMean;
  double quiet_fraction = 0.5;  // kQuietMean: the share of sensors averaged (at least 3)
  int min_sensors = 6;          // fewer usable sensors: no estimate (zero, and `valid` false)
};

struct CommonModeEstimate {
  double field_ut[3] = {0, 0, 0};  // the uniform change, per axis (uT)
  int sensors_used = 0;
  bool valid = false;  // false: too few usable sensors (or kNone): field_ut is zero
  double magnitude_ut() const;
};

// Estimates the common-mode change of one tared sample: `field_ut` holds 3 values per sensor
// (x, y, z), `channel_ok` (empty, or one entry per channel, 0 = unusable) marks sensors to leave
// out (a sensor is left out if any of its channels is). Non-finite channels are left out too.
CommonModeEstimate estimate_common_mode(std::span<const double> field_ut,
                                        std::span<const uint8_t> channel_ok = {},
                                        const CommonModeOptions& options = {});

// Subtracts `e` from every sensor of `field_ut` (no-op when !e.valid).
void remove_common_mode(std::span<double> field_ut, const CommonModeEstimate& e);

}  // namespace skinbus::host
