// skinbus/patch_sim/sim_source.h: the simulated patch board behind `skinbus-patchd --sim`.
//
// The daemon's driver code (patch_fw/) runs unchanged on the board's interfaces: the I2C bus is
// an EmulatedI2cBus carrying a TCA9546A and 16 emulated MLX90393s on the configured channels and
// addresses, and the field each chip converts comes from sim/ physics: a fabricated unit (its
// variation and noise seeded by the hardware UID) pressed by scripted contacts and, optionally,
// random presses, on a limb that may swing (turning the Earth's field). GPIO lines come from a
// FakeGpioChip. The settings are the daemon's own (patch_fw/config.h, its `sim` section).
//
// Contact script (CSV, one press a line, '#' comments, an optional header line):
//   t_start_s,t_end_s,u_mm,v_mm,depth_mm[,tip_radius_mm[,node[,u_end_mm,v_end_mm[,friction]]]]
// Times are seconds since the daemon started; a press ramps in and out over 0.15 s within its
// window. `node` (0 or absent: every node) lets one script drive several daemons. A press with
// an end slides there over its window, dragging the skin with `friction` times its normal force
// (sim::SceneContact).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/config.h"
#include "skinbus/patch_sim/emulator.h"
#include "skinbus/patch_sim/fake_gpio.h"
#include "skinbus/sim/scene.h"

namespace skinbus::patch_sim {

// Parses a contact script; keeps the presses for `node`. Errors name the line.
Result<std::vector<sim::SceneContact>> parse_contact_script(const std::string& text, uint8_t node);
Result<std::vector<sim::SceneContact>> load_contact_script(const std::string& path, uint8_t node);

// Random presses: a Poisson process of `per_min` presses a minute over [0, duration_s), at
// uniform positions inside the patch (10 mm margin), 0.5..3 mm deep, held 0.3..2 s, 8 mm tip.
std::vector<sim::SceneContact> random_presses(uint64_t seed, double per_min, double duration_s);

// The field of one fabricated patch over time (a FieldSource for the emulated chips). The whole
// patch is measured once per conversion round: calls within `round_us` of the last measurement
// reuse it.
class PatchPhysicsSource final : public FieldSource {
 public:
  static Result<std::unique_ptr<PatchPhysicsSource>> create(
      uint64_t hardware_uid, const std::vector<sim::SceneContact>& contacts,
      const patch_fw::SimSettings& settings, uint64_t start_us);
  sim::Vec3<double> field_ut(int sensor, uint64_t time_us) override;
  double temperature_c(int sensor, uint64_t time_us) override;
  uint64_t measurements() const { return measurements_; }

 private:
  PatchPhysicsSource() = default;
  sim::Scene scene_;
  uint64_t start_us_ = 0;
  uint64_t last_us_ = 0;
  bool have_ = false;
  std::vector<double> field_;
  uint64_t measurements_ = 0;
  static constexpr uint64_t kRoundUs = 5000;
};

// The emulated board: physics, chips on the configured layout, fake GPIO.
struct SimulatedBoard {
  std::unique_ptr<PatchPhysicsSource> physics;
  std::unique_ptr<EmulatedI2cBus> bus;
  std::unique_ptr<FakeGpioChip> gpio;
  // Builds the board the settings describe (validated settings). `clock` must outlive it.
  static Result<std::unique_ptr<SimulatedBoard>> create(const patch_fw::PatchNodeSettings& settings,
                                                        patch_fw::Clock* clock);
};

}  // namespace skinbus::patch_sim
