// skinbus/sim/pressed_area.h: the area a set of presses covers, in surface coordinates (mm).
// sim::pressed_area (dataset.h) takes it from a dataset; a unit file's note keeps the area the
// unit was identified on (unit_parameters.h).
#pragma once

namespace skinbus::sim {

// How far beyond a unit's pressed area a press still counts as inside it (mm): a press on the
// area's edge grid spreads over millimetres, and its tip's place is known to about that.
inline constexpr double kPressedAreaMarginMm = 1.0;

// The smallest rectangle in surface coordinates (mm) holding every press.
struct PressedArea {
  double u_min_mm = 0, u_max_mm = 0, v_min_mm = 0, v_max_mm = 0;
  // The square +-half_mm on each axis.
  static PressedArea square(double half_mm) { return {-half_mm, half_mm, -half_mm, half_mm}; }
  bool operator==(const PressedArea&) const = default;
  // True when (u, v) lies within the area widened by `margin_mm` on every side.
  bool contains(double u_mm, double v_mm, double margin_mm) const {
    return u_mm >= u_min_mm - margin_mm && u_mm <= u_max_mm + margin_mm &&
           v_mm >= v_min_mm - margin_mm && v_mm <= v_max_mm + margin_mm;
  }
};

}  // namespace skinbus::sim
