// skinbus/bus/budget.h: how much of a CAN bus the skin uses.
//
// Frame times use the worst case of bit stuffing (one stuff bit per four bits of the stuffed
// region), so loads here are upper bounds; real traffic with random data is ~10% lower.
// CAN FD frames are timed with the arbitration phase (and ACK, EOF, IFS) at the nominal bit
// rate and the data phase (ESI, DLC, data, stuff count, CRC) at the data bit rate.
// The frame sizes come from encoding real messages (skinbus/bus/codec.h), not from a copy of
// the protocol tables.
#pragma once

#include <cstddef>
#include <cstdint>

#include "skinbus/bus/protocol.h"

namespace skinbus::bus {

struct BusTiming {
  bool fd = true;
  double nominal_bps = 1e6;  // arbitration bit rate
  double data_bps = 5e6;     // CAN FD data-phase bit rate (ignored for classic)
};

// Worst-case time on the wire of one frame with `len` data bytes and an 11-bit identifier,
// including the 3-bit interframe space.
double frame_time_us(const BusTiming& timing, std::size_t len);

struct PatchTraffic {
  double sample_rate_hz = 41.7;
  double active_fraction = 1.0;  // share of time a patch streams samples (event mode: touched)
  double heartbeat_hz = 1.0;
};

struct BudgetResult {
  double sample_frames = 0;      // frames per sample message
  double sample_time_us = 0;     // wire time of one sample message
  double heartbeat_time_us = 0;  // wire time of one heartbeat
  double frames_per_s_per_patch = 0;
  double load_per_patch = 0;         // fraction of the bus, 0..1
  double load_total = 0;             // for `patches`
  int max_patches = 0;               // patches that fit under `load_limit` (capped at kNodeMax)
  double full_bus_frames_per_s = 0;  // a bus filled with 64-byte (FD) or 8-byte frames
};

// Bus load of `patches` patches with the given traffic. `load_limit` (0..1] sets max_patches.
BudgetResult compute_budget(const BusTiming& timing, const PatchTraffic& traffic, int patches,
                            double load_limit);

}  // namespace skinbus::bus
