// skinbus/patch_fw/config.h: the patch node daemon's settings, from a YAML file and flags.
//
// Every setting has a default that suits the reference patch (16 MLX90393 at 0x0C..0x0F on the
// four channels of a TCA9546A at 0x70, 41.7 Hz, event mode), so a file needs only what differs.
// The file format is documented in docs/patch_node.md and patch_fw/patch_node.example.yaml.
// Errors name the setting by its path in the file ("i2c.channels[1].addresses[2]") and say what
// would be valid.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "skinbus/common/result.h"
#include "skinbus/patch_fw/gate.h"
#include "skinbus/patch_fw/node.h"
#include "skinbus/patch_fw/sensor_array.h"

namespace skinbus::patch_fw {

struct GpioSettings {
  std::string chip = "gpiochip0";
  std::vector<unsigned> drdy_lines;   // data-ready inputs (rising edge), any number
  std::optional<unsigned> mux_reset;  // active-low output to the TCA9546A RESET pin
  std::optional<unsigned> identify_led;
  std::optional<unsigned> sync_in;  // rising edge = sample now (in sync mode)
};

// The `sim` section: what patch_sim::SimulatedBoard (skinbus/patch_sim/sim_source.h) builds when
// the daemon runs without hardware. Plain settings: this library does not link the simulator.
struct SimSettings {
  bool enabled = false;               // --sim: emulated chips fed by sim/ physics
  std::string contacts_file;          // scripted presses (CSV, docs/patch_node.md)
  double random_presses_per_min = 0;  // plus random presses
  uint64_t seed = 1;                  // noise and random presses
  double limb_swing_deg = 0;          // the patch's limb turns: the Earth's field changes
  double limb_period_s = 6;
};

struct PatchNodeSettings {
  std::string can_interface = "can0";
  bool can_fd = true;
  std::string candump_out;  // non-empty: write frames as a candump log here ("-": stdout)
  NodeConfig node;
  double rate_hz = 41.7;
  std::string i2c_device = "/dev/i2c-1";
  std::optional<uint8_t> mux_address = 0x70;  // nullopt: sensors on the trunk (channel -1)
  SensorArrayConfig array;                    // slots, chip settings, health thresholds
  GpioSettings gpio;
  GateConfig gate;
  SimSettings sim;
};

// The defaults: 16 sensors, channel c holding sensors 4c..4c+3 at 0x0C..0x0F.
PatchNodeSettings default_settings();

// Reads a YAML file over `settings` (keys absent from the file keep their value). kNotFound:
// no such file; kParse: YAML syntax or a value of the wrong type (line and column given);
// kInvalidArgument: an unknown key (so typos do not pass silently).
Status load_settings_file(const std::string& path, PatchNodeSettings* settings);
Status load_settings_text(const std::string& yaml, PatchNodeSettings* settings);

// Checks the settings as a whole: ranges, sensor layout (16 sensors, no channel listed twice,
// no address twice on a channel, valid MLX90393 and TCA9546A addresses), GPIO lines used once,
// and that the sample rate fits the sensors' conversion time. Fills settings->node.rate_chz
// and max_rate_chz. The error names the setting.
Status validate_settings(PatchNodeSettings* settings);

// The effective settings as YAML (what --print-config shows).
std::string settings_to_yaml(const PatchNodeSettings& settings);

}  // namespace skinbus::patch_fw
