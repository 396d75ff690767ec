// The SocketCAN transport's own logic, on any kernel: error-frame decoding, and the bounded
// transmit queue behind a full socket (a datagram socketpair stands in for the CAN socket, so
// EAGAIN happens for real). Real CAN sockets are tested in the VM (tests/kernel/).
#include "skinbus/bus/socketcan.h"

#include <gtest/gtest.h>
#include <linux/can.h>
#include <sys/socket.h>
#include <unistd.h>

namespace skinbus::bus {
namespace {

TEST(BusErrorTest, DecodesControllerEvents) {
  CanFrame f;
  f.error = true;
  f.len = 8;
  f.id = 0x100;  // CAN_ERR_RESTARTED
  EXPECT_TRUE(decode_error_frame(f).restarted);
  EXPECT_EQ(describe_bus_error(decode_error_frame(f)), "restarted");
  f.id = 0x004;             // CAN_ERR_CRTL
  f.data[1] = 0x04 | 0x10;  // RX warning, RX passive
  const BusErrorEvent e = decode_error_frame(f);
  EXPECT_TRUE(e.error_warning);
  EXPECT_TRUE(e.error_passive);
  EXPECT_FALSE(e.bus_off);
  f.id = 0x020;  // CAN_ERR_ACK
  EXPECT_EQ(describe_bus_error(decode_error_frame(f)), "no-ack");
}

class QueueTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_EQ(socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK, 0, fds_), 0);
    const int small = 4096;
    setsockopt(fds_[0], SOL_SOCKET, SO_SNDBUF, &small, sizeof small);
    setsockopt(fds_[1], SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
    port_ = SocketCanPort::adopt_for_testing(fds_[0], "pair0", true, 8);
  }
  void TearDown() override { close(fds_[1]); }
  // Reads every record the peer holds; returns their first data bytes (the frame numbers).
  std::vector<int> drain() {
    std::vector<int> got;
    canfd_frame k;
    while (read(fds_[1], &k, sizeof k) > 0) got.push_back(k.data[0]);
    return got;
  }
  int fds_[2];
  std::unique_ptr<SocketCanPort> port_;
};

TEST_F(QueueTest, FullSocketQueuesThenDropsAndCountsNeverSilently) {
  CanFrame f;
  f.id = 0x185;
  f.fd = true;
  f.len = 64;
  int sent_ok = 0, refused = 0;
  for (int i = 0; i < 200; ++i) {
    f.data[0] = static_cast<uint8_t>(i);
    Status s = port_->send(f);
    if (s.ok()) {
      ++sent_ok;
    } else {
      EXPECT_EQ(s.error().code, ErrorCode::kUnavailable);
      EXPECT_NE(s.error().message.find("pair0"), std::string::npos);
      ++refused;
    }
  }
  const PortStats& st = port_->stats();
  EXPECT_EQ(port_->queued(), 8u);  // the ring is full
  EXPECT_EQ(st.tx_queued, 8u);
  EXPECT_EQ(st.tx_dropped, static_cast<uint64_t>(refused));
  EXPECT_GT(refused, 0);
  // Every frame is accounted for: written, waiting in the ring, or counted as dropped.
  EXPECT_EQ(st.tx_frames + port_->queued() + st.tx_dropped, 200u);

  // The peer reads; the ring drains in order after what the socket already held.
  std::vector<int> got = drain();
  EXPECT_EQ(port_->flush(), 0u);
  for (int x : drain()) got.push_back(x);
  ASSERT_EQ(got.size(), static_cast<std::size_t>(sent_ok));
  for (std::size_t i = 1; i < got.size(); ++i) EXPECT_LT(got[i - 1], got[i]);
  EXPECT_EQ(st.tx_frames, static_cast<uint64_t>(sent_ok));
}

TEST_F(QueueTest, WriteErrorsOfQueuedFramesAreReported) {
  CanFrame f;
  f.id = 0x185;
  f.len = 8;
  for (int i = 0; i < 100 && port_->queued() < 3; ++i) ASSERT_TRUE(port_->send(f).ok());
  ASSERT_GT(port_->queued(), 0u);
  close(fds_[1]);  // the peer goes away: writes now fail hard
  fds_[1] = -1;
  const uint64_t before = port_->stats().tx_dropped;
  port_->flush();
  EXPECT_EQ(port_->queued(), 0u);
  EXPECT_GT(port_->stats().tx_dropped, before);
  Error e;
  EXPECT_TRUE(port_->take_tx_error(&e));
  EXPECT_NE(e.message.find("pair0"), std::string::npos);
  EXPECT_FALSE(port_->take_tx_error(&e));
  fds_[1] = dup(0);  // keep TearDown's close harmless
}

}  // namespace
}  // namespace skinbus::bus
