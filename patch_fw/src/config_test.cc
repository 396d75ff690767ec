// Settings: YAML parsing, defaults, and errors that name the setting.
#include "skinbus/patch_fw/config.h"

#include <gtest/gtest.h>

namespace skinbus::patch_fw {
namespace {

Status load_and_validate(const std::string& yaml, PatchNodeSettings* s) {
  *s = default_settings();
  if (Status st = load_settings_text(yaml, s); !st.ok()) return st;
  return validate_settings(s);
}

std::string error_of(const std::string& yaml) {
  PatchNodeSettings s;
  Status st = load_and_validate(yaml, &s);
  return st.ok() ? "" : st.error().message;
}

TEST(ConfigTest, DefaultsAreTheReferencePatch) {
  PatchNodeSettings s;
  ASSERT_TRUE(load_and_validate("", &s).ok());
  ASSERT_EQ(s.array.slots.size(), 16u);
  EXPECT_EQ(s.array.slots[5].channel, 1);
  EXPECT_EQ(s.array.slots[5].address, 0x0D);
  EXPECT_EQ(s.node.rate_chz, 4170);
  EXPECT_GT(s.node.max_rate_chz, 4170);
  EXPECT_EQ(s.node.mode, bus::PatchMode::kEvent);
  EXPECT_EQ(*s.mux_address, 0x70);
}

TEST(ConfigTest, ReadsEverySection) {
  PatchNodeSettings s;
  const std::string yaml = R"(
node: 17
mode: stream
rate_hz: 20
sync: true
hardware_uid: 0x00AB00CD00EF0012
can: {interface: can1, fd: false}
i2c:
  device: /dev/i2c-3
  mux_address: 0x72
  channels:
    - {channel: 3, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}
    - {channel: 2, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}
    - {channel: 1, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}
    - {channel: 0, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}
sensor: {gain_sel: 5, oversampling: 2, digital_filter: 3, resolution_z: 1}
gpio: {chip: gpiochip2, drdy: [5, 6], mux_reset: 7, identify_led: 8, sync_in: 9}
gate: {on_threshold_ut: 20, off_threshold_ut: 10, rms_on_threshold_ut: 1.5, rms_smoothing_samples: 6}
sim: {enabled: true, random_presses_per_min: 6, seed: 9}
)";
  ASSERT_TRUE(load_and_validate(yaml, &s).ok()) << error_of(yaml);
  EXPECT_EQ(s.node.node_id, 17);
  EXPECT_EQ(s.node.mode, bus::PatchMode::kStream);
  EXPECT_EQ(s.node.rate_chz, 2000);
  EXPECT_TRUE(s.node.sync_mode);
  EXPECT_EQ(s.node.hardware_uid, 0x00AB00CD00EF0012ull);
  EXPECT_EQ(s.can_interface, "can1");
  EXPECT_EQ(s.node.kind, bus::FrameKind::kClassic);
  EXPECT_EQ(s.i2c_device, "/dev/i2c-3");
  EXPECT_EQ(s.array.slots[0].channel, 3);
  EXPECT_EQ(s.array.slots[15].channel, 0);
  EXPECT_EQ(s.array.settings.chip.gain_sel, 5);
  EXPECT_EQ(s.array.settings.chip.res_z, 1);
  EXPECT_EQ(s.gpio.drdy_lines, (std::vector<unsigned>{5, 6}));
  EXPECT_EQ(*s.gpio.sync_in, 9u);
  EXPECT_DOUBLE_EQ(s.gate.on_threshold_ut, 20);
  EXPECT_DOUBLE_EQ(s.gate.rms_on_threshold_ut, 1.5);
  EXPECT_EQ(s.gate.rms_smoothing_samples, 6);
  EXPECT_TRUE(s.sim.enabled);
  EXPECT_TRUE(s.node.simulated);
}

TEST(ConfigTest, PrintedSettingsReadBackTheSame) {
  PatchNodeSettings a;
  ASSERT_TRUE(load_and_validate("node: 9\nmode: off\ngpio: {drdy: [1], sync_in: 4}\n", &a).ok());
  PatchNodeSettings b;
  ASSERT_TRUE(load_and_validate(settings_to_yaml(a), &b).ok()) << settings_to_yaml(a);
  EXPECT_EQ(settings_to_yaml(a), settings_to_yaml(b));
}

TEST(ConfigTest, ErrorsNameTheSetting) {
  struct Case {
    const char* yaml;
    const char* must_contain;
  };
  const Case cases[] = {
      {"node: 126", "node"},
      {"mode: fast", "mode"},
      {"rate_hz: abc", "rate_hz"},
      {"nodee: 3", "nodee"},  // a typo is an error, not silently ignored
      {"hardware_uid: \" -5\"", "hardware_uid (line 1): ' -5' is not a 64-bit unsigned integer"},
      {"node: 3\nnode: 4", "node (line 2): given twice"},
      {"i2c: {mux_address: 0x50}", "i2c.mux_address 0x50"},
      {"i2c: {channels: [{channel: 0, addresses: [0x0C, 0x0D, 0x0E, 0x50]},"
       " {channel: 1, addresses: [0x0C, 0x0D, 0x0E, 0x0F]},"
       " {channel: 2, addresses: [0x0C, 0x0D, 0x0E, 0x0F]},"
       " {channel: 3, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}]}",
       "address 0x50 is not an MLX90393 address"},
      {"i2c: {channels: [{channel: 0, addresses: [0x0C, 0x0D, 0x0E, 0x0F]},"
       " {channel: 0, addresses: [0x10, 0x11, 0x12, 0x13]}]}",
       "i2c.channels[1].channel (line 1): channel 0 is listed twice"},
      {"i2c: {channels: [{channel: 0, addresses: [0x0C, 0x0C, 0x0E, 0x0F]},"
       " {channel: 1, addresses: [0x0C, 0x0D, 0x0E, 0x0F]},"
       " {channel: 2, addresses: [0x0C, 0x0D, 0x0E, 0x0F]},"
       " {channel: 3, addresses: [0x0C, 0x0D, 0x0E, 0x0F]}]}",
       "listed twice on that channel"},
      {"i2c: {channels: [{channel: 0, addresses: [0x0C]}]}", "1 sensor addresses listed"},
      {"i2c: {channels: [{channel: 5, addresses: [0x0C]}]}", "i2c.channels[0].channel"},
      {"gpio: {drdy: [3], sync_in: 3}", "gpio.sync_in: line 3 is already used"},
      {"gate: {on_threshold_ut: 5, off_threshold_ut: 9}", "gate.off_threshold_ut"},
      {"gate: {rms_on_threshold_ut: 0.5, rms_off_threshold_ut: 0.9}", "gate.rms_off_threshold_ut"},
      {"gate: {rms_smoothing_samples: 0}", "gate.rms_smoothing_samples"},
      {"sensor: {oversampling: 3, digital_filter: 7}", "rate_hz 41.70: the sensors allow at most"},
      {"sensor: {gain_sel: 9}", "sensor.gain_sel"},
      {"node: [1, 2]", "node"},
      {"can: {interface: 'can 0'}", "can.interface 'can 0'"},
      {"can: {interface: averyveryverylongname0}", "1..15 printable characters"},
      {"node: 3\n  bad indent: [", "line"},
  };
  for (const Case& c : cases) {
    const std::string e = error_of(c.yaml);
    EXPECT_NE(e.find(c.must_contain), std::string::npos)
        << "yaml: " << c.yaml << "\nerror: '" << e << "'\nexpected to contain: " << c.must_contain;
  }
}

TEST(ConfigTest, OddStringsPrintAndReadBack) {
  PatchNodeSettings a;
  ASSERT_TRUE(load_and_validate("i2c: {device: \"/dev/i2c 1 \\\"x\\\" \"}\n"
                                "gpio: {chip: 'none'}\n",
                                &a)
                  .ok());
  EXPECT_EQ(a.i2c_device, "/dev/i2c 1 \"x\" ");
  EXPECT_EQ(a.gpio.chip, "none");
  PatchNodeSettings b;
  ASSERT_TRUE(load_and_validate(settings_to_yaml(a), &b).ok()) << settings_to_yaml(a);
  EXPECT_EQ(b.i2c_device, a.i2c_device);
  EXPECT_EQ(b.gpio.chip, "none");
}

TEST(ConfigTest, ImpossibleRateForTheConversionTime) {
  // 64 ADC samples per axis with the deepest filter: about 200 ms per XYZ conversion.
  PatchNodeSettings s;
  ASSERT_FALSE(
      load_and_validate("rate_hz: 5\nsensor: {oversampling: 3, digital_filter: 7}", &s).ok());
  ASSERT_TRUE(
      load_and_validate("rate_hz: 4\nsensor: {oversampling: 3, digital_filter: 7}", &s).ok());
  EXPECT_LT(s.node.max_rate_chz, 500);
  EXPECT_GT(s.node.max_rate_chz, 400);
  // A slower I2C clock lowers the ceiling too.
  EXPECT_FALSE(load_and_validate("rate_hz: 60\ni2c: {clock_hz: 100000}", &s).ok());
  EXPECT_TRUE(load_and_validate("rate_hz: 60", &s).ok());
}

TEST(ConfigTest, MissingFileIsNotFound) {
  PatchNodeSettings s = default_settings();
  Status st = load_settings_file("/nonexistent/patch.yaml", &s);
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().code, ErrorCode::kNotFound);
  EXPECT_NE(st.error().message.find("/nonexistent/patch.yaml"), std::string::npos);
}

}  // namespace
}  // namespace skinbus::patch_fw
