// skinbus/view/field_tap.h: the patches' own field readings for the web view's sensor panel,
// taken from the bus: the sample messages of every patch (tared on the patch: each channel is the
// field change since its baseline), as `fields` messages (docs/view.md):
//
//   {"type":"fields","stamp_us":...,"interface":"can0","node":3,"tared":true,
//    "field_ut":[48 values, sensor-major x,y,z in each chip's axes, uT; null: faulty sensor],
//    "saturated":[sensor indices]}
//
// Only what a page would show: a patch's fields are sent while any channel's change reaches
// `show_ut` (a press, not noise), at most `max_rate_hz` per patch, and once more when it falls
// back below (so the page clears it). Idle patches cost one comparison per sample.
//
// feed() and take_updates() may be called from different threads (a reader thread and the
// server's loop); both lock one mutex.
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/reassembler.h"

namespace skinbus::view {

struct FieldTapOptions {
  double show_ut = 5.0;     // a patch is shown while some channel's change is at least this
  double max_rate_hz = 10;  // fields messages per patch per second, at most
  int max_interfaces = 16;  // buses kept apart (frames of more are ignored, counted)
};

struct FieldTapStats {
  uint64_t frames = 0;         // fed
  uint64_t samples = 0;        // sample messages reassembled
  uint64_t rejected = 0;       // frames the reassembler rejected (not skinbus, corrupt)
  uint64_t updates = 0;        // fields messages produced
  uint64_t ignored_buses = 0;  // frames of interfaces past max_interfaces
};

class FieldTap {
 public:
  explicit FieldTap(const FieldTapOptions& options = {});

  // One received frame, its host receive time (us) and the bus it came from.
  void feed(const bus::CanFrame& frame, uint64_t rx_us, std::string_view iface);
  // The fields messages due at `now_us` (appended to *out, one JSON line each).
  void take_updates(uint64_t now_us, std::vector<std::string>* out);
  FieldTapStats stats() const;

 private:
  struct Patch {
    std::string json;    // the latest sample as a fields message
    bool fresh = false;  // a sample arrived since the last update
    bool shown = false;  // the page shows it (the last update was at or above show_ut)
    bool above = false;  // the latest sample is at or above show_ut
    uint64_t last_sent_us = 0;
  };
  FieldTapOptions options_;
  mutable std::mutex mutex_;
  std::map<std::string, std::unique_ptr<bus::Reassembler>, std::less<>> reassemblers_;
  std::map<std::tuple<std::string, int>, Patch> patches_;
  FieldTapStats stats_;
};

}  // namespace skinbus::view
