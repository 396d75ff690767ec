// SocketCAN transport against a real kernel: vcan0 (CAN FD, MTU 72) and vcanc0 (classic,
// MTU 16), as scripts/can_vm.sh sets them up in its guest. Run by tests/kernel/run_in_guest.sh;
// on a kernel without CAN every test fails with the reason (it is never silently skipped).
#include "skinbus/bus/socketcan.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <random>

#include "skinbus/bus/codec.h"
#include "skinbus/bus/reassembler.h"
#include "testing.h"

namespace skinbus::bus {
namespace {

constexpr const char* kFdIface = "vcan0";
constexpr const char* kClassicIface = "vcanc0";

std::unique_ptr<SocketCanPort> open_or_die(const char* name, SocketCanOptions opts = {}) {
  auto p = SocketCanPort::open(name, opts);
  if (!p.ok()) {
    ADD_FAILURE() << p.error().to_string();
    return nullptr;
  }
  return std::move(p).value();
}

// Reads frames until `n` arrived or `timeout_ms` passed.
std::vector<CanFrame> receive_n(SocketCanPort& port, std::size_t n, int timeout_ms = 2000,
                                std::vector<RxMeta>* metas = nullptr) {
  CanPoller poller;
  EXPECT_TRUE(poller.add(&port).ok());
  std::vector<CanFrame> got;
  const uint64_t end = monotonic_now_us() + static_cast<uint64_t>(timeout_ms) * 1000;
  while (got.size() < n && monotonic_now_us() < end) {
    auto r = poller.poll(
        20,
        [&](SocketCanPort&, const CanFrame& f, const RxMeta& m) {
          got.push_back(f);
          if (metas) metas->push_back(m);
        },
        [&](SocketCanPort&, const Error& e) { ADD_FAILURE() << e.to_string(); });
    EXPECT_TRUE(r.ok());
  }
  return got;
}

TEST(SocketCanTest, FdSamplesCrossTheKernelIntact) {
  auto tx = open_or_die(kFdIface);
  auto rx = open_or_die(kFdIface);
  ASSERT_TRUE(tx && rx);
  EXPECT_TRUE(tx->fd_enabled());
  std::mt19937_64 rng(testing::test_seed("SocketCanTest.FdSamplesCrossTheKernelIntact"));
  std::vector<Message> sent;
  std::vector<CanFrame> frames;
  for (int i = 0; i < 50; ++i) {
    sent.push_back(testing::random_message(rng, MessageClass::kSample, FrameKind::kFd,
                                           static_cast<uint8_t>(1 + i % 5),
                                           static_cast<uint8_t>(i)));
    for (const CanFrame& f : testing::encode_frames(sent.back())) frames.push_back(f);
  }
  for (const CanFrame& f : frames) ASSERT_TRUE(tx->send_blocking(f, 1000).ok());
  std::vector<RxMeta> metas;
  const auto got = receive_n(*rx, frames.size(), 2000, &metas);
  ASSERT_EQ(got.size(), frames.size());
  Reassembler r;
  std::size_t k = 0;
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i], frames[i]);
    EXPECT_TRUE(got[i].fd && got[i].brs);
    const FeedResult res = r.feed(got[i], metas[i].timestamp_us);
    if (res.status == FeedStatus::kMessage) {
      EXPECT_EQ(*res.message, sent[k++]);
    }
  }
  EXPECT_EQ(k, sent.size());
  // Kernel receive timestamps, close to now.
  EXPECT_EQ(metas[0].source, TimestampSource::kKernelSoftware);
  const uint64_t now = realtime_now_us();
  EXPECT_LE(metas.back().timestamp_us, now);
  EXPECT_GT(metas.back().timestamp_us, now - 10'000'000);
  EXPECT_EQ(rx->stats().rx_kernel_drops, 0u);
}

TEST(SocketCanTest, ClassicInterfaceCarriesClassicAndRefusesFd) {
  auto tx = open_or_die(kClassicIface);
  auto rx = open_or_die(kClassicIface);
  ASSERT_TRUE(tx && rx);
  EXPECT_FALSE(tx->fd_enabled());
  std::mt19937_64 rng(7);
  const Message m =
      testing::random_message(rng, MessageClass::kHeartbeat, FrameKind::kClassic, 9, 1);
  const auto frames = testing::encode_frames(m);
  for (const CanFrame& f : frames) ASSERT_TRUE(tx->send(f).ok());
  const auto got = receive_n(*rx, frames.size());
  ASSERT_EQ(got.size(), frames.size());
  for (std::size_t i = 0; i < got.size(); ++i) EXPECT_EQ(got[i], frames[i]);

  const Status s = tx->send(testing::encode_frames(
      testing::random_message(rng, MessageClass::kSample, FrameKind::kFd, 9, 2))[0]);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, ErrorCode::kUnsupported);
  EXPECT_NE(s.error().message.find("mtu 72"), std::string::npos) << s.error().message;
}

TEST(SocketCanTest, FdSocketStillSendsClassicFrames) {
  auto tx = open_or_die(kFdIface);
  SocketCanOptions classic_only;
  classic_only.fd = false;
  auto rx = open_or_die(kFdIface, classic_only);  // a reader that did not ask for FD
  ASSERT_TRUE(tx && rx);
  CanFrame cmd =
      testing::encode_frames(Message{12, 7, FrameKind::kClassic, Command{Opcode::kTare, {}}})[0];
  CanFrame fd = cmd;
  fd.fd = true;
  ASSERT_TRUE(tx->send(fd).ok());   // not delivered to a classic-only socket
  ASSERT_TRUE(tx->send(cmd).ok());  // delivered
  const auto got = receive_n(*rx, 2, 500);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0], cmd);
}

TEST(SocketCanTest, FiltersSelectOnePatchOrOneClass) {
  auto tx = open_or_die(kFdIface);
  SocketCanOptions node3;
  node3.filters = {filter_for_node(3)};
  SocketCanOptions samples;
  samples.filters = {filter_for_class(MessageClass::kSample)};
  auto rx_node = open_or_die(kFdIface, node3);
  auto rx_class = open_or_die(kFdIface, samples);
  ASSERT_TRUE(tx && rx_node && rx_class);
  std::mt19937_64 rng(8);
  int node3_frames = 0, sample_frames = 0;
  for (uint8_t node = 1; node <= 5; ++node) {
    for (MessageClass c : {MessageClass::kSample, MessageClass::kHeartbeat, MessageClass::kAck}) {
      for (const CanFrame& f :
           testing::encode_frames(testing::random_message(rng, c, FrameKind::kFd, node, 0))) {
        ASSERT_TRUE(tx->send_blocking(f, 1000).ok());
        node3_frames += node == 3;
        sample_frames += c == MessageClass::kSample;
      }
    }
  }
  const auto a = receive_n(*rx_node, static_cast<std::size_t>(node3_frames) + 1, 300);
  const auto b = receive_n(*rx_class, static_cast<std::size_t>(sample_frames) + 1, 300);
  EXPECT_EQ(a.size(), static_cast<std::size_t>(node3_frames));
  for (const CanFrame& f : a) EXPECT_EQ(can_id_node(f.id), 3);
  EXPECT_EQ(b.size(), static_cast<std::size_t>(sample_frames));
  for (const CanFrame& f : b)
    EXPECT_EQ(can_id_class(f.id), static_cast<uint8_t>(MessageClass::kSample));
}

// A receiver that does not read while its queue overflows: every frame is either delivered or
// counted as a kernel drop (SO_RXQ_OVFL); none vanishes silently. The kernel reports the drop
// count with the next frame that does get through, so one more frame follows the flood.
TEST(SocketCanTest, KernelDropsAreCounted) {
  auto tx = open_or_die(kFdIface);
  SocketCanOptions small;
  small.rcvbuf_bytes = 4096;
  auto rx = open_or_die(kFdIface, small);
  ASSERT_TRUE(tx && rx);
  const int n = 2000;
  CanFrame f =
      testing::encode_frames(Message{4, 0, FrameKind::kFd, Command{Opcode::kGetInfo, {}}})[0];
  for (int i = 0; i < n; ++i) {
    f.data[1] = static_cast<uint8_t>(i);
    ASSERT_TRUE(tx->send_blocking(f, 1000).ok());
  }
  auto got = receive_n(*rx, n, 300);  // drain what fitted
  EXPECT_LT(got.size(), static_cast<std::size_t>(n));
  ASSERT_TRUE(tx->send_blocking(f, 1000).ok());
  const auto last = receive_n(*rx, 1, 1000);
  ASSERT_EQ(last.size(), 1u);
  EXPECT_GT(rx->stats().rx_kernel_drops, 0u);
  EXPECT_EQ(got.size() + last.size() + rx->stats().rx_kernel_drops,
            static_cast<std::size_t>(n) + 1);
}

TEST(SocketCanTest, ErrorFramesAreSurfaced) {
  // vcan has no controller, so nothing raises real bus errors; a raw socket may still send a
  // frame with CAN_ERR_FLAG, which receivers with an error filter get as an error frame.
  auto tx = open_or_die(kFdIface);
  auto rx = open_or_die(kFdIface);
  ASSERT_TRUE(tx && rx);
  CanFrame err;
  err.error = true;
  err.id = 0x040 | 0x004;  // CAN_ERR_BUSOFF | CAN_ERR_CRTL
  err.len = 8;
  err.data[1] = 0x20;  // CAN_ERR_CRTL_TX_PASSIVE
  ASSERT_TRUE(tx->send(err).ok());
  const auto got = receive_n(*rx, 1, 500);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_TRUE(got[0].error);
  const BusErrorEvent e = decode_error_frame(got[0]);
  EXPECT_TRUE(e.bus_off);
  EXPECT_TRUE(e.error_passive);
  EXPECT_EQ(rx->stats().bus_off, 1u);
  EXPECT_EQ(rx->stats().error_passive, 1u);
  EXPECT_EQ(describe_bus_error(e), "bus-off, error-passive");
}

TEST(SocketCanTest, MissingInterfaceIsAClearError) {
  auto p = SocketCanPort::open("nocan7", {});
  ASSERT_FALSE(p.ok());
  EXPECT_EQ(p.error().code, ErrorCode::kNotFound);
  EXPECT_NE(p.error().message.find("nocan7"), std::string::npos);
  auto lo = SocketCanPort::open("lo", {});
  ASSERT_FALSE(lo.ok());
  EXPECT_NE(lo.error().message.find("not a CAN interface"), std::string::npos)
      << lo.error().message;
}

TEST(SocketCanTest, InterfaceDownAndUpAgain) {
  ASSERT_EQ(std::system("ip link add dev vcantmp type vcan && ip link set vcantmp mtu 72 up"), 0);
  auto tx = open_or_die("vcantmp");
  auto rx = open_or_die("vcantmp");
  ASSERT_TRUE(tx && rx);
  const CanFrame f =
      testing::encode_frames(Message{4, 0, FrameKind::kFd, Command{Opcode::kTare, {}}})[0];
  ASSERT_EQ(std::system("ip link set vcantmp down"), 0);
  const Status down = tx->send(f);
  EXPECT_FALSE(down.ok());
  if (!down.ok()) {
    EXPECT_NE(down.error().message.find("vcantmp"), std::string::npos);
  }
  ASSERT_EQ(std::system("ip link set vcantmp up"), 0);
  EXPECT_TRUE(tx->send(f).ok());
  // The reader sees the down event as a read error once, then frames again.
  std::vector<CanFrame> got;
  bool saw_error = false;
  CanPoller poller;
  ASSERT_TRUE(poller.add(rx.get()).ok());
  for (int i = 0; i < 20 && got.empty(); ++i) {
    auto r = poller.poll(
        20, [&](SocketCanPort&, const CanFrame& fr, const RxMeta&) { got.push_back(fr); },
        [&](SocketCanPort&, const Error&) { saw_error = true; });
    ASSERT_TRUE(r.ok());
  }
  EXPECT_TRUE(saw_error);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0], f);
  EXPECT_EQ(std::system("ip link del vcantmp"), 0);
}

}  // namespace
}  // namespace skinbus::bus
