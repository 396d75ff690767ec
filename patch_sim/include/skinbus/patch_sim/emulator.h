// skinbus/patch_sim/emulator.h: MLX90393 and TCA9546A emulators behind the I2cBus interface.
//
// EmulatedI2cBus is an I2C bus with chips on it, spoken to exactly as patch_fw's LinuxI2cBus is:
// one combined transaction of write/read messages. It carries an optional TCA9546A multiplexer
// whose four downstream channels hold MLX90393s, and MLX90393s on the trunk itself. Each
// MLX90393 emulates the command protocol (skinbus/mlx90393/protocol.h) at the transaction
// level: status byte (mode, error, reset and data-count bits), volatile registers, single and
// burst measurements that take the conversion time of their configuration, output codes in the
// configured gain and resolution (saturating; skinbus/mlx90393/measurement.h), RT and EX. The
// field each chip measures comes from a FieldSource (the simulated patch's physics, or a test's
// values).
//
// Faults can be injected per chip, so drivers are tested against what real buses do: a chip
// that NAKs (vanished, or loose cable), the error bit on the next commands, values stuck at
// their last reading, a spontaneous reset (brown-out: registers back to defaults, RS set),
// a wrong data count. The multiplexer can NAK and can be reset through its reset line.
//
// Time comes from a Clock (skinbus/patch_fw/clock.h), so a conversion is ready only when the
// clock has passed its end. Not thread-safe: one bus, one thread, as on the board.
//
// What a driver sees (the contract the emulator keeps; mlx90393/protocol.h names the bits):
// - Bus: every message's address must acknowledge, else transfer() stops there and returns
//   kUnavailable "... NAK at 0x0C ..." (messages before it have had their effect, as on real
//   hardware). Two chips acknowledging the same address (enabled mux channels, or the trunk
//   and a channel) is a bus conflict: kIo. An empty message list is kInvalidArgument. A
//   zero-length write is an address probe: acknowledged, no effect.
// - TCA9546A: a write sets the control register from its last byte (bits 0..3: channels,
//   bits 4..7 dropped), a read returns it in every byte. As on the real part, a channel
//   selection becomes active at the STOP that ends the transaction: select the channel in one
//   transfer() and talk to the chip behind it in the next.
// - MLX90393: a write message carries one command; the chip executes it at once and holds
//   its answer (status byte, then data) for the next read message, which consumes it. Bytes
//   read past the answer are 0xFF; a read with no answer pending returns the current status
//   (RS not consumed) and 0xFF. The status's mode bits show the mode AFTER the command.
//   RS is set in the first answer after power-on, RT or power_cycle(), then clear.
//   Command lengths are exact (NOP/SB/SM/RM/EX/HR/RT 1 byte, RR 2, WR 4); anything
//   malformed, unknown, or not allowed in the current mode answers ERROR (D = 0) and does
//   nothing: SB/SM while a single or burst measurement runs (leave with EX first), SB/SM
//   with HALLCONF != 0xC or no axes (SB with axes 0 takes BURST_SEL), RR/WR of a register
//   >= kRegCount (the low two bits of the register byte are ignored), SW (wake-on-change) and HS
//   (memory store), which are not emulated. HR reloads the power-on defaults. WR is allowed in any
//   mode; a measurement uses the registers at its start (a burst: at SB).
// - SM: the conversion (all of X, Y, Z, plus T when selected, per mlx90393::Config) ends
//   at now + ceil(mlx90393::conversion_time_us) of GAIN_SEL, RES_X/Y/Z, OSR, DIG_FILT.
//   The field and temperature are sampled from the FieldSource at the start.
// - SB: conversion k starts at t_SB + k * P and completes at t_SB + (k + 1) * P, with
//   P = max(ceil(conversion time), BURST_DATA_RATE * 20 ms); RM returns the latest complete
//   one (the same one again until the next completes).
// - RM: its axes must be a subset of the measured axes, and the conversion complete; else
//   ERROR with D = 0 (counted as an early read when a conversion is still running). Answer:
//   status with D = (measurement_bytes(axes) - 2) / 2, then T, X, Y, Z (those selected), 16 bit
//   high byte first. In single mode a successful RM consumes the measurement and returns the
//   chip to idle (SM bit clear in that answer); a second RM answers ERROR. EX, RT and
//   power_cycle() discard any measurement.
// - Codes: X/Y/Z = mlx90393::output_code(field, sensitivity of the axis, RES of the axis):
//   RES 0/1 signed (two's complement on the wire), RES 2/3 unsigned around 32768 / 16384. TCMP_EN,
//   offsets, OSR2, BIST and Z_SERIES are ignored. T = mlx90393::temperature_code(t_c)
//   (46244 at 25 degC, 45.2 LSB/degC, clamped to 0..65535), in every RES.
// - RT: answers a status, resets the registers to the power-on defaults (kDefaultConf1/2/3,
//   others 0), discards measurements, then NAKs every message for kResetTimeUs (only the read
//   of RT's own answer in the same transaction is still acknowledged).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string_view>
#include <vector>

#include "skinbus/patch_fw/clock.h"
#include "skinbus/patch_fw/i2c.h"
#include "skinbus/sim/vec3.h"

namespace skinbus::patch_sim {

// The field a chip sees: `sensor` is the index given when the chip was added.
class FieldSource {
 public:
  virtual ~FieldSource() = default;
  // Field at the sensor in uT (x, y, z in the sensor's frame) at `time_us`, and its
  // temperature in degC. Called for each conversion the chip delivers, with the conversion's
  // start time (in burst mode lazily, when it is read, so `time_us` may be a little in the
  // past); the times passed for one sensor never decrease.
  virtual sim::Vec3<double> field_ut(int sensor, uint64_t time_us) = 0;
  virtual double temperature_c(int /*sensor*/, uint64_t /*time_us*/) { return 25.0; }
};

struct Mlx90393Faults {
  bool nak = false;            // does not acknowledge its address (absent or vanished); cleared,
                               // the chip is back with its registers and mode intact
  int error_bit_commands = 0;  // the next N commands answer with ERROR set (and RS if pending)
                               // and do nothing
  bool stuck = false;          // RM repeats the codes of the last RM answer per axis
  int wrong_data_count = 0;    // the next N RM answers with data announce D - 1 (not below 0)
                               // and carry one axis fewer (the last one; 0xFF in its place)
  bool corrupt_register_reads = false;  // RR returns inverted data (a flaky bus)
};

struct Mlx90393Counters {
  uint64_t commands = 0;      // command writes acknowledged (including rejected ones)
  uint64_t measurements = 0;  // conversions started (burst: counted up to the chip's last command)
  uint64_t errors = 0;        // answers with ERROR set
  uint64_t resets = 0;        // RT commands and injected resets (power_cycle)
  uint64_t early_reads = 0;   // RM while the conversion was still running
};

class EmulatedI2cBus final : public patch_fw::I2cBus {
 public:
  // `clock` and `source` are not owned and must outlive the bus.
  EmulatedI2cBus(patch_fw::Clock* clock, FieldSource* source);
  ~EmulatedI2cBus() override;

  // Puts a TCA9546A at `address` (0x70..0x77) on the trunk. Call at most once.
  Status add_mux(uint8_t address);
  // Adds an MLX90393 at `address` on mux channel `channel` (0..3), or on the trunk with
  // channel = -1. `sensor` (>= 0) is the index passed to the FieldSource. Errors
  // (kInvalidArgument): no mux for a channel, channel out of range, address outside
  // [kAddressMin, kAddressMax] or already taken on that segment, sensor index taken. The chip
  // powers up idle with the default registers, RS pending.
  Status add_mlx90393(int channel, uint8_t address, int sensor);

  Status transfer(std::span<patch_fw::I2cMessage> messages) override;
  std::string_view name() const override { return "emulator"; }

  // Test and simulation side; `sensor` is the FieldSource index of a chip. An unknown index is
  // a bug in the caller: these abort with a message.
  Mlx90393Faults& faults(int sensor);
  const Mlx90393Counters& counters(int sensor) const;
  uint16_t register_value(int sensor, uint8_t reg) const;
  // A brown-out: registers to power-on defaults, RS set on the next status, any measurement
  // lost.
  void power_cycle(int sensor);
  // The multiplexer's control register (bit i: channel i enabled) and its faults; with
  // set_mux_nak(true) the mux does not acknowledge its address (its channels stay as they are).
  uint8_t mux_control() const;
  void set_mux_nak(bool nak);
  // The multiplexer's active-low RESET pin: asserting clears the control register.
  void mux_reset();
  uint64_t transactions() const { return transactions_; }

  struct Chip;  // internal

 private:
  patch_fw::Clock* clock_;
  FieldSource* source_;
  std::optional<uint8_t> mux_address_;
  uint8_t mux_control_ = 0;  // the register
  uint8_t mux_active_ = 0;   // the channels connected: the register as of the last STOP
  bool mux_nak_ = false;
  std::vector<std::unique_ptr<Chip>> chips_;
  uint64_t transactions_ = 0;
};

}  // namespace skinbus::patch_sim
