// skinbus/patch_fw/gpio.h: the patch node's GPIO lines behind a small interface.
//
// The node uses four kinds of line: data-ready inputs from the sensors (rising edge when a
// conversion is done), the multiplexer's active-low reset output, the identify LED output and a
// SYNC input (rising edge = take a sample now). The back end for boards is libgpiod 1.6 (the C++
// bindings Debian bookworm ships, gpio_gpiod.cc); a v2 back end implements the same interface.
// Tests and the simulated patch use patch_sim::FakeGpioChip (skinbus/patch_sim/fake_gpio.h),
// which records outputs and lets a test drive inputs and inject edges.
//
// Errors name the line as "line N of <chip>". No exception leaves these classes: the libgpiod
// bindings' exceptions are caught and returned as kIo (kUnavailable for EBUSY).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"

namespace skinbus::patch_fw {

enum class GpioEdge : uint8_t { kRising, kFalling };

struct GpioEvent {
  GpioEdge edge = GpioEdge::kRising;
  uint64_t timestamp_us = 0;  // the back end's clock (libgpiod 1.6: CLOCK_MONOTONIC)
};

class GpioOutput {
 public:
  virtual ~GpioOutput() = default;
  virtual Status set(bool active) = 0;  // active = logical 1 (after any active-low inversion)
};

class GpioInput {
 public:
  virtual ~GpioInput() = default;
  virtual Result<bool> get() = 0;  // the logical value (after any active-low inversion)
  // Waits up to `timeout_us` for an edge; false when none came (0 polls). Reads (consumes) one
  // event into `*event` (may be null). kInvalidArgument if the request asked for no edges.
  virtual Result<bool> wait_event(uint64_t timeout_us, GpioEvent* event) = 0;
  // A file descriptor that polls readable while an event is pending (-1 when the request asked
  // for no edges), so the daemon can wait on CAN and GPIO at once. Owned by the input: valid
  // until it is destroyed. Read events with wait_event, not from the descriptor.
  virtual int event_fd() const = 0;
};

struct GpioOutputRequest {
  unsigned offset = 0;
  bool active_low = false;
  bool initial = false;  // logical initial value
};
struct GpioInputRequest {
  unsigned offset = 0;
  bool active_low = false;
  bool rising = true;  // report rising edges (logical, i.e. after active-low inversion)
  bool falling = false;
};

// A GPIO chip the lines are requested from. Requests name their consumer (shown by gpioinfo).
// A line stays held until its GpioOutput/GpioInput is destroyed; then it can be requested again.
class GpioChip {
 public:
  virtual ~GpioChip() = default;
  virtual Result<std::unique_ptr<GpioOutput>> request_output(const GpioOutputRequest& request,
                                                             std::string_view consumer) = 0;
  virtual Result<std::unique_ptr<GpioInput>> request_input(const GpioInputRequest& request,
                                                           std::string_view consumer) = 0;
  virtual std::string_view name() const = 0;
  virtual unsigned line_count() const = 0;
};

// Opens a chip through libgpiod ("gpiochip0" or "/dev/gpiochip0"; a name without '/' is looked
// up in /dev). kNotFound when it does not exist or is not a GPIO chip, kIo when it cannot be
// opened (permissions), kInvalidArgument for an empty name. Requests fail with kOutOfRange for
// an offset past the chip's lines and kUnavailable when the line is held (by another process,
// or already by this chip), naming the holder when the kernel reports one. name() is the
// kernel's name ("gpiochip0"). Lines keep the chip open, so they may outlive the GpioChip.
// Event timestamps are CLOCK_MONOTONIC on kernels >= 5.7 (CLOCK_REALTIME before).
Result<std::unique_ptr<GpioChip>> open_gpiod_chip(std::string_view name);

}  // namespace skinbus::patch_fw
