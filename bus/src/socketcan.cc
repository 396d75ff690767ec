#include "skinbus/bus/socketcan.h"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <linux/errqueue.h>
#include <linux/net_tstamp.h>
#include <net/if.h>
#include <poll.h>
#include <sys/epoll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace skinbus::bus {

namespace {

Error errno_error(std::string what) {
  const int e = errno;
  ErrorCode code = ErrorCode::kIo;
  if (e == ENODEV || e == ENXIO) code = ErrorCode::kNotFound;
  if (e == ENETDOWN) code = ErrorCode::kUnavailable;
  return make_error(code, what + ": " + std::strerror(e));
}

uint64_t clock_us(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}

void to_kernel(const CanFrame& f, canfd_frame* k) {
  std::memset(k, 0, sizeof *k);
  k->can_id = f.id;
  if (f.extended) k->can_id |= CAN_EFF_FLAG;
  if (f.rtr) k->can_id |= CAN_RTR_FLAG;
  if (f.error) k->can_id |= CAN_ERR_FLAG;
  k->len = f.len;
  if (f.fd) k->flags = static_cast<uint8_t>((f.brs ? CANFD_BRS : 0) | (f.esi ? CANFD_ESI : 0));
  std::memcpy(k->data, f.data.data(), f.len);
}

void from_kernel(const canfd_frame& k, bool fd, CanFrame* f) {
  *f = CanFrame{};
  f->error = k.can_id & CAN_ERR_FLAG;
  f->extended = !f->error && (k.can_id & CAN_EFF_FLAG);
  f->rtr = !f->error && (k.can_id & CAN_RTR_FLAG);
  f->id = k.can_id & (f->extended || f->error ? CAN_EFF_MASK : CAN_SFF_MASK);
  f->fd = fd;
  if (fd) {
    f->brs = k.flags & CANFD_BRS;
    f->esi = k.flags & CANFD_ESI;
  }
  f->len = static_cast<uint8_t>(
      k.len > (fd ? CANFD_MAX_DLEN : CAN_MAX_DLEN) ? (fd ? CANFD_MAX_DLEN : CAN_MAX_DLEN) : k.len);
  std::memcpy(f->data.data(), k.data, f->len);
}

}  // namespace

uint64_t realtime_now_us() {
  return clock_us(CLOCK_REALTIME);
}
uint64_t monotonic_now_us() {
  return clock_us(CLOCK_MONOTONIC);
}

BusErrorEvent decode_error_frame(const CanFrame& f) {
  BusErrorEvent e;
  const uint32_t cls = f.id;
  e.bus_off = cls & CAN_ERR_BUSOFF;
  e.restarted = cls & CAN_ERR_RESTARTED;
  e.tx_timeout = cls & CAN_ERR_TX_TIMEOUT;
  e.lost_arbitration = cls & CAN_ERR_LOSTARB;
  e.protocol_violation = cls & CAN_ERR_PROT;
  e.no_ack = cls & CAN_ERR_ACK;
  e.transceiver = cls & CAN_ERR_TRX;
  if (cls & CAN_ERR_CRTL) {
    const uint8_t c = f.data[1];
    e.error_passive = c & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE);
    e.error_warning = c & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING);
    e.rx_overflow = c & (CAN_ERR_CRTL_RX_OVERFLOW | CAN_ERR_CRTL_TX_OVERFLOW);
  }
#ifdef CAN_ERR_CNT
  if (cls & CAN_ERR_CNT) {
    e.tx_error_count = f.data[6];
    e.rx_error_count = f.data[7];
  }
#endif
  return e;
}

std::string describe_bus_error(const BusErrorEvent& e) {
  std::string s;
  auto add = [&](bool on, const char* what) {
    if (!on) return;
    if (!s.empty()) s += ", ";
    s += what;
  };
  add(e.bus_off, "bus-off");
  add(e.error_passive, "error-passive");
  add(e.error_warning, "error-warning");
  add(e.restarted, "restarted");
  add(e.rx_overflow, "controller-overflow");
  add(e.tx_timeout, "tx-timeout");
  add(e.lost_arbitration, "lost-arbitration");
  add(e.protocol_violation, "protocol-violation");
  add(e.no_ack, "no-ack");
  add(e.transceiver, "transceiver");
  if (e.tx_error_count || e.rx_error_count) {
    s += " tx=" + std::to_string(e.tx_error_count) + " rx=" + std::to_string(e.rx_error_count);
  }
  return s.empty() ? "error frame" : s;
}

Result<std::unique_ptr<SocketCanPort>> SocketCanPort::open(std::string_view ifname,
                                                           const SocketCanOptions& options) {
  const std::string name(ifname);
  if (name.empty() || name.size() >= IFNAMSIZ) {
    return make_error(ErrorCode::kInvalidArgument, "bad CAN interface name '" + name + "'");
  }
  std::unique_ptr<SocketCanPort> port(new SocketCanPort());
  port->name_ = name;
  port->tx_limit_ = options.tx_queue_frames > 0 ? options.tx_queue_frames : 1;
  port->tx_ring_.resize(port->tx_limit_);
  port->fd_ = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (port->fd_ < 0) {
    if (errno == EAFNOSUPPORT || errno == EPROTONOSUPPORT) {
      return make_error(
          ErrorCode::kUnsupported,
          "this kernel has no SocketCAN (CONFIG_CAN / can-raw missing): cannot open '" + name +
              "'; replay a candump log instead, or run in the CAN test VM (scripts/can_vm.sh)");
    }
    return errno_error("socket(PF_CAN) for '" + name + "'");
  }
  const int fd = port->fd_;

  ifreq ifr{};
  std::memcpy(ifr.ifr_name, name.c_str(), name.size() + 1);
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) {
    return make_error(ErrorCode::kNotFound, "no CAN interface '" + name +
                                                "' (see `ip link show`): " + std::strerror(errno));
  }
  port->ifindex_ = ifr.ifr_ifindex;
  if (::ioctl(fd, SIOCGIFMTU, &ifr) < 0) return errno_error("SIOCGIFMTU on '" + name + "'");
  const bool iface_fd = ifr.ifr_mtu == static_cast<int>(CANFD_MTU);
  if (ifr.ifr_mtu != static_cast<int>(CANFD_MTU) && ifr.ifr_mtu != static_cast<int>(CAN_MTU)) {
    return make_error(
        ErrorCode::kUnsupported,
        "'" + name + "' has MTU " + std::to_string(ifr.ifr_mtu) + ": not a CAN interface");
  }
  if (options.fd && iface_fd) {
    const int on = 1;
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) < 0) {
      return errno_error("CAN_RAW_FD_FRAMES on '" + name + "'");
    }
    port->fd_enabled_ = true;
  }

  if (!options.filters.empty()) {
    std::vector<can_filter> kf;
    for (const CanIdFilter& f : options.filters)
      kf.push_back({f.id, f.mask | CAN_EFF_FLAG | CAN_RTR_FLAG});
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, kf.data(),
                     static_cast<socklen_t>(kf.size() * sizeof(can_filter))) < 0) {
      return errno_error("CAN_RAW_FILTER on '" + name + "'");
    }
  }
  if (options.error_frames) {
    const can_err_mask_t mask = CAN_ERR_MASK;
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &mask, sizeof mask) < 0) {
      return errno_error("CAN_RAW_ERR_FILTER on '" + name + "'");
    }
  }
  if (options.receive_own) {
    const int on = 1;
    ::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_RECV_OWN_MSGS, &on, sizeof on);
  }
  {
    const int on = 1;
    if (::setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on) < 0) {
      return errno_error("SO_RXQ_OVFL on '" + name + "'");
    }
  }
  {
    const int ts_flags = SOF_TIMESTAMPING_RX_SOFTWARE | SOF_TIMESTAMPING_SOFTWARE |
                         SOF_TIMESTAMPING_RX_HARDWARE | SOF_TIMESTAMPING_RAW_HARDWARE;
    if (::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPING, &ts_flags, sizeof ts_flags) < 0) {
      const int on = 1;
      ::setsockopt(fd, SOL_SOCKET, SO_TIMESTAMP, &on, sizeof on);  // older kernels: best effort
    }
  }
  if (options.rcvbuf_bytes > 0) {
    ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &options.rcvbuf_bytes, sizeof options.rcvbuf_bytes);
  }

  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = port->ifindex_;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
    return errno_error("bind to '" + name + "'");
  }
  return port;
}

std::unique_ptr<SocketCanPort> SocketCanPort::adopt_for_testing(int fd, std::string name,
                                                                bool fd_enabled,
                                                                std::size_t tx_queue_frames) {
  std::unique_ptr<SocketCanPort> port(new SocketCanPort());
  port->fd_ = fd;
  port->name_ = std::move(name);
  port->fd_enabled_ = fd_enabled;
  port->tx_limit_ = tx_queue_frames > 0 ? tx_queue_frames : 1;
  port->tx_ring_.resize(port->tx_limit_);
  return port;
}

SocketCanPort::~SocketCanPort() {
  if (fd_ >= 0) ::close(fd_);
}

Status SocketCanPort::write_now(const CanFrame& frame, bool* would_block) {
  *would_block = false;
  canfd_frame k;
  to_kernel(frame, &k);
  const std::size_t size = frame.fd ? CANFD_MTU : CAN_MTU;
  const ssize_t n = ::write(fd_, &k, size);
  if (n == static_cast<ssize_t>(size)) {
    ++stats_.tx_frames;
    return Status::Ok();
  }
  if (n < 0 && (errno == ENOBUFS || errno == EAGAIN)) {
    *would_block = true;
    return Status::Ok();
  }
  if (n >= 0) return make_error(ErrorCode::kIo, "short write on '" + name_ + "'");
  return errno_error("write to '" + name_ + "'");
}

Status SocketCanPort::send(const CanFrame& frame) {
  if (frame.fd && !fd_enabled_) {
    return make_error(ErrorCode::kUnsupported,
                      "'" + name_ +
                          "' is not in CAN FD mode (MTU 16): cannot send an FD frame; "
                          "use classic frames or `ip link set " +
                          name_ + " mtu 72`");
  }
  if (frame.len > (frame.fd ? kFdMaxLen : kClassicMaxLen)) {
    return make_error(ErrorCode::kInvalidArgument,
                      "frame length " + std::to_string(frame.len) + " too long");
  }
  flush();  // keep order: older queued frames first
  if (tx_count_ == 0) {
    bool would_block = false;
    Status s = write_now(frame, &would_block);
    if (!s.ok()) ++stats_.tx_dropped;
    if (!s.ok() || !would_block) return s;
  }
  if (tx_count_ >= tx_limit_) {
    ++stats_.tx_dropped;
    return make_error(ErrorCode::kUnavailable, "transmit queue of '" + name_ + "' full (" +
                                                   std::to_string(tx_limit_) +
                                                   " frames): frame dropped");
  }
  tx_ring_[(tx_head_ + tx_count_) % tx_limit_] = frame;
  ++tx_count_;
  ++stats_.tx_queued;
  return Status::Ok();
}

Status SocketCanPort::send_blocking(const CanFrame& frame, int timeout_ms) {
  const uint64_t deadline = monotonic_now_us() + static_cast<uint64_t>(timeout_ms) * 1000u;
  Status s = send(frame);
  if (!s.ok()) return s;
  while (tx_count_ > 0) {
    const uint64_t now = monotonic_now_us();
    if (now >= deadline) {
      return make_error(ErrorCode::kUnavailable,
                        "'" + name_ + "' still busy after " + std::to_string(timeout_ms) + " ms");
    }
    pollfd p{fd_, POLLOUT, 0};
    // A full qdisc does not always wake POLLOUT on CAN sockets: wait in short steps.
    ::poll(&p, 1, 1);
    flush();
  }
  return Status::Ok();
}

std::size_t SocketCanPort::flush() {
  while (tx_count_ > 0) {
    bool would_block = false;
    Status s = write_now(tx_ring_[tx_head_], &would_block);
    if (would_block) break;
    if (!s.ok()) {
      // A hard write error on a queued frame: counted, reported once, not retried.
      ++stats_.tx_dropped;
      tx_error_ = s.error();
      tx_error_pending_ = true;
    }
    tx_head_ = (tx_head_ + 1) % tx_limit_;
    --tx_count_;
  }
  return tx_count_;
}

bool SocketCanPort::take_tx_error(Error* error) {
  if (!tx_error_pending_) return false;
  *error = tx_error_;
  tx_error_pending_ = false;
  return true;
}

SocketCanPort::RecvStatus SocketCanPort::receive(CanFrame* frame, RxMeta* meta) {
  canfd_frame k{};
  iovec iov{&k, sizeof k};
  alignas(cmsghdr) char control[CMSG_SPACE(sizeof(scm_timestamping)) + CMSG_SPACE(sizeof(timeval)) +
                                CMSG_SPACE(sizeof(uint32_t)) + 64];
  msghdr msg{};
  msg.msg_iov = &iov;
  msg.msg_iovlen = 1;
  msg.msg_control = control;
  msg.msg_controllen = sizeof control;
  const ssize_t n = ::recvmsg(fd_, &msg, MSG_DONTWAIT);
  if (n < 0) {
    if (errno == EAGAIN || errno == EWOULDBLOCK) return RecvStatus::kNoFrame;
    error_ = errno_error("read from '" + name_ + "'");
    return RecvStatus::kError;
  }
  if (n != static_cast<ssize_t>(CAN_MTU) && n != static_cast<ssize_t>(CANFD_MTU)) {
    error_ =
        make_error(ErrorCode::kIo, "'" + name_ + "' gave a " + std::to_string(n) + "-byte frame");
    return RecvStatus::kError;
  }
  from_kernel(k, n == static_cast<ssize_t>(CANFD_MTU), frame);

  meta->source = TimestampSource::kUserspace;
  meta->timestamp_us = 0;
  for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
    if (c->cmsg_level != SOL_SOCKET) continue;
    if (c->cmsg_type == SO_TIMESTAMPING) {
      scm_timestamping ts;
      std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
      if (ts.ts[2].tv_sec || ts.ts[2].tv_nsec) {
        meta->timestamp_us = static_cast<uint64_t>(ts.ts[2].tv_sec) * 1000000u +
                             static_cast<uint64_t>(ts.ts[2].tv_nsec) / 1000u;
        meta->source = TimestampSource::kHardware;
      } else if (ts.ts[0].tv_sec || ts.ts[0].tv_nsec) {
        meta->timestamp_us = static_cast<uint64_t>(ts.ts[0].tv_sec) * 1000000u +
                             static_cast<uint64_t>(ts.ts[0].tv_nsec) / 1000u;
        meta->source = TimestampSource::kKernelSoftware;
      }
    } else if (c->cmsg_type == SO_TIMESTAMP) {
      timeval tv;
      std::memcpy(&tv, CMSG_DATA(c), sizeof tv);
      meta->timestamp_us =
          static_cast<uint64_t>(tv.tv_sec) * 1000000u + static_cast<uint64_t>(tv.tv_usec);
      meta->source = TimestampSource::kKernelSoftware;
    } else if (c->cmsg_type == SO_RXQ_OVFL) {
      uint32_t drops;
      std::memcpy(&drops, CMSG_DATA(c), sizeof drops);
      // The kernel reports a running total per socket; count what is new since last time.
      stats_.rx_kernel_drops += drops - last_drop_counter_;
      last_drop_counter_ = drops;
    }
  }
  if (meta->timestamp_us == 0) meta->timestamp_us = realtime_now_us();

  ++stats_.rx_frames;
  if (frame->error) {
    ++stats_.error_frames;
    const BusErrorEvent e = decode_error_frame(*frame);
    stats_.bus_off += e.bus_off;
    stats_.error_passive += e.error_passive;
    stats_.restarted += e.restarted;
  }
  return RecvStatus::kFrame;
}

CanPoller::CanPoller() : epfd_(::epoll_create1(EPOLL_CLOEXEC)) {}
CanPoller::~CanPoller() {
  if (epfd_ >= 0) ::close(epfd_);
}

Status CanPoller::add(SocketCanPort* port) {
  if (epfd_ < 0) return errno_error("epoll_create1");
  epoll_event ev{};
  ev.events = EPOLLIN;
  ev.data.u64 = ports_.size();
  if (::epoll_ctl(epfd_, EPOLL_CTL_ADD, port->fd(), &ev) < 0)
    return errno_error("epoll_ctl add " + port->name());
  ports_.push_back(port);
  return Status::Ok();
}

Result<std::size_t> CanPoller::poll(int timeout_ms, const FrameHandler& on_frame,
                                    const ErrorHandler& on_error) {
  bool pending = false;
  Error tx_error;
  for (SocketCanPort* p : ports_) {
    pending |= p->flush() > 0;
    if (p->take_tx_error(&tx_error) && on_error) on_error(*p, tx_error);
  }
  if (pending && (timeout_ms < 0 || timeout_ms > 1)) timeout_ms = 1;  // retry queued sends soon

  epoll_event events[16];
  const int n = ::epoll_wait(epfd_, events, 16, timeout_ms);
  if (n < 0) {
    if (errno == EINTR) return std::size_t{0};
    return errno_error("epoll_wait");
  }
  std::size_t delivered = 0;
  for (int i = 0; i < n; ++i) {
    SocketCanPort& port = *ports_[events[i].data.u64];
    CanFrame frame;
    RxMeta meta;
    // Drain up to a bound so one busy interface cannot starve the others.
    for (int k = 0; k < 256; ++k) {
      const auto st = port.receive(&frame, &meta);
      if (st == SocketCanPort::RecvStatus::kNoFrame) break;
      if (st == SocketCanPort::RecvStatus::kError) {
        if (on_error) on_error(port, port.error());
        break;
      }
      ++delivered;
      on_frame(port, frame, meta);
    }
  }
  return delivered;
}

}  // namespace skinbus::bus
