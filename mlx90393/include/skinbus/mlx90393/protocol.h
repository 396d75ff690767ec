// skinbus/mlx90393/protocol.h: the MLX90393's I2C command protocol, as data.
//
// Shared by the driver (skinbus/patch_fw/mlx90393.h) and the chip emulator
// (skinbus/patch_sim/emulator.h) so the two cannot disagree on a bit. From the MLX90393
// datasheet (command set, status byte, volatile register map, timing). What the settings in
// the registers do to a measurement is measurement.h.
//
// Every command is a write of 1..4 bytes followed (repeated START) by a read of the status byte
// and, for RM and RR, the data:
//   SB/SW/SM  0x10/0x20/0x30 | zyxt   -> status
//   RM        0x40 | zyxt             -> status, then T, X, Y, Z (those selected), 16 bit each,
//                                        high byte first
//   RR        0x50, reg << 2          -> status, data high, data low
//   WR        0x60, high, low, reg<<2 -> status
//   EX 0x80, HR 0xD0, HS 0xE0, RT 0xF0, NOP 0x00 -> status
#pragma once

#include <cstdint>

namespace skinbus::mlx90393 {

// 7-bit addresses: 0x0C + A1A0 strapping, and the other part codes' blocks up to 0x1B.
inline constexpr uint8_t kAddressMin = 0x0C;
inline constexpr uint8_t kAddressMax = 0x1B;

// Commands (high nibble); SB, SW, SM and RM take the axis selection in the low nibble.
inline constexpr uint8_t kCmdNop = 0x00;
inline constexpr uint8_t kCmdStartBurst = 0x10;
inline constexpr uint8_t kCmdStartWakeOnChange = 0x20;
inline constexpr uint8_t kCmdStartSingle = 0x30;
inline constexpr uint8_t kCmdReadMeasurement = 0x40;
inline constexpr uint8_t kCmdReadRegister = 0x50;
inline constexpr uint8_t kCmdWriteRegister = 0x60;
inline constexpr uint8_t kCmdExit = 0x80;
inline constexpr uint8_t kCmdMemoryRecall = 0xD0;
inline constexpr uint8_t kCmdMemoryStore = 0xE0;
inline constexpr uint8_t kCmdReset = 0xF0;

// Axis selection nibble (zyxt).
inline constexpr uint8_t kAxisT = 0x1;
inline constexpr uint8_t kAxisX = 0x2;
inline constexpr uint8_t kAxisY = 0x4;
inline constexpr uint8_t kAxisZ = 0x8;
inline constexpr uint8_t kAxesXyz = kAxisX | kAxisY | kAxisZ;

// Status byte.
inline constexpr uint8_t kStatusBurstMode = 1u << 7;
inline constexpr uint8_t kStatusWocMode = 1u << 6;
inline constexpr uint8_t kStatusSmMode = 1u << 5;
inline constexpr uint8_t kStatusError = 1u << 4;  // command rejected / measurement not available
inline constexpr uint8_t kStatusSed = 1u << 3;    // single-bit memory error corrected
inline constexpr uint8_t kStatusReset = 1u << 2;  // RS: first status after power-on or RT
inline constexpr uint8_t kStatusDataMask = 0x03;  // D1 D0: response data bytes = 2 + 2 * D
                                                  // (RM: the bytes that follow the status)

// Response data bytes the status's D bits announce.
constexpr int status_data_bytes(uint8_t status) {
  return 2 + 2 * (status & kStatusDataMask);
}
// Data bytes an RM of `axes` returns (2 per selected axis).
constexpr int measurement_bytes(uint8_t axes) {
  return 2 * (((axes >> 0) & 1) + ((axes >> 1) & 1) + ((axes >> 2) & 1) + ((axes >> 3) & 1));
}

// Volatile registers (the address goes on the wire shifted left by 2).
inline constexpr uint8_t kRegConf1 = 0x00;  // BIST | Z_SERIES | GAIN_SEL | HALLCONF
inline constexpr uint8_t kRegConf2 = 0x01;  // TRIG_INT | COMM_MODE | WOC_DIFF | EXT_TRG | TCMP_EN
                                            // | BURST_SEL | BURST_DATA_RATE
inline constexpr uint8_t kRegConf3 = 0x02;  // OSR2 | RES_Z | RES_Y | RES_X | DIG_FILT | OSR
inline constexpr uint8_t kRegSensTc = 0x03;
inline constexpr uint8_t kRegOffsetX = 0x04;
inline constexpr uint8_t kRegOffsetY = 0x05;
inline constexpr uint8_t kRegOffsetZ = 0x06;
inline constexpr uint8_t kRegWoXy = 0x07;
inline constexpr uint8_t kRegWoZ = 0x08;
inline constexpr uint8_t kRegWoT = 0x09;
inline constexpr uint8_t kRegCount = 0x20;  // customer area 0x00..0x1F

// Register 0x00.
inline constexpr int kHallconfShift = 0;  // 4 bits; 0xC is the default and the only one used
inline constexpr int kGainSelShift = 4;   // 3 bits
inline constexpr int kZSeriesBit = 7;
inline constexpr int kBistBit = 8;
inline constexpr uint16_t kHallconfDefault = 0xC;
// Register 0x01.
inline constexpr int kBurstDataRateShift = 0;  // 6 bits, in steps of kBurstDataRateStepUs
inline constexpr int kBurstSelShift = 6;       // 4 bits, zyxt
inline constexpr int kTcmpEnBit = 10;
inline constexpr int kExtTrgBit = 11;
inline constexpr int kWocDiffBit = 12;
inline constexpr int kCommModeShift = 13;  // 2 bits: 0/1 both, 2 SPI only, 3 I2C only
inline constexpr int kTrigIntBit = 15;     // 1: the INT/TRIG pin is the data-ready output
// Register 0x02.
inline constexpr int kOsrShift = 0;      // 2 bits
inline constexpr int kDigFiltShift = 2;  // 3 bits
inline constexpr int kResXShift = 5;     // 2 bits
inline constexpr int kResYShift = 7;     // 2 bits
inline constexpr int kResZShift = 9;     // 2 bits
inline constexpr int kOsr2Shift = 11;    // 2 bits (temperature oversampling)

// Power-on defaults of the volatile registers used here (the chip copies them from its
// non-volatile memory at power-on and on RT).
inline constexpr uint16_t kDefaultConf1 = 0x007C;  // GAIN_SEL 7, HALLCONF 0xC
inline constexpr uint16_t kDefaultConf2 = 0x0000;
inline constexpr uint16_t kDefaultConf3 = 0x0000;  // OSR 0, DIG_FILT 0, RES 0

// BURST_DATA_RATE unit: in burst mode a conversion starts every BURST_DATA_RATE * 20 ms, or
// back to back when it takes longer.
inline constexpr uint32_t kBurstDataRateStepUs = 20000;

// Time the chip needs after RT before it answers again, microseconds (datasheet: tPOR-like).
inline constexpr uint32_t kResetTimeUs = 1500;

}  // namespace skinbus::mlx90393
