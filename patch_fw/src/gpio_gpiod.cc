// The libgpiod 1.6 back end (C++ bindings, Debian bookworm's libgpiod-dev).
//
// The bindings report failures by throwing (std::system_error with errno, std::logic_error,
// std::bad_alloc); every call into them is wrapped so that only Status/Result leave this file.
#include <sys/stat.h>

#include <algorithm>
#include <bitset>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <exception>
#include <gpiod.hpp>
#include <limits>
#include <system_error>
#include <utility>

#include "skinbus/patch_fw/gpio.h"

namespace skinbus::patch_fw {

namespace {

std::string line_text(unsigned offset, const std::string& chip) {
  return "line " + std::to_string(offset) + " of " + chip;
}

// Converts the exception being handled into an Error whose message starts with `what`.
// EBUSY (the line is held) maps to kUnavailable, everything else to kIo.
Error current_exception_error(const std::string& what) {
  try {
    throw;
  } catch (const std::system_error& e) {
    const ErrorCode code = e.code().value() == EBUSY ? ErrorCode::kUnavailable : ErrorCode::kIo;
    return make_error(code, what + ": " + e.what());
  } catch (const std::exception& e) {
    return make_error(ErrorCode::kIo, what + ": " + e.what());
  } catch (...) {
    return make_error(ErrorCode::kInternal, what + ": unknown exception from libgpiod");
  }
}

// Releases the line, swallowing errors (used in destructors).
void release_quietly(gpiod::line& line) noexcept {
  try {
    if (line.is_requested()) line.release();
  } catch (...) {  // nothing sensible to do when releasing fails
  }
}

class GpiodOutput final : public GpioOutput {
 public:
  GpiodOutput(gpiod::line line, std::string text)
      : line_(std::move(line)), text_(std::move(text)) {}
  ~GpiodOutput() override { release_quietly(line_); }

  Status set(bool active) override {
    try {
      line_.set_value(active ? 1 : 0);
      return Status::Ok();
    } catch (...) {
      return current_exception_error(text_ + ": set");
    }
  }

 private:
  gpiod::line line_;  // holds a reference to the chip, so the chip stays open
  std::string text_;  // "line N of gpiochipM"
};

class GpiodInput final : public GpioInput {
 public:
  GpiodInput(gpiod::line line, std::string text, int fd)
      : line_(std::move(line)), text_(std::move(text)), fd_(fd) {}
  ~GpiodInput() override { release_quietly(line_); }

  Result<bool> get() override {
    try {
      return line_.get_value() != 0;
    } catch (...) {
      return current_exception_error(text_ + ": get");
    }
  }

  Result<bool> wait_event(uint64_t timeout_us, GpioEvent* event) override {
    if (fd_ < 0) {
      return make_error(ErrorCode::kInvalidArgument,
                        text_ + ": wait_event on an input without edges");
    }
    // Clamp so that the nanosecond count fits the int64 of std::chrono::nanoseconds.
    constexpr uint64_t kMaxTimeoutUs =
        static_cast<uint64_t>(std::numeric_limits<int64_t>::max() / 1000);
    const auto timeout =
        std::chrono::microseconds(static_cast<int64_t>(std::min(timeout_us, kMaxTimeoutUs)));
    try {
      if (!line_.event_wait(timeout)) return false;
      const gpiod::line_event e = line_.event_read();
      if (event != nullptr) {
        event->edge =
            e.event_type == gpiod::line_event::RISING_EDGE ? GpioEdge::kRising : GpioEdge::kFalling;
        const int64_t us =
            std::chrono::duration_cast<std::chrono::microseconds>(e.timestamp).count();
        event->timestamp_us = us > 0 ? static_cast<uint64_t>(us) : 0;
      }
      return true;
    } catch (...) {
      return current_exception_error(text_ + ": wait_event");
    }
  }

  int event_fd() const override { return fd_; }

 private:
  gpiod::line line_;
  std::string text_;
  int fd_;  // the line's event fd, -1 when no edges were requested
};

class GpiodChip final : public GpioChip {
 public:
  GpiodChip(gpiod::chip chip, std::string name, unsigned lines)
      : chip_(std::move(chip)), name_(std::move(name)), lines_(lines) {}

  Result<std::unique_ptr<GpioOutput>> request_output(const GpioOutputRequest& request,
                                                     std::string_view consumer) override {
    gpiod::line_request config{
        std::string(consumer), gpiod::line_request::DIRECTION_OUTPUT,
        request.active_low ? gpiod::line_request::FLAG_ACTIVE_LOW : std::bitset<32>()};
    Result<gpiod::line> line = request_line(request.offset, config, request.initial ? 1 : 0);
    if (!line) return line.error();
    return std::unique_ptr<GpioOutput>(
        std::make_unique<GpiodOutput>(std::move(*line), line_text(request.offset, name_)));
  }

  Result<std::unique_ptr<GpioInput>> request_input(const GpioInputRequest& request,
                                                   std::string_view consumer) override {
    int type = gpiod::line_request::DIRECTION_INPUT;
    if (request.rising && request.falling) {
      type = gpiod::line_request::EVENT_BOTH_EDGES;
    } else if (request.rising) {
      type = gpiod::line_request::EVENT_RISING_EDGE;
    } else if (request.falling) {
      type = gpiod::line_request::EVENT_FALLING_EDGE;
    }
    gpiod::line_request config{
        std::string(consumer), type,
        request.active_low ? gpiod::line_request::FLAG_ACTIVE_LOW : std::bitset<32>()};
    Result<gpiod::line> line = request_line(request.offset, config, 0);
    if (!line) return line.error();
    const std::string text = line_text(request.offset, name_);
    int fd = -1;
    if (type != gpiod::line_request::DIRECTION_INPUT) {
      try {
        fd = line->event_get_fd();
      } catch (...) {
        release_quietly(*line);
        return current_exception_error(text + ": event fd");
      }
    }
    return std::unique_ptr<GpioInput>(std::make_unique<GpiodInput>(std::move(*line), text, fd));
  }

  std::string_view name() const override { return name_; }
  unsigned line_count() const override { return lines_; }

 private:
  // Gets and requests one line; maps "held by someone" to kUnavailable naming the holder.
  Result<gpiod::line> request_line(unsigned offset, const gpiod::line_request& config,
                                   int initial) {
    const std::string text = line_text(offset, name_);
    if (offset >= lines_) {
      return make_error(ErrorCode::kOutOfRange,
                        text + ": the chip has " + std::to_string(lines_) + " lines");
    }
    gpiod::line line;
    try {
      line = chip_.get_line(offset);
      // libgpiod hands out one line object per offset and chip: requested means requested by
      // this process through this chip.
      if (line.is_requested()) return busy(line, text);
      line.request(config, initial);
      return line;
    } catch (const std::system_error& e) {
      if (e.code().value() == EBUSY && line) return busy(line, text);
      return current_exception_error(text + ": request as \"" + config.consumer + "\"");
    } catch (...) {
      return current_exception_error(text + ": request as \"" + config.consumer + "\"");
    }
  }

  // kUnavailable naming the line's current consumer when the kernel reports one.
  static Error busy(gpiod::line& line, const std::string& text) {
    std::string holder;
    try {
      line.update();
      holder = line.consumer();
    } catch (...) {  // the holder is only decoration for the message
    }
    return make_error(ErrorCode::kUnavailable,
                      text + " is busy" + (holder.empty() ? "" : ": held by \"" + holder + "\""));
  }

  gpiod::chip chip_;
  std::string name_;  // the kernel's name, e.g. "gpiochip0"
  unsigned lines_;
};

}  // namespace

Result<std::unique_ptr<GpioChip>> open_gpiod_chip(std::string_view name) {
  if (name.empty()) return make_error(ErrorCode::kInvalidArgument, "GPIO chip name is empty");
  // A bare name lives in /dev; anything with a slash is a path.
  const std::string given(name);
  const std::string path = given.find('/') == std::string::npos ? "/dev/" + given : given;
  const std::string what = "GPIO chip \"" + given + "\"" + (path == given ? "" : " (" + path + ")");

  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    const int e = errno;
    const ErrorCode code = e == ENOENT || e == ENOTDIR ? ErrorCode::kNotFound : ErrorCode::kIo;
    return make_error(code, what + ": " + std::strerror(e));
  }
  if (!S_ISCHR(st.st_mode)) {
    return make_error(ErrorCode::kNotFound, what + " is not a GPIO character device");
  }
  try {
    gpiod::chip chip(path, gpiod::chip::OPEN_BY_PATH);
    std::string kernel_name = chip.name();
    const unsigned lines = chip.num_lines();
    return std::unique_ptr<GpioChip>(std::make_unique<GpiodChip>(
        std::move(chip), kernel_name.empty() ? given : std::move(kernel_name), lines));
  } catch (const std::system_error& e) {
    // libgpiod checks the device is a GPIO chip: ENODEV/ENOTTY when it is some other device.
    const int code = e.code().value();
    if (code == ENOENT || code == ENODEV || code == ENOTTY) {
      return make_error(ErrorCode::kNotFound, what + " is not a GPIO chip: " + e.what());
    }
    return current_exception_error(what + ": open");
  } catch (...) {
    return current_exception_error(what + ": open");
  }
}

}  // namespace skinbus::patch_fw
