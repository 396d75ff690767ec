// skinbus/bus/socketcan.h: Linux SocketCAN raw sockets, classic and CAN FD.
//
// One SocketCanPort is one non-blocking CAN_RAW socket bound to one interface. CanPoller waits
// on several ports with epoll. Nothing here blocks unless a timeout is passed.
//
// What the kernel reports is surfaced, never swallowed:
//  * error frames (bus-off, error passive/warning, restarted, protocol and ack errors) are
//    decoded into BusErrorEvent and counted in PortStats;
//  * frames the kernel dropped because the receive queue overflowed (SO_RXQ_OVFL) are counted;
//  * a send that finds the kernel queue full (ENOBUFS / EAGAIN) is kept in a bounded transmit
//    queue and retried when the socket is writable; a frame that finds that queue full too is
//    dropped and counted (tx_dropped), and send() says so.
// Receive timestamps come from SO_TIMESTAMPING (hardware if the driver gives one, else the
// kernel's software stamp), else SO_TIMESTAMP, else the clock read after recvmsg.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "skinbus/bus/can_frame.h"
#include "skinbus/bus/protocol.h"
#include "skinbus/common/result.h"

namespace skinbus::bus {

// A kernel receive filter: a frame passes if (frame_id & mask) == (id & mask).
struct CanIdFilter {
  uint32_t id = 0;
  uint32_t mask = 0;
};
// The filters `candump can0,<id>:<mask>` would use for one patch or one message class.
constexpr CanIdFilter filter_for_node(uint8_t node) {
  return {node, kNodeMask};
}
constexpr CanIdFilter filter_for_class(MessageClass c) {
  return {make_can_id(c, 0), kClassMask};
}

struct SocketCanOptions {
  bool fd = true;                    // accept and send CAN FD frames if the interface MTU allows
  std::vector<CanIdFilter> filters;  // empty: every standard frame (extended frames too)
  bool error_frames = true;          // receive controller error frames
  bool receive_own = false;          // also receive frames this socket sent (CAN_RAW_RECV_OWN_MSGS)
  std::size_t tx_queue_frames = 256;  // bounded queue behind a full kernel queue
  int rcvbuf_bytes = 0;               // SO_RCVBUF; 0 keeps the kernel default
};

enum class TimestampSource : uint8_t { kHardware, kKernelSoftware, kUserspace };

struct RxMeta {
  uint64_t timestamp_us = 0;  // CLOCK_REALTIME microseconds
  TimestampSource source = TimestampSource::kUserspace;
};

// A controller event decoded from a SocketCAN error frame (<linux/can/error.h>).
struct BusErrorEvent {
  bool bus_off = false;
  bool error_passive = false;  // rx or tx error counter >= 128
  bool error_warning = false;  // rx or tx error counter >= 96
  bool restarted = false;      // controller restarted after bus-off
  bool rx_overflow = false;    // controller receive buffer overflow
  bool tx_timeout = false;
  bool lost_arbitration = false;
  bool protocol_violation = false;
  bool no_ack = false;  // nobody acknowledged (alone on the bus?)
  bool transceiver = false;
  uint8_t tx_error_count = 0;  // when the driver reports counters (CAN_ERR_CNT)
  uint8_t rx_error_count = 0;
};
// Decodes an error frame (frame.error must be true). Pure: testable without a kernel.
BusErrorEvent decode_error_frame(const CanFrame& frame);
// "bus-off, error-passive, tx=130 rx=0": for logs.
std::string describe_bus_error(const BusErrorEvent& e);

struct PortStats {
  uint64_t rx_frames = 0;
  uint64_t tx_frames = 0;        // accepted by the kernel
  uint64_t tx_queued = 0;        // sends that had to wait in the transmit queue
  uint64_t tx_dropped = 0;       // frames not sent: transmit queue full, or a write error
  uint64_t rx_kernel_drops = 0;  // frames the kernel dropped (SO_RXQ_OVFL)
  uint64_t error_frames = 0;
  uint64_t bus_off = 0;
  uint64_t error_passive = 0;
  uint64_t restarted = 0;
};

class SocketCanPort {
 public:
  // Opens and binds a raw socket on `ifname`. Errors name the interface and say what to do:
  // kUnsupported when the kernel has no CAN, kNotFound when the interface does not exist.
  static Result<std::unique_ptr<SocketCanPort>> open(std::string_view ifname,
                                                     const SocketCanOptions& options);
  // For tests of the transmit queue on machines without CAN: wraps an open, non-blocking
  // datagram socket (one end of a socketpair) that stands in for a CAN_RAW socket; frames are
  // written as the kernel's can_frame / canfd_frame records. Takes ownership of `fd`.
  static std::unique_ptr<SocketCanPort> adopt_for_testing(int fd, std::string name, bool fd_enabled,
                                                          std::size_t tx_queue_frames);
  ~SocketCanPort();
  SocketCanPort(const SocketCanPort&) = delete;
  SocketCanPort& operator=(const SocketCanPort&) = delete;

  int fd() const { return fd_; }
  const std::string& name() const { return name_; }
  bool fd_enabled() const { return fd_enabled_; }  // interface MTU is CAN FD and FD was asked for
  int ifindex() const { return ifindex_; }

  // Sends without blocking; see the header comment for the queue. kUnsupported for an FD frame
  // on a classic socket; kUnavailable when the frame had to be dropped (queue full).
  Status send(const CanFrame& frame);
  // Sends, waiting up to `timeout_ms` for room in the kernel queue.
  Status send_blocking(const CanFrame& frame, int timeout_ms);
  // Moves queued frames to the kernel until it is full again. Returns frames still queued.
  std::size_t flush();
  std::size_t queued() const { return tx_count_; }
  // The last error of a queued frame that flush() could not send (counted in tx_dropped), once:
  // true and `*error` set if there was one since the last call. CanPoller reports these.
  bool take_tx_error(Error* error);

  enum class RecvStatus { kFrame, kNoFrame, kError };
  // Reads one frame if one is waiting. kError: `error()` says what (e.g. interface down).
  RecvStatus receive(CanFrame* frame, RxMeta* meta);
  const Error& error() const { return error_; }
  // Error frames are returned as frames (frame.error) and also counted here.

  const PortStats& stats() const { return stats_; }

 private:
  SocketCanPort() = default;
  Status write_now(const CanFrame& frame, bool* would_block);

  int fd_ = -1;
  int ifindex_ = 0;
  std::string name_;
  bool fd_enabled_ = false;
  // Transmit queue: a ring of tx_limit_ frames allocated at open(); sending never allocates.
  std::vector<CanFrame> tx_ring_;
  std::size_t tx_limit_ = 0, tx_head_ = 0, tx_count_ = 0;
  bool tx_error_pending_ = false;
  Error tx_error_;
  uint32_t last_drop_counter_ = 0;
  Error error_;
  PortStats stats_;
};

// Waits on several ports at once.
class CanPoller {
 public:
  CanPoller();
  ~CanPoller();
  CanPoller(const CanPoller&) = delete;
  CanPoller& operator=(const CanPoller&) = delete;

  Status add(SocketCanPort* port);  // not owned; must outlive the poller

  using FrameHandler =
      std::function<void(SocketCanPort& port, const CanFrame& frame, const RxMeta& meta)>;
  using ErrorHandler = std::function<void(SocketCanPort& port, const Error& error)>;
  // Waits up to `timeout_ms` (-1: forever) for traffic, delivers every frame waiting on every
  // ready port, and flushes transmit queues. Returns the number of frames delivered.
  Result<std::size_t> poll(int timeout_ms, const FrameHandler& on_frame,
                           const ErrorHandler& on_error);

 private:
  int epfd_ = -1;
  std::vector<SocketCanPort*> ports_;
};

// Current CLOCK_REALTIME in microseconds (the clock of kernel receive timestamps).
uint64_t realtime_now_us();
// Current CLOCK_MONOTONIC in microseconds.
uint64_t monotonic_now_us();

}  // namespace skinbus::bus
