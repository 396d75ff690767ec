// FakeGpioChip: in-memory lines for tests and the simulated patch.
//
// Every offset has one LineState, shared (shared_ptr) by the chip and the GpioOutput/GpioInput
// holding it, so the test side (level, drive, fail_next) and the daemon side see the same line.
// A per-line mutex lets a simulator thread drive inputs while the daemon thread reads them.
#include <sys/eventfd.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <mutex>
#include <utility>

#include "skinbus/patch_sim/fake_gpio.h"

namespace skinbus::patch_sim {

using patch_fw::GpioEdge;
using patch_fw::GpioEvent;
using patch_fw::GpioInput;
using patch_fw::GpioInputRequest;
using patch_fw::GpioOutput;
using patch_fw::GpioOutputRequest;

struct FakeGpioChip::LineState {
  std::mutex mutex;
  bool level = false;  // physical level
  int transitions = 0;
  bool requested = false;
  std::string consumer;
  bool fail_next = false;
  // Input request settings (valid while an input holds the line).
  bool active_low = false;
  bool rising = false;
  bool falling = false;
  std::deque<GpioEvent> events;
  int event_fd = -1;  // EFD_SEMAPHORE: its counter equals events.size()
};

namespace {

using LineState = FakeGpioChip::LineState;

std::string line_text(unsigned offset, const std::string& chip) {
  return "line " + std::to_string(offset) + " of " + chip;
}

// Consumes an injected failure (call with the line's mutex held).
Status take_injected_failure(LineState& s, unsigned offset, const std::string& chip) {
  if (!s.fail_next) return Status::Ok();
  s.fail_next = false;
  return make_error(ErrorCode::kIo, line_text(offset, chip) + ": I/O error (injected)");
}

// Frees the line for the next request (call with the line's mutex held).
void release(LineState& s) {
  s.requested = false;
  s.consumer.clear();
  s.events.clear();
  s.rising = s.falling = s.active_low = false;
  if (s.event_fd >= 0) ::close(s.event_fd);
  s.event_fd = -1;
}

class FakeOutput final : public GpioOutput {
 public:
  FakeOutput(std::shared_ptr<LineState> state, unsigned offset, std::string chip, bool active_low)
      : state_(std::move(state)),
        offset_(offset),
        chip_(std::move(chip)),
        active_low_(active_low) {}
  ~FakeOutput() override {
    std::lock_guard lock(state_->mutex);
    release(*state_);
  }

  Status set(bool active) override {
    std::lock_guard lock(state_->mutex);
    if (Status s = take_injected_failure(*state_, offset_, chip_); !s) return s;
    const bool level = active != active_low_;
    if (level != state_->level) ++state_->transitions;
    state_->level = level;
    return Status::Ok();
  }

 private:
  std::shared_ptr<LineState> state_;
  unsigned offset_;
  std::string chip_;
  bool active_low_;
};

class FakeInput final : public GpioInput {
 public:
  FakeInput(std::shared_ptr<LineState> state, unsigned offset, std::string chip)
      : state_(std::move(state)), offset_(offset), chip_(std::move(chip)) {}
  ~FakeInput() override {
    std::lock_guard lock(state_->mutex);
    release(*state_);
  }

  Result<bool> get() override {
    std::lock_guard lock(state_->mutex);
    if (Status s = take_injected_failure(*state_, offset_, chip_); !s) return s.error();
    return state_->level != state_->active_low;
  }

  // Never blocks: `timeout_us` is ignored and the call returns at once.
  Result<bool> wait_event(uint64_t /*timeout_us*/, GpioEvent* event) override {
    std::lock_guard lock(state_->mutex);
    if (Status s = take_injected_failure(*state_, offset_, chip_); !s) return s.error();
    if (!state_->rising && !state_->falling) {
      return make_error(ErrorCode::kInvalidArgument,
                        line_text(offset_, chip_) + ": wait_event on an input without edges");
    }
    if (state_->events.empty()) return false;
    uint64_t one = 0;  // keep the eventfd counter equal to the queue length
    if (::read(state_->event_fd, &one, sizeof one) != static_cast<ssize_t>(sizeof one)) {
      return make_error(ErrorCode::kInternal,
                        line_text(offset_, chip_) + ": eventfd out of step with the queue");
    }
    if (event != nullptr) *event = state_->events.front();
    state_->events.pop_front();
    return true;
  }

  int event_fd() const override {
    std::lock_guard lock(state_->mutex);
    return state_->event_fd;
  }

 private:
  std::shared_ptr<LineState> state_;
  unsigned offset_;
  std::string chip_;
};

}  // namespace

FakeGpioChip::FakeGpioChip(std::string name, unsigned lines)
    : name_(std::move(name)), lines_(lines) {
  for (unsigned i = 0; i < lines_; ++i) state_.emplace(i, std::make_shared<LineState>());
}

// Lines still requested keep their LineState alive (shared_ptr) and release it themselves.
FakeGpioChip::~FakeGpioChip() = default;

namespace {

// Claims `offset` for `consumer` (call with the line's mutex held).
Status claim(LineState& s, unsigned offset, const std::string& chip, std::string_view consumer) {
  if (s.requested) {
    return make_error(ErrorCode::kUnavailable,
                      line_text(offset, chip) + " is busy: held by \"" + s.consumer + "\"");
  }
  s.requested = true;
  s.consumer = std::string(consumer);
  return Status::Ok();
}

Error out_of_range(unsigned offset, const std::string& chip, unsigned lines) {
  return make_error(ErrorCode::kOutOfRange,
                    line_text(offset, chip) + ": the chip has " + std::to_string(lines) + " lines");
}

}  // namespace

Result<std::unique_ptr<GpioOutput>> FakeGpioChip::request_output(const GpioOutputRequest& request,
                                                                 std::string_view consumer) {
  if (request.offset >= lines_) return out_of_range(request.offset, name_, lines_);
  const std::shared_ptr<LineState>& s = state_.at(request.offset);
  std::lock_guard lock(s->mutex);
  if (Status st = claim(*s, request.offset, name_, consumer); !st) return st.error();
  s->level = request.initial != request.active_low;  // not counted as a transition
  return std::unique_ptr<GpioOutput>(
      std::make_unique<FakeOutput>(s, request.offset, name_, request.active_low));
}

Result<std::unique_ptr<GpioInput>> FakeGpioChip::request_input(const GpioInputRequest& request,
                                                               std::string_view consumer) {
  if (request.offset >= lines_) return out_of_range(request.offset, name_, lines_);
  const std::shared_ptr<LineState>& s = state_.at(request.offset);
  std::lock_guard lock(s->mutex);
  int fd = -1;
  if (request.rising || request.falling) {
    fd = ::eventfd(0, EFD_NONBLOCK | EFD_SEMAPHORE | EFD_CLOEXEC);
    if (fd < 0) {
      return make_error(ErrorCode::kIo,
                        line_text(request.offset, name_) + ": eventfd: " + std::strerror(errno));
    }
  }
  if (Status st = claim(*s, request.offset, name_, consumer); !st) {
    if (fd >= 0) ::close(fd);
    return st.error();
  }
  s->active_low = request.active_low;
  s->rising = request.rising;
  s->falling = request.falling;
  s->event_fd = fd;
  return std::unique_ptr<GpioInput>(std::make_unique<FakeInput>(s, request.offset, name_));
}

bool FakeGpioChip::level(unsigned offset) const {
  if (offset >= lines_) return false;
  const std::shared_ptr<LineState>& s = state_.at(offset);
  std::lock_guard lock(s->mutex);
  return s->level;
}

int FakeGpioChip::transitions(unsigned offset) const {
  if (offset >= lines_) return 0;
  const std::shared_ptr<LineState>& s = state_.at(offset);
  std::lock_guard lock(s->mutex);
  return s->transitions;
}

std::string FakeGpioChip::consumer(unsigned offset) const {
  if (offset >= lines_) return "";
  const std::shared_ptr<LineState>& s = state_.at(offset);
  std::lock_guard lock(s->mutex);
  return s->requested ? s->consumer : "";
}

void FakeGpioChip::drive(unsigned offset, bool level, uint64_t timestamp_us) {
  if (offset >= lines_) return;
  const std::shared_ptr<LineState>& s = state_.at(offset);
  std::lock_guard lock(s->mutex);
  if (level == s->level) return;  // no edge
  s->level = level;
  if (!s->requested || s->event_fd < 0) return;
  const bool rising = level != s->active_low;  // logical edge, as the kernel reports it
  if (rising ? !s->rising : !s->falling) return;
  s->events.push_back({rising ? GpioEdge::kRising : GpioEdge::kFalling, timestamp_us});
  const uint64_t one = 1;
  // Cannot fail short of 2^64 - 2 pending events; the queue would exhaust memory first.
  [[maybe_unused]] const ssize_t n = ::write(s->event_fd, &one, sizeof one);
}

void FakeGpioChip::fail_next(unsigned offset) {
  if (offset >= lines_) return;
  const std::shared_ptr<LineState>& s = state_.at(offset);
  std::lock_guard lock(s->mutex);
  s->fail_next = true;
}

}  // namespace skinbus::patch_sim
