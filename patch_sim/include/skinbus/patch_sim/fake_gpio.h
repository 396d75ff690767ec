// skinbus/patch_sim/fake_gpio.h: an in-memory GPIO chip behind the patch node's GPIO interface
// (skinbus/patch_fw/gpio.h), for tests and the simulated patch.
//
// Lines requested from it share state with the chip (a per-line mutex lets a simulator thread
// drive lines the daemon reads). Errors mirror libgpiod's: kOutOfRange, kUnavailable naming the
// holder, kIo from fail_next. Lines start low and free; a requested output takes its initial
// level at once. Lines hold the shared state, so destroying the chip before them is safe (they
// just stop being observable). Inputs never block: wait_event returns at once whatever its
// timeout says; event_fd() polls readable exactly while events are queued.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <string>
#include <string_view>

#include "skinbus/common/result.h"
#include "skinbus/patch_fw/gpio.h"

namespace skinbus::patch_sim {

class FakeGpioChip final : public patch_fw::GpioChip {
 public:
  explicit FakeGpioChip(std::string name = "fake-gpiochip", unsigned lines = 32);
  ~FakeGpioChip() override;

  Result<std::unique_ptr<patch_fw::GpioOutput>> request_output(
      const patch_fw::GpioOutputRequest& request, std::string_view consumer) override;
  Result<std::unique_ptr<patch_fw::GpioInput>> request_input(
      const patch_fw::GpioInputRequest& request, std::string_view consumer) override;
  std::string_view name() const override { return name_; }
  unsigned line_count() const override { return lines_; }

  // Test side. Offsets past the chip are ignored (read as low, 0 and "").
  // Physical level of a line (before active-low inversion).
  bool level(unsigned offset) const;
  // Number of times set() changed an output line's physical level (the initial level applied
  // at request does not count), summed over every request of the line.
  int transitions(unsigned offset) const;
  // Who holds the line ("" if free).
  std::string consumer(unsigned offset) const;
  // Sets a line's physical level. On an input that asked for the resulting logical edge, queues
  // a GpioEvent stamped `timestamp_us` (no edge when the level does not change).
  void drive(unsigned offset, bool level, uint64_t timestamp_us = 0);
  // Makes the next set/get/wait_event on a line fail with kIo ("line N of <chip>: I/O error
  // (injected)"), as a chip that went away would; a pending event stays queued.
  void fail_next(unsigned offset);

  struct LineState;  // internal

 private:
  std::string name_;
  unsigned lines_;
  std::map<unsigned, std::shared_ptr<LineState>> state_;
};

}  // namespace skinbus::patch_sim
