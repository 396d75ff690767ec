// The chip emulators, driven only through transfer() with raw bytes, as a driver would.
#include "skinbus/patch_sim/emulator.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "skinbus/mlx90393/measurement.h"
#include "skinbus/mlx90393/protocol.h"

namespace skinbus::patch_sim {
namespace {

namespace mlx = mlx90393;
using patch_fw::I2cMessage;
using patch_fw::ManualClock;
using Bytes = std::vector<uint8_t>;

constexpr uint8_t kMux = 0x70;
constexpr uint8_t kMuxed = 0x0C;  // sensor 0 on channel 0, sensor 1 on channel 1
constexpr uint8_t kTrunk = 0x0D;  // sensor 2 on the trunk
constexpr int kTrunkSensor = 2;

// Known fields per sensor; records every call.
class TestField final : public FieldSource {
 public:
  sim::Vec3<double> field_ut(int sensor, uint64_t time_us) override {
    calls.emplace_back(sensor, time_us);
    return fields[sensor];
  }
  double temperature_c(int, uint64_t) override { return temperature; }

  std::map<int, sim::Vec3<double>> fields;
  double temperature = 25.0;
  std::vector<std::pair<int, uint64_t>> calls;
};

// Register-field values of a configuration, and what the chip makes of it.
struct Cfg {
  uint8_t gain = 7, res_x = 0, res_y = 0, res_z = 0, osr = 0, filt = 0;

  uint16_t conf1() const { return static_cast<uint16_t>(mlx::kHallconfDefault | gain << 4); }
  uint16_t conf3() const {
    return static_cast<uint16_t>(osr | filt << 2 | res_x << 5 | res_y << 7 | res_z << 9);
  }
  mlx::Config chip(bool temperature, uint8_t res_xy) const {
    return {gain, res_xy, res_z, osr, filt, temperature};
  }
  uint64_t conversion_us(bool temperature) const {
    return static_cast<uint64_t>(std::ceil(mlx::conversion_time_us(chip(temperature, 0))));
  }
  // Wire words X, Y, Z for a field.
  std::array<uint16_t, 3> codes(const sim::Vec3<double>& f, bool* any_saturated = nullptr) const {
    bool sx = false, sy = false, sz = false;
    const auto x = mlx::output_code(f.x, mlx::sensitivity_xy_ut(chip(false, res_x)), res_x, &sx);
    const auto y = mlx::output_code(f.y, mlx::sensitivity_xy_ut(chip(false, res_y)), res_y, &sy);
    const auto z = mlx::output_code(f.z, mlx::sensitivity_z_ut(chip(false, res_x)), res_z, &sz);
    if (any_saturated) *any_saturated = sx || sy || sz;
    return {static_cast<uint16_t>(x & 0xFFFF), static_cast<uint16_t>(y & 0xFFFF),
            static_cast<uint16_t>(z & 0xFFFF)};
  }
};

uint16_t word(const Bytes& b, size_t at) {
  return static_cast<uint16_t>(b[at] << 8 | b[at + 1]);
}

Bytes wr(uint8_t reg, uint16_t value) {
  return {mlx::kCmdWriteRegister, static_cast<uint8_t>(value >> 8),
          static_cast<uint8_t>(value & 0xFF), static_cast<uint8_t>(reg << 2)};
}
Bytes rr(uint8_t reg) {
  return {mlx::kCmdReadRegister, static_cast<uint8_t>(reg << 2)};
}
Bytes one(uint8_t cmd) {
  return {cmd};
}

class EmulatorTest : public ::testing::Test {
 protected:
  EmulatorTest() {
    EXPECT_TRUE(bus.add_mux(kMux).ok());
    EXPECT_TRUE(bus.add_mlx90393(0, kMuxed, 0).ok());
    EXPECT_TRUE(bus.add_mlx90393(1, kMuxed, 1).ok());
    EXPECT_TRUE(bus.add_mlx90393(-1, kTrunk, kTrunkSensor).ok());
  }

  // One transaction of any messages.
  Status run(std::vector<std::pair<uint8_t, Bytes*>> writes_reads, std::vector<bool> read) {
    std::vector<I2cMessage> msgs;
    for (size_t i = 0; i < writes_reads.size(); ++i) {
      msgs.push_back({writes_reads[i].first, read[i], std::span<uint8_t>(*writes_reads[i].second)});
    }
    return bus.transfer(msgs);
  }
  Status write(uint8_t address, Bytes out) { return run({{address, &out}}, {false}); }
  Result<Bytes> read(uint8_t address, size_t n) {
    Bytes in(n, 0xAA);
    Status s = run({{address, &in}}, {true});
    if (!s.ok()) return s.error();
    return in;
  }
  // A command and its answer in one transaction (repeated START), as the driver does.
  Result<Bytes> command(uint8_t address, Bytes out, size_t n) {
    Bytes in(n, 0xAA);
    Status s = run({{address, &out}, {address, &in}}, {false, true});
    if (!s.ok()) return s.error();
    return in;
  }
  // The status byte of a status-only command (fails the test on a bus error).
  int status(uint8_t address, Bytes out) {
    auto r = command(address, std::move(out), 1);
    EXPECT_TRUE(r.ok()) << r.error().to_string();
    return r.ok() ? r.value()[0] : -1;
  }
  void select(uint8_t mask) { ASSERT_TRUE(write(kMux, {mask}).ok()); }
  void configure(uint8_t address, const Cfg& c) {
    EXPECT_EQ(status(address, wr(mlx::kRegConf1, c.conf1())) & mlx::kStatusError, 0);
    EXPECT_EQ(status(address, wr(mlx::kRegConf3, c.conf3())) & mlx::kStatusError, 0);
  }
  // Clears the power-on RS of the trunk chip.
  void boot_trunk() { ASSERT_EQ(status(kTrunk, one(mlx::kCmdNop)), mlx::kStatusReset); }

  ManualClock clock{1'000'000};
  TestField source;
  EmulatedI2cBus bus{&clock, &source};
};

TEST_F(EmulatorTest, MuxSelectionGatesWhichChipsAnswer) {
  Status s = write(kMuxed, one(mlx::kCmdNop));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(s.error().message.find("NAK at 0x0C"), std::string::npos) << s.error().message;
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdNop)), mlx::kStatusReset);  // trunk: always there

  select(0xF1);  // bits 4..7 dropped
  EXPECT_EQ(bus.mux_control(), 0x01);
  EXPECT_EQ(read(kMux, 2).value(), (Bytes{0x01, 0x01}));
  EXPECT_EQ(status(kMuxed, one(mlx::kCmdNop)), mlx::kStatusReset);
  EXPECT_EQ(bus.counters(0).commands, 1u);
  EXPECT_EQ(bus.counters(1).commands, 0u);

  select(0x02);
  EXPECT_EQ(status(kMuxed, one(mlx::kCmdNop)), mlx::kStatusReset);  // sensor 1's first answer
  EXPECT_EQ(bus.counters(0).commands, 1u);
  EXPECT_EQ(bus.counters(1).commands, 1u);

  select(0x03);  // both chips at 0x0C on the bus
  s = write(kMuxed, one(mlx::kCmdNop));
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kIo);
  EXPECT_NE(s.error().message.find("conflict"), std::string::npos);

  // A selection becomes active at the STOP: not for the rest of its own transaction.
  select(0x00);
  Bytes sel{0x01}, nop{mlx::kCmdNop};
  s = run({{kMux, &sel}, {kMuxed, &nop}}, {false, false});
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  EXPECT_EQ(bus.mux_control(), 0x01);
  EXPECT_EQ(status(kMuxed, one(mlx::kCmdNop)), 0);

  bus.mux_reset();
  EXPECT_EQ(bus.mux_control(), 0x00);
  EXPECT_EQ(read(kMux, 1).value(), Bytes{0x00});
  EXPECT_EQ(write(kMuxed, one(mlx::kCmdNop)).error().code, ErrorCode::kUnavailable);
}

TEST_F(EmulatorTest, NakForAbsentVanishedChipAndMux) {
  boot_trunk();
  Status s = write(0x0E, one(mlx::kCmdNop));
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(s.error().message.find("NAK at 0x0E"), std::string::npos);

  // Messages before the NAK have had their effect.
  Bytes w = wr(mlx::kRegConf3, 0x0015), probe{mlx::kCmdNop};
  s = run({{kTrunk, &w}, {0x0E, &probe}}, {false, false});
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  EXPECT_EQ(bus.register_value(kTrunkSensor, mlx::kRegConf3), 0x0015);

  bus.set_mux_nak(true);
  s = write(kMux, {0x01});
  EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
  EXPECT_NE(s.error().message.find("NAK at 0x70"), std::string::npos);
  EXPECT_EQ(bus.mux_control(), 0x00);
  bus.set_mux_nak(false);
  select(0x01);

  // A vanished chip NAKs, and comes back with its registers.
  bus.faults(kTrunkSensor).nak = true;
  EXPECT_EQ(write(kTrunk, one(mlx::kCmdNop)).error().code, ErrorCode::kUnavailable);
  EXPECT_EQ(read(kTrunk, 1).error().code, ErrorCode::kUnavailable);
  bus.faults(kTrunkSensor).nak = false;
  EXPECT_EQ(command(kTrunk, rr(mlx::kRegConf3), 3).value(), (Bytes{0x00, 0x00, 0x15}));

  // ... unless it lost power meanwhile.
  bus.faults(kTrunkSensor).nak = true;
  bus.power_cycle(kTrunkSensor);
  bus.faults(kTrunkSensor).nak = false;
  EXPECT_EQ(command(kTrunk, rr(mlx::kRegConf3), 3).value(), (Bytes{mlx::kStatusReset, 0, 0}));
}

TEST_F(EmulatorTest, WriteThenReadRegisters) {
  boot_trunk();
  const std::pair<uint8_t, uint16_t> writes[] = {
      {mlx::kRegConf1, 0x005C}, {mlx::kRegConf2, 0x1234}, {mlx::kRegConf3, 0x0A5B}, {0x1F, 0xBEEF}};
  for (auto [reg, value] : writes) {
    EXPECT_EQ(status(kTrunk, wr(reg, value)), 0);
    EXPECT_EQ(bus.register_value(kTrunkSensor, reg), value);
  }
  for (auto [reg, value] : writes) {
    const Bytes got = command(kTrunk, rr(reg), 3).value();
    EXPECT_EQ(got[0], 0);  // D = 0: two data bytes
    EXPECT_EQ(word(got, 1), value) << int{reg};
  }
  // Bytes past the answer read 0xFF; a read with no answer pending gets the status only.
  EXPECT_EQ(command(kTrunk, rr(0x1F), 5).value(), (Bytes{0x00, 0xBE, 0xEF, 0xFF, 0xFF}));
  EXPECT_EQ(read(kTrunk, 3).value(), (Bytes{0x00, 0xFF, 0xFF}));

  // Rejected: registers beyond the map, malformed lengths, unknown or unemulated commands.
  EXPECT_EQ(status(kTrunk, Bytes{mlx::kCmdWriteRegister, 0x12, 0x34, 0x20 << 2}),
            mlx::kStatusError);
  EXPECT_EQ(command(kTrunk, Bytes{mlx::kCmdReadRegister, 0x20 << 2}, 3).value()[0],
            mlx::kStatusError);
  const Bytes bad[] = {{mlx::kCmdReadRegister},
                       {mlx::kCmdWriteRegister, 0x00, 0x00},
                       {mlx::kCmdNop, 0x00},
                       {0x01},
                       {0x70},
                       {0x90},
                       {0xA0},
                       {0xC0},
                       {mlx::kCmdStartWakeOnChange | mlx::kAxesXyz},
                       {mlx::kCmdMemoryStore},
                       {mlx::kCmdReset, 0x00},
                       {mlx::kCmdExit | 0x01}};
  for (const Bytes& b : bad) EXPECT_EQ(status(kTrunk, b), mlx::kStatusError) << int{b[0]};
  EXPECT_EQ(bus.register_value(kTrunkSensor, 0x1F), 0xBEEF);

  // HR reloads the power-on defaults.
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdMemoryRecall)), 0);
  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf1), 3).value(), 1), mlx::kDefaultConf1);
}

TEST_F(EmulatorTest, ResetRestoresDefaultsSetsRsOnceAndNaksMeanwhile) {
  boot_trunk();
  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf1, 0x001C)), 0);
  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf3, 0x0A5B)), 0);
  EXPECT_EQ(status(kTrunk, wr(0x10, 0x4242)), 0);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusSmMode);

  // RT's own answer is readable in its transaction; then the chip NAKs for kResetTimeUs.
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdReset)), 0);
  EXPECT_EQ(write(kTrunk, one(mlx::kCmdNop)).error().code, ErrorCode::kUnavailable);
  clock.advance_us(mlx::kResetTimeUs - 1);
  EXPECT_EQ(read(kTrunk, 1).error().code, ErrorCode::kUnavailable);
  clock.advance_us(1);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdNop)), mlx::kStatusReset);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdNop)), 0);

  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf1), 3).value(), 1), mlx::kDefaultConf1);
  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf2), 3).value(), 1), mlx::kDefaultConf2);
  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf3), 3).value(), 1), mlx::kDefaultConf3);
  EXPECT_EQ(word(command(kTrunk, rr(0x10), 3).value(), 1), 0);
  // The measurement started before RT is gone.
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxesXyz), 7).value()[0],
            mlx::kStatusError);
  EXPECT_EQ(bus.counters(kTrunkSensor).resets, 1u);

  // RT written alone, answer never read: same effect.
  ASSERT_TRUE(write(kTrunk, one(mlx::kCmdReset)).ok());
  EXPECT_EQ(read(kTrunk, 1).error().code, ErrorCode::kUnavailable);
  clock.advance_us(mlx::kResetTimeUs);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdExit)), mlx::kStatusReset);
  EXPECT_EQ(bus.counters(kTrunkSensor).resets, 2u);
}

TEST_F(EmulatorTest, SingleMeasurementTimingAndCodes) {
  boot_trunk();
  const sim::Vec3<double> f{123.4, -56.7, 890.1};
  source.fields[kTrunkSensor] = f;
  const Cfg cfgs[] = {{7, 0, 0, 0, 0, 0}, {0, 2, 1, 3, 1, 2}, {3, 1, 3, 0, 3, 7}};
  uint64_t early = 0;
  for (const Cfg& c : cfgs) {
    SCOPED_TRACE(testing::Message() << "gain " << int{c.gain} << " res " << int{c.res_x});
    configure(kTrunk, c);
    const uint64_t t0 = clock.now_us();
    EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusSmMode);
    EXPECT_EQ(source.calls.back(), (std::pair<int, uint64_t>{kTrunkSensor, t0}));
    source.fields[kTrunkSensor] = {1, 2, 3};  // sampled at the start: later changes unseen

    const Bytes rm = one(mlx::kCmdReadMeasurement | mlx::kAxesXyz);
    EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusSmMode | mlx::kStatusError);
    clock.advance_us(c.conversion_us(false) - 1);
    EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusSmMode | mlx::kStatusError);
    early += 2;
    EXPECT_EQ(bus.counters(kTrunkSensor).early_reads, early);
    clock.advance_us(1);
    const Bytes got = command(kTrunk, rm, 7).value();
    EXPECT_EQ(got[0], 2);  // idle again, D = 2: six data bytes
    EXPECT_EQ(mlx::status_data_bytes(got[0]), 6);
    const auto want = c.codes(f);
    EXPECT_EQ(word(got, 1), want[0]);
    EXPECT_EQ(word(got, 3), want[1]);
    EXPECT_EQ(word(got, 5), want[2]);
    // Consumed: a second RM has nothing to read (and is not an early read).
    EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusError);
    EXPECT_EQ(bus.counters(kTrunkSensor).early_reads, early);
    source.fields[kTrunkSensor] = f;
  }
  // The codes really differ between gain/res settings (RES 0 signed, RES 2 around 32768).
  EXPECT_NE(cfgs[0].codes(f)[0], cfgs[1].codes(f)[0]);
  EXPECT_EQ(cfgs[0].codes(f)[1], static_cast<uint16_t>(-378));  // -56.7 / 0.150
  EXPECT_EQ(bus.counters(kTrunkSensor).measurements, 3u);
}

TEST_F(EmulatorTest, SaturatesAtLargeFields) {
  boot_trunk();
  const Bytes sm = one(mlx::kCmdStartSingle | mlx::kAxesXyz);
  const Bytes rm = one(mlx::kCmdReadMeasurement | mlx::kAxesXyz);
  const sim::Vec3<double> big{1e6, -1e6, 1e6};
  source.fields[kTrunkSensor] = big;

  const Cfg signed_cfg{7, 0, 0, 0, 0, 0};
  configure(kTrunk, signed_cfg);
  bool saturated = false;
  const auto want = signed_cfg.codes(big, &saturated);
  EXPECT_TRUE(saturated);
  EXPECT_EQ(status(kTrunk, sm), mlx::kStatusSmMode);
  clock.advance_us(signed_cfg.conversion_us(false));
  Bytes got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(word(got, 1), want[0]);
  EXPECT_EQ(word(got, 1), 0x7FFF);
  EXPECT_EQ(word(got, 3), 0x8001);  // -32767
  EXPECT_EQ(word(got, 5), 0x7FFF);

  const Cfg unsigned_cfg{0, 2, 2, 2, 0, 1};
  configure(kTrunk, unsigned_cfg);
  EXPECT_EQ(status(kTrunk, sm), mlx::kStatusSmMode);
  clock.advance_us(unsigned_cfg.conversion_us(false));
  got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(word(got, 1), 0xFFFF);
  EXPECT_EQ(word(got, 3), 0x0000);
  EXPECT_EQ(word(got, 5), 0xFFFF);
}

TEST_F(EmulatorTest, TemperatureAndAxisOrder) {
  boot_trunk();
  const Cfg c{5, 1, 0, 1, 1, 1};
  configure(kTrunk, c);
  const sim::Vec3<double> f{-300.0, 150.0, 42.0};
  source.fields[kTrunkSensor] = f;
  source.temperature = 40.0;
  const auto want = c.codes(f);
  const uint16_t want_t = 46922;  // 46244 + 15 degC * 45.2 LSB/degC

  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | 0x0F)), mlx::kStatusSmMode);
  clock.advance_us(c.conversion_us(true) - 1);  // T adds to the conversion time
  ASSERT_GT(c.conversion_us(true), c.conversion_us(false));
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | 0x0F), 9).value()[0],
            mlx::kStatusSmMode | mlx::kStatusError);
  clock.advance_us(1);
  Bytes got = command(kTrunk, one(mlx::kCmdReadMeasurement | 0x0F), 9).value();
  EXPECT_EQ(got[0], 3);  // D = 3: eight bytes
  EXPECT_EQ(word(got, 1), want_t);
  EXPECT_EQ(word(got, 3), want[0]);
  EXPECT_EQ(word(got, 5), want[1]);
  EXPECT_EQ(word(got, 7), want[2]);

  // A subset of the measured axes, in T, X, Y, Z order.
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | 0x0F)), mlx::kStatusSmMode);
  clock.advance_us(c.conversion_us(true));
  got = command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisZ | mlx::kAxisT), 5).value();
  EXPECT_EQ(got, (Bytes{1, static_cast<uint8_t>(want_t >> 8), static_cast<uint8_t>(want_t),
                        static_cast<uint8_t>(want[2] >> 8), static_cast<uint8_t>(want[2])}));

  // Axes that were not measured cannot be read.
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxisX)), mlx::kStatusSmMode);
  clock.advance_us(c.conversion_us(false));
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisY), 3).value()[0],
            mlx::kStatusSmMode | mlx::kStatusError);
  got = command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisX), 3).value();
  EXPECT_EQ(got[0], 0);
  EXPECT_EQ(word(got, 1), want[0]);
}

TEST_F(EmulatorTest, BurstModeDeliversTheLatestConversion) {
  boot_trunk();
  const Cfg c{7, 0, 0, 0, 0, 0};
  const uint64_t period_us = c.conversion_us(false);
  ASSERT_EQ(period_us, 777u);  // 3 * (67 + 64 * 3)
  const sim::Vec3<double> f1{10, 20, 30}, f2{-40, 50, -60};
  source.fields[kTrunkSensor] = f1;
  const Bytes rm = one(mlx::kCmdReadMeasurement | mlx::kAxesXyz);

  const uint64_t t0 = clock.now_us();
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartBurst | mlx::kAxesXyz)), mlx::kStatusBurstMode);
  EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusBurstMode | mlx::kStatusError);
  EXPECT_EQ(bus.counters(kTrunkSensor).early_reads, 1u);
  clock.advance_us(period_us);
  Bytes got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(got[0], mlx::kStatusBurstMode | 2);
  EXPECT_EQ(word(got, 1), c.codes(f1)[0]);
  EXPECT_EQ(word(got, 5), c.codes(f1)[2]);
  EXPECT_EQ(source.calls.back().second, t0);  // sampled at the conversion's start

  source.fields[kTrunkSensor] = f2;
  EXPECT_EQ(word(command(kTrunk, rm, 7).value(), 1), c.codes(f1)[0]);  // same conversion
  clock.advance_us(period_us);
  got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(got[0], mlx::kStatusBurstMode | 2);
  EXPECT_EQ(word(got, 1), c.codes(f2)[0]);
  EXPECT_EQ(word(got, 3), c.codes(f2)[1]);
  EXPECT_EQ(source.calls.back().second, t0 + period_us);

  // Burst holds until EX.
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)),
            mlx::kStatusBurstMode | mlx::kStatusError);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartBurst | mlx::kAxesXyz)),
            mlx::kStatusBurstMode | mlx::kStatusError);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdExit)), 0);
  EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusError);
  EXPECT_EQ(bus.counters(kTrunkSensor).measurements, 3u);  // started at t0, +P, +2P

  // SB with no axes takes BURST_SEL; BURST_DATA_RATE stretches the period (20 ms steps).
  const uint16_t conf2 = static_cast<uint16_t>(mlx::kAxisZ << mlx::kBurstSelShift | 2);
  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf2, conf2)), 0);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartBurst)), mlx::kStatusBurstMode);
  clock.advance_us(period_us);
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisZ), 3).value()[0],
            mlx::kStatusBurstMode | mlx::kStatusError);
  clock.advance_us(40'000 - period_us);
  got = command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisZ), 3).value();
  EXPECT_EQ(got[0], mlx::kStatusBurstMode);
  EXPECT_EQ(word(got, 1), c.codes(f2)[2]);
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxisX), 3).value()[0],
            mlx::kStatusBurstMode | mlx::kStatusError);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdExit)), 0);
}

TEST_F(EmulatorTest, ExitLeavesSingleModeAndHallconfIsChecked) {
  boot_trunk();
  source.fields[kTrunkSensor] = {1, 1, 1};
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusSmMode);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)),
            mlx::kStatusSmMode | mlx::kStatusError);  // one at a time
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdExit)), 0);
  clock.advance_us(100'000);
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxesXyz), 7).value()[0],
            mlx::kStatusError);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle)), mlx::kStatusError);  // no axes
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusSmMode);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdExit)), 0);

  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf1, 0x0070)), 0);  // HALLCONF 0
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusError);
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartBurst | mlx::kAxesXyz)), mlx::kStatusError);
  EXPECT_EQ(bus.counters(kTrunkSensor).measurements, 2u);
}

TEST_F(EmulatorTest, ErrorBitFault) {
  boot_trunk();
  bus.faults(kTrunkSensor).error_bit_commands = 2;
  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf1, 0x005C)), mlx::kStatusError);
  EXPECT_EQ(command(kTrunk, rr(mlx::kRegConf1), 3).value(), (Bytes{mlx::kStatusError, 0xFF, 0xFF}));
  EXPECT_EQ(bus.faults(kTrunkSensor).error_bit_commands, 0);
  EXPECT_EQ(command(kTrunk, rr(mlx::kRegConf1), 3).value(),
            (Bytes{0, 0, static_cast<uint8_t>(mlx::kDefaultConf1)}));  // the WR did nothing
  EXPECT_EQ(bus.counters(kTrunkSensor).errors, 2u);
}

TEST_F(EmulatorTest, StuckFaultRepeatsTheLastCodes) {
  boot_trunk();
  const Cfg c;
  const Bytes sm = one(mlx::kCmdStartSingle | mlx::kAxesXyz);
  const Bytes rm = one(mlx::kCmdReadMeasurement | mlx::kAxesXyz);
  auto measure = [&] {
    EXPECT_EQ(status(kTrunk, sm), mlx::kStatusSmMode);
    clock.advance_us(c.conversion_us(false));
    return command(kTrunk, rm, 7).value();
  };
  const sim::Vec3<double> a{100, 200, 300}, b{-5, -6, -7};
  source.fields[kTrunkSensor] = a;
  const Bytes first = measure();
  EXPECT_EQ(word(first, 1), c.codes(a)[0]);
  bus.faults(kTrunkSensor).stuck = true;
  source.fields[kTrunkSensor] = b;
  EXPECT_EQ(measure(), first);
  EXPECT_EQ(measure(), first);
  bus.faults(kTrunkSensor).stuck = false;
  const Bytes fresh = measure();
  EXPECT_EQ(word(fresh, 1), c.codes(b)[0]);
  EXPECT_EQ(word(fresh, 5), c.codes(b)[2]);
}

TEST_F(EmulatorTest, WrongDataCountFault) {
  boot_trunk();
  const Cfg c;
  const sim::Vec3<double> f{100, 200, 300};
  source.fields[kTrunkSensor] = f;
  const Bytes sm = one(mlx::kCmdStartSingle | mlx::kAxesXyz);
  const Bytes rm = one(mlx::kCmdReadMeasurement | mlx::kAxesXyz);
  bus.faults(kTrunkSensor).wrong_data_count = 1;
  // Early reads do not use up the fault.
  EXPECT_EQ(status(kTrunk, sm), mlx::kStatusSmMode);
  EXPECT_EQ(command(kTrunk, rm, 7).value()[0], mlx::kStatusSmMode | mlx::kStatusError);
  clock.advance_us(c.conversion_us(false));
  Bytes got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(got[0], 1);  // D = 1 although three axes were asked for
  EXPECT_EQ(word(got, 1), c.codes(f)[0]);
  EXPECT_EQ(word(got, 3), c.codes(f)[1]);
  EXPECT_EQ(word(got, 5), 0xFFFF);
  EXPECT_EQ(bus.faults(kTrunkSensor).wrong_data_count, 0);

  EXPECT_EQ(status(kTrunk, sm), mlx::kStatusSmMode);
  clock.advance_us(c.conversion_us(false));
  got = command(kTrunk, rm, 7).value();
  EXPECT_EQ(got[0], 2);
  EXPECT_EQ(word(got, 5), c.codes(f)[2]);
}

TEST_F(EmulatorTest, CorruptRegisterReadsAndPowerCycle) {
  boot_trunk();
  EXPECT_EQ(status(kTrunk, wr(mlx::kRegConf3, 0x0123)), 0);
  bus.faults(kTrunkSensor).corrupt_register_reads = true;
  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf3), 3).value(), 1), 0xFEDC);
  EXPECT_EQ(bus.register_value(kTrunkSensor, mlx::kRegConf3), 0x0123);  // only the read is bad
  bus.faults(kTrunkSensor).corrupt_register_reads = false;
  EXPECT_EQ(word(command(kTrunk, rr(mlx::kRegConf3), 3).value(), 1), 0x0123);

  // A brown-out mid-measurement: defaults, measurement lost, RS on the next answer only.
  source.fields[kTrunkSensor] = {1, 2, 3};
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | mlx::kAxesXyz)), mlx::kStatusSmMode);
  bus.power_cycle(kTrunkSensor);
  clock.advance_us(100'000);
  EXPECT_EQ(read(kTrunk, 1).value()[0], mlx::kStatusReset);  // status peek keeps RS
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | mlx::kAxesXyz), 7).value()[0],
            mlx::kStatusReset | mlx::kStatusError);
  EXPECT_EQ(command(kTrunk, rr(mlx::kRegConf3), 3).value(), (Bytes{0, 0, 0}));
  EXPECT_EQ(bus.counters(kTrunkSensor).resets, 1u);
}

TEST_F(EmulatorTest, CountersAndTransactions) {
  const uint64_t t0 = bus.transactions();
  boot_trunk();                                               // NOP
  EXPECT_EQ(status(kTrunk, wr(0x30, 1)), mlx::kStatusError);  // bad register
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdStartSingle | 0x0F)), mlx::kStatusSmMode);
  EXPECT_EQ(command(kTrunk, one(mlx::kCmdReadMeasurement | 0x0F), 9).value()[0],
            mlx::kStatusSmMode | mlx::kStatusError);  // early
  EXPECT_EQ(status(kTrunk, one(mlx::kCmdReset)), 0);
  EXPECT_FALSE(write(kTrunk, one(mlx::kCmdNop)).ok());  // NAK: not a command
  EXPECT_FALSE(write(kTrunk, {}).ok());                 // a probe NAKs too
  clock.advance_us(mlx::kResetTimeUs);
  EXPECT_TRUE(write(kTrunk, {}).ok());  // probe: no command
  bus.power_cycle(kTrunkSensor);

  const Mlx90393Counters& n = bus.counters(kTrunkSensor);
  EXPECT_EQ(n.commands, 5u);
  EXPECT_EQ(n.errors, 2u);
  EXPECT_EQ(n.measurements, 1u);
  EXPECT_EQ(n.early_reads, 1u);
  EXPECT_EQ(n.resets, 2u);
  EXPECT_EQ(bus.counters(0).commands, 0u);
  EXPECT_EQ(bus.transactions() - t0, 8u);
  std::vector<I2cMessage> none;
  EXPECT_EQ(bus.transfer(none).error().code, ErrorCode::kInvalidArgument);
  EXPECT_EQ(bus.transactions() - t0, 9u);
}

TEST(EmulatorSetupTest, ValidatesTheTopology) {
  ManualClock clock;
  TestField source;
  EmulatedI2cBus bus(&clock, &source);
  const auto invalid = [](const Status& s) {
    return !s.ok() && s.error().code == ErrorCode::kInvalidArgument;
  };
  EXPECT_TRUE(invalid(bus.add_mlx90393(0, 0x0C, 0)));  // no mux yet
  EXPECT_TRUE(bus.add_mlx90393(-1, 0x0C, 0).ok());
  EXPECT_TRUE(invalid(bus.add_mux(0x6F)));
  EXPECT_TRUE(invalid(bus.add_mux(0x78)));
  EXPECT_TRUE(bus.add_mux(0x77).ok());
  EXPECT_TRUE(invalid(bus.add_mux(0x70)));  // once only
  EXPECT_TRUE(invalid(bus.add_mlx90393(4, 0x0C, 1)));
  EXPECT_TRUE(invalid(bus.add_mlx90393(-2, 0x0C, 1)));
  EXPECT_TRUE(invalid(bus.add_mlx90393(0, 0x0B, 1)));
  EXPECT_TRUE(invalid(bus.add_mlx90393(0, 0x1C, 1)));
  EXPECT_TRUE(invalid(bus.add_mlx90393(-1, 0x0C, 1)));  // taken on the trunk
  EXPECT_TRUE(invalid(bus.add_mlx90393(0, 0x0D, 0)));   // sensor index taken
  EXPECT_TRUE(invalid(bus.add_mlx90393(0, 0x0D, -1)));
  EXPECT_TRUE(bus.add_mlx90393(0, 0x0C, 1).ok());
  EXPECT_TRUE(bus.add_mlx90393(3, 0x0C, 2).ok());
  EXPECT_TRUE(invalid(bus.add_mlx90393(3, 0x0C, 3)));
  EXPECT_TRUE(bus.add_mlx90393(3, 0x1B, 3).ok());
  EXPECT_EQ(bus.register_value(3, mlx::kRegConf1), mlx::kDefaultConf1);

  // Trunk and an enabled channel answering at one address: a bus conflict.
  Bytes sel{0x01}, nop{mlx::kCmdNop};
  I2cMessage m{0x77, false, sel};
  ASSERT_TRUE(bus.transfer(std::span(&m, 1)).ok());
  m = {0x0C, false, nop};
  EXPECT_EQ(bus.transfer(std::span(&m, 1)).error().code, ErrorCode::kIo);
}

TEST(EmulatorDeathTest, UnknownSensorAborts) {
  ManualClock clock;
  TestField source;
  EmulatedI2cBus bus(&clock, &source);
  EXPECT_DEATH(bus.faults(7), "no MLX90393 with sensor index 7");
}

}  // namespace
}  // namespace skinbus::patch_sim
