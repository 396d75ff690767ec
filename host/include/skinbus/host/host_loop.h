// skinbus/host/host_loop.h: the host's run loop around an Aggregator: inputs, cadence, sinks.
//
// The aggregator (aggregator.h) is the pipeline; HostLoop is what drives it, for every program
// that runs one (skinbus-host, `skinbus-bench host`, the aggregator's benchmark and fuzz target):
//
//   inputs --frames--> Aggregator::on_frame()
//     - SocketCAN interfaces (bus/socketcan.h), read as they come; an interface that fails is
//       reported (kInterfaceDown) and reopened every second once it is up (kInterfaceUp);
//     - a candump -L log replayed at recorded speed (frames fed when due, stamped with when they
//       were due), or as fast as possible (the log's time is the host's), or read as a live pipe
//       (without blocking, on the host's clock); a log's time that runs backwards or jumps ahead
//       is taken in file order and reported (kLogTime events);
//     - interfaces and a log at recorded speed at once (the log's frames on one more bus).
//   joint states --JointInput::update()--> Aggregator::set_joint_state(), before each process()
//   cadence: after every batch of frames step(): process() -> HostSink::contacts() on a change;
//     tick() every tick_period_us (100 ms); status() -> HostSink::status() every
//     status_period_us (1 s) from the start of the run
//   the end: finish(): held contacts run out (an empty publication), the final status
//
// The tool parses options, builds the aggregator (with bus_names() and on_host_clock() of the
// same options), its sinks (JSON lines, DDS: they live with the tool, host does not link dds)
// and its joint input, and calls run(). A caller with its own frames (a benchmark, a fuzz
// target) feeds aggregator().on_frame() and calls step() and finish(): the same cadence.
//
// Time: host time is CLOCK_REALTIME microseconds (HostClock::now_us; injectable for tests),
// except in a replay as fast as possible, where it is the log's time.
//
// Errors are values: run() returns a Status whose message is a complete line for the log,
// naming the interface or file (an interface that does not open, a log that cannot be opened or
// read, a log none of whose frames is on a named interface, a log mostly out of time order).
// Nothing here throws.
//
// Threading: not thread-safe; run() blocks the calling thread until its inputs end, the
// duration passes or HostClock::stop_requested() answers true (polled at least every 100 ms;
// it may be set from a signal handler or another thread). The sinks are called on that thread.
//
// Ownership: the aggregator, the sink and the joint input are borrowed and must outlive the
// loop. Cost: the loop adds O(frames) reading and parsing, and one poll() wake-up at least every
// 20 ms on live inputs; the pipeline's own cost is the aggregator's.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "skinbus/body_map/joint_trajectory.h"
#include "skinbus/common/result.h"
#include "skinbus/host/aggregator.h"
#include "skinbus/host/contacts.h"

namespace skinbus::host {

// Where the loop's results go. Every call is on the loop's thread; the arguments are valid for
// the call only.
class HostSink {
 public:
  virtual ~HostSink() = default;
  // A publication (the contact set changed; the empty array when the last contact ended).
  // `estimated_rx_us`: the receive times (host clock) of the samples it estimated, for latency
  // figures; empty when the loop runs on a log's time (a fast replay) or flushes at the end.
  virtual void contacts(const ContactArray& contacts,
                        std::span<const uint64_t> estimated_rx_us) = 0;
  // Every patch's status, every status_period_us and at the end, with the events since the
  // previous one in `status.events` (patches, interfaces, log time, lag).
  virtual void status(const PatchStatusArray& status) = 0;
  // A line for the log at the end of a run (lines that could not be parsed, frames of
  // interfaces not named): no prefix, no newline.
  virtual void log(const std::string& line) { (void)line; }
};

// Joint states for the aggregator, fed before every process() of the loop.
class JointInput {
 public:
  virtual ~JointInput() = default;
  // Feeds `agg` the joint states known at host time `now_us` (each at its own stamp);
  // `run_start_us` is the run's time zero.
  virtual void update(Aggregator& agg, uint64_t now_us, uint64_t run_start_us) = 0;
};

// Joint states from a trajectory file (body_map/joint_trajectory.h: time from the start of the
// run): its rows at their own times as the run passes them, then the pose at `now_us` at most
// every 10 ms, so the aggregator's history interpolates exactly as the file does. The caller
// checks the names against the robot (RobotModel::check_joint_names). O(rows passed + joints)
// per update.
class TrajectoryJointInput : public JointInput {
 public:
  explicit TrajectoryJointInput(body_map::JointTrajectory trajectory);
  void update(Aggregator& agg, uint64_t now_us, uint64_t run_start_us) override;

 private:
  body_map::JointTrajectory traj_;
  std::size_t next_row_ = 0;
  uint64_t last_now_us_ = 0;  // when the pose "now" was last fed
  std::vector<double> q_;
};

// The loop's clock and stop request. Defaults: CLOCK_REALTIME, sleeps in slices of at most
// 50 ms, never stopped. Tests inject a clock whose sleep moves its time on.
struct HostClock {
  std::function<uint64_t()> now_us;           // empty: bus::realtime_now_us
  std::function<void(uint64_t us)> sleep_us;  // empty: nanosleep
  std::function<bool()> stop_requested;       // empty: never
};

// How a log (HostLoopOptions::replay) is read.
enum class ReplayPace : uint8_t {
  kRecorded,  // at recorded speed: frames fed when due, on the host's clock
  kFast,      // as fast as possible: the log's time is host time
  kLive,      // a pipe written as it is read: without blocking, on the host's clock
};

struct HostLoopOptions {
  // SocketCAN interfaces, one bus each, in bus order. With a replay alone: the log's interface
  // names in bus order (frames of other names are skipped and reported); none: every frame of
  // the log goes to bus 0.
  std::vector<std::string> interfaces;
  std::string replay;  // a candump -L log ("-": standard input); empty: none
  ReplayPace pace = ReplayPace::kRecorded;
  // With interfaces and a replay: read the interfaces live and replay the log at recorded speed
  // on one more bus named "replay" (else the interfaces name the log's buses).
  bool interfaces_and_replay = false;
  uint64_t duration_us = 0;               // stop after this long (of log time in a replay); 0: none
  uint64_t status_period_us = 1'000'000;  // between status() calls; 0: none (but the final one)
  uint64_t tick_period_us = 100'000;      // between Aggregator::tick() calls
  // At recorded speed, a silence in the log longer than this is replayed as this long.
  uint64_t max_gap_us = 10'000'000;
  HostClock clock;
};

class HostLoop {
 public:
  // The aggregator's bus names for `options`: the interfaces, plus "replay" with
  // interfaces_and_replay, or "can0" for a replay without interface names.
  static std::vector<std::string> bus_names(const HostLoopOptions& options);
  // Whether the run is on the host's clock (AggregatorOptions::clock_us should then be set, so
  // that the lag bound covers the model runs' time): all but a fast replay alone.
  static bool on_host_clock(const HostLoopOptions& options);

  // `aggregator` (created with bus_names(options)) and `sink` are required; `joints` may be
  // null. All three are borrowed.
  HostLoop(Aggregator& aggregator, HostSink& sink, HostLoopOptions options = {},
           JointInput* joints = nullptr);

  // Reads the inputs of the options until they end (a log's end; never for interfaces), the
  // duration passes or a stop is requested, then finish(). Call once. kInvalidArgument for
  // options without an input or a live pipe without a log (or with interfaces); kNotFound / kIo
  // for an interface or log that cannot be opened or read; kInvalidArgument for a log none of
  // whose frames is on a named interface or that is mostly out of time order.
  Status run();

  // For callers with their own frames, and used by run():
  // Starts the run at host time `now_us`: time zero of the joint input, the first status due.
  void start(uint64_t now_us);
  // After a batch of frames (or a quiet wait) at host time `now_us`: joint states, process() and
  // a publication to the sink if the contacts changed, tick() and status() when due. Costs the
  // aggregator's process() (one batched model run per model file with queued samples).
  void step(uint64_t now_us);
  // The end of the run at `end_us`: what is queued, then held contacts run out (an empty
  // publication) and the final status, without advancing the registry's timers past the end.
  void finish(uint64_t end_us);

  Aggregator& aggregator() { return agg_; }
  uint64_t run_start_us() const { return run_start_us_; }

 private:
  Status run_replay();
  Status run_live();
  Status run_live_pipe();
  void publish(uint64_t now_us, bool measured);
  void publish_status(uint64_t now_us);
  uint64_t now_us() const;
  bool sleep_unless_stopped(uint64_t us) const;
  bool stop_requested() const;

  Aggregator& agg_;
  HostSink& sink_;
  HostLoopOptions options_;
  JointInput* joints_;
  uint64_t run_start_us_ = 0, next_status_us_ = 0, next_tick_us_ = 0;
  ContactArray contacts_;
  PatchStatusArray status_;
};

}  // namespace skinbus::host
